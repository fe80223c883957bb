//! `mars-hil curve` on a tiny setting: Pick Cup demos per seed, training with snapshots, every snapshot rolled
//! out against the sim plant, the tables and the plot.

use std::path::PathBuf;
use std::process::Command;

use mars_policy::config::PolicyConfig;

fn repo(path: &str) -> PathBuf {
    PathBuf::from(concat!(env!("CARGO_MANIFEST_DIR"), "/..")).join(path)
}

#[test]
fn pick_cup_curve_scores_every_snapshot() {
    let dir = std::env::temp_dir().join(format!("mars-hil-curve-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    let mut tiny = PolicyConfig::load(&repo("configs/fr3_policy.toml")).unwrap().shrunk(16, 2);
    tiny.train.knn_m = 4;
    let cfg = dir.join("tiny.toml");
    std::fs::write(&cfg, tiny.to_toml()).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_mars-hil"))
        .current_dir(repo(""))
        .args(["curve", "--in-process", "--config", cfg.to_str().unwrap(), "--out", dir.to_str().unwrap()])
        .args(["--seeds", "2", "--demos", "4", "--epochs", "2", "--every", "1", "--episodes", "2"])
        .args(["--policies", "mars,fm", "--jobs", "2"])
        .output()
        .expect("mars-hil runs");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let md = std::fs::read_to_string(dir.join("curves.md")).unwrap();
    for want in ["fr3_pick_cup", "| 1 |", "| 2 |", "| mars |", "| fm |", "mars-hil curve --task"] {
        assert!(md.contains(want), "curves.md lacks {want:?}:\n{md}");
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(dir.join("curves.json")).unwrap()).unwrap();
    assert_eq!(json[1].as_array().map(Vec::len), Some(2 * 2 * 2), "seeds × policies × snapshots scored");
    // Each snapshot's grasp shares against its seed's demos (the expert balances them).
    for score in json[1].as_array().unwrap() {
        let tv = score["score"]["tv"].as_f64().unwrap_or_else(|| panic!("no TV to the demos' grasps: {score}"));
        assert!((0.0..=1.0).contains(&tv), "{score}");
    }
    assert!(dir.join("curves.png").metadata().map(|m| m.len() > 0).unwrap_or(false));
    std::fs::remove_dir_all(&dir).unwrap();
}
