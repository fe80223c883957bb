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

/// The layout family on a tiny setting (two layouts of the shipped family, two seeds), then `diagnose` and the
/// step ablations of `eval` on one of its checkpoints.
#[test]
fn family_writes_a_table_per_layout_and_the_verdicts() {
    let dir = tmp("family");
    let cfg = tiny_config(&dir);
    let layouts = dir.join("layouts");
    std::fs::create_dir_all(&layouts).unwrap();
    for name in ["three_passages", "four_passages"] {
        let src = format!("{}/../configs/nav2d_family/{name}.toml", env!("CARGO_MANIFEST_DIR"));
        std::fs::copy(src, layouts.join(format!("{name}.toml"))).unwrap();
    }
    let out = mars(&[
        "family",
        "--out",
        dir.to_str().unwrap(),
        "--config",
        cfg.to_str().unwrap(),
        "--layouts",
        layouts.to_str().unwrap(),
        "--seeds",
        "2",
        "--demos",
        "6",
        "--epochs",
        "1",
        "--rollouts",
        "2",
        "--jobs",
        "2",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let md = std::fs::read_to_string(dir.join("family.md")).unwrap();
    for want in ["## three_passages", "## four_uneven_passages", "| mars |", "| fm |", "MARS mean K ≤ 3"] {
        assert!(md.contains(want), "family.md lacks {want:?}:\n{md}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("family.json")).unwrap()).unwrap();
    assert_eq!(json.as_array().map(Vec::len), Some(2), "one result per layout");
    let run = dir.join("three_passages/seed1");
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("mars/policy.json")).unwrap()).unwrap();
    let k_full_w = meta["model"]["k_full_w"].as_f64().unwrap();
    assert!(k_full_w > 0.0 && k_full_w < 1.0, "the calibrated K(w) scale is saved with the checkpoint: {k_full_w}");

    let layout = layouts.join("three_passages.toml");
    let (ckpt, layout) = (run.join("mars"), layout.to_str().unwrap().to_string());
    let out = mars(&[
        "diagnose",
        "--checkpoint",
        ckpt.to_str().unwrap(),
        "--demos",
        run.join("demos.json").to_str().unwrap(),
        "--layout",
        &layout,
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("| entry_gate |"));
    for ablation in [["--steps", "3"], ["--k-full-w", "0.5"]] {
        let args = ["eval", "--checkpoint", ckpt.to_str().unwrap(), "--layout", &layout, "--rollouts", "2"];
        let out = mars(&[&args[..], &ablation[..]].concat());
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
    let forced: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(ckpt.join("eval_k3.json")).unwrap()).unwrap();
    assert_eq!(forced["mean_k"].as_f64(), Some(3.0), "--steps 3 integrates with exactly 3 steps");
    assert!(ckpt.join("eval_kfull0.5.json").exists());
    let out = mars(&["eval", "--checkpoint", ckpt.to_str().unwrap(), "--layout", &layout, "--k-full-w", "0"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("--k-full-w"));
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
