//! The servo thread, the robot's side of marsd. A state frame enters in [`servo_loop`] and is judged by [`frame`];
//! the policy's time-stamped chunks ([`chunk`]) become a reference, smoothed by ruckig ([`smoothing`]) or, for a
//! policy that acts on the table, through the arm's kinematics ([`effector`]); [`limits`] is the last check before
//! the command leaves in [`servo_loop`]; [`timeliness`] says whether it reached the HAL in time, and [`watchdog`]
//! when misses are too many.
//!
//! One servo tick, as plain logic: state frame and chunk in, command out. No I/O here (the loop around it in
//! [`crate::servo::servo_loop`] reads and writes iceoryx2), so the whole decision is testable and provably
//! allocation-free: every field is fixed-size and preallocated in [`ServoTick::new`].
//!
//! Phases: waiting for the HAL → idle (holding) → resetting to an episode's start pose → ready → running the
//! policy's chunks → … → stopping (jerk-limited brake) → finished (a hold command sent to the HAL).

pub mod chunk;
pub mod effector;
pub mod frame;
pub mod limits;
pub mod servo_loop;
pub mod smoothing;
pub mod timeliness;
pub mod watchdog;

use mars_ipc::{CommandMode, HoldReason, JointCommand, MAX_JOINTS, RobotState, status};
use mars_profile::Profile;

use crate::config::DaemonConfig;
use crate::servo::chunk::{MAX_ACTION, Schedule, TimedChunk};
use crate::servo::effector::PlanarEffector;
use crate::servo::frame::FrameCheck;
use crate::servo::limits::LimitCheck;
use crate::servo::smoothing::{Kinematics, Limits, Smoother, SmoothingError};
use crate::servo::timeliness::CommandTimeliness;
use crate::servo::watchdog::{ServoWatchdog, Trip};
use crate::shared::{Observed, Phase, Request};

/// A reset waits until the measured gripper is this close to its target (m).
const GRIPPER_TOLERANCE: f64 = 0.002;

/// Why the loop is stopping.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StopCause {
    /// The episodes are done.
    Finished,
    /// SIGTERM/SIGINT.
    Signal,
    Trip(Trip),
}

/// What the loop hands in each tick.
#[derive(Debug, Clone, Copy)]
pub struct TickInput<'a> {
    pub now_ns: u64,
    /// Servo periods skipped before this tick (a stall).
    pub missed: u64,
    /// The newest state frame read this tick, if any.
    pub frame: Option<&'a RobotState>,
    /// The newest chunk, if the policy published one since the last tick.
    pub chunk: Option<&'a TimedChunk>,
    pub request: Option<Request>,
    pub stop_requested: bool,
    /// The liveness watch says the HAL process is gone.
    pub hal_gone: bool,
}

/// What the tick decided.
#[derive(Debug, Clone, Copy, Default)]
pub struct TickOutput {
    pub command: Option<JointCommand>,
    /// The newest usable state, when this tick accepted one.
    pub observed: Option<Observed>,
    /// The capture time of the camera frame behind the chunk this tick adopted (its first command is this tick's).
    pub adopted_capture_ns: Option<u64>,
}

/// Counters for the report.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct ServoCounters {
    pub ticks: u64,
    pub commands_sent: u64,
    pub chunks_adopted: u64,
    /// Actions skipped because their chunk arrived after they were due.
    pub actions_dropped: u64,
    /// Ticks in `Running` with the chunk used up and no newer one.
    pub starved_ticks: u64,
    /// Policy joint targets moved inside the position limits (minus the margin).
    pub clamped_targets: u64,
    /// Commands that failed the final limit check (never sent). Must be 0.
    pub limit_violations: u64,
    /// Commands that reached the HAL after its next tick (see [`crate::servo::timeliness`]): a deadline miss of its
    /// own — the tick finished, but too late for the HAL.
    pub late_commands: u64,
    /// Times the HAL had not applied the last command exactly (it arrived late, so the HAL smoothed the gap)
    /// and the trajectory continued from the HAL's applied setpoint.
    pub resyncs: u64,
    /// Ticks that found no new state frame and so sent no command (one command per frame).
    pub frameless_ticks: u64,
}

