//! `marsd doctor` as a user runs it: it measures for the time asked, prints its measurements and a verdict, and
//! writes doctor.json with every field. No pass mark on the figures themselves: they are what this machine did
//! (the verdict's logic is unit-tested on synthetic machines in src/doctor.rs).

use std::path::Path;
use std::process::Command;
use std::time::{Duration, Instant};

// It runs a SCHED_FIFO thread on the servo core: one real-time rig at a time on this machine (see
// `mars_rt::rig_lock`).
use mars_runtime::rt::rig_lock::rt_rig_lock;

#[test]
fn marsd_doctor_measures_prints_a_verdict_and_writes_every_field() {
    let _rt = rt_rig_lock().expect("taking the real-time rig lock");
    let out = std::env::temp_dir().join(format!("mars-doctor-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out);
    let started = Instant::now();
    let o = Command::new(env!("CARGO_BIN_EXE_marsd"))
        .current_dir(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/..")))
        .args(["doctor", "--seconds", "1"])
        .env(mars_runtime::rt::rig_lock::HELD_BY_PARENT, std::process::id().to_string())
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let took = started.elapsed();
    let stdout = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{:?}\n{stdout}\n{}", o.status, String::from_utf8_lossy(&o.stderr));
    eprintln!("{stdout}");
    assert!(took >= Duration::from_secs(1), "measured for only {took:?}");
    let verdict = stdout.lines().find(|l| {
        ["good:", "expect missed servo periods", "expect occasional watchdog trips", "expect watchdog trips"]
            .iter()
            .any(|v| l.starts_with(&format!("doctor: {v}")))
    });
    assert!(verdict.is_some(), "no verdict line:\n{stdout}");
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("doctor.json")).unwrap()).unwrap();
    for field in [
        "/wakeups/seconds",
        "/wakeups/period_us",
        "/wakeups/priority",
        "/wakeups/core",
        "/wakeups/pin_error",
        "/wakeups/sched_fifo",
        "/wakeups/memory_locked",
        "/wakeups/wakeups",
        "/wakeups/missed_periods",
        "/wakeups/late_p50_us",
        "/wakeups/late_p99_us",
        "/wakeups/late_max_us",
        "/wakeups/steal_ms",
        "/machine/cpus",
        "/machine/rlimit_rtprio",
        "/machine/rlimit_memlock",
        "/machine/cap_sys_nice",
        "/machine/cap_ipc_lock",
        "/machine/preempt_rt",
        "/machine/kernel_version",
        "/machine/governors",
        "/machine/isolated",
        "/budget/period_ms",
        "/budget/max_state_gap_ms",
        "/budget/command_timeout_ms",
        "/verdict/level",
        "/verdict/expect",
        "/verdict/advice",
    ] {
        assert!(json.pointer(field).is_some(), "doctor.json has no {field}:\n{json:#}");
    }
    // Every period of the 1 kHz profile over 1 s, either a recorded wake-up or counted as missed (the last
    // wake-up may skip past the end).
    let woke = json["wakeups"]["wakeups"].as_u64().unwrap();
    let periods = woke + json["wakeups"]["missed_periods"].as_u64().unwrap();
    assert!(woke > 0 && periods >= 1000, "{json:#}");
    let (p50, p99, max) = (
        json["wakeups"]["late_p50_us"].as_f64().unwrap(),
        json["wakeups"]["late_p99_us"].as_f64().unwrap(),
        json["wakeups"]["late_max_us"].as_f64().unwrap(),
    );
    assert!(0.0 <= p50 && p50 <= p99 && p99 <= max, "{p50} {p99} {max}");
    let _ = std::fs::remove_dir_all(&out);
}
