//! The checker as a program: a recording that keeps the FR3's limits is clean (exit 0); each kind of deliberately
//! out-of-limit stream is caught with its reason (exit 1); input that cannot be judged is refused (exit 2).

use std::path::{Path, PathBuf};
use std::process::Command;

use mars_checker::stream::{Frame, HEADER, bits};

fn profile() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")
}

/// The profile's `home` (libfranka's example start pose), far from every limit.
fn home() -> [f64; 7] {
    let t: toml::Table = toml::from_str(&std::fs::read_to_string(profile()).unwrap()).unwrap();
    let v: Vec<f64> = t["home"].as_array().unwrap().iter().map(|x| x.as_float().unwrap()).collect();
    v.try_into().unwrap()
}

/// Frames at 1 kHz, one per position list, the arm followed (ACTIVE) and at the end held at rest.
fn frames(positions: &[[f64; 7]]) -> Vec<Frame> {
    let last = positions.len() - 1;
    positions
        .iter()
        .enumerate()
        .map(|(i, q)| Frame {
            recv_ns: 1_000_000 * i as u64,
            seq: i as u64 + 1,
            hal_ns: 1_000_000 * i as u64,
            session: 1,
            status: if i == last { bits::HOLDING | bits::AT_REST } else { bits::ACTIVE },
            q: q.to_vec(),
            ..Frame::default()
        })
        .collect()
}

/// A smooth move of joint `j` by `amplitude` and back, `q = home + A(1 − cos ωt)` over one period of `seconds`, then
/// 50 ms held.
fn smooth_move(j: usize, amplitude: f64, seconds: f64) -> Vec<[f64; 7]> {
    let n = (seconds * 1000.0) as usize;
    let w = 2.0 * std::f64::consts::PI / seconds;
    let mut out: Vec<[f64; 7]> = (0..=n)
        .map(|i| {
            let mut q = home();
            q[j] += amplitude * (1.0 - (w * i as f64 * 1e-3).cos());
            q
        })
        .collect();
    out.extend(std::iter::repeat_n(home(), 50));
    out
}

/// Runs `mars-checker check` on `frames`; (exit status, stdout + stderr).
fn check(name: &str, frames: &[Frame], extra: &[&str]) -> (i32, String) {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join(format!("{name}.csv"));
    let mut text = format!("{HEADER}\n");
    for f in frames {
        f.write_line(&mut text);
    }
    std::fs::write(&file, text).unwrap();
    check_file(&file, extra)
}

fn check_file(file: &Path, extra: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_mars-checker"))
        .arg("check")
        .arg(file)
        .arg("--profile")
        .arg(profile())
        .args(extra)
        .output()
        .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    (out.status.code().unwrap_or(-1), text)
}

#[test]
fn a_stream_within_the_limits_is_clean() {
    // Joint 1 by 0.1 rad over 2 s: at most 0.31 rad/s, 0.99 rad/s², 3.1 rad/s³.
    let (code, text) = check("clean", &frames(&smooth_move(0, 0.1, 2.0)), &[]);
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("0 violations, 0 reflexes") && text.contains("CLEAN"), "{text}");
}

#[test]
fn a_velocity_under_the_cap_but_over_the_bound_near_a_limit_is_caught() {
    // Joint 1 at 0.5 rad/s toward its upper limit, at 2.70 rad: far under the 2.62 rad/s cap, but there the FR3's
    // braking curve allows only √(2·6·0.0501) − 0.3 ≈ 0.475 rad/s. Constant speed: no acceleration, no jerk.
    let positions: Vec<[f64; 7]> = (0..=20)
        .map(|i| {
            let mut q = home();
            q[0] = 2.69 + 0.0005 * i as f64;
            q
        })
        .collect();
    let (code, text) = check("near-limit", &frames(&positions), &[]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("joint 0: velocity outside the bound at its position 0.5"), "{text}");
    // The same speed far from the limit is fine.
    let far: Vec<[f64; 7]> = positions.iter().map(|q| [q[0] - 2.0, q[1], q[2], q[3], q[4], q[5], q[6]]).collect();
    let (code, text) = check("far", &frames(&far), &[]);
    assert_eq!(code, 0, "{text}");
}

