//! The real `mars-hal` binary in its own process, driven over iceoryx2 from the test. Each test uses its own
//! robot namespace (pid + counter), so tests run in parallel.

mod support;

use std::f64::consts::{FRAC_PI_2, FRAC_PI_4};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use mars_ipc::node::create_node;
use mars_ipc::*;
use mars_profile::Profile;

// One real-time rig at a time on this machine, across test binaries (see `mars_rt::rig_lock`).
use mars_rt::rig_lock::{RtRigLock, rt_rig_lock};
use stall_witness::process_exit::ExitWatch;
use stall_witness::{Attempt, at_most_one_rerun, witness};

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
    hal: Proc,
    /// When [`Rig::stream`] last sent a command (CLOCK_MONOTONIC ns, the clock of the HAL's frame stamps).
    last_sent_ns: std::cell::Cell<u64>,
    /// Declared last: released after the HAL was killed.
    _rt: RtRigLock,
}

impl Rig {
    fn start(profile: &str) -> Self {
        Self::start_with(profile, &[])
    }

    /// Start `mars-hal` with extra command-line arguments (fault injection).
    fn start_with(profile: &str, extra: &[&str]) -> Self {
        Self::start_at(&profile_path(profile), extra)
    }

    /// Start `mars-hal` with the profile file at `path`.
    fn start_at(path: &str, extra: &[&str]) -> Self {
        let rt = rt_rig_lock().expect("taking the real-time rig lock");
        let robot = unique_robot();
        let ns = RobotNamespace::new(&robot).unwrap();
        let (node, _) = create_node("hal-test").unwrap();
        // Open our ports first so no early frame is missed.
        let states = StateReader::new(&node, &ns).unwrap();
        let commands = CommandWriter::new(&node, &ns).unwrap();
        let hal = Command::new(env!("CARGO_BIN_EXE_mars-hal"))
            .args(["--profile", path, "--robot", &robot])
            .args(if extra.contains(&"--duration-s") { &[][..] } else { &["--duration-s", "30"][..] })
            .args(extra)
            .env("RUST_LOG", "warn")
            .stdout(Stdio::null())
            .spawn()
            .unwrap();
        let profile = Profile::load(Path::new(path)).unwrap();
        let rig = Rig { ns, _node: node, states, commands, profile, hal: Proc(hal), last_sent_ns: 0.into(), _rt: rt };
        rig.wait_for("the first state frame", Duration::from_secs(10), |_| true);
        rig
    }

    /// Read frames until `pred` holds for one; panic with `what` after `timeout`.
    fn wait_for(&self, what: &str, timeout: Duration, pred: impl FnMut(&RobotState) -> bool) -> RobotState {
        support::states::wait_for(&self.states, None, what, timeout, pred, || None).unwrap_or_else(|e| panic!("{e}"))
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
                self.last_sent_ns.set(clock::monotonic_ns());
                last = s;
            }
            std::thread::sleep(Duration::from_micros(100));
        }
        last
    }
}

#[test]
fn state_frames_arrive_at_the_profile_rate() {
    witness();
    at_most_one_rerun("state frames at the profile's rate", frames_at_the_profile_rate);
}

/// One attempt of the test above: within 10 % of the rate, or fewer only by the periods the witness saw the machine
/// take (a frame is published per tick; a tick the machine delays past its period is skipped, not made up).
fn frames_at_the_profile_rate(_attempt: u32) -> Attempt {
    let rig = Rig::start("fr3.toml");
    let first = rig.latest();
    std::thread::sleep(Duration::from_millis(1000));
    let last = rig.latest();
    let secs = (last.timestamp_ns - first.timestamp_ns) as f64 * 1e-9;
    let rate = (last.seq - first.seq) as f64 / secs;
    assert!(rate < 1.1 * rig.profile.rate_hz, "{rate} Hz");
    if rate <= 0.9 * rig.profile.rate_hz {
        let short_ms = (0.9 * rig.profile.rate_hz - rate) * secs / rig.profile.rate_hz * 1e3;
        let failure = format!("{rate:.0} Hz of state frames, under 90 % of {} Hz", rig.profile.rate_hz);
        return Err(witness()
            .excuse(failure.clone(), first.timestamp_ns, last.timestamp_ns, short_ms)
            .unwrap_or_else(|| panic!("{failure}")));
    }
    assert_eq!(last.num_joints, 7);
    assert_eq!(HoldReason::from_u32(last.hold_reason), Some(HoldReason::NoSession));
    assert!(last.is(status::HOLDING) && last.is(status::AT_REST));
    Ok(())
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
    // By the kernel's count of the loop thread's voluntary context switches in each tick.
    assert_eq!(last.ticks_blocked, 0, "the HAL's tick never blocks");
}