/// The HAL's own counters (from its state frames), since this controller's handshake: the robot side's verdict
/// on the command stream, and its last resorts.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct HalCounts {
    /// Commands refused (NaN, wrong joint count, out of limits under `reject`).
    pub rejected: u64,
    /// Out-of-limit commands clamped into the limits (under `clamp`).
    pub clamped: u64,
    /// Commands that arrived after the tick they answered had passed.
    pub late: u64,
    /// Second commands answering one frame (this controller ticked twice between two frames): not followed.
    pub duplicate: u64,
    /// Ticks the safety filter's position guard stopped a joint at its limit (breaking acc/jerk limits).
    pub position_guard_hits: u64,
    /// Ticks no setpoint satisfied every limit and the filter took the middle of the empty interval.
    pub infeasible_steps: u64,
    /// Errors of the HAL's backend or its own ports.
    pub backend_errors: u64,
}

impl HalCounts {
    fn of(f: &RobotState) -> Self {
        Self {
            rejected: f.rejected_commands,
            clamped: f.clamped_commands,
            late: f.late_commands,
            duplicate: f.duplicate_commands,
            position_guard_hits: f.position_guard_hits,
            infeasible_steps: f.infeasible_steps,
            backend_errors: f.backend_errors,
        }
    }

    fn since(&self, start: &Self) -> Self {
        Self {
            rejected: self.rejected.saturating_sub(start.rejected),
            clamped: self.clamped.saturating_sub(start.clamped),
            late: self.late.saturating_sub(start.late),
            duplicate: self.duplicate.saturating_sub(start.duplicate),
            position_guard_hits: self.position_guard_hits.saturating_sub(start.position_guard_hits),
            infeasible_steps: self.infeasible_steps.saturating_sub(start.infeasible_steps),
            backend_errors: self.backend_errors.saturating_sub(start.backend_errors),
        }
    }
}

pub struct ServoTick {
    n: usize,
    dt_ns: u64,
    session: u64,
    seq: u64,
    smoother: Smoother,
    schedule: Schedule,
    pending: TimedChunk,
    frames: FrameCheck,
    limits: LimitCheck,
    watchdog: ServoWatchdog,
    phase: Phase,
    episode: u64,
    stop: Option<StopCause>,
    pose: [f64; MAX_JOINTS],
    gripper_target: f64,
    gripper: f64,
    q_lo: [f64; MAX_JOINTS],
    q_hi: [f64; MAX_JOINTS],
    g_lo: f64,
    g_hi: f64,
    settle_tolerance: f64,
    /// Resets move at this fraction of the velocity limits (`servo.reset_speed`).
    reset_speed: f64,
    last_state: RobotState,
    /// The HAL has followed this session at least once (so a HOLDING status afterwards means it stopped).
    followed: bool,
    /// A frame was refused for its content since the last usable one: marsd has nothing new to answer, so every
    /// command it sends answers an old frame and the HAL's command timeout runs out too.
    refused_for_content: bool,
    /// A policy acting on the table: its (x, y) references become joint targets here. `None`: the actions are
    /// joint targets and the gripper.
    effector: Option<PlanarEffector>,
    /// The HAL's counters at the handshake: the HAL counts since it started.
    hal_counts_at_start: HalCounts,
    /// Whether each command reached the HAL before its next tick.
    timeliness: CommandTimeliness,
    /// The first command refused by the final check, for the report.
    pub first_violation: Option<crate::servo::limits::Violation>,
    /// The smoother's first refusal (a trip; the tick cannot log), for the report.
    pub first_smoothing_error: Option<SmoothingError>,
    pub counters: ServoCounters,
}

