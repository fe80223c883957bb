//! The HAL driven by a Franka robot: the robot's 1 kHz loop is the HAL's loop.
//!
//! Each state the robot sends runs one HAL tick inside franka-rs's `control_joint_positions` callback: the state
//! is the measurement, the controller's newest command goes through the same safety filter as with the sim, and
//! the filtered setpoint is what the callback returns, within the same cycle. libfranka's rate limiter (on by
//! default, `fci.limit_rate`) stands behind our filter as a second guard with the same FR3 limits.
//!
//! Around it, what a robot engineer expects:
//! - **Start**: the robot is read before anything else; a robot in reflex, user-stopped or with errors set is
//!   refused with its reasons (nothing commanded). Each motion starts where the robot holds the arm: its own
//!   setpoint `q_d` at the motion's first state, taken over only within 0.01 rad of the measured pose.
//! - **Reflex** (any `ControlException`): the HAL reports the robot's reasons (log, state frame bits, exit
//!   report), holds, keeps publishing the robot's state, and does **not** recover on its own. SIGUSR1 (or
//!   `mars-hal recover` with no HAL running) runs the robot's error recovery; the HAL resumes from the pose it
//!   measures then, and a controller starts a new session.
//! - **Lost connection** (no state within franka-rs's 1 s UDP timeout, or the socket closed): reported and the
//!   process ends (exit 1) without a panic.
//! - **SIGTERM / the duration**: stop following, brake the setpoint to rest within the limits, then finish the
//!   motion and release the robot.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use franka::{ControllerMode, FrankaError, JointPositions, RobotMode, RobotState};
use mars_rt::overlong::Stamp;
use tracing::{info, warn};

use super::JOINTS;
use super::hand::{Grasp, Hand};
use super::recent_cycles::{CycleRecord, RecentCycles};
use super::report::RobotLoopReport;
use super::setpoint_sync::{ResyncFrom, RobotSetpoints};
use super::state::measurement;
use super::{Fci, FciParams, LateCommands, Realtime, connect};
use crate::backend::{Backend, BackendError, Measurement, RobotReport};
use crate::gripper::GripperMove;
use crate::runner::{Ended, HalLoop, Next, Report, RunOptions};
use mars_profile::Profile;

/// A state that comes less than half the robot's 1 ms period after the one before is bunched behind it.
const BUNCHED: Duration = Duration::from_micros(500);

/// The cycles before a reflex whose regularity its report gives (and whose last few it logs).
const REGULARITY_CYCLES: usize = 64;

/// Why the HAL would not take the robot over: nothing was commanded.
#[derive(Debug, thiserror::Error)]
pub enum FciStartRefusal {
    #[error(
        "the robot at {addr} is in {mode:?} mode with errors [{errors}]: nothing was commanded; clear it first \
         (`mars-hal recover --robot-ip {addr}`, or in Desk)"
    )]
    NotReady { addr: String, mode: RobotMode, errors: String },
    #[error(
        "this kernel is not PREEMPT_RT (/sys/kernel/realtime does not read 1): a real FR3 needs one (see README, \
         \"On a real FR3\"); set `[fci] realtime = \"ignore\"` (or --realtime ignore) to run anyway, e.g. against \
         franka-sim"
    )]
    NoRealtimeKernel,
}

/// A robot mode as the wire carries it (`mars_ipc::robot_mode`).
pub fn wire_mode(m: RobotMode) -> u32 {
    use mars_ipc::robot_mode as w;
    match m {
        RobotMode::Other => w::OTHER,
        RobotMode::Idle => w::IDLE,
        RobotMode::Move => w::MOVE,
        RobotMode::Guiding => w::GUIDING,
        RobotMode::Reflex => w::REFLEX,
        RobotMode::UserStopped => w::USER_STOPPED,
        RobotMode::AutomaticErrorRecovery => w::AUTOMATIC_ERROR_RECOVERY,
    }
}

