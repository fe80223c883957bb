//! marsd's servo tick and the HAL's tick, both as plain logic, on one simulated clock: the HAL ticks every
//! millisecond; the servo ticks 300 µs after each HAL tick, except that (seeded, at random) it sometimes ticks
//! twice between two HAL ticks (the second tick finds no new frame and sends nothing), wakes so late that it skips a frame (the HAL gets no
//! command in one tick), or sends a command that reaches the HAL only after its next tick (a late command).
//! That is what a noisy machine does to the two processes; the test makes it happen thousands of times in a few
//! seconds, deterministically, while the servo runs reset motions between random poses.
//!
//! Whatever the timing, the servo's smoother never fails, the HAL never has to clamp a command (late ones are
//! timing, counted apart), it never gets two answers to one frame, and its applied setpoints stay within every
//! limit. The same with a robot whose clock runs slower than marsd's.

use std::path::{Path, PathBuf};
use std::time::Duration;

use mars_hal::backend::Backend;
use mars_hal::control::HalControl;
use mars_hal::events::EventLogger;
use mars_hal::sim::SimBackend;
use mars_ipc::{JointCommand, MAX_JOINTS, RobotState};
use mars_profile::Profile;
use mars_runtime::config::DaemonConfig;
use mars_runtime::servo::{ServoTick, StopCause, TickInput};
use mars_runtime::shared::{Phase, Request};

const MS: u64 = 1_000_000;

fn root() -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/..")).canonicalize().unwrap()
}

/// Tiny deterministic generator.
struct Lcg(u64);
impl Lcg {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[derive(Debug, Default)]
struct Outcome {
    stop: Option<StopCause>,
    resets: u64,
    clamped: u64,
    rejected: u64,
    late: u64,
    duplicates: u64,
    /// Servo ticks that found no new frame (and sent nothing).
    frameless: u64,
    last_resorts: u64,
    worst: [f64; 3],
    /// Setpoint resyncs to a robot history that differs from the HAL's (see [`run_with_robot_resyncs`]).
    robot_resyncs: u64,
}

/// One servo and one HAL (on the mock plant) for `resets` reset motions between seeded random poses, stepped by
/// the caller on its simulated clock.
struct Rig {
    sim: SimBackend,
    hal: HalControl,
    ev: mars_hal::events::EventSender,
    logger: EventLogger,
    servo: ServoTick,
    rng: Lcg,
    profile: Profile,
    q_lo: Vec<f64>,
    q_hi: Vec<f64>,
    resets: u64,
    episode: u64,
    finishing: bool,
}

impl Rig {
    fn new(seed: u64, resets: u64) -> Self {
        let root = root();
        let cfg = DaemonConfig::load(&root.join("configs/marsd.toml")).unwrap();
        let mut profile = Profile::load(&root.join("configs/fr3.toml")).unwrap();
        profile.sim.seed = seed;
        let mut sim = SimBackend::new(&profile);
        let hal = HalControl::start(&profile, &sim.read().unwrap()).unwrap();
        let (ev, logger) = EventLogger::start(4096, Duration::from_millis(5), |_| {}).unwrap();
        let servo = ServoTick::new(&cfg, &profile, 7).unwrap();
        let (q_lo, q_hi) = profile.position_limits();
        let rng = Lcg(seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1);
        Self { sim, hal, ev, logger, servo, rng, profile, q_lo, q_hi, resets, episode: 0, finishing: false }
    }

    /// The servo's tick at `now` with the frames that arrived since its last one: the next reset (or the finish
    /// once all are done) when it is idle, and the command it sends, if any.
    fn servo_tick(&mut self, now: u64, arrived: &[RobotState]) -> Option<JointCommand> {
        for f in arrived {
            self.servo.note_frame_timing(f);
        }
        let request = match self.servo.phase() {
            Phase::Idle | Phase::Ready if !self.finishing => {
                if self.episode == self.resets {
                    self.finishing = true;
                    Some(Request::Finish)
                } else {
                    self.episode += 1;
                    let mut pose = [0.0; MAX_JOINTS];
                    for (j, p) in pose.iter_mut().enumerate().take(self.q_lo.len()) {
                        let (lo, hi) = (self.q_lo[j] + 0.3, self.q_hi[j] - 0.3);
                        *p = lo + (hi - lo) * self.rng.unit();
                    }
                    Some(Request::MoveTo { episode: self.episode, pose, gripper: 0.07 })
                }
            }
            _ => None,
        };
        let input = TickInput {
            now_ns: now,
            missed: 0,
            frame: arrived.last(),
            chunk: None,
            request,
            stop_requested: false,
            hal_gone: false,
        };
        self.servo.tick(&input).command
    }

