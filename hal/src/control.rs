//! One HAL tick as plain logic, free of I/O: what the loop read (a measurement or an error, commands or receive
//! errors, the controller's liveness) goes in, the setpoint, the gripper move and the state frame come out.
//! [`crate::runner`] does the I/O around it; the tests here drive every error path directly.
//!
//! The HAL's own safety, as a robot runtime needs it:
//! - **It starts from the measured arm.** [`HalControl::start`] takes the first measurement: the safety filter's
//!   setpoint is the measured position (at rest), the gripper's target its measured opening. A measurement
//!   outside the limits, of a moving arm, non-finite or flagged faulty refuses the start, and nothing is
//!   commanded: a restarted HAL never jumps an arm to `home` or closes its gripper.
//! - **It holds on error instead of exiting.** Every error of the backend (read, apply, gripper) or of its own
//!   ports (receive, send) is counted, ends the active session ([`HoldReason::HalError`]: brake to rest and
//!   hold) and is published (`backend_errors`, `status::BACKEND_ERROR`, `fault::NO_MEASUREMENT` on a frame
//!   whose measurement failed). The loop goes on; a new session resumes once the errors stop. Only a
//!   [`BackendError::Fatal`] ends the process, and only at rest ([`HalControl::exit_reason`]).
//! - **Its last resorts are visible**: position-guard stops and infeasible steps are counted in every frame
//!   and flagged with `status::LAST_RESORT` in the tick they happen.

use mars_ipc::{
    CommandMode, FrameReceiveError, FrameSendError, HoldReason, JointCommand, MAX_JOINTS, RobotState, fault, status,
};

use crate::backend::{BackendError, Measurement};
use crate::events::{EventSender, LoopEvent};
use crate::gripper::{GripperMove, GripperTarget};
use crate::safety::SafetyFilter;
use crate::session::{Decision, LoopClock, Mode, Supervisor};
use crate::takeover::check_takeover;
pub use crate::takeover::{START_MAX_SPEED, StartError};
use mars_profile::Profile;

/// After a fatal error, this many failed `apply` calls in a row mean nothing can be commanded any more: the
/// process exits without waiting for rest (the robot's own reflex brakes it; e.g. the FR3's on lost packets).
const FATAL_APPLY_FAILURES: u64 = 100;
/// Clamped commands logged with their reason; the rest are only counted.
const CLAMPS_LOGGED: u64 = 10;

/// What the HAL counted since start (besides the safety filter's own counters).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ErrorCounts {
    pub read: u64,
    pub apply: u64,
    pub gripper: u64,
    pub receive: u64,
    pub send: u64,
}

impl ErrorCounts {
    pub fn total(&self) -> u64 {
        self.read + self.apply + self.gripper + self.receive + self.send
    }
}

/// The setpoint and gripper move of one tick.
pub struct Step<'a> {
    pub setpoint: &'a [f64],
    pub gripper: Option<GripperMove>,
}

pub struct HalControl {
    n: usize,
    /// For a restart from a new measurement ([`Self::resume_from`]).
    profile: Profile,
    filter: SafetyFilter,
    supervisor: Supervisor,
    clock: LoopClock,
    /// Two periods: how long the controller may be silent before its dead process ends the session.
    quiet_ns: u64,
    /// The watch's verdict when it last reported a controller lost, for a loss ended later (it went quiet).
    lost_peer: mars_ipc::Peer,
    gripper: GripperTarget,
    target: Option<[f64; MAX_JOINTS]>,
    last_command_seq: u64,
    /// State frames built so far; the newest one's `seq` (commands answering an older one are late).
    frames: u64,
    /// The frame count when the setpoint was last re-synchronised to the robot's own (it extrapolated over a
    /// command it did not get): a clamp soon after one is reported with it.
    robot_resync_at: Option<u64>,
    /// (session, frame) of the last command followed: one command per frame is this tick's.
    followed_answer: (u64, u64),
    /// The last measurement read, and whether this tick's read succeeded.
    measured: Measurement,
    measured_now: bool,
    loop_ns: u64,
    error_this_tick: bool,
    /// Backend calls failed in a row (for the "recovered" event).
    backend_failures_in_a_row: u64,
    apply_failures_in_a_row: u64,
    fatal: Option<BackendError>,
    /// The robot stopped itself (a reflex): nothing is followed until [`Self::resume_from`].
    robot_fault: bool,
    /// The HAL was asked to exit: nothing is followed, the setpoint brakes to rest.
    stopping: bool,
    last_resorts_before: (u64, u64),
    pub errors: ErrorCounts,
    pub schema_refusals: u64,
    pub late_commands: u64,
    /// Position commands that answered a frame an earlier followed one had answered (see
    /// `RobotState::duplicate_commands`).
    pub duplicate_commands: u64,
}

