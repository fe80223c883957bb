//! `mars-hal fci-status` as a user runs it: against franka-sim (a MuJoCo FR3 speaking the real FCI protocol, see
//! `support/franka_sim.rs`), and against addresses where no robot answers. It only connects and reads one state
//! (no 1 kHz loop), so a debug build is fine.

mod support;

use std::net::TcpListener;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use support::franka_sim::{FrankaSim, start_pose_and_rest_mode};

fn fci_status(args: &[&str]) -> (Output, Duration) {
    let start = Instant::now();
    let out = Command::new(env!("CARGO_BIN_EXE_mars-hal"))
        .arg("fci-status")
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .expect("running mars-hal fci-status");
    (out, start.elapsed())
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The value of the line `name: value` in `stdout`.
fn field<'a>(stdout: &'a str, name: &str) -> &'a str {
    stdout
        .lines()
        .find_map(|l| l.strip_prefix(name).and_then(|r| r.strip_prefix(':')))
        .unwrap_or_else(|| panic!("no line {name:?} in:\n{stdout}"))
        .trim()
}

#[test]
fn fci_status_reads_the_simulators_start_pose_and_rest_mode() {
    let (q0, rest_mode) = start_pose_and_rest_mode();
    let sim = FrankaSim::start();
    let (out, took) = fci_status(&["--robot-ip", "127.0.0.1"]);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert!(
        out.status.success(),
        "exit {:?}\nstdout:\n{stdout}\nstderr:\n{stderr}\nfranka-sim's log:\n{}",
        out.status,
        sim.log_text()
    );
    eprintln!("fci-status took {:.2} s:\n{stdout}", took.as_secs_f64());
    let q: Vec<f64> = field(&stdout, "joint positions (rad)").split_whitespace().map(|v| v.parse().unwrap()).collect();
    assert_eq!(q.len(), 7, "{stdout}");
    for (i, (q, q0)) in q.iter().zip(q0).enumerate() {
        assert!((q - q0).abs() < 1e-3, "joint {i}: fci-status says {q}, franka-sim starts at {q0}\n{stdout}");
    }
    assert_eq!(field(&stdout, "robot mode"), rest_mode, "{stdout}");
    assert_eq!(field(&stdout, "current errors"), "none", "{stdout}");
    assert_eq!(field(&stdout, "last motion errors"), "none", "{stdout}");
    // No motion runs, so the robot reports no command success rate (0 by libfranka's definition).
    assert_eq!(field(&stdout, "control command success rate").parse::<f64>().unwrap(), 0.0, "{stdout}");
    assert!(field(&stdout, "robot").starts_with("127.0.0.1 (FCI V10"), "{stdout}");
}

/// What every "could not reach the robot" message must say besides the address.
fn says_what_to_check(stderr: &str) {
    for hint in ["FCI is activated in Desk", "the robot's IP", "network"] {
        assert!(stderr.contains(hint), "stderr does not say {hint:?}:\n{stderr}");
    }
}

/// Fails within a bound, exit status 1, and names the address and what to check.
fn assert_unreachable(addr: &str, timeout_s: &str, bound: Duration) -> String {
    let (out, took) = fci_status(&["--robot-ip", addr, "--timeout-s", timeout_s]);
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    eprintln!("{addr}: exit {:?} after {:.2} s: {stderr}", out.status.code(), took.as_secs_f64());
    assert_eq!(out.status.code(), Some(1), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(took < bound, "took {took:?} (bound {bound:?})");
    assert!(stderr.contains(&format!("robot at {addr}")), "stderr does not name {addr}:\n{stderr}");
    says_what_to_check(&stderr);
    assert!(stdout.is_empty(), "{stdout}");
    stderr
}

#[test]
fn fci_status_where_nothing_listens_fails_at_once_and_says_what_to_check() {
    // Port 1 on loopback: nothing listens (binding it needs root and no service uses it), so the kernel refuses.
    let stderr = assert_unreachable("127.0.0.1:1", "2", Duration::from_secs(5));
    assert!(stderr.contains("refused"), "{stderr}");
}

#[test]
fn fci_status_to_an_unroutable_address_fails_within_its_bound() {
    // 192.0.2.1 (TEST-NET-1, RFC 5737) is never assigned: no route here gives an immediate error, a default route
    // franka-rs's 1 s connect timeout; either way well inside --timeout-s 2 plus the process's start.
    assert_unreachable("192.0.2.1", "2", Duration::from_secs(5));
}

#[test]
fn fci_status_to_a_peer_that_never_answers_gives_up_at_its_timeout() {
    // Accepts TCP connections (the kernel completes them into the backlog) and never answers the FCI handshake:
    // franka-rs alone would wait for the reply forever.
    let silent = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = silent.local_addr().unwrap().to_string();
    let stderr = assert_unreachable(&addr, "2", Duration::from_secs(5));
    assert!(stderr.contains("no answer") && stderr.contains("within 2.0 s"), "{stderr}");
    drop(silent);
}

#[test]
fn fci_status_refuses_bad_arguments_with_status_2() {
    for args in [&["--robot-ip", "127.0.0.1", "--timeout-s", "0"][..], &["--robot-ip", "", "--timeout-s", "1"][..]] {
        let (out, _) = fci_status(args);
        assert_eq!(out.status.code(), Some(2), "{args:?}: {}", text(&out.stderr));
    }
    let (out, _) = fci_status(&[]);
    assert_eq!(out.status.code(), Some(2), "--robot-ip is required: {}", text(&out.stderr));
}

#[test]
fn the_hal_process_still_takes_its_own_arguments_and_does_not_mix_with_the_subcommand() {
    let hal = |args: &[&str]| Command::new(env!("CARGO_BIN_EXE_mars-hal")).args(args).output().unwrap();
    let none = hal(&[]);
    assert_eq!(none.status.code(), Some(2));
    assert!(text(&none.stderr).contains("--profile"), "{}", text(&none.stderr));
    // The HAL's own arguments still reach it (here it stops at reading the profile: no rig is started).
    let missing = hal(&["--profile", "/nonexistent/fr3.toml", "--duration-s", "1"]);
    assert_eq!(missing.status.code(), Some(1), "{}", text(&missing.stderr));
    assert!(text(&missing.stderr).contains("reading profile /nonexistent/fr3.toml"), "{}", text(&missing.stderr));
    let both = hal(&["--profile", "configs/fr3.toml", "fci-status", "--robot-ip", "127.0.0.1"]);
    assert_eq!(both.status.code(), Some(2), "{}", text(&both.stderr));
}