    /// The HAL's tick at `h`: read, the commands that arrived, step, apply, publish.
    fn hal_tick(&mut self, h: u64, commands: &mut Vec<JointCommand>) -> RobotState {
        self.hal.begin_tick(h);
        self.hal.on_read(self.sim.read(), &mut self.ev);
        for c in commands.drain(..) {
            self.hal.on_command(&c, &mut self.ev);
        }
        let step = self.hal.step(20, &mut self.ev);
        let (setpoint, gripper) = (step.setpoint.to_vec(), step.gripper);
        let r = self.sim.apply(&setpoint);
        self.hal.on_apply(r, &mut self.ev);
        if let Some(g) = gripper {
            let r = self.sim.move_gripper(g);
            self.hal.on_gripper(r, &mut self.ev);
        }
        self.hal.state_frame(h)
    }

    fn finish(mut self, worst: [f64; 3]) -> Outcome {
        drop(self.ev);
        self.logger.finish();
        let last = self.hal.state_frame(0);
        Outcome {
            stop: self.servo.stop_cause(),
            resets: self.episode,
            clamped: last.clamped_commands,
            rejected: last.rejected_commands,
            late: last.late_commands,
            duplicates: last.duplicate_commands,
            frameless: self.servo.counters.frameless_ticks,
            last_resorts: last.position_guard_hits + last.infeasible_steps,
            worst,
            robot_resyncs: 0,
        }
    }
}

/// Runs `resets` reset motions with the servo ticking as described in the module doc, for seed `seed`.
fn run(seed: u64, resets: u64, p_fault: f64) -> Outcome {
    run_with_robot_resyncs(seed, resets, p_fault, 0.0)
}

/// [`run`], and before a HAL tick, with probability `p_resync`, the robot's setpoint history differs from the
/// HAL's as franka-sim's does after it extrapolated over a state the HAL never saw: the same position (q_d is the
/// HAL's last setpoint) but the one before it elsewhere, so the robot's finite-difference velocity and
/// acceleration (dq_d, ddq_d) differ from the HAL's; the HAL continues from them (`resync_setpoint`), as its fci
/// backend does. It comes in the HAL tick that takes the servo's first command after a re-synchronisation of its
/// own (after a late command), as in the clamp franka-sim showed: the command continues the servo's new stream
/// from the last frame, and the robot's history moved under it.
fn run_with_robot_resyncs(seed: u64, resets: u64, p_fault: f64, p_resync: f64) -> Outcome {
    let mut rig = Rig::new(seed, resets);
    let n = rig.q_lo.len();
    let (dq_max, ddq_max, jerk_max) =
        (rig.profile.dq_max.clone(), rig.profile.ddq_max.clone(), rig.profile.jerk_max.clone());
    // Frames in flight to the servo and commands in flight to the HAL, with the time they were sent.
    let mut to_servo: Vec<RobotState> = Vec::new();
    let mut to_hal: Vec<JointCommand> = Vec::new();
    // Commands that reach the HAL only after its next tick: while `delaying`, every command sent (the wire is
    // FIFO: a later one cannot overtake a delayed one).
    let mut delayed: Vec<JointCommand> = Vec::new();
    let mut delaying = false;
    let mut worst = [0.0f64; 3];
    let mut prev: Vec<[f64; MAX_JOINTS]> = Vec::new();
    // Servo tick times not yet run (planned one HAL period ahead).
    let mut servo_ticks: Vec<u64> = Vec::new();
    let (mut robot_resyncs, mut servo_resyncs) = (0u64, 0u64);
    'run: for k in 1..200_000u64 {
        let h = k * MS;
        // The servo's ticks before this HAL tick: each sees the frames published by then and sends a command
        // that the HAL takes at its first tick after it.
        while let Some(&now) = servo_ticks.first()
            && now < h
        {
            servo_ticks.remove(0);
            let arrived: Vec<RobotState> = to_servo.iter().filter(|f| f.timestamp_ns <= now).copied().collect();
            to_servo.retain(|f| f.timestamp_ns > now);
            if let Some(cmd) = rig.servo_tick(now, &arrived) {
                if delaying { delayed.push(cmd) } else { to_hal.push(cmd) }
            }
            if rig.servo.phase() == Phase::Finished {
                break 'run;
            }
        }
        let servo_resynced = rig.servo.counters.resyncs > servo_resyncs;
        servo_resyncs = rig.servo.counters.resyncs;
        if servo_resynced && p_resync > 0.0 && rig.rng.unit() < p_resync {
            // The robot's previous position ε off the HAL's: its velocity ε/dt lower, its acceleration 2ε/dt²
            // lower; ε chosen so that the robot's acceleration is half the limit, one way or the other (a robot
            // braking or speeding up over the state the HAL missed).
            let f = rig.hal.filter();
            let (q, mut v, mut a) = (f.position().to_vec(), f.velocity().to_vec(), f.acceleration().to_vec());
            let dt = 1e-3;
            for j in 0..n {
                let a_robot = if rig.rng.unit() < 0.5 { -0.5 } else { 0.5 } * ddq_max[j];
                let eps = (a[j] - a_robot) * dt * dt / 2.0;
                v[j] -= eps / dt;
                a[j] = a_robot;
            }
            rig.hal.resync_setpoint(&q, &v, &a);
            robot_resyncs += 1;
            // The robot's jerk at the next tick is from its acceleration, not the HAL's last frame's.
            if let Some(last) = prev.last_mut() {
                last[..n].copy_from_slice(&a);
            }
        }
        let frame = rig.hal_tick(h, &mut to_hal);
        to_hal.append(&mut delayed);
        delaying = false;
        // The HAL's applied stream, differentiated like the robot does: its frames' velocity and acceleration are
        // the finite differences over the robot's own history (which a robot resync replaces), the jerk theirs.
        prev.push(frame.applied_acceleration);
        if prev.len() > 2 {
            prev.remove(0);
        }
        if prev.len() == 2 {
            for j in 0..n {
                let (v, a) = (frame.applied_velocity[j], frame.applied_acceleration[j]);
                let jerk = (prev[1][j] - prev[0][j]) * 1e3;
                let ratios = [v / dq_max[j], a / ddq_max[j], jerk / jerk_max[j]];
                for (w, x) in worst.iter_mut().zip(ratios) {
                    *w = w.max(x.abs());
                }
            }
        }
        to_servo.push(frame);

        // The servo's ticks in this period: normally one at +0.3 ms; sometimes one more at +0.8 (a double tick:
        // the second finds no new frame); sometimes the one at +0.3 comes at +1.2 instead (after the HAL's next
        // tick and frame: this frame is skipped); sometimes its command is delivered after the HAL's next tick.
        let u = rig.rng.unit() / p_fault;
        if u < 1.0 {
            servo_ticks.extend([h + 300_000, h + 800_000]);
        } else if u < 2.0 {
            servo_ticks.push(h + 1_200_000);
        } else {
            delaying = u < 3.0;
            servo_ticks.push(h + 300_000);
        }
        servo_ticks.sort_unstable();
    }
    let mut o = rig.finish(worst);
    o.robot_resyncs = robot_resyncs;
    o
}