/// libfranka's error flags as bits (flag i → bit i; there are 41).
pub fn error_bits(e: &franka::Errors) -> u64 {
    e.0.iter().enumerate().fold(0, |bits, (i, &set)| bits | (u64::from(set) << i))
}

/// The measurement of one robot state, with the hand's width and the robot's own report. Allocates nothing.
fn measured(s: &RobotState, hand: Option<&Hand>) -> Measurement {
    let mut m = measurement(s);
    m.gripper = hand.map_or(0.0, Hand::width);
    m.robot = RobotReport {
        mode: wire_mode(s.robot_mode),
        errors: error_bits(&s.current_errors),
        reflex_errors: error_bits(&s.last_motion_errors),
        success_rate: s.control_command_success_rate,
        cycles: 0,
    };
    m
}

/// The backend the HAL tick sees inside one robot cycle: `read` is the state just received, `apply` fills the
/// command the callback returns, the gripper target goes to the hand's thread.
struct Cycle<'a> {
    state: &'a RobotState,
    hand: Option<&'a mut Hand>,
    command: [f64; JOINTS],
    /// Whether the robot takes commands now (false while holding after a reflex: the setpoint is only reported).
    commanding: bool,
    /// The robot's cycles since the last state the HAL saw (0 while holding: nothing is commanded).
    cycles: u32,
}

impl Backend for Cycle<'_> {
    fn read(&mut self) -> Result<Measurement, BackendError> {
        let mut m = measured(self.state, self.hand.as_deref());
        m.robot.cycles = self.cycles;
        Ok(m)
    }

    fn apply(&mut self, position: &[f64]) -> Result<(), BackendError> {
        self.command.copy_from_slice(&position[..JOINTS]);
        Ok(())
    }

    fn move_gripper(&mut self, to: GripperMove) -> Result<(), BackendError> {
        if !self.commanding {
            return Err(BackendError::Transient("the robot is holding after a reflex"));
        }
        match self.hand.as_deref_mut().map(|hand| hand.request(to)) {
            Some(true) => Ok(()),
            Some(false) => Err(BackendError::Transient("the Franka Hand is still busy with earlier targets")),
            None => Err(BackendError::Transient("no gripper: [fci] gripper = false")),
        }
    }
}

/// How a control phase ended.
enum Phase {
    /// The HAL's run ended (duration or termination at rest): the motion was finished.
    Done(Ended),
    /// The robot stopped itself; its reasons.
    Reflex(String),
    /// The connection is gone.
    Lost(String),
}

/// Runs the HAL on the FCI robot at `addr` with the settings `p` (its `[fci]` table, checked) until the duration
/// ends, a termination request (at rest), or the connection breaks. Refuses to start (nothing commanded) when the
/// robot cannot be read or is not ready.
pub fn run(profile: &Profile, p: &FciParams, addr: &str, opts: &RunOptions) -> anyhow::Result<Report> {
    if p.realtime == Realtime::Enforce && !realtime_kernel() {
        return Err(FciStartRefusal::NoRealtimeKernel.into());
    }
    let timeout = Duration::from_secs_f64(p.connect_timeout_s);
    let fci = connect(addr, timeout)?;
    let state = fci.read_once(timeout)?;
    refuse_unless_ready(&state, addr)?;
    let grasp = Grasp { below_m: p.grasp_below_m, force_n: p.grasp_force_n };
    let mut hand = if p.gripper { Some(Hand::start(addr, timeout, grasp)?) } else { None };
    let mut hal = HalLoop::start(profile, measured(&state, hand.as_ref()), opts)?;
    let recover = Arc::new(AtomicBool::new(false));
    signal_hook::flag::register(signal_hook::consts::SIGUSR1, recover.clone())?;
    let mut report = RobotLoopReport { addr: addr.to_string(), ..Default::default() };
    info!(addr, fci = ?fci.fci_version(), gripper = p.gripper, "driving the robot over FCI");

    let ended = loop {
        match control(&fci, &mut hal, hand.as_mut(), p, &mut report) {
            Phase::Done(e) => break e,
            Phase::Lost(why) => {
                warn!(addr, "lost the connection to the robot: {why}");
                report.connection_lost = Some(why);
                break Ended::ConnectionLost;
            }
            Phase::Reflex(reasons) => {
                warn!(addr, "the robot stopped itself (reflex: {reasons}); holding until SIGUSR1 asks to recover");
                report.reflexes.push(reasons);
                hal.on_robot_fault();
            }
        }
        match hold(&fci, &mut hal, hand.as_mut(), &recover, timeout, &mut report) {
            Ok(None) => continue,
            Ok(Some(e)) => break e,
            Err(why) => {
                warn!(addr, "lost the connection to the robot while holding: {why}");
                report.connection_lost = Some(why);
                break Ended::ConnectionLost;
            }
        }
    };
    report.gripper = hand.as_ref().map(Hand::counts);
    drop(hand);
    Ok(hal.finish(ended, 0, Some(Box::new(report))))
}