impl HalControl {
    /// Takes over the arm as `first` measured it, or refuses (see the module doc).
    pub fn start(profile: &Profile, first: &Measurement) -> Result<Self, StartError> {
        let n = profile.joints;
        let filter = SafetyFilter::new(profile, &first.position[..n]);
        check_takeover(&filter, profile, first)?;
        let (g_min, g_max) = (profile.gripper_min, profile.gripper_max);
        let period_ns = (profile.period_s() * 1e9) as u64;
        Ok(Self {
            n,
            profile: profile.clone(),
            filter,
            supervisor: Supervisor::new(profile.timeout_ns()),
            // Silence of the controller is judged in the loop's own time (see `LoopClock`): two periods at most
            // per tick.
            clock: LoopClock::new(2 * period_ns),
            quiet_ns: 2 * period_ns,
            lost_peer: mars_ipc::Peer::Unknown,
            gripper: GripperTarget::new(profile, first.gripper.clamp(g_min, g_max)),
            target: None,
            last_command_seq: 0,
            frames: 0,
            robot_resync_at: None,
            followed_answer: (0, 0),
            measured: *first,
            measured_now: true,
            loop_ns: 0,
            error_this_tick: false,
            backend_failures_in_a_row: 0,
            apply_failures_in_a_row: 0,
            fatal: None,
            robot_fault: false,
            stopping: false,
            last_resorts_before: (0, 0),
            errors: ErrorCounts::default(),
            schema_refusals: 0,
            late_commands: 0,
            duplicate_commands: 0,
        })
    }

    pub fn filter(&self) -> &SafetyFilter {
        &self.filter
    }

    pub fn mode(&self) -> Mode {
        self.supervisor.mode()
    }

    pub fn gripper(&self) -> &GripperTarget {
        &self.gripper
    }

    /// Starts a tick at `wall_ns` (CLOCK_MONOTONIC).
    pub fn begin_tick(&mut self, wall_ns: u64) {
        self.loop_ns = self.clock.tick(wall_ns);
        self.error_this_tick = false;
    }

    /// This tick's measurement, or the backend's error.
    pub fn on_read(&mut self, read: Result<Measurement, BackendError>, ev: &mut EventSender) {
        match read {
            Ok(m) => {
                self.measured = m;
                self.measured_now = true;
                self.backend_ok(ev);
            }
            Err(e) => {
                self.measured_now = false;
                self.errors.read += 1;
                self.backend_failed(e, ev);
            }
        }
    }

    /// The result of this tick's `apply`.
    pub fn on_apply(&mut self, r: Result<(), BackendError>, ev: &mut EventSender) {
        match r {
            Ok(()) => {
                self.apply_failures_in_a_row = 0;
                self.backend_ok(ev);
            }
            Err(e) => {
                self.apply_failures_in_a_row += 1;
                self.errors.apply += 1;
                self.backend_failed(e, ev);
            }
        }
    }

    /// The result of a `move_gripper`.
    pub fn on_gripper(&mut self, r: Result<(), BackendError>, ev: &mut EventSender) {
        if let Err(e) = r {
            self.errors.gripper += 1;
            self.backend_failed(e, ev);
        }
    }

    fn backend_ok(&mut self, ev: &mut EventSender) {
        if self.backend_failures_in_a_row > 0 && !self.error_this_tick {
            ev.send(LoopEvent::BackendRecovered { errors: self.backend_failures_in_a_row, tick: self.frames });
            self.backend_failures_in_a_row = 0;
        }
    }

    fn backend_failed(&mut self, e: BackendError, ev: &mut EventSender) {
        if self.backend_failures_in_a_row == 0 {
            ev.send(LoopEvent::Backend { error: e, tick: self.frames });
        }
        self.backend_failures_in_a_row += 1;
        if e.is_fatal() && self.fatal.is_none() {
            self.fatal = Some(e);
            ev.send(LoopEvent::Fatal(e));
        }
        self.hal_error(ev);
    }

    /// An error of the HAL itself: end the session (brake, hold) and flag the frame.
    fn hal_error(&mut self, ev: &mut EventSender) {
        self.error_this_tick = true;
        if self.supervisor.on_hal_error() {
            self.target = None;
            ev.send(LoopEvent::HoldingOnError);
        }
    }

