//! `mars-hil faults` in short, as CI runs it: marsd killed or stopped at random moments of Pick Cup on the mock HAL
//! and on franka-sim, each trial judged by `mars-checker` (its own program; checker/tests/checker.rs shows it
//! catching out-of-limit streams). The full set is `mars-hil faults` with its default 100 trials per backend.

use std::path::{Path, PathBuf};
use std::process::Command;

fn root() -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/..")).canonicalize().expect("workspace root")
}

/// franka-sim serves one client on fixed ports: the lock hil/tests/franka_sim.rs and hal/tests take too. (The
/// real-time rig lock is taken by the fault runner itself, a process of its own.)
fn franka_sim_lock() -> std::fs::File {
    let path = std::env::temp_dir().join("mars-franka-sim.lock");
    let file = std::fs::OpenOptions::new().create(true).truncate(false).write(true).open(&path).unwrap();
    file.lock().unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    file
}

#[test]
fn marsd_killed_or_stopped_mid_episode_leaves_the_arm_within_limits_on_both_backends() {
    let checker = Path::new(env!("CARGO_BIN_EXE_mars-hil")).with_file_name("mars-checker");
    assert!(
        checker.exists(),
        "{} is missing: `cargo test --workspace` builds it (the mars-checker crate's tests need it), or \
         `cargo build -p mars-checker`",
        checker.display()
    );
    let installed = Command::new(root().join(".ci/franka-sim-venv")).current_dir(root()).status().unwrap();
    assert!(installed.success(), ".ci/franka-sim-venv failed");
    let _sim = franka_sim_lock();
    let out = tempfile::tempdir().unwrap();
    // Seed 0's first four trials: SIGSTOP 9 ms, SIGSTOP 232 ms, SIGKILL, SIGSTOP 43 ms (both kinds, a stop shorter
    // and stops longer than the HAL's 20 ms command timeout).
    let run = Command::new(env!("CARGO_BIN_EXE_mars-hil"))
        .args(["faults", "--trials", "4", "--seed", "0", "--out"])
        .arg(out.path())
        .arg("--checker")
        .arg(&checker)
        .current_dir(root())
        .output()
        .unwrap();
    let stdout = String::from_utf8_lossy(&run.stdout);
    let stderr = String::from_utf8_lossy(&run.stderr);
    if run.status.code() != Some(0) {
        // Each trial's recording, logs and verdict stay for a look.
        let kept = out.keep();
        panic!("exit status {:?}; the trials are kept in {}:\n{stdout}\n{stderr}", run.status.code(), kept.display());
    }
    for backend in ["mock", "franka-sim"] {
        for fault in ["SIGKILL", "SIGSTOP"] {
            let row = stdout
                .lines()
                .find(|l| l.starts_with(&format!("| {backend} | {fault} |")))
                .unwrap_or_else(|| panic!("no row for {backend} {fault}:\n{stdout}"));
            let cells: Vec<&str> = row.split('|').map(str::trim).collect();
            // | backend | fault | trials | faults sent | violations | reflexes | …
            assert!(cells[4].parse::<u32>().unwrap() > 0, "no fault sent: {row}");
            assert_eq!((cells[5], cells[6]), ("0", "0"), "violations, reflexes: {row}");
        }
    }
    assert!(stdout.contains("not clean: none"), "{stdout}");
    // Every trial left a recording the checker judged.
    let recordings = std::fs::read_dir(out.path().join("mock"))
        .unwrap()
        .flatten()
        .filter(|e| e.path().join("stream.csv").exists())
        .count();
    assert_eq!(recordings, 5, "the baseline and 4 trials");
}