/// Why a motion ended at its first state: the take-over checks the arm passed when the HAL read it failed there
/// (it moved, or left its range, in between), or the robot's setpoint was not where the arm is.
const MOVED_BEFORE_THE_MOTION: &str = "at the motion's first state the arm moved, or the robot's setpoint was away \
     from it (more than 0.01 rad), since the HAL read it: nothing was commanded";

/// How far (rad) the robot's own setpoint may be from the measured pose for the HAL to take the arm over at it:
/// an internal controller's tracking error at rest is far smaller (0.4 mrad seen on franka-sim, settling).
const HELD_SETPOINT_GAP_RAD: f64 = 0.01;

/// The state with the setpoint the robot holds the arm at as the position to take over at: `q_d`, from which the
/// robot judges our first command and libfranka's rate limiter continues it (libfranka's examples start a joint
/// motion from it too). At rest it is the measured pose within the internal controller's tracking error; `None`
/// where it is not (the HAL would move the arm to a pose it did not measure).
fn held_by_the_robot(state: &RobotState, hand: Option<&Hand>) -> Option<Measurement> {
    let near = state.q_d.iter().zip(&state.q).all(|(d, q)| (d - q).abs() <= HELD_SETPOINT_GAP_RAD);
    let mut m = measured(state, hand);
    m.position[..JOINTS].copy_from_slice(&state.q_d);
    near.then_some(m)
}

/// One motion: the robot's callback runs the HAL tick until the HAL ends (at rest) or the robot stops. The HAL
/// takes the arm over again at the motion's first state, at the robot's own setpoint: the read before (at start,
/// or after a recovery) may be hundreds of ms old, an arm still settling from the last motion has moved since, and
/// a first command away from `q_d` is rate-limited by libfranka into a setpoint the HAL then resyncs to (0.4 mrad
/// from the held pose, seen on franka-sim on a loaded machine).
fn control(
    fci: &Fci,
    hal: &mut HalLoop,
    mut hand: Option<&mut Hand>,
    p: &FciParams,
    report: &mut RobotLoopReport,
) -> Phase {
    let mut done = None;
    let mut motion = Motion::new(p.late_commands == LateCommands::Applied);
    let result = fci.robot().control_joint_positions(
        |state, period| {
            let start = Stamp::now();
            if motion.cycles == 0
                && held_by_the_robot(state, hand.as_deref()).is_none_or(|m| hal.take_over_at(&m).is_err())
            {
                done = Some(Ended::NotTakenOver(MOVED_BEFORE_THE_MOTION));
                return JointPositions { motion_finished: true, ..JointPositions::new(state.q) };
            }
            let (missed, bunched) = motion.timing(start.at, period, state, hal, report);
            let resynced = motion.follow_the_robot(state, missed, hal, report);
            let mut cycle = Cycle {
                state,
                hand: hand.as_deref_mut(),
                command: state.q,
                commanding: true,
                cycles: u32::try_from(missed + 1).unwrap_or(u32::MAX),
            };
            let next = hal.tick(&mut cycle, start);
            motion.sent(state, period, cycle.command, resynced, bunched);
            let mut cmd = JointPositions::new(cycle.command);
            if let Next::End(e) = next {
                done = Some(e);
                cmd.motion_finished = true;
            }
            cmd
        },
        ControllerMode::JointImpedance,
        p.limit_rate,
        p.cutoff_hz,
    );
    match (result, done) {
        (Ok(()), Some(e)) => Phase::Done(e),
        (Ok(()), None) => Phase::Lost("the robot ended the motion without being asked".into()),
        (Err(FrankaError::Control(ce)), _) => Phase::Reflex(motion.reflex_reasons(&ce, report)),
        (Err(e), _) => Phase::Lost(e.to_string()),
    }
}