    /// A command frame (of this build's schema). Every one is judged and counted; the newest valid one wins.
    pub fn on_command(&mut self, cmd: &JointCommand, ev: &mut EventSender) {
        // The newest frame built so far is `frames`: a command answering an older one missed the tick it was
        // meant for, and a too-big step in it is timing, not content. A second position command answering a frame
        // already answered is the controller's next tick come early (it ticked twice between two frames): the
        // first one is this tick's; the second is judged (refusals count) but not followed.
        let late = cmd.state_seq < self.frames;
        let hold = cmd.mode == CommandMode::Hold as u32;
        let duplicate = !hold && (cmd.session, cmd.state_seq) == self.followed_answer;
        let admitted = match self.filter.admit(cmd, late || duplicate) {
            Err(refusal) => return ev.send(LoopEvent::Refused { seq: cmd.seq, refusal }),
            Ok(t) => t,
        };
        // The first clamps are logged with the limit they met (a controller that needs clamping has a bug worth
        // a line); the rest only counted, so a broken controller cannot flood the log.
        if let Some(reason) = admitted.clamp_reason
            && self.filter.clamped <= CLAMPS_LOGGED
        {
            let since_robot_resync = self.robot_resync_at.map(|f| self.frames - f);
            ev.send(LoopEvent::Clamped {
                seq: cmd.seq,
                reason,
                answered: cmd.state_seq,
                newest: self.frames,
                since_robot_resync,
            });
        }
        if cmd.session == 0 {
            self.filter.rejected += 1;
            ev.send(LoopEvent::ReservedSession { seq: cmd.seq });
        } else if duplicate && matches!(self.supervisor.mode(), Mode::Active { .. }) {
            self.duplicate_commands += 1;
        } else if self.fatal.is_none()
            && !self.robot_fault
            && !self.stopping
            && self.supervisor.on_command(cmd.session, hold, self.loop_ns) == Decision::Follow
        {
            self.followed_answer = (cmd.session, cmd.state_seq);
            if !hold {
                if late {
                    self.late_commands += 1;
                }
                self.target = Some(admitted.position);
                self.gripper.request(admitted.gripper, admitted.gripper_speed);
            } else {
                self.target = None;
            }
            self.last_command_seq = cmd.seq;
        }
    }

    /// A failed receive: a frame of another schema version is refused (the first one logged), a port error is
    /// an error of the HAL.
    pub fn on_receive_error(&mut self, e: FrameReceiveError, ev: &mut EventSender) {
        match e {
            FrameReceiveError::Schema(mismatch) => {
                self.schema_refusals += 1;
                if self.schema_refusals == 1 {
                    ev.send(LoopEvent::WrongSchema(mismatch));
                }
            }
            FrameReceiveError::Port(_) => {
                self.errors.receive += 1;
                ev.send(LoopEvent::ReceiveFailed(e));
                self.hal_error(ev);
            }
        }
    }

    /// The liveness watch saw a controller process die.
    pub fn on_controller_lost(&mut self, peer: mars_ipc::Peer, ev: &mut EventSender) {
        self.lost_peer = peer;
        if self.supervisor.on_controller_lost(self.loop_ns, self.quiet_ns) {
            ev.send(LoopEvent::ControllerLost(peer));
            self.target = None;
        }
    }

