//! The `mars` binary end to end on a tiny setting, and its refusal of bad input before any work is done.

mod mars_cli;

use mars_cli::mars;
use mars_policy::config::PolicyConfig;
use std::path::{Path, PathBuf};

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("mars-cli-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// The shipped config shrunk to train in seconds, written to `dir` for the command line.
fn tiny_config(dir: &Path) -> PathBuf {
    let shipped = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/policy.toml"));
    let mut cfg = PolicyConfig::load(shipped).unwrap().shrunk(16, 1);
    cfg.train.knn_m = 4;
    let path = dir.join("tiny.toml");
    std::fs::write(&path, cfg.to_toml()).unwrap();
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
    assert!(md.contains("95 % intervals (percentile bootstrap over this run's rollouts"), "{md}");
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
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("| mars |") && stdout.contains("2 rollouts: success "), "{stdout}");
    let intervals: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("mars/eval_intervals.json")).unwrap()).unwrap();
    assert_eq!(intervals["rollouts"].as_u64(), Some(2));
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
    // Its command line names every input, so that rerunning it reads the same files.
    let command = format!("`mars family --config {} --layouts {} --seeds 2", cfg.display(), layouts.display());
    for want in ["## three_passages", "## four_uneven_passages", "| mars |", "| fm |", "MARS mean K ≤ 3", &command] {
        assert!(md.contains(want), "family.md lacks {want:?}:\n{md}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("family.json")).unwrap()).unwrap();
    assert_eq!(json.as_array().map(Vec::len), Some(2), "one result per layout");
    let run = dir.join("three_passages/seed1");
    // The layouts × seeds ran two at a time, and each benchmark says its latencies were not measured alone.
    let results = std::fs::read_to_string(run.join("results.md")).unwrap();
    assert!(results.contains("beside other layouts or seeds"), "{results}");
    let command = format!(
        "`mars benchmark --config {} --layout {}",
        cfg.display(),
        layouts.join("three_passages.toml").display()
    );
    assert!(results.contains(&command), "{results}");
    let meta: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("mars/policy.json")).unwrap()).unwrap();
    let k_full_w = meta["model"]["k_full_w"].as_f64().unwrap();
    assert!(k_full_w > 0.0 && k_full_w < 1.0, "the calibrated K(w) scale is saved with the checkpoint: {k_full_w}");

    // --resume: a third seed adds to the two, whose checkpoints are kept (still evaluated) and not retrained;
    // other demos under the same folder are refused, not silently mixed with the kept checkpoints.
    let weights = |seed: u32| std::fs::read(dir.join(format!("three_passages/seed{seed}/mars/model.safetensors")));
    let seed0 = weights(0).unwrap();
    let family = |seeds: &str, demos: &str, extra: &[&str]| {
        let (d, c, l) = (dir.to_str().unwrap(), cfg.to_str().unwrap(), layouts.to_str().unwrap());
        let args = ["family", "--out", d, "--config", c, "--layouts", l, "--seeds", seeds, "--demos", demos];
        mars(&[&args[..], &["--epochs", "1", "--rollouts", "2", "--jobs", "2", "--resume"][..], extra].concat())
    };
    let out = family("3", "6", &[]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let kept = String::from_utf8_lossy(&out.stdout).matches("with this configuration, kept").count();
    assert_eq!(kept, 2 * 2 * 2, "layouts × old seeds × policies kept");
    assert_eq!(weights(0).unwrap(), seed0, "a kept checkpoint is not rewritten");
    assert!(weights(2).is_ok(), "the new seed is trained");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("family.json")).unwrap()).unwrap();
    assert_eq!(json[0]["policies"][0]["per_seed"].as_array().map(Vec::len), Some(3), "three seeds aggregated");
    let demos0 = std::fs::read(dir.join("three_passages/seed0/demos.json")).unwrap();
    let out = family("3", "7", &[]);
    assert!(!out.status.success(), "other demos under --resume must be refused");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("--resume") && err.contains("demos.json"), "{err}");
    assert_eq!(std::fs::read(dir.join("three_passages/seed0/demos.json")).unwrap(), demos0, "refused: nothing lost");
    // --k-full-w with --resume: the very same checkpoints judged under the paper's K(w), written beside their own
    // evaluation, and the option in the command line.
    let out = family("3", "6", &["--k-full-w", "1"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(weights(0).unwrap(), seed0, "--k-full-w evaluates, it does not retrain");
    assert!(dir.join("three_passages/seed0/mars/eval_kfull1.json").exists());
    assert!(std::fs::read_to_string(dir.join("family.md")).unwrap().contains("--k-full-w 1 --policies"));
    let out = family("3", "6", &["--k-full-w", "1.5"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("--k-full-w"));

    // diagnose-family: every layout, policy and seed at the fork, beside its rollouts, with the verdicts.
    let out = mars(&["diagnose-family", dir.to_str().unwrap(), "--layouts", layouts.to_str().unwrap(), "--draws", "2"]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let md = std::fs::read_to_string(dir.join("diagnose_family.md")).unwrap();
    for want in ["| three_passages (", "| four_uneven_passages (", "| fm |", "rollouts − fork", "MARS − FM = "] {
        assert!(md.contains(want), "diagnose_family.md lacks {want:?}:\n{md}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("diagnose_family.json")).unwrap()).unwrap();
    for layout in json.as_array().unwrap() {
        for policy in layout["policies"].as_array().unwrap() {
            assert_eq!(policy["fork_tv"].as_array().map(Vec::len), Some(3), "every seed: {policy}");
        }
    }
    let out = mars(&["diagnose-family", layouts.to_str().unwrap()]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("family.json"));

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
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(stdout.contains("| entry_gate |") && stdout.contains("Heading of the first chunk past the entry gate"));
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

/// The training-efficiency curves on a tiny setting: snapshots every epoch, each scored, the tables and plot.
#[test]
fn curve_scores_every_snapshot_and_writes_the_tables_and_plot() {
    let dir = tmp("curve");
    let cfg = tiny_config(&dir);
    let out = mars(&[
        "curve",
        "--out",
        dir.to_str().unwrap(),
        "--config",
        cfg.to_str().unwrap(),
        "--seeds",
        "2",
        "--demos",
        "6",
        "--epochs",
        "2",
        "--every",
        "1",
        "--episodes",
        "2",
        "--policies",
        "mars,fm",
        "--thresholds",
        "0,101",
        "--jobs",
        "2",
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let md = std::fs::read_to_string(dir.join("curves.md")).unwrap();
    for want in ["| 1 |", "| 2 |", "epochs to 0 % success", "| mars | 1.0 ± 0.0 (2/2 seeds) | not reached (0/2 seeds)"]
    {
        assert!(md.contains(want), "curves.md lacks {want:?}:\n{md}");
    }
    // The last quarter's success, γ and TV to the demos each as a mean with its interval over the two seeds.
    let mars_row = md.lines().find(|l| l.starts_with("| mars |")).unwrap();
    assert_eq!(mars_row.matches(" (").count(), 2 + 3, "{mars_row}");
    assert!(md.contains("TV to the demos over the last quarter"), "{md}");
    for seed in ["seed0", "seed1"] {
        for kind in ["mars", "fm"] {
            for epoch in ["epoch_0001", "epoch_0002"] {
                let score = dir.join(seed).join(kind).join("snapshots").join(epoch).join("score.json");
                assert!(score.exists(), "missing {}", score.display());
            }
        }
    }
    assert!(dir.join("curves.png").metadata().map(|m| m.len() > 0).unwrap_or(false));
    // Rescoring reuses the snapshots (no training, so no new weights) and refuses flags that do not match them.
    let weights = dir.join("seed0/mars/snapshots/epoch_0002/model.safetensors");
    let before = std::fs::metadata(&weights).unwrap().modified().unwrap();
    let common = ["--out", dir.to_str().unwrap(), "--config", cfg.to_str().unwrap(), "--seeds", "2", "--demos", "6"];
    let flags = ["--epochs", "2", "--every", "1", "--episodes", "3", "--policies", "mars,fm", "--rescore"];
    let out = mars(&[&["curve"][..], &common[..], &flags[..]].concat());
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(std::fs::metadata(&weights).unwrap().modified().unwrap(), before, "rescoring trained again");
    assert!(std::fs::read_to_string(dir.join("curves.md")).unwrap().contains("--rescore"));
    let flags = ["--epochs", "2", "--every", "2", "--policies", "mars,fm", "--rescore"];
    let out = mars(&[&["curve"][..], &common[..], &flags[..]].concat());
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("snapshots at epochs"));
    let out = mars(&["curve", "--out", dir.to_str().unwrap(), "--epochs", "2", "--every", "3"]);
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("--every"));
}

/// The curves with training in `mars train --snapshot-every` processes (how `mars-hil curve` trains): the same
/// snapshots and scores as in-process training, and a failing training is reported with its log.
#[test]
fn curve_trains_through_the_mars_binary_and_reports_its_failures() {
    use mars_policy::curve::{CurveOptions, Trainer, run};
    let dir = tmp("curve-cmd");
    let cfg = tiny_config(&dir);
    let task = mars_policy::cli::Nav2dCurve {
        layout: PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/nav2d.toml")),
        demos: 4,
        rollouts: 2,
        exec_horizon: mars_policy::cli::DEFAULT_EXEC_HORIZON,
    };
    let opts = CurveOptions {
        policies: vec![mars_policy::config::PolicyKind::Mars],
        seeds: 1,
        epochs: 2,
        every: 1,
        jobs: 1,
        thresholds: vec![0.0],
        eval_seed: 7,
        rescore: false,
    };
    let mars_bin = Trainer::Command(PathBuf::from(env!("CARGO_BIN_EXE_mars")));
    let by_cmd = run(&dir.join("cmd"), &cfg, &opts, &task, &mars_bin, "test").unwrap();
    let in_proc = run(&dir.join("in"), &cfg, &opts, &task, &Trainer::InProcess, "test").unwrap();
    for epoch in ["epoch_0001", "epoch_0002"] {
        let w = |root: &str| {
            std::fs::read(dir.join(root).join("seed0/mars/snapshots").join(epoch).join("model.safetensors")).unwrap()
        };
        assert_eq!(w("cmd"), w("in"), "{epoch}: the same seeded training either way");
    }
    let scores = |c: &[mars_policy::curve::PolicyCurve]| {
        c[0].points.iter().map(|p| (p.epoch, p.success_pct.mean, p.gamma.mean)).collect::<Vec<_>>()
    };
    assert_eq!(scores(&by_cmd), scores(&in_proc));
    assert!(dir.join("cmd/seed0/mars/train.log").exists());

    let broken = dir.join("broken.toml");
    let mut bad_lr = PolicyConfig::load(&cfg).unwrap();
    bad_lr.train.lr = -1.0;
    std::fs::write(&broken, bad_lr.to_toml()).unwrap();
    let err = run(&dir.join("bad"), &broken, &opts, &task, &mars_bin, "test").unwrap_err();
    assert!(format!("{err:#}").contains("train.lr"), "the config is checked before any training: {err:#}");
    let failing = Trainer::Command(PathBuf::from("/bin/false"));
    let err = run(&dir.join("fail"), &cfg, &opts, &task, &failing, "test").unwrap_err();
    assert!(format!("{err:#}").contains("train.log"), "a failed training points at its log: {err:#}");
}

/// Both FM ablations on a tiny setting over two seeds: one FM per value and seed, trained, rolled out, tabled
/// (mean ± std) and plotted; a knob's value actually reaches the trained checkpoint; `--resume` keeps every
/// training and gives the same table.
#[test]
fn ablate_trains_fm_per_value_and_seed_and_writes_the_table() {
    let dir = tmp("ablate");
    let cfg = tiny_config(&dir);
    for (knob, values, field) in [("source-std", "0,2", "source_std"), ("fm-lambda-rec", "0,1", "fm_lambda_rec")] {
        let out_dir = dir.join(knob);
        let args = ["--demos", "6", "--epochs", "1", "--rollouts", "2", "--jobs", "2", "--seeds", "2"];
        let base = ["ablate", "--knob", knob, "--values", values, "--config", cfg.to_str().unwrap()];
        let ablate =
            |extra: &[&str]| mars(&[&base[..], &["--out", out_dir.to_str().unwrap()], &args[..], extra].concat());
        let out = ablate(&[]);
        assert!(out.status.success(), "{knob}: {}", String::from_utf8_lossy(&out.stderr));
        let md = std::fs::read_to_string(out_dir.join("ablation.md")).unwrap();
        let setting = |l: &&str| l.starts_with("| std ") || l.starts_with("| λ_rec ");
        let (rows, paired): (Vec<&str>, Vec<&str>) = md.lines().filter(setting).partition(|l| l.contains(" ± "));
        assert_eq!(rows.len(), 2, "{md}");
        // The second value against the first, paired by seed: four differences, each with its verdict or none.
        assert_eq!(paired.len(), 1, "{md}");
        let judged = ["differ", "undecided", "(a seed with no successful rollout)"];
        assert_eq!(
            paired[0].split(" | ").filter(|c| judged.iter().any(|j| c.trim_end_matches(" |").ends_with(j))).count(),
            4,
            "{md}"
        );
        assert!(
            rows.iter()
                .all(|r| r.contains(" ± ") && r.trim_end_matches(" |").rsplit(" | ").next().unwrap().contains(", ")),
            "mean ± std and one success per seed:\n{md}"
        );
        // Success, γ and TV to the demos: each a mean with its 95 % interval over seeds.
        assert!(rows.iter().all(|r| r.matches('–').count() == 3), "intervals over seeds:\n{md}");
        assert!(out_dir.join("losses.png").exists());
        let last = values.split(',').next_back().unwrap();
        let meta: serde_json::Value = serde_json::from_str(
            &std::fs::read_to_string(out_dir.join("seed1").join(format!("{knob}_{last}")).join("policy.json")).unwrap(),
        )
        .unwrap();
        assert_eq!(meta["kind"], "fm");
        assert_eq!(meta["train"]["seed"], 1);
        let section = if field == "source_std" { "model" } else { "train" };
        assert!(meta[section][field].as_f64().is_some_and(|v| v > 0.0), "{knob}: {}", meta[section]);
        if knob == "source-std" {
            let out = ablate(&["--resume"]);
            assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
            assert_eq!(String::from_utf8_lossy(&out.stdout).matches(", kept").count(), 4, "2 values × 2 seeds kept");
            assert_eq!(
                std::fs::read_to_string(out_dir.join("ablation.md")).unwrap(),
                md,
                "kept, re-evaluated: same table"
            );
        }
    }
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