/// What the robot's callback keeps from cycle to cycle of one motion: when the last state came, the model of the
/// robot's setpoint history, and the recent cycles a reflex's report describes. Every method runs inside the
/// robot's cycle: no allocation, no lock.
struct Motion {
    last: Option<Instant>,
    cycles: u64,
    setpoints: RobotSetpoints,
    /// The robot cycle of the last resync and the states unseen before it.
    last_resync: Option<(u64, u64)>,
    recent: RecentCycles<REGULARITY_CYCLES>,
}

impl Motion {
    fn new(late_commands_applied: bool) -> Self {
        Self {
            last: None,
            cycles: 0,
            setpoints: RobotSetpoints::new(late_commands_applied),
            last_resync: None,
            recent: RecentCycles::default(),
        }
    }

    /// The state's timing against the one before: how many states the robot sent that we never saw, and whether
    /// this one came bunched behind a late one; counted in the report with the robot's success rate.
    fn timing(
        &mut self,
        woke: Instant,
        period: franka::Duration,
        state: &RobotState,
        hal: &mut HalLoop,
        report: &mut RobotLoopReport,
    ) -> (u64, bool) {
        let bunched = self.last.is_some_and(|prev| woke - prev < BUNCHED);
        if let Some(prev) = self.last {
            hal.late_us.saturating_record((woke - prev).as_micros().saturating_sub(1000) as u64);
        }
        report.bunched_states += u64::from(bunched);
        self.last = Some(woke);
        // States the robot sent between the last one we saw and this one.
        let missed = period.as_millis().saturating_sub(1);
        report.cycles += 1;
        report.lost_states += missed;
        self.cycles += 1;
        report.last_success_rate = state.control_command_success_rate;
        if self.cycles > 100 {
            report.success_rate(state.control_command_success_rate);
        }
        (missed, bunched)
    }

    /// Continues the HAL's filter from the robot's own setpoint history when the robot applied another than our
    /// last command (the robot's q_d is the setpoint it applied last cycle: ours, unless it extrapolated over a
    /// command it did not get or over states we never saw: see `setpoint_sync`), and has the next command judged
    /// from each history the robot may yet be in. Whether it resynced.
    fn follow_the_robot(
        &mut self,
        state: &RobotState,
        missed: u64,
        hal: &mut HalLoop,
        report: &mut RobotLoopReport,
    ) -> bool {
        let rate = state.control_command_success_rate;
        let resync = self.setpoints.observe(&state.q_d, &state.dq_d, &state.ddq_d, rate, missed);
        if let Some(r) = &resync {
            hal.control.resync_setpoint(&r.q, &r.v, &r.a);
            report.resyncs += 1;
            report.resyncs_thrown_away += u64::from(self.setpoints.last_from == Some(ResyncFrom::LateThrownAway));
            self.last_resync = Some((report.cycles, missed));
        }
        let mut judged_twice = false;
        for (h, cycles) in self.setpoints.alternatives() {
            hal.control.also_judged_from(&h.q, &h.v, &h.a, cycles);
            judged_twice = true;
        }
        report.judged_twice += u64::from(judged_twice);
        resync.is_some()
    }