impl ServoTick {
    pub fn new(cfg: &DaemonConfig, profile: &Profile, session: u64) -> Result<Self, SmoothingError> {
        let n = profile.joints;
        let margin = cfg.servo.position_margin;
        let (mut q_lo, mut q_hi) = ([0.0; MAX_JOINTS], [0.0; MAX_JOINTS]);
        let (q_min, q_max) = profile.position_limits();
        for j in 0..n {
            q_lo[j] = q_min[j] + margin;
            q_hi[j] = q_max[j] - margin;
        }
        Ok(Self {
            n,
            dt_ns: (profile.period_s() * 1e9).round() as u64,
            session,
            seq: 0,
            smoother: Smoother::new(n, profile.period_s(), &Limits::from_profile(profile))?,
            schedule: Schedule::new(n + 1),
            pending: TimedChunk::default(),
            frames: FrameCheck::new(n, (cfg.servo.stale_state_ms * 1e6) as u64),
            limits: LimitCheck::new(profile),
            watchdog: ServoWatchdog::new(&cfg.watchdog),
            phase: Phase::WaitingForHal,
            episode: 0,
            stop: None,
            pose: [0.0; MAX_JOINTS],
            gripper_target: profile.gripper_min,
            gripper: profile.gripper_min,
            q_lo,
            q_hi,
            g_lo: profile.gripper_min,
            g_hi: profile.gripper_max,
            settle_tolerance: cfg.servo.settle_tolerance,
            reset_speed: cfg.servo.reset_speed,
            last_state: RobotState::default(),
            followed: false,
            refused_for_content: false,
            effector: None,
            hal_counts_at_start: HalCounts::default(),
            timeliness: CommandTimeliness::default(),
            first_violation: None,
            first_smoothing_error: None,
            counters: ServoCounters::default(),
        })
    }

    /// Actions are planar end-effector references (x, y) for `effector` instead of joint targets.
    pub fn with_effector(mut self, effector: PlanarEffector) -> Self {
        self.schedule = Schedule::new(2);
        self.effector = Some(effector);
        self
    }

    pub fn effector(&self) -> Option<&PlanarEffector> {
        self.effector.as_ref()
    }

    pub fn phase(&self) -> Phase {
        self.phase
    }

    pub fn episode(&self) -> u64 {
        self.episode
    }

    pub fn stop_cause(&self) -> Option<StopCause> {
        self.stop
    }

    pub fn frames(&self) -> &FrameCheck {
        &self.frames
    }

    fn stop_with(&mut self, cause: StopCause) {
        // The first cause is the one reported — except that a dead HAL explains the stale state it caused
        // (the liveness watch needs 10–20 ms, as long as the state-gap limit).
        if self.stop.is_none()
            || (self.stop == Some(StopCause::Trip(Trip::StaleState)) && cause == StopCause::Trip(Trip::HalDied))
        {
            self.stop = Some(cause);
        }
        self.phase = match self.phase {
            // Nothing was ever commanded, or nobody is left to command: done at once.
            Phase::WaitingForHal | Phase::Finished => Phase::Finished,
            _ if cause == StopCause::Trip(Trip::HalDied) => Phase::Finished,
            _ => Phase::Stopping,
        };
    }

    /// One servo period: judge the state frame, the watchdog and the requests, take a chunk, and compute the
    /// command for the next tick's time (none while waiting, frameless or finished).
    pub fn tick(&mut self, input: &TickInput) -> TickOutput {
        self.counters.ticks += 1;
        let mut out = TickOutput::default();
        if self.phase == Phase::Finished {
            return out;
        }
        let Some(usable) = self.take_frame(input, &mut out) else { return out };
        self.supervise(input, usable);
        if matches!(self.phase, Phase::WaitingForHal | Phase::Finished) {
            return out;
        }
        if !self.take_chunk(input, &mut out) {
            return out;
        }
        let Some(kin) = self.next_motion(input.now_ns) else { return out };
        out.command = self.command(&kin, input.now_ns);
        out
    }