#[test]
fn a_noisy_servo_timing_never_fails_the_smoother_nor_makes_the_hal_clamp() {
    let (mut late, mut frameless) = (0, 0);
    for seed in 0..30 {
        let o = run(seed, 12, 0.02);
        eprintln!("seed {seed}: {o:?}");
        assert_eq!(o.stop, Some(StopCause::Finished), "seed {seed}: {o:?}");
        assert_eq!(o.resets, 12, "seed {seed}");
        assert_eq!((o.clamped, o.rejected, o.last_resorts), (0, 0, 0), "seed {seed}: {o:?}");
        assert!(o.worst.iter().all(|w| *w <= 1.0 + 1e-6), "seed {seed}: {o:?}");
        late += o.late;
        assert_eq!(o.duplicates, 0, "one command per frame: seed {seed}: {o:?}");
        frameless += o.frameless;
    }
    assert!(late > 100 && frameless > 100, "the timing faults happened: {late} late, {frameless} frameless ticks");
}

/// franka-sim's occasional clamp (stop 33's open problem in issue 12), reproduced: after the robot extrapolated over
/// a state the HAL never saw, its q_d is the HAL's last setpoint but its dq_d and ddq_d are not, and the HAL
/// continues from them. The servo's next command continues its own stream, whose velocity the HAL's frame still
/// matches; the acceleration it does not, and a command that ignores that jumps the robot's acceleration by up to
/// a limit's worth in one tick (the HAL clamped "implied jerk" ≈ 2 × the limit). The servo must re-synchronise on
/// the acceleration too: with a robot resync after every other servo resync, no command is clamped and the applied
/// stream stays within the limits as the robot differentiates it.
#[test]
fn a_robot_setpoint_resync_that_changes_only_velocity_and_acceleration_is_followed_without_a_clamp() {
    let mut resyncs = 0;
    for seed in 0..30 {
        let o = run_with_robot_resyncs(seed, 6, 0.02, 0.5);
        eprintln!("seed {seed}: {o:?}");
        assert_eq!(o.stop, Some(StopCause::Finished), "seed {seed}: {o:?}");
        assert_eq!((o.clamped, o.rejected, o.last_resorts), (0, 0, 0), "seed {seed}: {o:?}");
        assert!(o.worst.iter().all(|w| *w <= 1.0 + 1e-6), "seed {seed}: {o:?}");
        resyncs += o.robot_resyncs;
    }
    assert!(resyncs > 100, "the robot resynced {resyncs} times");
}

