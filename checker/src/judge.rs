//! The verdict on a recorded stream: every applied setpoint within the position limits; by finite differences of
//! consecutive setpoints (one period apart) the velocity within the robot's bound at that position, the acceleration
//! and the jerk within theirs; the robot's reflexes; and, given when a fault was injected, how the HAL reacted.

use serde::Serialize;

use crate::limits::Limits;
use crate::stream::{Frame, bits};

/// Relative slack of every comparison: floating-point rounding of the differences, not a margin.
pub const REL_TOL: f64 = 1e-6;
/// Violations listed in full (all are counted).
const LISTED: usize = 10;

#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct Violation {
    pub seq: u64,
    pub joint: usize,
    pub what: String,
    pub value: f64,
    pub limit: f64,
}

/// The largest |value| / limit seen of each difference.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Ratios {
    pub velocity: f64,
    pub acceleration: f64,
    pub jerk: f64,
}

/// What the HAL did after the fault.
#[derive(Debug, Clone, Serialize)]
pub struct Reaction {
    /// The arm was moving (not at rest) in the last frame before the fault.
    pub moving: bool,
    /// The HAL stopped following the session that ran at the fault (its first HOLDING frame of that session).
    pub held: bool,
    /// Why, as the HAL said in that frame.
    pub hold_reason: String,
    /// Fault → that frame (ms, the recorder's clock).
    pub hold_ms: Option<f64>,
    /// Fault → the first frame holding at rest after it (ms).
    pub rest_ms: Option<f64>,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct Verdict {
    pub frames: usize,
    /// Frames the recording is missing (gaps in `seq`): nothing is differenced across them.
    pub lost_frames: u64,
    /// Frames after robot cycles the HAL never saw: judged by the mean velocity over those cycles.
    pub robot_gaps: u64,
    /// The longest time between the HAL's stamps of two consecutive frames (ms): how long the HAL (or the robot
    /// pacing it) did not publish.
    pub largest_gap_ms: f64,
    pub velocity_steps: u64,
    pub acceleration_steps: u64,
    pub jerk_steps: u64,
    pub max_ratio: Ratios,
    /// The least distance of a step's velocity to the bound at its position (rad/s; negative: outside).
    pub least_velocity_room: f64,
    pub violations: u64,
    pub first_violations: Vec<Violation>,
    /// The robot's reflexes: frames where it enters one (its mode, its reflex reasons or the HAL's fault bit).
    pub reflexes: u64,
    pub reaction: Option<Reaction>,
    /// The last frame holds the arm at rest.
    pub ends_at_rest: bool,
}

impl Verdict {
    /// Nothing out of limits, no reflex, and the arm left at rest.
    pub fn clean(&self) -> bool {
        self.violations == 0 && self.reflexes == 0 && self.ends_at_rest && self.frames > 0
    }

    fn violate(&mut self, seq: u64, joint: usize, what: &str, value: f64, limit: f64) {
        self.violations += 1;
        if self.first_violations.len() < LISTED {
            self.first_violations.push(Violation { seq, joint, what: what.into(), value, limit });
        }
    }
}

/// Judges `frames` (in recorded order) against `lim`; `fault_at_ns` (the recorder's clock) adds the reaction.
pub fn judge(frames: &[Frame], lim: &Limits, fault_at_ns: Option<u64>) -> Verdict {
    let mut v = Verdict { frames: frames.len(), least_velocity_room: f64::INFINITY, ..Verdict::default() };
    // The current run of frames one period apart, newest last (four make a jerk).
    let mut run: Vec<&Frame> = Vec::with_capacity(4);
    let mut was_reflex = false;
    for f in frames {
        if f.q.len() != lim.joints {
            v.violate(f.seq, 0, "joint count", f.q.len() as f64, lim.joints as f64);
            run.clear();
            continue;
        }
        check_positions(&mut v, f, lim);
        if let Some(p) = run.last().filter(|p| f.seq == p.seq + 1) {
            v.largest_gap_ms = v.largest_gap_ms.max(f.hal_ns.saturating_sub(p.hal_ns) as f64 * 1e-6);
        }
        if f.in_reflex() {
            // The robot stopped itself: what the HAL reports as applied is the robot's own held reference, not a
            // command, and a motion after the recovery starts afresh. The reflex is counted, not differenced.
            v.reflexes += u64::from(!was_reflex);
            was_reflex = true;
            run.clear();
            continue;
        }
        was_reflex = false;
        continue_run(&mut v, &mut run, f, lim);
        check_differences(&mut v, &run, lim);
    }
    v.ends_at_rest = frames.last().is_some_and(|f| f.is(bits::HOLDING) && f.is(bits::AT_REST));
    v.reaction = fault_at_ns.and_then(|t| reaction(frames, t));
    v
}

fn check_positions(v: &mut Verdict, f: &Frame, lim: &Limits) {
    for (j, &q) in f.q.iter().enumerate() {
        let slack = REL_TOL * lim.q_max[j].abs().max(lim.q_min[j].abs()).max(1.0);
        if !q.is_finite() || q < lim.q_min[j] - slack {
            v.violate(f.seq, j, "position below q_min", q, lim.q_min[j]);
        } else if q > lim.q_max[j] + slack {
            v.violate(f.seq, j, "position above q_max", q, lim.q_max[j]);
        }
    }
}

/// Adds `f` to the run of consecutive frames, or starts a new run where the recording lost frames or the robot ran
/// cycles the HAL never saw (then the step is judged as the mean velocity over those cycles).
fn continue_run<'a>(v: &mut Verdict, run: &mut Vec<&'a Frame>, f: &'a Frame, lim: &Limits) {
    if let Some(p) = run.last().copied() {
        if f.seq != p.seq + 1 {
            v.lost_frames += f.seq.saturating_sub(p.seq + 1);
            run.clear();
        } else if f.robot_cycles > 1 {
            v.robot_gaps += 1;
            check_velocity(v, f, p, lim.dt * f64::from(f.robot_cycles), lim);
            run.clear();
        }
    }
    if run.len() == 4 {
        run.remove(0);
    }
    run.push(f);
}