    /// Step 1, the state frame: judged, observed, and the handshake on the first usable one. `Some(usable)`, or `None`
    /// when the tick must end here (no start the smoother can take).
    fn take_frame(&mut self, input: &TickInput, out: &mut TickOutput) -> Option<bool> {
        let verdict = input.frame.map(|f| self.frames.judge(f, input.now_ns));
        let usable = matches!(verdict, Some(Ok(())));
        if let Some(Err(r)) = verdict {
            self.refused_for_content |= r.is_content();
        }
        if !usable && let Some(f) = input.frame {
            self.note_refused_hold(f);
        }
        let Some(f) = input.frame.filter(|_| usable) else { return Some(false) };
        self.refused_for_content = false;
        self.last_state = *f;
        out.observed = Some(self.observed(f));
        if self.phase == Phase::WaitingForHal && !self.handshake(f) {
            return None;
        }
        if f.session == self.session {
            if f.is(status::ACTIVE) {
                self.followed = true;
                self.resync(f);
            } else if self.followed && self.phase != Phase::Finished {
                let reason = HoldReason::from_u32(f.hold_reason).unwrap_or(HoldReason::None);
                self.stop_with(StopCause::Trip(Trip::HalHolding(reason)));
            }
        }
        Some(true)
    }

    /// A frame refused for its measurements can still say that the HAL stopped following this session (a robot
    /// reflex flags the frame and holds): that is the cause to report, not the gap of usable frames after it —
    /// unless the HAL's hold is the command timeout that marsd's own refusals caused (it had no new frame to
    /// answer, as long as the HAL's timeout and marsd's allowed gap, 20 ms each): then the cause is the unusable
    /// state, whichever of the two limits marsd happens to notice first.
    fn note_refused_hold(&mut self, f: &RobotState) {
        if self.followed && f.session == self.session && f.is(status::HOLDING) && self.phase != Phase::Finished {
            let reason = HoldReason::from_u32(f.hold_reason).unwrap_or(HoldReason::None);
            let trip = if reason == HoldReason::CommandTimeout && self.refused_for_content {
                Trip::StaleState
            } else {
                Trip::HalHolding(reason)
            };
            self.stop_with(StopCause::Trip(trip));
        }
    }

    fn observed(&self, f: &RobotState) -> Observed {
        let mut obs = Observed {
            seq: f.seq,
            timestamp_ns: f.timestamp_ns,
            gripper: f.gripper,
            status: f.status,
            fault: f.fault,
            hold_reason: f.hold_reason,
            ..Default::default()
        };
        obs.position[..self.n].copy_from_slice(&f.position[..self.n]);
        obs
    }

    /// The handshake: start from the setpoint the HAL applies (as libfranka motion generators start from the last
    /// desired position, not the noisy measurement), so the first command continues the robot's own setpoint
    /// stream exactly. A HAL that reports none gets the measurement. False if the smoother cannot start there.
    fn handshake(&mut self, f: &RobotState) -> bool {
        let applied = &f.applied_position[..self.n];
        let start = if applied.iter().all(|q| q.is_finite()) && applied.iter().any(|q| *q != 0.0) {
            applied
        } else {
            &f.position[..self.n]
        };
        if let Err(e) = self.smoother.reset(start) {
            // A position the smoother cannot start from (beyond any joint's range): command nothing.
            self.first_smoothing_error.get_or_insert(e);
            self.stop_with(StopCause::Trip(Trip::Smoothing));
            return false;
        }
        self.pose[..self.n].copy_from_slice(start);
        self.gripper = f.gripper.clamp(self.g_lo, self.g_hi);
        self.gripper_target = self.gripper;
        self.phase = if self.stop.is_some() { Phase::Stopping } else { Phase::Idle };
        self.hal_counts_at_start = HalCounts::of(f);
        true
    }