/// One servo and one HAL on the simulated clock; from HAL tick `nan_from` on, joint 3 measures NaN (as the HAL's
/// fault injection does). The servo ticks `offset_ns` after each HAL tick, except that it stalls for `stall_ms`
/// starting 19 ms after the first NaN frame (when both sides' 20 ms limits are about to run out). Returns the cause
/// the servo reports.
fn nan_sensor_run(offset_ns: u64, stall_ms: u64, nan: bool) -> Option<StopCause> {
    let root = root();
    let cfg = DaemonConfig::load(&root.join("configs/marsd.toml")).unwrap();
    let profile = Profile::load(&root.join("configs/fr3.toml")).unwrap();
    let mut sim = SimBackend::new(&profile);
    let mut hal = HalControl::start(&profile, &sim.read().unwrap()).unwrap();
    let (mut ev, logger) = EventLogger::start(4096, Duration::from_millis(5), |_| {}).unwrap();
    let mut servo = ServoTick::new(&cfg, &profile, 7).unwrap();
    let nan_from = 500u64;
    let stall = ((nan_from + 19) * MS + offset_ns)..((nan_from + 19 + stall_ms) * MS + offset_ns);
    let mut to_servo: Vec<RobotState> = Vec::new();
    let mut to_hal: Vec<JointCommand> = Vec::new();
    let mut next_servo = MS + offset_ns;
    for k in 1..2_000u64 {
        let h = k * MS;
        while next_servo < h {
            let now = next_servo;
            next_servo += MS;
            if stall.contains(&now) {
                continue;
            }
            let arrived = std::mem::take(&mut to_servo);
            for f in &arrived {
                servo.note_frame_timing(f);
            }
            let missed = if now == stall.end && stall_ms > 0 { stall_ms } else { 0 };
            let input = TickInput {
                now_ns: now,
                missed,
                frame: arrived.last(),
                chunk: None,
                request: None,
                stop_requested: false,
                hal_gone: false,
            };
            if let Some(cmd) = servo.tick(&input).command {
                to_hal.push(cmd);
            }
            if servo.stop_cause().is_some() {
                drop(ev);
                logger.finish();
                return servo.stop_cause();
            }
        }
        hal.begin_tick(h);
        hal.on_read(sim.read(), &mut ev);
        for c in to_hal.drain(..) {
            hal.on_command(&c, &mut ev);
        }
        let step = hal.step(20, &mut ev);
        let setpoint = step.setpoint.to_vec();
        let r = sim.apply(&setpoint);
        hal.on_apply(r, &mut ev);
        let mut frame = hal.state_frame(h);
        if nan && k >= nan_from {
            frame.position[3] = f64::NAN;
        }
        to_servo.push(frame);
    }
    drop(ev);
    logger.finish();
    servo.stop_cause()
}