#[test]
fn every_bad_command_is_refused_and_never_applied() {
    let rig = Rig::start("r1_lite.toml"); // limit_policy = "reject"
    let before = rig.latest();
    // Each answers the newest frame (so none is late) and starts from the HAL's own setpoint.
    let (here, seq) = (before.applied_position[..6].to_vec(), before.seq);
    let send = |c: JointCommand| rig.commands.send(&c).unwrap();
    let mut nan = JointCommand::position(5, 1, seq, &here);
    nan.position[2] = f64::NAN;
    send(nan);
    let mut beyond = JointCommand::position(5, 2, seq, &here);
    beyond.position[0] = rig.profile.q_max[0] + 0.1;
    send(beyond);
    let mut jump = JointCommand::position(5, 3, seq, &here);
    jump.position[1] += 0.5; // 100 rad/s implied at 200 Hz, far beyond the 12.6 rad/s limit
    send(jump);
    let mut fast = JointCommand::position(5, 4, seq, &here);
    fast.velocity[3] = 2.0 * rig.profile.dq_max[3];
    send(fast);
    send(JointCommand::position(5, 5, seq, &here[..5])); // wrong joint count
    let s = rig.wait_for("five refusals", Duration::from_secs(5), |s| s.rejected_commands >= 5);
    assert_eq!(s.rejected_commands, 5);
    assert_eq!(s.session, 0, "no refused command may start a session");
    assert_eq!(&s.applied_position[..6], &before.applied_position[..6], "nothing moved");
}

#[test]
fn brakes_and_holds_when_commands_stop_and_resumes_only_on_a_new_session() {
    witness();
    at_most_one_rerun("command timeout", command_timeout_scenario);
}

