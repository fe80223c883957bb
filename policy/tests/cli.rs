//! The `mars` binary end to end on a tiny setting, and its refusal of bad input before any work is done.

use std::path::{Path, PathBuf};
use std::process::Command;

fn mars(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_mars"))
        .args(args)
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
        .env("RAYON_NUM_THREADS", "1")
        .output()
        .expect("mars runs")
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mars-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn tiny_config(dir: &Path) -> PathBuf {
    let text = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/policy.toml")).unwrap();
    let text = text
        .replace("dit_width = 128", "dit_width = 16")
        .replace("dit_depth = 4", "dit_depth = 1")
        .replace("hidden = 128", "hidden = 16")
        .replace("obs_embed_dim = 128", "obs_embed_dim = 16")
        .replace("scheduler_hidden = 128", "scheduler_hidden = 16")
        .replace("knn_m = 20", "knn_m = 4");
    let path = dir.join("tiny.toml");
    std::fs::write(&path, text).unwrap();
    path
}

#[test]
fn benchmark_writes_results_checkpoints_and_plots() {
    let dir = tmp("bench");
    let cfg = tiny_config(&dir);
    let out = mars(&[
        "benchmark",
        "--out",
        dir.to_str().unwrap(),
        "--config",
        cfg.to_str().unwrap(),
        "--demos",
        "8",
        "--epochs",
        "1",
        "--rollouts",
        "3",
        "--policies",
        "mars,fm",
        "--jobs",
        "2",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let md = std::fs::read_to_string(dir.join("results.md")).unwrap();
    assert!(md.contains("| mars |") && md.contains("| fm |"), "{md}");
    for f in [
        "demos.png",
        "losses.png",
        "k_per_step.png",
        "rollouts_mars.png",
        "rollouts_fm.png",
        "mars/model.safetensors",
        "fm/eval.json",
    ] {
        assert!(dir.join(f).metadata().map(|m| m.len() > 0).unwrap_or(false), "missing {f}");
    }
    // `eval` on the written checkpoint works on its own too.
    let out = mars(&["eval", "--checkpoint", dir.join("mars").to_str().unwrap(), "--rollouts", "2"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("| mars |"));
}

#[test]
fn bad_input_fails_with_a_clear_message_and_nonzero_exit() {
    let dir = tmp("bad");
    let bad_cfg = dir.join("bad.toml");
    std::fs::write(&bad_cfg, "kind = \"mars\"\n[model]\nobs_dim = 0\n").unwrap();
    let cases: Vec<(Vec<String>, &str)> = vec![
        (
            vec!["train".into(), "--config".into(), bad_cfg.display().to_string(), "--demos".into(), "x.json".into()],
            "bad.toml",
        ),
        (vec!["train".into(), "--demos".into(), "/nonexistent/demos.json".into()], "/nonexistent/demos.json"),
        (vec!["eval".into(), "--checkpoint".into(), "/nonexistent/ckpt".into()], "/nonexistent/ckpt"),
        (vec!["demos".into(), "--layout".into(), "/nonexistent/layout.toml".into()], "/nonexistent/layout.toml"),
        (
            vec!["demos".into(), "--n".into(), "0".into(), "--out".into(), dir.join("d.json").display().to_string()],
            "--n",
        ),
    ];
    for (args, needle) in cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = mars(&args);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} succeeded");
        assert!(err.contains("error:") && err.contains(needle), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    }
}