    /// Step 2: watchdog, requests, signals.
    fn supervise(&mut self, input: &TickInput, usable: bool) {
        if input.hal_gone {
            self.stop_with(StopCause::Trip(Trip::HalDied));
        }
        if self.phase != Phase::WaitingForHal
            && let Some(trip) = self.watchdog.tick(input.now_ns, input.missed, usable)
        {
            self.stop_with(StopCause::Trip(trip));
        }
        match input.request {
            Some(Request::Trip(t)) => self.stop_with(StopCause::Trip(t)),
            // After a SIGTERM/SIGINT the policy thread ends its loop and asks to finish; its request can arrive in
            // the very tick that first sees the signal, and is handled first: the signal is still the cause.
            Some(Request::Finish) if input.stop_requested => self.stop_with(StopCause::Signal),
            Some(Request::Finish) => self.stop_with(StopCause::Finished),
            Some(Request::MoveTo { episode, pose, gripper }) if self.stop.is_none() => {
                self.episode = episode;
                self.pose = pose;
                self.gripper_target = gripper.clamp(self.g_lo, self.g_hi);
                self.phase = Phase::Resetting;
                // The config checked the speed; were it refused anyway, moving at full speed would be a silent
                // fallback: stop instead.
                if self.smoother.set_speed(self.reset_speed).is_err() {
                    self.stop_with(StopCause::Trip(Trip::Smoothing));
                }
            }
            _ => {}
        }
        if input.stop_requested {
            self.stop_with(StopCause::Signal);
        }
    }

    /// Step 3, chunks: keep the newest of this episode; switch to it when the current one is used up. False if this
    /// tick sends nothing (it found no new frame).
    fn take_chunk(&mut self, input: &TickInput, out: &mut TickOutput) -> bool {
        let next = input.now_ns + self.dt_ns;
        if let Some(c) = input.chunk
            && c.episode == self.episode
            && c.seq > self.pending.seq.max(self.schedule.current_seq())
        {
            self.pending = *c;
        }
        // A tick that found no new frame (its clock ran ahead of the robot's, as franka-sim's does under load, or it
        // woke twice in one HAL period) sends nothing and leaves the motion where it is: the HAL follows one answer
        // per frame, so a second one would only put the motion ahead of the joints. Nor does it adopt a chunk: the
        // first command from a chunk is the one that reports its camera's capture → command latency. A stop brakes
        // on regardless, so that it ends even when frames have stopped coming (the HAL brakes on its own then).
        if input.frame.is_none() && self.seq > 0 && self.phase != Phase::Stopping {
            self.counters.frameless_ticks += 1;
            return false;
        }
        if matches!(self.phase, Phase::Ready | Phase::Running)
            && self.pending.seq > self.schedule.current_seq()
            && self.pending.episode == self.episode
            && self.schedule.ready_for(&self.pending, next)
        {
            // Everything below is evaluated at the next tick's time, the time the command is for.
            let a = self.schedule.adopt(&self.pending, next);
            out.adopted_capture_ns = (self.pending.capture_ns != 0).then_some(self.pending.capture_ns);
            self.counters.chunks_adopted += 1;
            self.counters.actions_dropped += a.dropped as u64;
            self.phase = Phase::Running;
        }
        true
    }

    /// Step 4, motion for the next tick — one per state frame, as libfranka's controller answers each robot packet.
    /// `None` if nothing safe can be sent (the HAL's command timeout brakes).
    fn next_motion(&mut self, now: u64) -> Option<Kinematics> {
        let motion = match self.phase {
            Phase::Idle => self.smoother.track(&self.pose[..self.n], &[0.0; MAX_JOINTS][..self.n]).copied(),
            Phase::Resetting => self.reset_motion(now),
            Phase::Ready | Phase::Running => self.chunk_motion(now + self.dt_ns),
            Phase::Stopping => self.smoother.brake().copied(),
            Phase::WaitingForHal | Phase::Finished => return None,
        };
        match motion {
            Ok(k) => Some(k),
            Err(e) => {
                self.first_smoothing_error.get_or_insert(e);
                self.stop_with(StopCause::Trip(Trip::Smoothing));
                self.smoother.brake().ok().copied()
            }
        }
    }