    /// The command sent this cycle: into the setpoint model and the recent cycles.
    fn sent(
        &mut self,
        state: &RobotState,
        period: franka::Duration,
        command: [f64; JOINTS],
        resynced: bool,
        bunched: bool,
    ) {
        self.setpoints.sent(command);
        self.recent.push(CycleRecord {
            period_ms: period.as_millis(),
            q_d: state.q_d,
            dq_d: state.dq_d,
            ddq_d: state.ddq_d,
            sent: command,
            resynced,
            bunched,
            success_rate: state.control_command_success_rate,
        });
    }

    /// A reflex's reasons as the robot gave them, with what came before it: the last resync, how regularly the
    /// states came, and (logged) the last cycles of the joint our commands jerked most against the robot's report.
    fn reflex_reasons(&self, ce: &franka::ControlException, report: &RobotLoopReport) -> String {
        let reasons = ce.last_motion_errors.names();
        let mut why = if reasons.is_empty() { ce.message.clone() } else { reasons.join(", ") };
        // Whether the robot had just extrapolated over a lost command (the usual cause of a discontinuity).
        if let (Some((at, missed)), Some(from)) = (self.last_resync, self.setpoints.last_from) {
            why += &format!(
                " ({} cycles after the last setpoint resync, over {missed} unseen states, from {from:?})",
                report.cycles - at
            );
        }
        // How regularly the states came before it: the robot may have applied what the HAL could only guess.
        why += &format!("; {}", self.recent.regularity());
        // The cycles before it, for the joint where our last commands implied the largest jerk against the
        // robot's report (a discontinuity is usually there).
        let joint = self.recent.roughest_joint(8);
        warn!("the last cycles before the reflex, joint {}:{}", joint + 1, self.recent.describe(joint, 8));
        why
    }
}

/// After a reflex: publish the robot's state (nothing commanded) until SIGUSR1 asks for a recovery that
/// succeeds (`Ok(None)`: resume), the HAL's run ends (`Ok(Some)`), or the connection breaks (`Err`).
fn hold(
    fci: &Fci,
    hal: &mut HalLoop,
    mut hand: Option<&mut Hand>,
    recover: &AtomicBool,
    timeout: Duration,
    report: &mut RobotLoopReport,
) -> Result<Option<Ended>, String> {
    loop {
        // read_once waits for the next state (the robot sends them at 1 kHz in every mode).
        let state = fci.read_once(timeout).map_err(|e| e.to_string())?;
        let mut cycle =
            Cycle { state: &state, hand: hand.as_deref_mut(), command: state.q, commanding: false, cycles: 0 };
        if let Next::End(e) = hal.tick(&mut cycle, Stamp::now()) {
            return Ok(Some(e));
        }
        if !recover.swap(false, Ordering::AcqRel) {
            continue;
        }
        info!("recovery requested: running the robot's automatic error recovery");
        if let Err(e) = fci.recover(timeout) {
            warn!("the robot's error recovery failed: {e}; still holding");
            continue;
        }
        let state = fci.read_once(timeout).map_err(|e| e.to_string())?;
        match hal.control.resume_from(&measured(&state, hand.as_deref())) {
            Ok(()) => {
                report.recoveries += 1;
                info!(q = ?state.q, "recovered: resuming from the measured pose; a controller starts a new session");
                return Ok(None);
            }
            Err(e) => warn!("recovered, but the arm cannot be taken over: {e}; still holding"),
        }
    }
}