    /// The setpoint for this tick (following the session, or braking to rest) and the gripper move, if any.
    pub fn step(&mut self, timeout_ms: u64, ev: &mut EventSender) -> Step<'_> {
        if self.supervisor.on_tick_after_loss(self.loop_ns) {
            ev.send(LoopEvent::ControllerLost(self.lost_peer));
            self.target = None;
        }
        if self.supervisor.on_tick(self.loop_ns) {
            ev.send(LoopEvent::CommandTimeout { ms: timeout_ms });
            self.target = None;
        }
        let follow = matches!(self.supervisor.mode(), Mode::Active { .. })
            && self.fatal.is_none()
            && !self.robot_fault
            && !self.stopping;
        self.last_resorts_before = (self.filter.position_guard_hits, self.filter.infeasible_steps);
        let gripper = self.gripper.tick();
        self.filter.step(if follow { self.target.as_ref() } else { None });
        Step { setpoint: self.filter.position(), gripper }
    }

    /// This tick's state frame (`seq` = frames built so far + 1), stamped `timestamp_ns`.
    pub fn state_frame(&mut self, timestamp_ns: u64) -> RobotState {
        let n = self.n;
        self.frames += 1;
        let m = &self.measured;
        let mut fault_bits = m.fault;
        if !self.measured_now {
            fault_bits |= fault::NO_MEASUREMENT;
        }
        // The measurement is only reported, never fed back into the setpoint: a NaN or frozen sensor cannot move
        // the arm. It is flagged so the controller can refuse the frame.
        if m.position[..n].iter().chain(&m.velocity[..n]).any(|x| !x.is_finite()) {
            fault_bits |= fault::NON_FINITE_MEASUREMENT;
        }
        let (session, mut hold_reason) = match self.supervisor.mode() {
            // No session, and the backend failing this tick: the error is why it holds now (a controller that
            // connects sees that, not merely "no session").
            Mode::Idle if self.error_this_tick => (0, HoldReason::HalError),
            Mode::Idle => (0, HoldReason::NoSession),
            Mode::Active { session } => (session, HoldReason::None),
            Mode::Holding { session, reason } => (session, reason),
        };
        // What the HAL itself does overrides the session's state: a robot fault or an exit in progress.
        if self.robot_fault {
            hold_reason = HoldReason::RobotFault;
            fault_bits |= fault::ROBOT_REFLEX;
        } else if self.stopping {
            hold_reason = HoldReason::HalStopping;
        }
        self.filter.note_published(self.frames);
        let f = &self.filter;
        let mut st = RobotState {
            seq: self.frames,
            timestamp_ns,
            session,
            last_command_seq: self.last_command_seq,
            position: m.position,
            velocity: m.velocity,
            effort: m.effort,
            gripper: m.gripper,
            gripper_target: self.gripper.target(),
            rejected_commands: f.rejected,
            clamped_commands: f.clamped,
            late_commands: self.late_commands,
            duplicate_commands: self.duplicate_commands,
            position_guard_hits: f.position_guard_hits,
            infeasible_steps: f.infeasible_steps,
            backend_errors: self.errors.total(),
            status: if hold_reason == HoldReason::None { status::ACTIVE } else { status::HOLDING },
            fault: fault_bits,
            hold_reason: hold_reason as u32,
            num_joints: n as u32,
            robot_errors: m.robot.errors,
            robot_reflex_errors: m.robot.reflex_errors,
            robot_success_rate: m.robot.success_rate,
            robot_mode: m.robot.mode,
            robot_cycles: m.robot.cycles,
            ..Default::default()
        };
        st.applied_position[..n].copy_from_slice(f.position());
        st.applied_velocity[..n].copy_from_slice(f.velocity());
        st.applied_acceleration[..n].copy_from_slice(f.acceleration());
        if f.at_rest() {
            st.status |= status::AT_REST;
        }
        if (f.position_guard_hits, f.infeasible_steps) != self.last_resorts_before {
            st.status |= status::LAST_RESORT;
        }
        if self.error_this_tick || hold_reason == HoldReason::HalError || self.fatal.is_some() {
            st.status |= status::BACKEND_ERROR;
        }
        st
    }

    /// The result of publishing this tick's frame.
    pub fn on_sent(&mut self, r: Result<usize, FrameSendError>, ev: &mut EventSender) {
        if let Err(e) = r {
            self.errors.send += 1;
            if self.errors.send == 1 || self.errors.send.is_power_of_two() {
                ev.send(LoopEvent::SendFailed(e));
            }
            self.hal_error(ev);
        }
    }

    /// The robot stopped itself (a reflex, or its connection broke): the session ends, nothing is followed and
    /// the setpoint stops where the robot measured it, until [`Self::resume_from`] after a recovery.
    pub fn on_robot_fault(&mut self, ev: &mut EventSender) {
        self.robot_fault = true;
        self.hal_error(ev);
        let m = self.measured;
        self.filter.restart(&m.position[..self.n]);
    }

    pub fn robot_fault(&self) -> bool {
        self.robot_fault
    }

    /// After the robot was recovered: take the arm over again from `m` exactly as at start (at rest, within the
    /// limits, the setpoint its measured position); the old session stays ended, a new one is followed.
    pub fn resume_from(&mut self, m: &Measurement) -> Result<(), StartError> {
        check_takeover(&self.filter, &self.profile, m)?;
        self.filter.restart(&m.position[..self.n]);
        let (g_min, g_max) = (self.profile.gripper_min, self.profile.gripper_max);
        self.gripper = GripperTarget::new(&self.profile, m.gripper.clamp(g_min, g_max));
        self.target = None;
        self.measured = *m;
        self.robot_fault = false;
        Ok(())
    }

    /// The robot applied another setpoint than ours in the last cycle (it extrapolated over a command it did not
    /// get in time, or over states we never saw): the filter continues from the robot's (see
    /// [`SafetyFilter::resync`]), so the next command is continuous with what the robot did.
    pub fn resync_setpoint(&mut self, q: &[f64], v: &[f64], a: &[f64]) {
        self.robot_resync_at = Some(self.frames);
        self.filter.resync(q, v, a);
    }

    /// For this tick's step only: the robot may judge it against this history instead of ours, over `cycles`
    /// cycles (see [`SafetyFilter::also_judged_from`]).
    pub fn also_judged_from(&mut self, q: &[f64], v: &[f64], a: &[f64], cycles: u64) {
        self.filter.also_judged_from(q, v, a, cycles);
    }

    /// The HAL was asked to exit: stop following, brake the setpoint to rest (see [`Self::stopped`]).
    pub fn begin_stop(&mut self) {
        self.stopping = true;
        self.target = None;
    }

    /// Asked to exit and the setpoint is at rest: control may be released.
    pub fn stopped(&self) -> bool {
        self.stopping && self.filter.at_rest()
    }

    /// After a fatal backend error: the error, once the setpoint is at rest (or nothing can be commanded any
    /// more); the loop then ends.
    pub fn exit_reason(&self) -> Option<BackendError> {
        let e = self.fatal?;
        (self.filter.at_rest() || self.apply_failures_in_a_row >= FATAL_APPLY_FAILURES).then_some(e)
    }
}