#[test]
fn too_much_acceleration_or_jerk_is_caught() {
    // 0.1 rad over 0.2 s: peak 31 rad/s³·… acceleration 0.1·(2π/0.2)² ≈ 98.7 rad/s² > 10.
    let (code, text) = check("accel", &frames(&smooth_move(3, 0.1, 0.2)), &[]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("acceleration"), "{text}");
    // A step of acceleration: 0 → 9 rad/s² in one period is 9000 rad/s³ > 5000, while every acceleration is ≤ 10.
    let mut positions = vec![home(); 5];
    let mut v = 0.0;
    let mut q = home();
    for _ in 0..20 {
        v += 9.0 * 1e-3;
        q[2] += v * 1e-3;
        positions.push(q);
    }
    let (code, text) = check("jerk", &frames(&positions), &[]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("joint 2: jerk 9000") && !text.contains("acceleration 9"), "{text}");
}

#[test]
fn a_position_outside_the_range_is_caught() {
    let q_max = mars_checker::limits::Limits::load(&profile()).unwrap().q_max[3];
    let mut q = home();
    q[3] = q_max + 0.01;
    let (code, text) = check("position", &frames(&[q, q, q]), &[]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains(&format!("joint 3: position above q_max {} (limit {q_max})", q[3])), "{text}");
}

#[test]
fn a_reflex_or_an_arm_not_left_at_rest_is_not_clean() {
    let mut f = frames(&smooth_move(0, 0.1, 2.0));
    f[1000].robot_mode = bits::MODE_REFLEX;
    let (code, text) = check("reflex", &f, &[]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("0 violations, 1 reflexes"), "{text}");
    // In a reflex the robot holds a reference of its own (the HAL reports it as applied): a jump into it is not a
    // command, and the motion after the recovery starts afresh. One reflex of ten frames.
    let mut f = frames(&smooth_move(0, 0.1, 2.0));
    for x in &mut f[1000..1010] {
        x.robot_mode = bits::MODE_REFLEX;
        x.q[0] += 1e-3;
    }
    let (code, text) = check("reflex-hold", &f, &[]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("0 violations, 1 reflexes"), "{text}");
    let mut f = frames(&smooth_move(0, 0.1, 2.0));
    f.last_mut().unwrap().status = bits::ACTIVE;
    let (code, text) = check("moving", &f, &[]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("does not end with the arm held at rest"), "{text}");
}

#[test]
fn the_robots_own_log_counts_its_aborts() {
    let dir = tempfile::tempdir().unwrap();
    let log = dir.path().join("sim.log");
    std::fs::write(&log, "INFO ok\nERROR joint_velocity_violation -- aborting the motion\n").unwrap();
    let (code, text) = check("log", &frames(&smooth_move(0, 0.1, 2.0)), &["--robot-log", log.to_str().unwrap()]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("1 in the robot's log"), "{text}");
}

#[test]
fn the_reaction_to_a_fault_is_measured_from_the_fault() {
    // Moving, then at 1.000 s a fault; the HAL holds from frame 1021 (21 ms later) and is at rest at the end.
    let mut f = frames(&smooth_move(0, 0.1, 2.0));
    for x in f.iter_mut().skip(1021) {
        x.status = bits::HOLDING;
        x.hold_reason = 4;
    }
    f.last_mut().unwrap().status = bits::HOLDING | bits::AT_REST;
    let at = (f[1000].recv_ns + 1).to_string();
    let (code, text) = check("reaction", &f, &["--fault-at-ns", &at, "--json"]);
    assert_eq!(code, 0, "{text}");
    let v: serde_json::Value = serde_json::from_str(text.trim()).unwrap();
    let r = &v["reaction"];
    assert_eq!((r["moving"].as_bool(), r["held"].as_bool()), (Some(true), Some(true)), "{v}");
    assert_eq!(r["hold_reason"], "controller lost");
    assert!((r["hold_ms"].as_f64().unwrap() - 21.0).abs() < 0.01, "{v}");
}

#[test]
fn input_that_cannot_be_judged_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let bad = dir.path().join("bad.csv");
    std::fs::write(&bad, "not a recording\n").unwrap();
    let (code, text) = check_file(&bad, &[]);
    assert_eq!(code, 2, "{text}");
    assert!(text.contains("not a checker recording"), "{text}");
    let (code, text) = check_file(&dir.path().join("missing.csv"), &[]);
    assert_eq!(code, 2, "{text}");
}