fn refuse_unless_ready(s: &RobotState, addr: &str) -> Result<(), FciStartRefusal> {
    let bad_mode = matches!(s.robot_mode, RobotMode::Reflex | RobotMode::UserStopped | RobotMode::Other);
    if bad_mode || s.current_errors.any() {
        let mut names: Vec<String> = s.current_errors.names().into_iter().map(str::to_string).collect();
        names.extend(s.last_motion_errors.names().into_iter().map(|n| format!("{n} (last motion)")));
        return Err(FciStartRefusal::NotReady {
            addr: addr.to_string(),
            mode: s.robot_mode,
            errors: if names.is_empty() { "none".into() } else { names.join(", ") },
        });
    }
    Ok(())
}

/// Whether the running kernel is PREEMPT_RT.
fn realtime_kernel() -> bool {
    std::fs::read_to_string("/sys/kernel/realtime").is_ok_and(|s| s.trim() == "1")
}

#[cfg(test)]
mod tests {
    use super::*;
    use franka::Errors;

    fn errors(names: &[&str]) -> Errors {
        let mut e = Errors::default();
        for n in names {
            e.0[Errors::index_of(n).unwrap()] = true;
        }
        e
    }

    #[test]
    fn a_motion_takes_the_arm_over_at_the_robot_s_setpoint_only_where_it_is_near_the_measured_pose() {
        let q = [0.1, -0.2, 0.0, -1.5, 0.0, 1.6, 0.8];
        let settling = RobotState { q, q_d: q.map(|x| x + 4e-4), ..RobotState::default() };
        let m = held_by_the_robot(&settling, None).expect("0.4 mrad: the robot's tracking error");
        assert_eq!(&m.position[..JOINTS], &settling.q_d, "the robot's own setpoint");
        assert_eq!(&m.velocity[..JOINTS], &settling.dq, "measured velocities, for the take-over checks");
        let mut away = settling;
        away.q_d[3] += 0.02;
        assert!(held_by_the_robot(&away, None).is_none(), "a setpoint 0.02 rad away is not taken over");
        away.q_d[3] = f64::NAN;
        assert!(held_by_the_robot(&away, None).is_none());
    }

    #[test]
    fn a_robot_in_reflex_user_stopped_or_with_errors_is_refused_with_its_reasons() {
        let ready = RobotState { robot_mode: RobotMode::Idle, ..RobotState::default() };
        assert!(refuse_unless_ready(&ready, "r").is_ok());
        assert!(refuse_unless_ready(&RobotState { robot_mode: RobotMode::Move, ..ready }, "r").is_ok());
        let reflex = RobotState {
            robot_mode: RobotMode::Reflex,
            current_errors: errors(&["joint_reflex"]),
            last_motion_errors: errors(&["communication_constraints_violation"]),
            ..ready
        };
        let msg = refuse_unless_ready(&reflex, "172.16.0.2").unwrap_err().to_string();
        assert!(msg.contains("Reflex") && msg.contains("joint_reflex"), "{msg}");
        assert!(msg.contains("communication_constraints_violation (last motion)"), "{msg}");
        assert!(msg.contains("mars-hal recover --robot-ip 172.16.0.2") && msg.contains("nothing was commanded"));
        let stopped = RobotState { robot_mode: RobotMode::UserStopped, ..ready };
        assert!(refuse_unless_ready(&stopped, "r").unwrap_err().to_string().contains("UserStopped"));
        let errors_only = RobotState { current_errors: errors(&["joint_position_limits_violation"]), ..ready };
        assert!(refuse_unless_ready(&errors_only, "r").is_err());
    }

    #[test]
    fn error_flags_become_bits_in_libfrankas_order_and_modes_their_wire_values() {
        let e = errors(&["joint_position_limits_violation", "communication_constraints_violation"]);
        assert_eq!(error_bits(&e), 1 | (1 << 25));
        assert_eq!(error_bits(&Errors::default()), 0);
        assert_eq!(wire_mode(RobotMode::Reflex), mars_ipc::robot_mode::REFLEX);
        assert_eq!(mars_ipc::robot_mode::name(wire_mode(RobotMode::Move)), "Move");
    }
}