#[cfg(test)]
mod tests {
    use std::path::Path;
    use std::sync::{Arc, Mutex};
    use std::time::Duration;

    use mars_ipc::SchemaMismatch;

    use super::*;
    use crate::events::EventLogger;

    fn fr3() -> Profile {
        Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")).unwrap()
    }

    fn at(q: &[f64], gripper: f64) -> Measurement {
        let mut m = Measurement { gripper, ..Default::default() };
        m.position[..q.len()].copy_from_slice(q);
        m
    }

    /// An event sender whose events are collected (read them after `finish`).
    fn events() -> (EventSender, EventLogger, Arc<Mutex<Vec<LoopEvent>>>) {
        let seen = Arc::new(Mutex::new(Vec::new()));
        let sink = seen.clone();
        let (tx, logger) =
            EventLogger::start(256, Duration::from_millis(1), move |e| sink.lock().unwrap().push(e)).unwrap();
        (tx, logger, seen)
    }

    /// A rig around [`HalControl`] that runs ticks at 1 kHz of loop time.
    struct Ticks {
        c: HalControl,
        ev: EventSender,
        now: u64,
        frames: Vec<RobotState>,
        setpoints: Vec<Vec<f64>>,
        gripper_moves: Vec<GripperMove>,
    }

    impl Ticks {
        fn new(c: HalControl) -> (Self, EventLogger, Arc<Mutex<Vec<LoopEvent>>>) {
            let (ev, logger, seen) = events();
            (Self { c, ev, now: 1_000_000_000, frames: vec![], setpoints: vec![], gripper_moves: vec![] }, logger, seen)
        }

        /// One tick: `read`, then `commands` (each answering the newest frame), apply `apply`.
        fn tick(
            &mut self,
            read: Result<Measurement, BackendError>,
            commands: &[JointCommand],
            apply: Result<(), BackendError>,
        ) -> RobotState {
            self.now += 1_000_000;
            self.c.begin_tick(self.now);
            self.c.on_read(read, &mut self.ev);
            for cmd in commands {
                self.c.on_command(cmd, &mut self.ev);
            }
            let step = self.c.step(20, &mut self.ev);
            self.setpoints.push(step.setpoint.to_vec());
            if let Some(g) = step.gripper {
                self.gripper_moves.push(g);
            }
            self.c.on_apply(apply, &mut self.ev);
            let st = self.c.state_frame(self.now);
            self.frames.push(st);
            st
        }

        fn command(&self, session: u64, q: &[f64], gripper: f64) -> JointCommand {
            let newest = self.frames.last().map_or(0, |f| f.seq);
            let mut c = JointCommand::position(session, newest + 1, newest, q);
            c.gripper = gripper;
            c
        }
    }

    const START: [f64; 7] = [0.3, -0.2, 0.1, -2.0, 0.2, 1.9, 0.5];

