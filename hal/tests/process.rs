//! The real `mars-hal` binary in its own process, driven over iceoryx2 from the test. Each test uses its own
//! robot namespace (pid + counter), so tests run in parallel.

use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use mars_hal::profile::Profile;
use mars_ipc::node::create_node;
use mars_ipc::*;

fn profile_path(name: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs").join(name).display().to_string()
}

fn unique_robot() -> String {
    static N: AtomicU32 = AtomicU32::new(0);
    format!("hal{}-{}", std::process::id(), N.fetch_add(1, Ordering::Relaxed))
}

/// A child process killed (SIGKILL) when dropped, so a failing test leaves nothing running.
struct Proc(Child);
impl Drop for Proc {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

struct Rig {
    ns: RobotNamespace,
    /// Keeps our ports alive.
    _node: Node<ipc::Service>,
    states: StateReader,
    commands: CommandWriter,
    profile: Profile,
    _hal: Proc,
}

impl Rig {
    fn start(profile: &str) -> Self {
        let robot = unique_robot();
        let ns = RobotNamespace::new(&robot).unwrap();
        let (node, _) = create_node("hal-test").unwrap();
        // Open our ports first so no early frame is missed.
        let states = StateReader::new(&node, &ns).unwrap();
        let commands = CommandWriter::new(&node, &ns).unwrap();
        let hal = Command::new(env!("CARGO_BIN_EXE_mars-hal"))
            .args(["--profile", &profile_path(profile), "--robot", &robot, "--duration-s", "30"])
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .spawn()
            .unwrap();
        let profile = Profile::load(Path::new(&profile_path(profile))).unwrap();
        let rig = Rig { ns, _node: node, states, commands, profile, _hal: Proc(hal) };
        rig.wait_for("the first state frame", Duration::from_secs(10), |_| true);
        rig
    }