/// A NaN sensor makes both sides' limits run out together: marsd has no usable frame for its allowed gap (20 ms),
/// and the HAL, whose commands from marsd all answer the last usable frame, gets no new one for its command
/// timeout (20 ms). Which one marsd notices first depends on the two processes' phase and on a stall of marsd at
/// that moment; the cause it reports must not: it is the state marsd could not use (the HAL's hold follows from
/// it). A stall of marsd without a bad sensor is reported as the HAL's command timeout, which it is.
#[test]
fn a_nan_sensor_is_reported_as_unusable_state_whatever_the_timing() {
    use mars_ipc::HoldReason;
    use mars_runtime::servo::watchdog::Trip;
    for offset_us in [50, 300, 700, 950] {
        for stall_ms in [0, 2, 5, 25] {
            let cause = nan_sensor_run(offset_us * 1000, stall_ms, true);
            assert_eq!(cause, Some(StopCause::Trip(Trip::StaleState)), "offset {offset_us} µs, stall {stall_ms} ms");
        }
        let cause = nan_sensor_run(offset_us * 1000, 25, false);
        assert_eq!(
            cause,
            Some(StopCause::Trip(Trip::HalHolding(HoldReason::CommandTimeout))),
            "no NaN, offset {offset_us} µs, stall 25 ms"
        );
    }
}

/// A robot slower than marsd's clock (franka-sim runs at 0.6–0.9× real time on a loaded machine): the HAL ticks
/// every `robot_period_ns` of marsd's time while the servo ticks every millisecond, so the servo often finds no
/// new frame.
fn slow_robot_run(seed: u64, resets: u64, robot_period_ns: u64) -> Outcome {
    let mut rig = Rig::new(seed, resets);
    let mut to_servo: Vec<RobotState> = Vec::new();
    let mut to_hal: Vec<JointCommand> = Vec::new();
    let mut next_servo = 300_000u64;
    'run: for k in 1..400_000u64 {
        let h = k * robot_period_ns;
        while next_servo < h {
            let arrived = std::mem::take(&mut to_servo);
            if let Some(cmd) = rig.servo_tick(next_servo, &arrived) {
                to_hal.push(cmd);
            }
            next_servo += MS;
            if rig.servo.phase() == Phase::Finished {
                break 'run;
            }
        }
        to_servo.push(rig.hal_tick(h, &mut to_hal));
    }
    rig.finish([0.0; 3])
}

#[test]
fn a_robot_slower_than_the_servo_clock_gets_one_command_per_frame_and_none_clamped() {
    for (seed, period_us) in [(0, 1100), (1, 1250), (2, 1430), (3, 1670)] {
        let o = slow_robot_run(seed, 6, period_us * 1000);
        eprintln!("robot period {period_us} µs: {o:?}");
        assert_eq!(o.stop, Some(StopCause::Finished), "period {period_us} µs: {o:?}");
        assert_eq!(o.resets, 6);
        assert_eq!((o.clamped, o.rejected, o.last_resorts), (0, 0, 0), "period {period_us} µs: {o:?}");
        assert_eq!(o.duplicates, 0, "one command per frame: period {period_us} µs: {o:?}");
        assert!(o.frameless > 0, "the servo's clock ran ahead: period {period_us} µs: {o:?}");
    }
}