    /// Follows a stream in session 1 until joint 1 moves at about 2 rad/s (within every limit); the last target.
    fn move_fast(t: &mut Ticks) -> [f64; 7] {
        let mut q = START;
        for k in 0..300 {
            q[0] = START[0] + 0.4 * (1.0 - (k as f64 * 5e-3).cos());
            let c = t.command(1, &q, 0.03);
            t.tick(Ok(at(&q, 0.03)), &[c], Ok(()));
        }
        assert!(t.c.filter().velocity()[0] > 1.5, "{:?}", t.c.filter().velocity());
        q
    }

    #[test]
    fn it_starts_from_the_measured_arm_not_from_home_and_commands_nothing_unasked() {
        let p = fr3();
        let (mut t, _logger, _) = Ticks::new(HalControl::start(&p, &at(&START, 0.031)).unwrap());
        for _ in 0..100 {
            let st = t.tick(Ok(at(&START, 0.031)), &[], Ok(()));
            assert_eq!(&st.applied_position[..7], &START[..]);
            assert_eq!(st.gripper_target, 0.031);
            assert_eq!(st.hold_reason, HoldReason::NoSession as u32);
        }
        assert!(t.setpoints.iter().all(|s| s[..] == START[..]), "every setpoint is the measured pose");
        assert!(t.gripper_moves.is_empty(), "the gripper is never sent anywhere unasked");
    }

    #[test]
    fn a_start_outside_the_limits_moving_faulty_or_nan_is_refused() {
        let p = fr3();
        let mut q = START;
        q[3] = -0.05; // above joint 4's limit of −0.1169
        assert!(matches!(HalControl::start(&p, &at(&q, 0.03)), Err(StartError::OutsideLimits { joint: 3, .. })));
        let mut moving = at(&START, 0.03);
        moving.velocity[1] = 0.2;
        assert!(matches!(HalControl::start(&p, &moving), Err(StartError::Moving { joint: 1, .. })));
        let mut faulty = at(&START, 0.03);
        faulty.fault = fault::FROZEN_SENSOR;
        assert_eq!(HalControl::start(&p, &faulty).err(), Some(StartError::Faulty(fault::FROZEN_SENSOR)));
        let mut nan = at(&START, 0.03);
        nan.position[6] = f64::NAN;
        assert!(matches!(HalControl::start(&p, &nan), Err(StartError::NotFinite { joint: 6, .. })));
        assert!(matches!(HalControl::start(&p, &at(&START, 0.2)), Err(StartError::Gripper { .. })));
        let msg = HalControl::start(&p, &at(&q, 0.03)).err().unwrap().to_string();
        assert!(msg.contains("joint 3") && msg.contains("nothing was commanded"), "{msg}");
    }

    /// A transient read error while following a moving stream: the session ends at once, the arm brakes to rest
    /// and holds with HalError, the frame is flagged; the loop goes on, and a new session resumes.
    #[test]
    fn a_backend_error_brakes_and_holds_and_a_new_session_resumes() {
        let p = fr3();
        let (mut t, logger, seen) = Ticks::new(HalControl::start(&p, &at(&START, 0.03)).unwrap());
        let mut q = START;
        for k in 0..300 {
            q[0] = START[0] + 0.2 * (1.0 - (k as f64 * 2e-3).cos());
            let c = t.command(7, &q, 0.03);
            t.tick(Ok(at(&q, 0.03)), &[c], Ok(()));
        }
        assert!(!t.c.filter().at_rest(), "moving when the error comes");
        let c = t.command(7, &q, 0.03);
        let st = t.tick(Err(BackendError::Transient("bus")), &[c], Ok(()));
        assert_eq!(st.hold_reason, HoldReason::HalError as u32);
        assert!(st.is(status::BACKEND_ERROR) && st.is(status::HOLDING));
        assert_eq!(st.fault & fault::NO_MEASUREMENT, fault::NO_MEASUREMENT);
        assert_eq!(st.backend_errors, 1);
        // Its commands are no longer followed: the setpoint brakes to rest.
        for _ in 0..1000 {
            let c = t.command(7, &q, 0.03);
            t.tick(Ok(at(&q, 0.03)), &[c], Ok(()));
        }
        let st = *t.frames.last().unwrap();
        assert!(st.is(status::AT_REST) && st.hold_reason == HoldReason::HalError as u32, "{st:?}");
        assert_eq!(st.fault, 0, "the next reads worked");
        // A new session is followed again.
        let target = st.applied_position;
        let c = t.command(8, &target[..7], 0.03);
        let st = t.tick(Ok(at(&q, 0.03)), &[c], Ok(()));
        assert_eq!((st.session, st.hold_reason), (8, HoldReason::None as u32));
        assert!(t.c.exit_reason().is_none(), "a transient error never ends the process");
        drop(t);
        logger.finish();
        let seen = seen.lock().unwrap();
        assert!(seen.contains(&LoopEvent::HoldingOnError), "{seen:?}");
        assert!(seen.iter().any(|e| matches!(e, LoopEvent::BackendRecovered { errors: 1, .. })), "{seen:?}");
    }