/// The step from `p` to `f` over `dt` within the velocity bound at `f`'s position.
fn check_velocity(v: &mut Verdict, f: &Frame, p: &Frame, dt: f64, lim: &Limits) {
    v.velocity_steps += 1;
    for j in 0..lim.joints {
        let vel = (f.q[j] - p.q[j]) / dt;
        let (lo, hi) = lim.velocity_bounds(j, f.q[j]);
        let room = (hi - vel).min(vel - lo);
        v.least_velocity_room = v.least_velocity_room.min(room);
        v.max_ratio.velocity = v.max_ratio.velocity.max(vel.abs() / lim.dq_max[j]);
        if room < -REL_TOL * lim.dq_max[j] || !vel.is_finite() {
            let bound = if vel >= 0.0 { hi } else { lo };
            v.violate(f.seq, j, "velocity outside the bound at its position", vel, bound);
        }
    }
}

/// Acceleration and jerk of the newest frame of `run` by backward differences; its velocity too.
fn check_differences(v: &mut Verdict, run: &[&Frame], lim: &Limits) {
    let k = run.len();
    if k >= 2 {
        check_velocity(v, run[k - 1], run[k - 2], lim.dt, lim);
    }
    let q = |back: usize, j: usize| run[k - 1 - back].q[j];
    let dt = lim.dt;
    if k >= 3 {
        v.acceleration_steps += 1;
        for j in 0..lim.joints {
            let a = (q(0, j) - 2.0 * q(1, j) + q(2, j)) / (dt * dt);
            v.max_ratio.acceleration = v.max_ratio.acceleration.max(a.abs() / lim.ddq_max[j]);
            if !within(a, lim.ddq_max[j]) {
                v.violate(run[k - 1].seq, j, "acceleration", a, lim.ddq_max[j]);
            }
        }
    }
    if k >= 4 {
        v.jerk_steps += 1;
        for j in 0..lim.joints {
            let jerk = (q(0, j) - 3.0 * q(1, j) + 3.0 * q(2, j) - q(3, j)) / (dt * dt * dt);
            v.max_ratio.jerk = v.max_ratio.jerk.max(jerk.abs() / lim.jerk_max[j]);
            if !within(jerk, lim.jerk_max[j]) {
                v.violate(run[k - 1].seq, j, "jerk", jerk, lim.jerk_max[j]);
            }
        }
    }
}

/// |value| ≤ limit up to rounding; a NaN or an infinity never is.
fn within(value: f64, limit: f64) -> bool {
    value.is_finite() && value.abs() <= limit * (1.0 + REL_TOL)
}

/// How the HAL answered a fault at `fault_at` (recorder clock): the first frame holding the session that ran then,
/// and the first after it holding at rest. `None` when nothing was recorded before the fault.
fn reaction(frames: &[Frame], fault_at: u64) -> Option<Reaction> {
    let before = frames.iter().rev().find(|f| f.recv_ns < fault_at)?;
    let after = || frames.iter().filter(|f| f.recv_ns >= fault_at && f.session == before.session);
    let ms = |f: &Frame| (f.recv_ns - fault_at) as f64 * 1e-6;
    let hold = after().find(|f| f.is(bits::HOLDING));
    let rest = hold.and_then(|h| after().find(|f| f.seq >= h.seq && f.is(bits::HOLDING) && f.is(bits::AT_REST)));
    Some(Reaction {
        moving: !before.is(bits::AT_REST),
        held: hold.is_some(),
        hold_reason: hold.map_or("none", |h| bits::hold_reason(h.hold_reason)).into(),
        hold_ms: hold.map(ms),
        rest_ms: rest.map(ms),
    })
}