/// A chunk that becomes due in a tick with no new frame is adopted in the next tick that has one, and that tick's
/// command reports the chunk's camera capture time: every adopted chunk gets its capture → command latency (CI saw
/// 22 latencies for 23 adopted chunks when the frameless tick adopted and sent nothing).
#[test]
fn a_chunk_due_in_a_frameless_tick_reports_its_capture_with_the_next_command() {
    use mars_runtime::servo::chunk::TimedChunk;
    let root = root();
    let cfg = DaemonConfig::load(&root.join("configs/marsd.toml")).unwrap();
    let profile = Profile::load(&root.join("configs/fr3.toml")).unwrap();
    let mut servo = ServoTick::new(&cfg, &profile, 7).unwrap();
    let n = profile.home.len();
    let frame = |seq: u64, now: u64| {
        let mut f = RobotState { seq, timestamp_ns: now, num_joints: n as u32, gripper: 0.07, ..Default::default() };
        f.position[..n].copy_from_slice(&profile.home);
        f.applied_position[..n].copy_from_slice(&profile.home);
        f
    };
    fn input<'a>(
        now: u64,
        frame: Option<&'a RobotState>,
        chunk: Option<&'a TimedChunk>,
        request: Option<Request>,
    ) -> TickInput<'a> {
        TickInput { now_ns: now, missed: 0, frame, chunk, request, stop_requested: false, hal_gone: false }
    }
    // At home, a reset to home: the servo is at rest there at once and waits for the policy's chunk.
    let mut pose = [0.0; MAX_JOINTS];
    pose[..n].copy_from_slice(&profile.home);
    let t0 = 1000 * MS;
    let (f1, f2) = (frame(1, t0), frame(2, t0 + MS));
    servo.tick(&input(t0, Some(&f1), None, None));
    servo.tick(&input(t0 + MS, Some(&f2), None, Some(Request::MoveTo { episode: 1, pose, gripper: 0.07 })));
    let mut now = t0 + 2 * MS;
    for seq in 3.. {
        let f = frame(seq, now);
        assert!(servo.tick(&input(now, Some(&f), None, None)).command.is_some());
        now += MS;
        if servo.phase() == Phase::Ready {
            break;
        }
        assert!(seq < 100, "the reset to the pose it is at never settled: {:?}", servo.phase());
    }
    // A chunk holding the pose, its first action due now: adoptable at once.
    let mut chunk = TimedChunk {
        seq: 1 << 32 | 1,
        episode: 1,
        first_due_ns: now + MS,
        period_ns: 10 * MS,
        len: 4,
        ready_ns: now,
        capture_ns: now - 20 * MS,
        ..Default::default()
    };
    for a in chunk.actions.iter_mut().take(4) {
        a[..n].copy_from_slice(&profile.home);
        a[n] = 0.07;
    }
    let frameless = servo.tick(&input(now, None, Some(&chunk), None));
    assert!(frameless.command.is_none() && frameless.adopted_capture_ns.is_none(), "{frameless:?}");
    assert_eq!(servo.counters.chunks_adopted, 0, "adopted in a tick that sent nothing");
    let f = frame(1000, now + MS / 2);
    let next = servo.tick(&input(now + MS / 2, Some(&f), None, None));
    assert!(next.command.is_some(), "{next:?}");
    assert_eq!(next.adopted_capture_ns, Some(chunk.capture_ns));
    assert_eq!(servo.counters.chunks_adopted, 1);
    assert_eq!(servo.phase(), Phase::Running);
}

/// The rule the test above exercises, directly: a frame in which the HAL applied the servo's last command (the same
/// position and velocity) but reports another acceleration (the robot's history moved under it) makes the servo
/// re-synchronise, and its next command, differentiated from that frame as the robot differentiates, is within the
/// jerk limit.
#[test]
fn a_frame_whose_acceleration_is_not_the_servo_s_makes_it_resync_and_stay_within_the_jerk_limit() {
    let mut rig = Rig::new(3, 1);
    let n = rig.q_lo.len();
    let (ddq_max, jerk_max) = (rig.profile.ddq_max.clone(), rig.profile.jerk_max.clone());
    let mut to_hal = Vec::new();
    let mut h = 0;
    // Lock-step, the servo 0.3 ms after each HAL tick, until the first reset motion is well under way.
    let frame = loop {
        h += MS;
        assert!(h < 20_000 * MS, "the arm never moved");
        let f = rig.hal_tick(h, &mut to_hal);
        if f.applied_velocity[..n].iter().any(|v| v.abs() > 0.2) {
            break f;
        }
        if let Some(c) = rig.servo_tick(h + 300_000, &[f]) {
            to_hal.push(c);
        }
    };
    let before = rig.servo.counters.resyncs;
    let mut f = frame;
    for (a, a_max) in f.applied_acceleration.iter_mut().zip(&ddq_max) {
        *a = if *a > 0.0 { -0.5 } else { 0.5 } * a_max;
    }
    let c = rig.servo_tick(h + 300_000, &[f]).expect("a command for the frame");
    assert_eq!(rig.servo.counters.resyncs, before + 1, "the servo re-synchronised to the frame's acceleration");
    let dt = 1e-3;
    for (j, &j_max) in jerk_max.iter().enumerate() {
        let v = (c.position[j] - f.applied_position[j]) / dt;
        let a = (v - f.applied_velocity[j]) / dt;
        let jerk = (a - f.applied_acceleration[j]) / dt;
        assert!(jerk.abs() <= j_max * (1.0 + 1e-6), "joint {j}: jerk {jerk} against the limit {j_max}");
    }
}