    /// Read frames until `pred` holds for one; panic with `what` after `timeout`.
    fn wait_for(&self, what: &str, timeout: Duration, mut pred: impl FnMut(&RobotState) -> bool) -> RobotState {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            while let Some(s) = self.states.receive().unwrap() {
                if pred(&s) {
                    return s;
                }
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        panic!("timed out after {timeout:?} waiting for {what}");
    }

    fn latest(&self) -> RobotState {
        let mut last = None;
        let end = Instant::now() + Duration::from_secs(5);
        while last.is_none() && Instant::now() < end {
            while let Some(s) = self.states.receive().unwrap() {
                last = Some(s);
            }
            std::thread::sleep(Duration::from_micros(200));
        }
        last.expect("a state frame")
    }

    /// Send commands following `q_of_t(t)` for `secs`, one per state frame, in session `session`.
    fn stream(&self, session: u64, secs: f64, mut q_of_t: impl FnMut(f64) -> Vec<f64>) -> RobotState {
        let start = Instant::now();
        let mut seq = 0;
        let mut last = self.latest();
        while start.elapsed().as_secs_f64() < secs {
            while let Some(s) = self.states.receive().unwrap() {
                seq += 1;
                let q = q_of_t(start.elapsed().as_secs_f64());
                self.commands.send(&JointCommand::position(session, seq, s.seq, &q)).unwrap();
                last = s;
            }
            std::thread::sleep(Duration::from_micros(100));
        }
        last
    }
}

#[test]
fn state_frames_arrive_at_the_profile_rate() {
    let rig = Rig::start("fr3.toml");
    let first = rig.latest();
    std::thread::sleep(Duration::from_millis(1000));
    let last = rig.latest();
    let rate = (last.seq - first.seq) as f64 / ((last.timestamp_ns - first.timestamp_ns) as f64 * 1e-9);
    assert!((rate - rig.profile.rate_hz).abs() < 0.1 * rig.profile.rate_hz, "{rate} Hz");
    assert_eq!(last.num_joints, 7);
    assert_eq!(HoldReason::from_u32(last.hold_reason), Some(HoldReason::NoSession));
    assert!(last.is(status::HOLDING) && last.is(status::AT_REST));
}

#[test]
fn a_valid_command_stream_is_tracked() {
    let rig = Rig::start("fr3.toml");
    let home = rig.profile.home.clone();
    // 0.2 rad, 0.5 Hz sinusoid on every joint: well inside FR3's limits, starting at zero velocity offset.
    let traj = |t: f64| home.iter().map(|h| h + 0.2 * (std::f64::consts::TAU * 0.5 * t).sin()).collect::<Vec<_>>();
    let last = rig.stream(1, 1.5, traj);
    assert!(last.is(status::ACTIVE), "status {:b}", last.status);
    assert_eq!(last.session, 1);
    // The measured joints follow the commanded trajectory closely (latency + filter lag: a few ms at 0.63 rad/s).
    let target = traj(1.5);
    #[allow(clippy::needless_range_loop)]
    for i in 0..7 {
        assert!((last.position[i] - target[i]).abs() < 0.03, "joint {i}: {} vs {}", last.position[i], target[i]);
    }
    assert_eq!(last.rejected_commands, 0);
}

#[test]
fn every_bad_command_is_refused_and_never_applied() {
    let rig = Rig::start("r1_lite.toml"); // limit_policy = "reject"
    let home = rig.profile.home.clone();
    let before = rig.latest();
    let send = |c: JointCommand| rig.commands.send(&c).unwrap();
    let mut nan = JointCommand::position(5, 1, 0, &home);
    nan.position[2] = f64::NAN;
    send(nan);
    let mut beyond = JointCommand::position(5, 2, 0, &home);
    beyond.position[0] = rig.profile.q_max[0] + 0.1;
    send(beyond);
    let mut jump = JointCommand::position(5, 3, 0, &home);
    jump.position[1] += 0.5; // 100 rad/s implied at 200 Hz
    send(jump);
    let mut fast = JointCommand::position(5, 4, 0, &home);
    fast.velocity[3] = 10.0;
    send(fast);
    send(JointCommand::position(5, 5, 0, &home[..5])); // wrong joint count
    let s = rig.wait_for("five refusals", Duration::from_secs(5), |s| s.rejected_commands >= 5);
    assert_eq!(s.rejected_commands, 5);
    assert_eq!(s.session, 0, "no refused command may start a session");
    assert_eq!(&s.applied_position[..6], &before.applied_position[..6], "nothing moved");
}

#[test]
fn brakes_and_holds_when_commands_stop_and_resumes_only_on_a_new_session() {
    let rig = Rig::start("fr3.toml");
    let home = rig.profile.home.clone();
    // Moving at ~0.3 rad/s when the stream stops.
    let moving = rig.stream(1, 0.5, |t| home.iter().map(|h| h - 0.3 * t).collect());
    assert!(moving.is(status::ACTIVE));
    let stopped_at = moving.timestamp_ns;
    let held = rig.wait_for("hold after timeout", Duration::from_secs(2), |s| s.is(status::HOLDING));
    let timeout_ns = rig.profile.timeout_ns();
    assert_eq!(HoldReason::from_u32(held.hold_reason), Some(HoldReason::CommandTimeout));
    // Detected within the timeout plus a few ticks of slack for our own last send.
    assert!(held.timestamp_ns - stopped_at <= timeout_ns + 10_000_000, "{} ns", held.timestamp_ns - stopped_at);
    let rest = rig.wait_for("rest", Duration::from_secs(2), |s| s.is(status::AT_REST));
    assert!(rest.timestamp_ns - held.timestamp_ns < 500_000_000, "braking took too long");
    for i in 0..7 {
        assert!(rest.applied_position[i] >= rig.profile.q_min[i] && rest.applied_position[i] <= rig.profile.q_max[i]);
    }
    // The old session coming back is ignored ...
    let held_at = rig.latest().applied_position;
    let q = held_at[..7].to_vec();
    let mut far = q.clone();
    far[0] -= 0.2;
    let after_old = rig.stream(1, 0.3, |_| far.clone());
    assert!(after_old.is(status::HOLDING));
    assert_eq!(&after_old.applied_position[..7], &held_at[..7]);
    // ... and a new session resumes.
    let after_new = rig.stream(2, 0.3, |_| far.clone());
    assert!(after_new.is(status::ACTIVE) && after_new.session == 2);
    assert!(after_new.applied_position[0] < held_at[0] - 0.01);
}

#[test]
fn brakes_and_holds_when_the_controller_process_is_sigkilled() {
    let rig = Rig::start("fr3.toml");
    let probe = Command::new(env!("CARGO_BIN_EXE_mars-hal-probe"))
        .args(["--robot", rig.ns.robot(), "--session", "77"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut probe = Proc(probe);
    rig.wait_for("the probe's session", Duration::from_secs(10), |s| s.session == 77 && s.is(status::ACTIVE));
    // Let it control for a while, then SIGKILL it: no goodbye, no Hold command.
    std::thread::sleep(Duration::from_millis(200));
    let alive = rig.latest();
    assert!(alive.is(status::ACTIVE), "probe lost control before it was killed");
    probe.0.kill().unwrap();
    let killed = Instant::now();
    probe.0.wait().unwrap();
    let held = rig.wait_for("hold after SIGKILL", Duration::from_secs(2), |s| s.is(status::HOLDING));
    assert_eq!(HoldReason::from_u32(held.hold_reason), Some(HoldReason::CommandTimeout));
    assert_eq!(held.session, 77);
    let waited = killed.elapsed();
    assert!(waited < Duration::from_millis(rig.profile.command_timeout_ms as u64 + 200), "{waited:?}");
}

#[test]
fn a_command_with_a_wrong_schema_version_is_refused() {
    let rig = Rig::start("fr3.toml");
    let home = rig.profile.home.clone();
    let mut q = home.clone();
    q[0] += 0.001;
    for seq in 1..=20 {
        let c = JointCommand::position(3, seq, 0, &q);
        rig.commands.send_with_header(&c, FrameHeader { schema_version: SCHEMA_VERSION + 1 }).unwrap();
    }
    std::thread::sleep(Duration::from_millis(200));
    let s = rig.latest();
    assert_eq!(s.session, 0, "a mismatched build must not start a session");
    assert_eq!(s.last_command_seq, 0);
    assert!(s.is(status::HOLDING));
}