/// One run of the command-timeout scenario; its excuse if the hold came later than its bound while the stall
/// witness saw the machine stall at least the excess between the last command and the hold.
fn command_timeout_scenario(_attempt: u32) -> Attempt {
    let rig = Rig::start("fr3.toml");
    let home = rig.profile.home.clone();
    // Moving at ~0.3 rad/s when the stream stops.
    let moving = rig.stream(1, 0.5, |t| home.iter().map(|h| h - 0.3 * t).collect());
    assert!(moving.is(status::ACTIVE));
    let stopped_at = rig.last_sent_ns.get();
    let frames = collect(&rig, Duration::from_secs(2), |s| s.is(status::HOLDING));
    let held = *frames.last().filter(|s| s.is(status::HOLDING)).expect("no hold within 2 s of the last command");
    let timeout_ns = rig.profile.timeout_ns();
    assert_eq!(HoldReason::from_u32(held.hold_reason), Some(HoldReason::CommandTimeout));
    // Detected within the timeout of our last send plus a few of the HAL's ticks (the command reaches it on its next
    // tick; the hold is published on the tick after the timeout).
    let took_ns = held.timestamp_ns.saturating_sub(stopped_at);
    let bound_ns = timeout_ns + 10_000_000;
    let (took_ms, bound_ms) = (took_ns as f64 * 1e-6, bound_ns as f64 * 1e-6);
    witness().within_or_excused("last command → hold", took_ms, bound_ms, stopped_at, held.timestamp_ns)?;
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
    // ... and a new session resumes (held again only if the machine stalled its stream past the timeout: on the
    // witness's stall of half the timeout while it streamed).
    let streamed_from = clock::monotonic_ns();
    let after_new = rig.stream(2, 0.3, |_| far.clone());
    if after_new.session == 2 && HoldReason::from_u32(after_new.hold_reason) == Some(HoldReason::CommandTimeout) {
        let failure = "the new session timed out while it streamed";
        let half_timeout_ms = timeout_ns as f64 * 0.5e-6;
        if let Some(e) = witness().excuse(failure, streamed_from, after_new.timestamp_ns, half_timeout_ms) {
            return Err(e);
        }
    }
    assert!(after_new.is(status::ACTIVE) && after_new.session == 2, "{after_new:?}");
    assert!(after_new.applied_position[0] < held_at[0] - 0.01);
    Ok(())
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

/// Every frame until `until` holds for one (included) or `timeout` passes.
fn collect(rig: &Rig, timeout: Duration, mut until: impl FnMut(&RobotState) -> bool) -> Vec<RobotState> {
    let mut frames = Vec::new();
    let end = Instant::now() + timeout;
    while Instant::now() < end {
        while let Some(s) = rig.states.receive().unwrap() {
            frames.push(s);
            if until(&s) {
                return frames;
            }
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    frames
}

#[test]
fn injected_frame_drops_show_as_seq_gaps() {
    let rig = Rig::start_with("fr3.toml", &["--drop-every", "10"]);
    let frames = collect(&rig, Duration::from_secs(5), |s| s.seq >= 400);
    assert!(frames.len() >= 100, "only {} frames", frames.len());
    assert!(frames.iter().all(|s| s.seq % 10 != 0), "a frame that should have been dropped arrived");
    let gaps = frames.windows(2).filter(|w| w[1].seq == w[0].seq + 2 && w[0].seq % 10 == 9).count();
    assert!(gaps >= 5, "expected the every-10th gaps, saw {gaps}");
}

#[test]
fn injected_crash_kills_the_process_non_zero_at_its_tick() {
    let mut rig = Rig::start_with("fr3.toml", &["--crash-at-tick", "300"]);
    let first = rig.latest();
    let started = Instant::now();
    let end = started + Duration::from_secs(10);
    let status = loop {
        if let Some(status) = rig.hal.0.try_wait().unwrap() {
            break status;
        }
        assert!(Instant::now() < end, "mars-hal still running 10 s after the injected crash tick");
        std::thread::sleep(Duration::from_millis(2));
    };
    let lived = started.elapsed();
    assert!(!status.success(), "a crash must exit non-zero: {status:?}");
    // Tick 300 is 300 ms after the first frame at 1 kHz; the first frame we saw came at most a little later.
    let expected = Duration::from_millis(300 - first.seq.min(300));
    assert!(
        lived + Duration::from_millis(50) >= expected && lived < expected + Duration::from_millis(1500),
        "{lived:?}"
    );
    let frames = collect(&rig, Duration::from_millis(100), |_| false);
    assert!(frames.iter().all(|s| s.seq <= 300), "a frame after the crash tick");
}

#[test]
fn injected_stall_shows_as_a_timestamp_gap() {
    let rig = Rig::start_with("fr3.toml", &["--stall-at-tick", "150", "--stall-ms", "120"]);
    let hal = HalLiveness::hal(&rig.ns).unwrap();
    let frames = collect(&rig, Duration::from_secs(5), |s| s.seq >= 300);
    // A stalled HAL misses its heartbeat deadline but is not dead: the watch must not say so.
    let end = Instant::now() + Duration::from_secs(2);
    while hal.peer() != Peer::Alive {
        assert!(Instant::now() < end, "HAL not alive again after its stall: {:?}", hal.peer());
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!(hal.deaths(), 0);
    let gap = frames
        .windows(2)
        .filter(|w| w[1].seq == w[0].seq + 1)
        .map(|w| w[1].timestamp_ns - w[0].timestamp_ns)
        .max()
        .unwrap();
    assert!((110_000_000..400_000_000).contains(&gap), "largest gap {gap} ns");
}

#[test]
fn nan_sensor_is_flagged_and_never_reaches_the_applied_setpoint() {
    let rig = Rig::start_with("fr3.toml", &["--nan-joint", "1", "--nan-at-tick", "200"]);
    let p = rig.profile.clone();
    // A naive controller that commands "measured position + a small step": once the sensor is NaN its
    // commands are NaN too. The HAL must refuse them and keep a finite setpoint within the limits.
    let start = Instant::now();
    let mut seq = 0;
    let mut frames = Vec::new();
    while start.elapsed() < Duration::from_millis(600) {
        while let Some(s) = rig.states.receive().unwrap() {
            seq += 1;
            let q: Vec<f64> = s.positions().iter().map(|x| x + 1e-5).collect();
            rig.commands.send(&JointCommand::position(1, seq, s.seq, &q)).unwrap();
            frames.push(s);
        }
        std::thread::sleep(Duration::from_micros(100));
    }
    let nan: Vec<&RobotState> = frames.iter().filter(|s| s.seq > 200).collect();
    assert!(nan.len() > 50, "only {} frames after the NaN tick", nan.len());
    for s in &nan {
        assert!(s.position[1].is_nan());
        assert_eq!(s.fault, fault::NAN_SENSOR | fault::NON_FINITE_MEASUREMENT, "seq {}", s.seq);
    }
    assert!(frames.iter().filter(|s| s.seq <= 200).all(|s| s.fault == 0 && s.position[1].is_finite()));
    let last = frames.last().unwrap();
    assert!(last.rejected_commands > 10, "NaN commands must be refused, {} were", last.rejected_commands);
    for s in &frames {
        for i in 0..7 {
            let a = s.applied_position[i];
            assert!(a.is_finite() && a >= p.q_min[i] && a <= p.q_max[i], "seq {} joint {i}: {a}", s.seq);
        }
    }
}

/// An FR3 profile changed for one test, written to a temp file that is removed when dropped.
struct TempProfile(std::path::PathBuf);
impl TempProfile {
    /// The FR3 profile with `from` replaced by `to` (which must occur).
    fn fr3_with(from: &str, to: &str) -> Self {
        let text = std::fs::read_to_string(profile_path("fr3.toml")).unwrap();
        assert!(text.contains(from), "{from:?} not in fr3.toml");
        let path = std::env::temp_dir().join(format!("{}.toml", unique_robot()));
        std::fs::write(&path, text.replacen(from, to, 1)).unwrap();
        Self(path)
    }
    fn fr3_with_timeout(ms: u32) -> Self {
        Self::fr3_with("command_timeout_ms = 20.0", &format!("command_timeout_ms = {ms}.0"))
    }
    /// The sim arm starts at `q` with the gripper at `gripper` (as a real arm the HAL finds there).
    fn fr3_starting_at(q: &[f64], gripper: f64) -> Self {
        Self::fr3_with("[sim]\n", &format!("[sim]\nstart = {q:?}\nstart_gripper = {gripper}\n"))
    }
    fn path(&self) -> String {
        self.0.display().to_string()
    }
}
impl Drop for TempProfile {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.0);
    }
}

#[test]
fn hal_sees_a_sigkilled_controller_die_through_iceoryx2_events_long_before_the_command_timeout() {
    // A 3 s command timeout: a hold within a fraction of that can only come from the liveness watch.
    let profile = TempProfile::fr3_with_timeout(3000);
    let rig = Rig::start_at(&profile.path(), &[]);
    let probe = Command::new(env!("CARGO_BIN_EXE_mars-hal-probe"))
        .args(["--robot", rig.ns.robot(), "--session", "91", "--heartbeat"])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut probe = Proc(probe);
    rig.wait_for("the probe's session", Duration::from_secs(10), |s| s.session == 91 && s.is(status::ACTIVE));
    std::thread::sleep(Duration::from_millis(200));
    assert!(rig.latest().is(status::ACTIVE), "probe lost control before it was killed");
    probe.0.kill().unwrap();
    let killed = Instant::now();
    probe.0.wait().unwrap();
    let held = rig.wait_for("hold after SIGKILL", Duration::from_secs(3), |s| s.is(status::HOLDING));
    let waited = killed.elapsed();
    assert_eq!(HoldReason::from_u32(held.hold_reason), Some(HoldReason::ControllerLost));
    assert_eq!(held.session, 91);
    // Deadline 10 ms + clean-up + one tick; generous for a loaded 2-core machine, far below the 3 s timeout.
    assert!(waited < Duration::from_millis(1000), "{waited:?}");
    let rest = rig.wait_for("rest", Duration::from_secs(2), |s| s.is(status::AT_REST));
    assert_eq!(HoldReason::from_u32(rest.hold_reason), Some(HoldReason::ControllerLost));
}

#[test]
fn controller_sees_a_sigkilled_hal_die_through_iceoryx2_events() {
    witness();
    at_most_one_rerun("a SIGKILLed HAL seen dead", sigkilled_hal_seen_dead);
}

/// README's bound for a SIGKILLed HAL seen dead after the kernel's end of its process (the HAL's pidfd, which
/// also wakes the watch): the watch's wake-up and the poller's 0.1 ms sleep.
const DEATH_SEEN_AFTER_END_MS: f64 = 1.0;
/// marsd's default `[watch] priority` (runtime/src/config.rs): the SCHED_FIFO priority of its HAL watch.
const MARSD_WATCH_PRIORITY: i32 = 60;
/// The HIL rig's `--rt-priority` for the HAL (runtime/src/cli.rs).
const HAL_PRIORITY: &str = "85";

/// Raises the calling thread to SCHED_FIFO `priority`, as marsd raises its threads; the test needs the right.
fn at_fifo(priority: i32) {
    let outcome = mars_rt::try_sched_fifo(priority);
    assert_eq!(outcome, mars_rt::Outcome::Applied, "SCHED_FIFO {priority} (the test needs root or RLIMIT_RTPRIO)");
}

/// One run of the test above; its excuse if the death was seen later than the bound while the stall witness saw
/// the machine stall at least the excess meanwhile.
///
/// Everything on the path runs as in the HIL rig, so the figure is marsd's and not that of ordinary threads queued
/// behind the machine's other work: the HAL at `--rt-priority 85` (its exit, which lets go of its iceoryx2 node, is
/// done by its own threads), the watch at marsd's priority and the clock read by a poller just above it.
fn sigkilled_hal_seen_dead(_attempt: u32) -> Attempt {
    let mut rig = Rig::start_with("fr3.toml", &["--rt-priority", HAL_PRIORITY]);
    let hal = PeerWatch::spawn_then(&rig.ns, Side::Hal, || at_fifo(MARSD_WATCH_PRIORITY)).unwrap();
    let start = Instant::now();
    while hal.peer() != Peer::Alive {
        assert!(start.elapsed() < Duration::from_secs(5), "HAL heartbeat never seen: {:?}", hal.peer());
        std::thread::sleep(Duration::from_millis(1));
    }
    std::thread::sleep(Duration::from_millis(100));
    // (A descheduled HAL may be `Late` on a loaded machine, but a running one is never `Dead`.)
    assert_ne!(hal.peer(), Peer::Dead, "a running HAL must not be declared dead");
    assert_eq!(hal.deaths(), 0);
    let exit = ExitWatch::start(rig.hal.0.id() as libc::pid_t).expect("a pidfd for the HAL");
    let (killed_ns, seen_ns) = std::thread::scope(|s| {
        let poller = s.spawn(|| {
            at_fifo(MARSD_WATCH_PRIORITY + 1);
            let start = Instant::now();
            while hal.peer() != Peer::Dead {
                assert!(start.elapsed() < Duration::from_secs(3), "still {:?} 3 s after SIGKILL", hal.peer());
                std::thread::sleep(Duration::from_micros(100));
            }
            stall_witness::monotonic_ns()
        });
        rig.hal.0.kill().unwrap();
        let killed_ns = stall_witness::monotonic_ns();
        (killed_ns, poller.join().unwrap_or_else(|p| std::panic::resume_unwind(p)))
    });
    let gone_ns = exit.join().expect("the kernel's word that the HAL is gone");
    rig.hal.0.wait().unwrap();
    let ms = |a: u64, b: u64| (b as f64 - a as f64) / 1e6;
    // The watch declares the death before iceoryx2's clean-up emits its dead event; that event must not count it
    // again.
    std::thread::sleep(Duration::from_millis(100));
    assert_eq!(hal.deaths(), 1, "one SIGKILL, one death");
    eprintln!(
        "HAL death seen {:.1} ms after SIGKILL; its process gone {:.1} ms after it (pidfd); seen {:.2} ms after \
         that (README: within {DEATH_SEEN_AFTER_END_MS} ms)",
        ms(killed_ns, seen_ns),
        ms(killed_ns, gone_ns),
        ms(gone_ns, seen_ns)
    );
    let late_ms = ms(gone_ns, seen_ns);
    witness().within_or_excused("SIGKILL → HAL seen dead", late_ms, DEATH_SEEN_AFTER_END_MS, gone_ns, seen_ns)
}

#[test]
fn controller_sees_an_injected_hal_crash_as_a_death() {
    let rig = Rig::start_with("fr3.toml", &["--crash-at-tick", "400"]);
    let hal = HalLiveness::hal(&rig.ns).unwrap();
    let start = Instant::now();
    while hal.peer() != Peer::Dead {
        assert!(start.elapsed() < Duration::from_secs(5), "still {:?}", hal.peer());
        std::thread::sleep(Duration::from_micros(500));
    }
    assert_eq!(hal.deaths(), 1);
}

#[test]
fn a_clean_hal_exit_is_seen_as_left_not_dead() {
    let rig = Rig::start_with("fr3.toml", &["--duration-s", "0.6"]);
    let hal = HalLiveness::hal(&rig.ns).unwrap();
    let start = Instant::now();
    while hal.peer() != Peer::Left {
        assert!(start.elapsed() < Duration::from_secs(5), "still {:?}", hal.peer());
        std::thread::sleep(Duration::from_millis(1));
    }
    assert_eq!((hal.deaths(), hal.exits()), (0, 1));
}

/// Names of the dead (crashed, not yet cleaned up) iceoryx2 nodes on this machine.
fn dead_node_names() -> Vec<String> {
    use iceoryx2::node::NodeView;
    let mut names = Vec::new();
    Node::<ipc::Service>::list(Config::global_config(), |state| {
        if let NodeState::Dead(view) = state
            && let Some(d) = view.details()
        {
            names.push(d.name().as_str().to_owned());
        }
        CallbackProgression::Continue
    })
    .unwrap();
    names
}

#[test]
fn a_sigkilled_hals_resources_are_cleaned_up_when_the_next_node_starts() {
    let mut rig = Rig::start("fr3.toml");
    let hal_node = format!("mars-hal-{}", rig.ns.robot());
    rig.hal.0.kill().unwrap();
    rig.hal.0.wait().unwrap();
    // A restarted HAL (or controller) creates its node through `create_node`, which removes what dead nodes
    // left behind; after it, no dead node of the killed HAL may remain.
    let (_node, _cleaned) = create_node("hal-test-restart").unwrap();
    let dead = dead_node_names();
    assert!(!dead.iter().any(|n| n.contains(rig.ns.robot())), "{hal_node} left behind: {dead:?}");
    // And a new HAL on the same robot id starts and publishes (the old one's frames are drained first).
    while rig.states.receive().unwrap().is_some() {}
    let robot = rig.ns.robot().to_owned();
    let hal = Command::new(env!("CARGO_BIN_EXE_mars-hal"))
        .args(["--profile", &profile_path("fr3.toml"), "--robot", &robot, "--duration-s", "30"])
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .spawn()
        .unwrap();
    rig.hal = Proc(hal);
    rig.wait_for("a frame from the restarted HAL", Duration::from_secs(10), |_| true);
}

#[test]
fn injected_late_frames_arrive_late() {
    let rig = Rig::start_with("fr3.toml", &["--late-every", "100", "--late-ms", "40"]);
    let t0 = Instant::now();
    let mut frames = Vec::new(); // (frame, our receive time ns since t0)
    let end = t0 + Duration::from_secs(5);
    while Instant::now() < end && frames.last().is_none_or(|(s, _): &(RobotState, u64)| s.seq < 450) {
        while let Some(s) = rig.states.receive().unwrap() {
            frames.push((s, t0.elapsed().as_nanos() as u64));
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    // Our clock minus the HAL's, up to the smallest delivery delay: the least lateness over all frames.
    let offset = frames.iter().map(|(s, rx)| *rx as i64 - s.timestamp_ns as i64).min().unwrap();
    let lateness = |(s, rx): &(RobotState, u64)| (*rx as i64 - s.timestamp_ns as i64 - offset) as f64 * 1e-6;
    let late: Vec<f64> = frames.iter().filter(|(s, _)| s.seq % 100 == 0).map(lateness).collect();
    assert!(late.len() >= 3, "only {} late frames seen", late.len());
    assert!(late.iter().all(|&ms| ms >= 35.0), "late frames arrived after {late:?} ms");
    // Frames just before a late one are on time (the median, so a descheduled test thread cannot fail it).
    let mut before: Vec<f64> = frames.iter().filter(|(s, _)| s.seq % 100 == 90).map(lateness).collect();
    before.sort_by(f64::total_cmp);
    assert!(before[before.len() / 2] < 20.0, "on-time frames arrived after {before:?} ms");
}

#[test]
fn frozen_sensor_is_flagged_while_the_applied_setpoint_keeps_moving() {
    let rig = Rig::start_with("fr3.toml", &["--freeze-at-tick", "150"]);
    let home = rig.profile.home.clone();
    let last = rig.stream(1, 0.5, |t| home.iter().map(|h| h + 0.2 * t).collect());
    let frozen = collect(&rig, Duration::from_secs(2), |s| s.seq > last.seq + 5);
    let f = frozen.last().unwrap();
    assert!(f.seq > 150);
    assert_eq!(f.fault, fault::FROZEN_SENSOR);
    assert!(f.velocity[..7].iter().all(|&v| v == 0.0));
    // The sensor shows the pose of tick 150; the arm (its applied setpoint) went on to follow the stream.
    assert!(f.applied_position[0] > f.position[0] + 0.03, "{} vs {}", f.applied_position[0], f.position[0]);
}

#[test]
fn an_invalid_fault_flag_is_refused_with_a_clear_error() {
    let out = Command::new(env!("CARGO_BIN_EXE_mars-hal"))
        .args(["--profile", &profile_path("fr3.toml"), "--robot", &unique_robot(), "--duration-s", "1"])
        .args(["--nan-joint", "7", "--nan-at-tick", "0"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("sim.faults.nan_joint = 7 but the robot has 7 joints"), "{err}");
}

#[test]
fn a_controller_restarted_after_a_sigkill_takes_over_without_waiting_for_the_command_timeout() {
    let profile = TempProfile::fr3_with_timeout(3000);
    let rig = Rig::start_at(&profile.path(), &[]);
    let probe = |session: &str| {
        let c = Command::new(env!("CARGO_BIN_EXE_mars-hal-probe"))
            .args(["--robot", rig.ns.robot(), "--session", session, "--heartbeat"])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .unwrap();
        Proc(c)
    };
    let mut first = probe("11");
    rig.wait_for("the first probe's session", Duration::from_secs(10), |s| s.session == 11 && s.is(status::ACTIVE));
    first.0.kill().unwrap();
    first.0.wait().unwrap();
    let killed = Instant::now();
    let _second = probe("12");
    rig.wait_for("the second probe's session", Duration::from_secs(3), |s| s.session == 12 && s.is(status::ACTIVE));
    assert!(killed.elapsed() < Duration::from_millis(2000), "{:?}", killed.elapsed());
    // The first one's death does not end the second one's session.
    std::thread::sleep(Duration::from_millis(300));
    let s = rig.latest();
    assert!(s.session == 12 && s.is(status::ACTIVE), "session {} status {:b}", s.session, s.status);
}

/// `--core N` pins the loop thread (the main thread, tid = pid) to that core; without it the HAL keeps the
/// affinity it was started with.
#[test]
fn core_flag_pins_the_loop_thread() {
    let allowed = |pid: u32| -> String {
        let status = std::fs::read_to_string(format!("/proc/{pid}/task/{pid}/status")).unwrap();
        let line = status.lines().find(|l| l.starts_with("Cpus_allowed_list:")).unwrap();
        line.split_whitespace().nth(1).unwrap().to_string()
    };
    let last_core = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1) - 1;
    let core = last_core.to_string();
    let pinned = Rig::start_with("fr3.toml", &["--core", &core]);
    assert_eq!(allowed(pinned.hal.0.id()), core, "the HAL loop is not pinned to core {core}");
    if last_core > 0 {
        let free = Rig::start("fr3.toml");
        assert_ne!(allowed(free.hal.0.id()), core, "without --core the HAL must not pin itself");
    }
}

/// "Late" means answering any frame older than the newest one the HAL built, so an on-time answer must reach the
/// HAL within the same 1 ms tick: a test process stalled by the machine misses that now and then. The on-time case
/// is therefore tried until one lands (each miss is counted and shown), and the late case is checked against the
/// count before it.
#[test]
fn a_command_answering_an_old_frame_is_counted_late_not_out_of_limits() {
    let rig = Rig::start("fr3.toml");
    let here = rig.latest().applied_position[..7].to_vec();
    let (mut seq, mut misses) = (0, Vec::new());
    let s = loop {
        // On time: answers the newest frame, holding the HAL's own setpoint (the measured start).
        let newest = rig.latest();
        seq += 1;
        rig.commands.send(&JointCommand::position(9, seq, newest.seq, &here)).unwrap();
        let s = rig.wait_for("the command", Duration::from_secs(5), |f| f.session == 9 && f.last_command_seq == seq);
        if s.late_commands == misses.len() as u64 {
            break s;
        }
        misses.push(s.seq - newest.seq);
        assert!(
            misses.len() < 20,
            "no answer to the newest frame arrived within its tick; ticks late each: {misses:?}"
        );
    };
    // Late: answers a frame 50 ticks old (the same target, so nothing about it is out of limits).
    rig.commands.send(&JointCommand::position(9, seq + 1, s.seq.saturating_sub(50), &here)).unwrap();
    let s = rig.wait_for("the late command", Duration::from_secs(5), |f| f.last_command_seq == seq + 1);
    assert_eq!(s.late_commands, misses.len() as u64 + 1);
    assert_eq!((s.rejected_commands, s.clamped_commands), (0, 0));
    assert_eq!(s.gripper_target, JointCommand::default().gripper);
}

#[test]
fn a_stopped_and_continued_hal_keeps_running() {
    // SIGCONT interrupts the loop's sleep; only SIGTERM/SIGINT may end it (it used to exit on any interrupted sleep).
    let mut rig = Rig::start("fr3.toml");
    let pid = rig.hal.0.id() as libc::pid_t;
    // SAFETY: kill(2) on our own, running child.
    unsafe {
        assert_eq!(libc::kill(pid, libc::SIGSTOP), 0);
        std::thread::sleep(Duration::from_millis(50));
        assert_eq!(libc::kill(pid, libc::SIGCONT), 0);
    }
    let s = rig.latest();
    let later = rig.wait_for("frames after SIGCONT", Duration::from_secs(5), |f| f.seq > s.seq + 200);
    assert!(later.seq > s.seq);
    assert!(rig.hal.0.try_wait().unwrap().is_none(), "the HAL exited after SIGCONT");
}

/// A restarted HAL (systemd's `Restart=on-failure`) finds the arm wherever it is: it holds it there and leaves
/// the gripper as it is, it does not jump to `home` or close the gripper.
#[test]
fn the_hal_starts_from_the_measured_pose_and_gripper_not_from_home() {
    let start = [0.3, -0.2, 0.1, -2.0, 0.2, 1.9, 0.5];
    let profile = TempProfile::fr3_starting_at(&start, 0.031);
    let rig = Rig::start_at(&profile.path(), &[]);
    let frames = collect(&rig, Duration::from_secs(5), |s| s.seq >= 300);
    assert!(frames.len() > 100, "{} frames", frames.len());
    // The setpoint is the first measurement (the sim's noise is 1e-5 rad) and never changes.
    let held = frames[0].applied_position;
    for s in &frames {
        assert_eq!(s.session, 0);
        assert_eq!(s.applied_position, held, "seq {}", s.seq);
        for (i, q) in start.iter().enumerate() {
            assert!((held[i] - q).abs() < 1e-4, "joint {i}: holds {} not the measured {q}", held[i]);
            assert!((s.position[i] - q).abs() < 1e-3, "the arm stays where it was: {}", s.position[i]);
        }
        assert_eq!(s.gripper_target, 0.031, "seq {}", s.seq);
        assert!((s.gripper - 0.031).abs() < 1e-12, "the gripper stays where it was: {}", s.gripper);
    }
}

/// A measured pose outside the limits: mars-hal refuses to start, says why, publishes and commands nothing.
#[test]
fn a_start_outside_the_limits_is_refused_and_nothing_is_commanded() {
    let _rt = rt_rig_lock().expect("taking the real-time rig lock");
    let profile = TempProfile::fr3_starting_at(&[0.0, -FRAC_PI_4, 0.0, -0.05, 0.0, FRAC_PI_2, FRAC_PI_4], 0.04);
    let robot = unique_robot();
    let ns = RobotNamespace::new(&robot).unwrap();
    let (node, _) = create_node("hal-test").unwrap();
    let states = StateReader::new(&node, &ns).unwrap();
    let out = Command::new(env!("CARGO_BIN_EXE_mars-hal"))
        .args(["--profile", &profile.path(), "--robot", &robot, "--duration-s", "5"])
        .env("RUST_LOG", "warn")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("joint 3 is at -0.0500 rad, outside") && stderr.contains("nothing was commanded"),
        "{stderr}"
    );
    assert!(states.receive().unwrap().is_none(), "a HAL that refused to start published a frame");
}

/// A streaming controller; the backend's read fails for 5 ticks while the arm moves. The HAL brakes to rest and
/// holds (HalError), flags the frames, keeps running, and follows a new session afterwards.
#[test]
fn a_backend_error_while_moving_brakes_and_holds_and_the_hal_keeps_running() {
    let rig = Rig::start_with("fr3.toml", &["--read-error-at-tick", "1200", "--read-error-ticks", "5"]);
    let start = rig.latest();
    let here = start.applied_position[..7].to_vec();
    // Moving at ~0.2 rad/s on every joint when the errors come (tick 1200 ≈ 1.2 s after the start).
    let last = rig.stream(1, 2.0, |t| here.iter().map(|h| h + 0.2 * t).collect());
    assert!(last.seq > 1300, "the stream outlived the errors: {}", last.seq);
    let frames = collect(&rig, Duration::from_secs(2), |s| s.seq > last.seq + 1000);
    let s = rig.wait_for("the hold", Duration::from_secs(1), |s| s.seq >= last.seq);
    assert_eq!(s.hold_reason, HoldReason::HalError as u32, "{s:?}");
    assert!(s.is(status::BACKEND_ERROR) && s.is(status::HOLDING) && s.is(status::AT_REST), "{s:?}");
    assert_eq!(s.backend_errors, 5);
    assert!(frames.iter().all(|f| f.fault == 0), "reads work again after the 5 errors");
    // A new session is followed.
    let held = s.applied_position[..7].to_vec();
    let resumed = rig.stream(2, 0.3, |_| held.clone());
    let s = rig.wait_for("the new session", Duration::from_secs(1), |s| s.seq > resumed.seq);
    assert_eq!((s.session, s.hold_reason), (2, HoldReason::None as u32));
}

/// The backend fails for good while the arm moves: the HAL brakes to rest, publishes that, then exits 1 saying
/// why (and only then).
#[test]
fn a_fatal_backend_error_brakes_to_rest_and_then_exits() {
    let mut rig = Rig::start_with("fr3.toml", &["--fatal-at-tick", "1000"]);
    let start = rig.latest();
    let here = start.applied_position[..7].to_vec();
    // Stream a motion (~0.3 rad/s on every joint) and keep every frame until the process ends.
    let (t0, mut seq, mut frames) = (Instant::now(), 0, Vec::new());
    let status = loop {
        while let Some(f) = rig.states.receive().unwrap() {
            seq += 1;
            let t = t0.elapsed().as_secs_f64();
            let q: Vec<f64> = here.iter().map(|h| h - 0.3 * t).collect();
            rig.commands.send(&JointCommand::position(1, seq, f.seq, &q)).unwrap();
            frames.push(f);
        }
        if let Some(status) = rig.hal.0.try_wait().unwrap() {
            break status;
        }
        assert!(t0.elapsed() < Duration::from_secs(10), "mars-hal still running 10 s after its backend failed");
        std::thread::sleep(Duration::from_micros(200));
    };
    while let Some(f) = rig.states.receive().unwrap() {
        frames.push(f);
    }
    assert_eq!(status.code(), Some(1), "{status:?}");
    let moving = frames.iter().find(|f| f.seq == 1000).expect("the frame of the failure");
    assert!(moving.applied_velocity[..7].iter().all(|v| v.abs() > 0.2), "moving when it failed: {moving:?}");
    let after: Vec<&RobotState> = frames.iter().filter(|f| f.seq > 1000).collect();
    let last = after.last().expect("frames after the failure");
    assert!(last.is(status::AT_REST), "the last frame before the exit is at rest: {last:?}");
    assert_eq!(last.hold_reason, HoldReason::HalError as u32);
    assert!(after.iter().all(|f| f.fault & fault::NO_MEASUREMENT != 0), "every frame after the failure is flagged");
    assert!(after.len() > 50, "it braked over {} frames before exiting", after.len());
}
