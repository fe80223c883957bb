//! Pick Cup through marsd → mars-hal (fci backend) → franka-sim: the HIL demo on the other protocol, as a user
//! runs it (`mars-hil demo --backend franka-sim`), with the simulator's reflexes on (20 lost cycles, motion
//! limits). Task success, no reflex, and the robot's own control-success rate.

// The helpers are shared with the HIL tests; this file uses a few of them.
#[allow(unused_imports)]
mod common;

use std::process::Command;
use std::time::Duration;

use common::*;

/// The number after `name` in `text` (e.g. "min 0.970" → 0.97).
fn number_after(text: &str, name: &str) -> f64 {
    let rest = &text[text.find(name).unwrap_or_else(|| panic!("no {name:?} in:\n{text}")) + name.len()..];
    rest.split_whitespace()
        .next()
        .and_then(|w| w.trim_end_matches([',', ';']).parse().ok())
        .unwrap_or_else(|| panic!("no number after {name:?} in:\n{text}"))
}

#[test]
fn pick_cup_succeeds_through_the_fci_hal_on_franka_sim_with_no_reflex() {
    // franka-sim into .venv-sim/ (returns at once when installed).
    let installed = Command::new(root().join(".ci/franka-sim-venv")).current_dir(root()).status().unwrap();
    assert!(installed.success(), ".ci/franka-sim-venv failed");
    let _rt = rt_rig_lock();
    let logs = TempDir::new("franka-sim-demo");
    let robot = robot("fsdemo");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_mars-hil"));
    cmd.args(["demo", "--backend", "franka-sim", "--episodes", "2", "--robot", &robot])
        .arg("--out")
        .arg(logs.join("out"));
    let mut demo = spawn_named(cmd, "demo", &logs);
    let code = demo.exit_code(Duration::from_secs(240));
    let (out, err) = (demo.stdout_text(), demo.stderr_text());
    assert_eq!(code, 0, "{}", demo.logs());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(logs.join("out/summary.json")).unwrap()).unwrap();
    assert_eq!((summary["episodes"].as_u64(), summary["successes"].as_u64()), (Some(2), Some(2)), "{summary}");
    // The HAL's report (stdout): the robot's side.
    let robot_line = find_line(&out, &["robot 127.0.0.1:"]).unwrap_or_else(|| panic!("no robot line:\n{out}\n{err}"));
    eprintln!("{robot_line}");
    assert!(robot_line.contains(" 0 reflexes"), "{robot_line}");
    let rate = number_after(robot_line, "control success rate min");
    assert!(rate >= 0.95, "the robot's control command success rate fell to {rate}");
    assert!(find_line(&out, &["loop allocations after warm-up: 0 system-allocator calls"]).is_some(), "{out}");
}