    /// Towards the episode's start pose; once settled there, the schedule holds it and the phase is `Ready`.
    fn reset_motion(&mut self, now: u64) -> Result<Kinematics, SmoothingError> {
        // The gripper is a target the HAL moves to at its own rate: sent as it is, awaited in `settled`.
        self.gripper = self.gripper_target;
        let r = self.smoother.track(&self.pose[..self.n], &[0.0; MAX_JOINTS][..self.n]).copied();
        if r.is_ok() && self.settled() {
            let mut hold = [0.0; MAX_ACTION];
            match &mut self.effector {
                None => {
                    hold[..self.n].copy_from_slice(&self.pose[..self.n]);
                    hold[self.n] = self.gripper;
                }
                Some(e) => {
                    // The policy's first reference is where the flange is: IK continues from this pose.
                    e.seed(&self.pose[..self.n]);
                    hold[..2].copy_from_slice(&e.xy(&self.pose[..self.n]));
                }
            }
            self.schedule.hold(now, &hold);
            self.phase = Phase::Ready;
            self.smoother.set_speed(1.0).expect("1.0 is a valid speed");
        }
        r
    }

    /// The schedule's reference at `next` (through the effector's IK if actions are planar), clamped inside the
    /// joint limits' margin, smoothed.
    fn chunk_motion(&mut self, next: u64) -> Result<Kinematics, SmoothingError> {
        let r = self.schedule.sample(next);
        if r.exhausted && self.phase == Phase::Running {
            self.counters.starved_ticks += 1;
        }
        let (mut q_ref, mut v_ref) = (r.position, r.velocity);
        if let Some(e) = &mut self.effector {
            // (x, y) on the table → joints; the gripper keeps its target.
            let (xy, v) = ([r.position[0], r.position[1]], [r.velocity[0], r.velocity[1]]);
            e.joints(xy, v, &mut q_ref[..self.n], &mut v_ref[..self.n]);
            q_ref[self.n] = self.gripper;
        }
        let (mut target, mut target_v) = ([0.0; MAX_JOINTS], [0.0; MAX_JOINTS]);
        for j in 0..self.n {
            target[j] = q_ref[j].clamp(self.q_lo[j], self.q_hi[j]);
            if target[j] != q_ref[j] {
                self.counters.clamped_targets += 1;
            } else {
                target_v[j] = v_ref[j];
            }
        }
        let g = q_ref[self.n];
        self.gripper = if g.is_finite() { g.clamp(self.g_lo, self.g_hi) } else { self.gripper };
        self.smoother.track(&target[..self.n], &target_v[..self.n]).copied()
    }

    /// Step 5, the command after the last check; `None` (and finished) if it would leave the limits.
    fn command(&mut self, kin: &Kinematics, now: u64) -> Option<JointCommand> {
        if let Err(v) = self.limits.admit(&kin.position[..self.n]) {
            self.counters.limit_violations += 1;
            self.first_violation.get_or_insert(v);
            self.stop_with(StopCause::Trip(Trip::LimitViolation));
            // No command this controller computes can be trusted now: send nothing more, and the HAL brakes to
            // rest on command loss (its own safety) within its timeout.
            self.phase = Phase::Finished;
            return None;
        }
        let stopping_done = self.phase == Phase::Stopping && self.smoother.is_at_rest();
        self.seq += 1;
        let mut cmd = JointCommand::position(self.session, self.seq, self.last_state.seq, &kin.position[..self.n]);
        cmd.timestamp_ns = now;
        cmd.velocity = kin.velocity;
        cmd.acceleration = kin.acceleration;
        cmd.gripper = self.gripper;
        if stopping_done {
            // At rest: end the session explicitly, so the HAL holds here rather than timing out.
            cmd.mode = CommandMode::Hold as u32;
            self.phase = Phase::Finished;
        }
        self.counters.commands_sent += 1;
        self.timeliness.sent(cmd.state_seq, cmd.seq);
        Some(cmd)
    }