    /// With no session yet, a failing read still says why the HAL holds: HalError while it fails, then no session.
    #[test]
    fn a_backend_error_with_no_session_is_the_hold_reason_while_it_lasts() {
        let p = fr3();
        let (mut t, _logger, _) = Ticks::new(HalControl::start(&p, &at(&START, 0.03)).unwrap());
        let st = t.tick(Ok(at(&START, 0.03)), &[], Ok(()));
        assert_eq!(st.hold_reason, HoldReason::NoSession as u32);
        for _ in 0..3 {
            let st = t.tick(Err(BackendError::Transient("no feedback")), &[], Ok(()));
            assert_eq!((st.session, st.hold_reason), (0, HoldReason::HalError as u32));
            assert!(st.is(status::BACKEND_ERROR) && st.is(status::HOLDING), "{st:?}");
        }
        let st = t.tick(Ok(at(&START, 0.03)), &[], Ok(()));
        assert_eq!(st.hold_reason, HoldReason::NoSession as u32);
        assert!(!st.is(status::BACKEND_ERROR), "{st:?}");
    }

    #[test]
    fn port_errors_are_classified_counted_and_hold() {
        let p = fr3();
        let (mut t, logger, seen) = Ticks::new(HalControl::start(&p, &at(&START, 0.03)).unwrap());
        let c = t.command(3, &START, 0.03);
        t.tick(Ok(at(&START, 0.03)), &[c], Ok(()));
        let mismatch = SchemaMismatch { found: 1, expected: mars_ipc::SCHEMA_VERSION };
        for _ in 0..3 {
            t.c.on_receive_error(FrameReceiveError::Schema(mismatch), &mut t.ev);
        }
        assert_eq!((t.c.schema_refusals, t.c.errors.total()), (3, 0), "a wrong schema is a refusal, not an error");
        assert_eq!(t.c.mode(), Mode::Active { session: 3 });
        let port = FrameReceiveError::Port(iceoryx2::port::ReceiveError::ExceedsMaxBorrows);
        t.c.on_receive_error(port, &mut t.ev);
        t.c.on_sent(Err(FrameSendError::Loan(iceoryx2::port::LoanError::OutOfMemory)), &mut t.ev);
        assert_eq!((t.c.errors.receive, t.c.errors.send), (1, 1));
        assert_eq!(t.c.mode(), Mode::Holding { session: 3, reason: HoldReason::HalError });
        drop(t);
        logger.finish();
        let seen = seen.lock().unwrap();
        assert_eq!(seen.iter().filter(|e| matches!(e, LoopEvent::WrongSchema(_))).count(), 1, "{seen:?}");
        assert!(seen.iter().any(|e| matches!(e, LoopEvent::ReceiveFailed(_))));
        assert!(seen.iter().any(|e| matches!(e, LoopEvent::SendFailed(_))));
    }

    /// A fatal error while moving: no exit until the setpoint is at rest; then the exit reason is the error.
    #[test]
    fn a_fatal_error_exits_only_at_rest() {
        let p = fr3();
        let (mut t, _logger, _) = Ticks::new(HalControl::start(&p, &at(&START, 0.03)).unwrap());
        let q = move_fast(&mut t);
        let gone = BackendError::Fatal("gone");
        let mut ticks_to_exit = None;
        for k in 0..2000 {
            let c = t.command(1, &q, 0.03);
            let st = t.tick(Err(gone), &[c], Ok(()));
            assert_eq!(st.hold_reason, HoldReason::HalError as u32);
            if let Some(e) = t.c.exit_reason() {
                assert_eq!(e, gone);
                assert!(st.is(status::AT_REST), "exit only at rest");
                ticks_to_exit = Some(k);
                break;
            }
        }
        let k = ticks_to_exit.expect("exits once at rest");
        assert!(k > 150, "braking from 2 rad/s at ≤ 10 rad/s² takes ≥ 200 ms: {k} ticks");
        // A new session is not followed after a fatal error.
        let c = t.command(2, &q, 0.03);
        assert_eq!(t.tick(Err(gone), &[c], Ok(())).session, 1);
    }