    /// Re-attributes a stale-state stop to the HAL's death, found out after the loop had already stopped.
    pub fn blame_hal_death(&mut self) {
        if self.stop == Some(StopCause::Trip(Trip::StaleState)) {
            self.stop = Some(StopCause::Trip(Trip::HalDied));
        }
    }

    /// The HAL's counters since the handshake, as of its newest usable frame.
    pub fn hal_counts(&self) -> HalCounts {
        HalCounts::of(&self.last_state).since(&self.hal_counts_at_start)
    }

    /// A fault found by the loop around the tick (the wire): stop as for any trip.
    pub fn trip(&mut self, t: Trip) {
        self.stop_with(StopCause::Trip(t));
    }

    /// Every state frame the loop receives, in order (also those a newer one supersedes in the same tick):
    /// the first one after a command's frame tells whether the HAL had the command in time.
    pub fn note_frame_timing(&mut self, f: &RobotState) {
        self.timeliness.frame(f, self.session);
        self.counters.late_commands = self.timeliness.late();
    }

    /// If the HAL's applied setpoint is not the last command sent (a late command: the HAL held or smoothed
    /// instead), continue from the setpoint the joints actually follow, as libfranka motion generators continue
    /// from q_d: the next command is then within every limit relative to it, and the HAL applies it exactly.
    fn resync(&mut self, f: &RobotState) {
        let n = self.n;
        let ours = &self.smoother.state().position[..n];
        // In step: the HAL applied our last command, and the two before it in the ticks before (its velocity and
        // acceleration, finite differences, are ours). A HAL tick without a new command (we skipped one of its
        // frames) leaves the position right but stops the joints: that needs a resync as much as a late command
        // does. So does a robot whose setpoint history moved under ours (franka-sim after it extrapolated over a
        // state the HAL never saw: the same q_d, another dq_d and ddq_d, which the HAL continues from): a command
        // that ignored the acceleration the robot differentiates from would jump it, up to twice the jerk limit.
        let in_step = (0..n).all(|j| {
            self.limits.last_velocity(j).is_none_or(|v| (f.applied_velocity[j] - v).abs() <= 1e-9 * (1.0 + v.abs()))
                && self.limits.last_acceleration(j).is_none_or(|a| {
                    // Rounding: a second difference of positions ~1 rad over dt² carries ~1e-16/dt² of error.
                    (f.applied_acceleration[j] - a).abs() <= 1e-6 * (1.0 + a.abs())
                })
        });
        if self.seq == 0 || (f.last_command_seq == self.seq && f.applied_position[..n] == *ours && in_step) {
            return;
        }
        // The HAL's velocity and acceleration are finite differences over the last tick, i.e. the values half a
        // tick back; the smoother's state is instantaneous. Shifting the velocity by half a tick of acceleration
        // makes the first commands' finite differences continue the HAL's without a jerk artifact of a/(2·dt).
        let dt = self.dt_ns as f64 * 1e-9;
        let mut applied = Kinematics {
            position: f.applied_position,
            velocity: f.applied_velocity,
            acceleration: f.applied_acceleration,
        };
        for j in 0..n {
            applied.velocity[j] += 0.5 * dt * f.applied_acceleration[j];
        }
        if self.smoother.continue_from(&applied).is_ok() {
            self.limits.continue_from(&f.applied_position[..n], &f.applied_velocity[..n], &f.applied_acceleration[..n]);
            self.counters.resyncs += 1;
        }
    }

    /// At rest at the target pose, and the measured arm agrees.
    fn settled(&self) -> bool {
        let k = self.smoother.state();
        let tol = self.settle_tolerance;
        self.smoother.is_at_rest()
            && (self.gripper - self.gripper_target).abs() < 1e-12
            && (self.last_state.gripper - self.gripper_target).abs() <= GRIPPER_TOLERANCE
            && (0..self.n).all(|j| {
                (k.position[j] - self.pose[j]).abs() <= tol && (self.last_state.position[j] - self.pose[j]).abs() <= tol
            })
    }
}