    #[test]
    fn a_fatal_error_with_apply_failing_too_exits_without_waiting_for_rest() {
        let p = fr3();
        let (mut t, _logger, _) = Ticks::new(HalControl::start(&p, &at(&START, 0.03)).unwrap());
        move_fast(&mut t);
        let gone = BackendError::Fatal("gone");
        let exited = (0..200).position(|_| {
            t.tick(Err(gone), &[], Err(gone));
            t.c.exit_reason().is_some()
        });
        assert_eq!(exited, Some(FATAL_APPLY_FAILURES as usize - 1));
    }

    /// A late command's too-big step is counted late, not clamped; one on time that is too big is clamped.
    #[test]
    fn late_and_out_of_limit_commands_are_counted_apart() {
        let p = fr3();
        let (mut t, logger, seen) = Ticks::new(HalControl::start(&p, &at(&START, 0.03)).unwrap());
        t.tick(Ok(at(&START, 0.03)), &[], Ok(()));
        t.tick(Ok(at(&START, 0.03)), &[], Ok(()));
        let mut jump = START;
        jump[0] += 0.01;
        let mut late = t.command(1, &jump, 0.03);
        late.state_seq -= 1;
        let st = t.tick(Ok(at(&START, 0.03)), &[late], Ok(()));
        assert_eq!((st.late_commands, st.clamped_commands, st.rejected_commands), (1, 0, 0));
        // On time and out of limits: that is content.
        let on_time = t.command(1, &[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0][..], 0.03);
        let st = t.tick(Ok(at(&START, 0.03)), &[on_time], Ok(()));
        assert_eq!((st.late_commands, st.clamped_commands), (1, 1));
        logger.finish();
        // The clamp is logged with the limit it met; the late step is not a clamp.
        let seen = seen.lock().unwrap();
        let clamps: Vec<String> =
            seen.iter().filter(|e| matches!(e, LoopEvent::Clamped { .. })).map(|e| e.to_string()).collect();
        assert_eq!(clamps.len(), 1, "{seen:?}");
        assert!(clamps[0].contains("exceeds the limit"), "{}", clamps[0]);
    }

    /// The controller ticked twice between two frames: two commands answer the same frame, the second one a tick
    /// ahead. The first is this tick's and is applied exactly; the second is counted and not followed.
    #[test]
    fn a_second_command_answering_the_same_frame_is_not_followed() {
        let p = fr3();
        let (mut t, _logger, _) = Ticks::new(HalControl::start(&p, &at(&START, 0.03)).unwrap());
        let step = |t: &mut Ticks, cmds: &[[f64; 7]]| {
            let c: Vec<JointCommand> = cmds.iter().map(|q| t.command(1, q, 0.03)).collect();
            t.tick(Ok(at(&START, 0.03)), &c, Ok(()))
        };
        // Accelerating at 4 rad/s²: a compliant stream.
        let (mut q, mut v) = (START, 0.0);
        let next = |q: &mut [f64; 7], v: &mut f64| {
            *v += 4e-3;
            q[0] += *v * 1e-3;
            *q
        };
        for _ in 0..50 {
            let c = next(&mut q, &mut v);
            step(&mut t, &[c]);
        }
        let first = next(&mut q, &mut v);
        let second = next(&mut q, &mut v);
        let st = step(&mut t, &[first, second]);
        assert_eq!(st.applied_position[0], first[0], "the first answer is applied exactly");
        assert_eq!((st.duplicate_commands, st.clamped_commands, st.late_commands), (1, 0, 0));
        // The controller sees last_command_seq and continues from what the HAL applied: exact again.
        let mut after = first;
        after[0] += v * 1e-3;
        let st = step(&mut t, &[after]);
        assert_eq!(st.applied_position[0], after[0]);
        assert_eq!(st.clamped_commands, 0);
    }

    #[test]
    fn the_gripper_target_goes_to_the_backend_only_on_change() {
        let p = fr3();
        let (mut t, _logger, _) = Ticks::new(HalControl::start(&p, &at(&START, 0.07)).unwrap());
        for _ in 0..100 {
            let c = t.command(1, &START, 0.07);
            t.tick(Ok(at(&START, 0.07)), &[c], Ok(()));
        }
        assert!(t.gripper_moves.is_empty());
        for _ in 0..100 {
            let c = t.command(1, &START, 0.02);
            let st = t.tick(Ok(at(&START, 0.07)), &[c], Ok(()));
            assert_eq!(st.gripper_target, 0.02);
        }
        assert_eq!(t.gripper_moves, [GripperMove { width: 0.02, speed: p.gripper_speed_max }]);
    }
}
