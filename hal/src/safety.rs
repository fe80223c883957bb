//! The HAL's safety filter: whatever the controller sends, the setpoint applied to the joints stays inside
//! the profile's position, velocity, acceleration and jerk limits.
//!
//! Two stages:
//! 1. [`SafetyFilter::admit`] judges a command: NaN/∞ anywhere, a wrong joint count, an unknown mode or a bad
//!    gripper speed is always refused; a target outside the position limits or an intent (velocity/acceleration
//!    field) outside the limits is clamped or refused per the profile's [`LimitPolicy`] and counted. A step from
//!    the current setpoint that would exceed velocity/acceleration/jerk is counted the same way, unless the
//!    caller knows the step is off because of *timing* (the command came late, or is a second answer to the
//!    same frame): then it is not counted as out of limits, the caller counts it, and [`SafetyFilter::step`]
//!    smooths it. Timing the caller cannot see does the same: a HAL that missed a tick gets two ticks of the
//!    stream at once, and after the robot extrapolated its own setpoint ([`SafetyFilter::resync`]) the setpoint
//!    lags the stream. So a command whose step from the setpoint is too big is judged by the two steps its
//!    controller may have meant: from its own previous command (over their seq interval), or from the setpoint
//!    published in the frame it answers (where a controller that re-synchronises, as marsd does, continues
//!    from). Within limits either way, it is timing (smoothed, counted apart); a first command or a jump of the
//!    stream itself is still out of limits.
//! 2. [`SafetyFilter::step`] moves the applied setpoint one tick toward the admitted target (or to rest when
//!    braking) with a jerk-, acceleration- and velocity-bounded law, so even a clamped jump is reached smoothly.
//!
//! Velocity bounds may depend on position (the FR3's, see [`mars_profile::velocity_limits`]). The filter plans with
//! their braking *envelope*, less the profile's `velocity_headroom`, tightened by the most its velocity law can
//! lag a falling bound (A²/J: it follows a bound that drops at A/2 from A²/(2J) above, and twice that covers the
//! transients), so the applied velocity meets the robot's bound at every position it reaches.

use mars_ipc::{CommandMode, JointCommand, MAX_JOINTS};

use mars_profile::velocity_limits::{JointVelocityBound, VelocityLimits};
use mars_profile::{LimitPolicy, Profile};

/// Relative slack for floating-point rounding when comparing against a limit.
const EPS: f64 = 1e-9;
/// Velocity loop gain of the setpoint generator (1/s): settles a step in about 0.1 s.
const KV: f64 = 100.0;

/// Why a command was refused.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum Refusal {
    #[error("command has {found} joints, the robot has {expected}")]
    JointCount { expected: usize, found: u32 },
    #[error("command mode {0} is unknown")]
    UnknownMode(u32),
    #[error("joint {joint}: {field} is not a finite number")]
    NotFinite { joint: usize, field: &'static str },
    #[error("gripper target is not a finite number")]
    GripperNotFinite,
    #[error("gripper speed {0} is not a finite number ≥ 0")]
    GripperSpeed(f64),
    #[error("joint {joint}: target position {value} outside [{min}, {max}]")]
    Position { joint: usize, value: f64, min: f64, max: f64 },
    #[error("joint {joint}: {quantity} {value} exceeds the limit {limit}")]
    Rate { joint: usize, quantity: &'static str, value: f64, limit: f64 },
    #[error("gripper target {value} outside [{min}, {max}]")]
    Gripper { value: f64, min: f64, max: f64 },
}

/// A command that passed [`SafetyFilter::admit`]: the (possibly clamped) target.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Target {
    pub position: [f64; MAX_JOINTS],
    pub gripper: f64,
    pub gripper_speed: f64,
    /// Whether anything had to be clamped because it was out of limits (counted in `clamped`).
    pub clamped: bool,
    /// The first limit it was clamped to, as a refusal would have said it (the HAL logs it).
    pub clamp_reason: Option<Refusal>,
    /// The step from the applied setpoint exceeds a rate limit, and that is timing: the caller said so, or the
    /// step the controller meant is within the limits (not counted as clamped; `step` smooths it).
    pub late_step: bool,
}

/// A rate limit exceeded: (quantity, value, limit).
type Excess = (&'static str, f64, f64);

/// How many published setpoints are kept for judging the commands that answer them.
const PUBLISHED_KEPT: usize = 8;

/// A setpoint as published in a state frame.
#[derive(Debug, Clone, Copy)]
struct Published {
    frame: u64,
    q: [f64; MAX_JOINTS],
    v: [f64; MAX_JOINTS],
    a: [f64; MAX_JOINTS],
}

/// A setpoint history: position, velocity and acceleration of every joint.
#[derive(Debug, Clone, Copy)]
struct Setpoint {
    q: [f64; MAX_JOINTS],
    v: [f64; MAX_JOINTS],
    a: [f64; MAX_JOINTS],
}

impl Setpoint {
    fn of(&self, i: usize) -> (f64, f64, f64) {
        (self.q[i], self.v[i], self.a[i])
    }
}

/// The last position command admitted, for judging the next one by the controller's own step.
#[derive(Debug, Clone, Copy)]
struct StreamPoint {
    session: u64,
    seq: u64,
    q: [f64; MAX_JOINTS],
    /// The stream's velocity there, if the command before it was its predecessor (seq − 1).
    v: Option<[f64; MAX_JOINTS]>,
}

/// The most other histories one step is kept within the limits from (see [`SafetyFilter::also_judged_from`]).
pub const MAX_ALTERNATIVES: usize = 8;

/// Another history the robot may judge the next step against, over `cycles` cycles (franka-sim records a command
/// that came late over the cycles since the last one it recorded).
#[derive(Debug, Clone, Copy)]
struct Alternative {
    from: Setpoint,
    cycles: u64,
}

/// The fraction of the acceleration and jerk limits the filter's own trajectories use (marsd's smoother plans at
/// 0.9 for the same reason).
const OWN_PLAN_FACTOR: f64 = 0.95;

/// Limits and the applied setpoint (position, velocity, acceleration) of every joint.
pub struct SafetyFilter {
    n: usize,
    dt: f64,
    policy: LimitPolicy,
    /// The positions a joint may be commanded to and rest in (`Profile::position_limits`, tightened with the
    /// velocity bounds).
    q_min: [f64; MAX_JOINTS],
    q_max: [f64; MAX_JOINTS],
    /// The robot's velocity bounds, and the tightened ones the setpoint law plans with.
    bound: [JointVelocityBound; MAX_JOINTS],
    plan: [JointVelocityBound; MAX_JOINTS],
    a_max: [f64; MAX_JOINTS],
    j_max: [f64; MAX_JOINTS],
    g_min: f64,
    g_max: f64,
    q: [f64; MAX_JOINTS],
    v: [f64; MAX_JOINTS],
    a: [f64; MAX_JOINTS],
    /// Position and velocity loop gains of [`Self::step`] (1/s).
    kp: f64,
    kv: f64,
    stream: Option<StreamPoint>,
    /// For the next step only: other histories the robot may judge it against (see [`Self::also_judged_from`]).
    alternatives: [Option<Alternative>; MAX_ALTERNATIVES],
    /// The setpoints of the last frames published, by frame seq modulo the length.
    published: [Option<Published>; PUBLISHED_KEPT],
    pub rejected: u64,
    pub clamped: u64,
    /// Commands whose step from the setpoint was too big, the caller did not know why, and the step the controller
    /// meant was within limits (timing: a tick the HAL missed, or a setpoint the robot moved).
    pub timing_steps: u64,
    /// Ticks in which the position guard had to stop a joint at its limit (expected to stay zero).
    pub position_guard_hits: u64,
    /// Joint steps in which no acceleration met every bound at once, so the middle of the empty interval was
    /// taken (a last resort, expected to stay zero).
    pub infeasible_steps: u64,
}

fn arr(v: &[f64]) -> [f64; MAX_JOINTS] {
    let mut a = [0.0; MAX_JOINTS];
    a[..v.len()].copy_from_slice(v);
    a
}

impl SafetyFilter {
    /// A filter at rest at `start`: the measured position, which the caller has checked lies within
    /// [`Self::position_range`] (see [`crate::control`]).
    pub fn new(p: &Profile, start: &[f64]) -> Self {
        let unused = JointVelocityBound::new(VelocityLimits::Constant, 0, 1.0);
        let (mut bound, mut plan) = ([unused; MAX_JOINTS], [unused; MAX_JOINTS]);
        let (mut q_min, mut q_max) = ([0.0; MAX_JOINTS], [0.0; MAX_JOINTS]);
        for (i, (b, planning)) in p.velocity_bounds().into_iter().zip(p.filter_velocity_bounds()).enumerate() {
            bound[i] = b;
            plan[i] = planning;
            (q_min[i], q_max[i]) = plan[i].rest_range(p.q_min[i], p.q_max[i]);
        }
        Self {
            n: p.joints,
            dt: p.period_s(),
            policy: p.limit_policy,
            q_min,
            q_max,
            bound,
            plan,
            a_max: arr(&p.ddq_max),
            j_max: arr(&p.jerk_max),
            g_min: p.gripper_min,
            g_max: p.gripper_max,
            q: arr(start),
            v: [0.0; MAX_JOINTS],
            a: [0.0; MAX_JOINTS],
            // kv = 4·kp is critical damping; kv·dt ≤ 0.5 keeps the discrete loop well inside stability.
            kp: KV.min(0.5 * p.rate_hz) / 4.0,
            kv: KV.min(0.5 * p.rate_hz),
            stream: None,
            alternatives: [None; MAX_ALTERNATIVES],
            published: [None; PUBLISHED_KEPT],
            rejected: 0,
            clamped: 0,
            timing_steps: 0,
            position_guard_hits: 0,
            infeasible_steps: 0,
        }
    }

    /// Starts over at rest at `start` (the measured position after the robot stopped itself), keeping the
    /// counters.
    pub fn restart(&mut self, start: &[f64]) {
        self.q = arr(start);
        self.v = [0.0; MAX_JOINTS];
        self.a = [0.0; MAX_JOINTS];
    }

    /// Continues from the setpoint state the robot applied (position, velocity, acceleration), where it differs
    /// from ours: after a cycle the robot did not get our command for, it extrapolated its own.
    pub fn resync(&mut self, q: &[f64], v: &[f64], a: &[f64]) {
        self.q = arr(q);
        self.v = arr(v);
        self.a = arr(a);
    }

    /// For the next step only: the robot may judge it against this history (position, velocity, acceleration),
    /// over `cycles` cycles, instead of ours, which it cannot tell us yet (franka-sim, where it may have thrown a late
    /// command of ours away: `fci::late_reads`). Called once per such history, likelier first. The step is kept
    /// within the rate limits from ours and from each in turn, for each joint where some step is within the limits
    /// from ours and all those heeded before; where none is, that history is not heeded: ours is the likelier, and
    /// a step between two histories breaks the limits from both (a version that took the middle raised franka-sim's
    /// reflexes). Beyond [`MAX_ALTERNATIVES`], ignored.
    pub fn also_judged_from(&mut self, q: &[f64], v: &[f64], a: &[f64], cycles: u64) {
        if let Some(slot) = self.alternatives.iter_mut().find(|s| s.is_none()) {
            *slot = Some(Alternative { from: Setpoint { q: arr(q), v: arr(v), a: arr(a) }, cycles: cycles.max(1) });
        }
    }

    /// Joint `i`'s step accelerations (the filter's own law, `v += a·dt; q += v·dt`) within `factor` of the jerk and
    /// acceleration limits as the robot judges the step from `alt`: over `m` cycles from another position and
    /// velocity, the step's acceleration reads as `α + a/m²` there.
    fn alternative_bound(&self, i: usize, alt: &Alternative, factor: f64) -> (f64, f64) {
        let dt = self.dt;
        let (am, jm) = (self.a_max[i] * factor, self.j_max[i] * factor);
        let step = alt.cycles as f64 * dt;
        let (q, v, a) = alt.from.of(i);
        let alpha = ((self.q[i] + self.v[i] * dt - q) / step - v) / step;
        let beta = (dt / step) * (dt / step);
        let lo = (-am).max(a - jm * step);
        let hi = am.min(a + jm * step);
        ((lo - alpha) / beta, (hi - alpha) / beta)
    }

    /// Joint `i`'s step accelerations within the planned limits from ours alone.
    fn own_bound(&self, i: usize) -> (f64, f64) {
        let (am, jm) = (self.a_max[i] * OWN_PLAN_FACTOR, self.j_max[i] * OWN_PLAN_FACTOR);
        ((self.a[i] - jm * self.dt).max(-am), (self.a[i] + jm * self.dt).min(am))
    }

    /// Narrows `(lo, hi)` by each alternative heeded for joint `i` (bit k of `heeded`: the k-th), in turn, where
    /// that leaves a step; returns the alternatives it could heed.
    fn heed(&self, i: usize, (lo, hi): &mut (f64, f64), alts: &[Option<Alternative>], heeded: u8) -> u8 {
        let mut kept = 0;
        for (k, alt) in alts.iter().enumerate().filter(|(k, _)| heeded & (1 << k) != 0) {
            let Some(alt) = alt else { continue };
            let (alo, ahi) = self.alternative_bound(i, alt, OWN_PLAN_FACTOR);
            let (blo, bhi) = (lo.max(alo), hi.min(ahi));
            if blo <= bhi {
                (*lo, *hi) = (blo, bhi);
                kept |= 1 << k;
            }
        }
        kept
    }

    /// The setpoint now goes out in state frame `frame`: a command answering that frame may continue from it.
    pub fn note_published(&mut self, frame: u64) {
        self.published[(frame % PUBLISHED_KEPT as u64) as usize] =
            Some(Published { frame, q: self.q, v: self.v, a: self.a });
    }

    /// The positions joint `i` may be commanded to and rest in.
    pub fn position_range(&self, i: usize) -> (f64, f64) {
        (self.q_min[i], self.q_max[i])
    }

    pub fn position(&self) -> &[f64] {
        &self.q[..self.n]
    }
    pub fn velocity(&self) -> &[f64] {
        &self.v[..self.n]
    }
    pub fn acceleration(&self) -> &[f64] {
        &self.a[..self.n]
    }

    pub fn at_rest(&self) -> bool {
        self.v[..self.n].iter().all(|v| v.abs() < 1e-3)
    }

    /// Judge a `Position` command against the limits and the current setpoint; counts refusals and clamps.
    /// `timing`: a too-big step would be the command's timing, not its content (see [`Target::late_step`]).
    pub fn admit(&mut self, cmd: &JointCommand, timing: bool) -> Result<Target, Refusal> {
        let r = self.judge(cmd, timing);
        match &r {
            Err(_) => self.rejected += 1,
            Ok(t) if t.clamped => self.clamped += 1,
            Ok(t) if t.late_step && !timing => self.timing_steps += 1,
            Ok(_) => {}
        }
        if let Ok(t) = &r
            && cmd.mode == CommandMode::Position as u32
        {
            // `checked_add`: a controller's seq is its own word (u64::MAX overflowed here, found by mars-fuzz).
            let next = |p: &StreamPoint| p.seq.checked_add(1) == Some(cmd.seq);
            let v = self.stream.filter(|p| p.session == cmd.session && next(p)).map(|p| {
                let mut v = [0.0; MAX_JOINTS];
                for ((v, q), q0) in v.iter_mut().zip(&t.position).zip(&p.q).take(self.n) {
                    *v = (q - q0) / self.dt;
                }
                v
            });
            self.stream = Some(StreamPoint { session: cmd.session, seq: cmd.seq, q: t.position, v });
        }
        r
    }

    fn judge(&self, cmd: &JointCommand, timing: bool) -> Result<Target, Refusal> {
        let n = self.n;
        if cmd.num_joints as usize != n {
            return Err(Refusal::JointCount { expected: n, found: cmd.num_joints });
        }
        if CommandMode::from_u32(cmd.mode).is_none() {
            return Err(Refusal::UnknownMode(cmd.mode));
        }
        // Non-finite values are refused under every policy: there is no sensible value to clamp NaN to.
        for (field, v) in
            [("position", &cmd.position), ("velocity", &cmd.velocity), ("acceleration", &cmd.acceleration)]
        {
            if let Some(joint) = v[..n].iter().position(|x| !x.is_finite()) {
                return Err(Refusal::NotFinite { joint, field });
            }
        }
        if !cmd.gripper.is_finite() {
            return Err(Refusal::GripperNotFinite);
        }
        if !(cmd.gripper_speed.is_finite() && cmd.gripper_speed >= 0.0) {
            return Err(Refusal::GripperSpeed(cmd.gripper_speed));
        }
        let reject = self.policy == LimitPolicy::Reject;
        let mut t = Target {
            position: [0.0; MAX_JOINTS],
            gripper: cmd.gripper,
            gripper_speed: cmd.gripper_speed,
            clamped: false,
            clamp_reason: None,
            late_step: false,
        };
        // Under the clamp policy, the same reason a refusal would give is kept (the first one) and the value clamped.
        fn clamp(t: &mut Target, reason: Refusal) {
            t.clamped = true;
            t.clamp_reason.get_or_insert(reason);
        }
        for i in 0..n {
            let (lo, hi) = (self.q_min[i], self.q_max[i]);
            let q = cmd.position[i];
            if q < lo || q > hi {
                let reason = Refusal::Position { joint: i, value: q, min: lo, max: hi };
                if reject {
                    return Err(reason);
                }
                clamp(&mut t, reason);
            }
            t.position[i] = q.clamp(lo, hi);
            // The controller's stated intent must itself be possible.
            let (v_lo, v_hi) = self.bound[i].hard(t.position[i]);
            let intent_v = cmd.velocity[i];
            let v_limit = if intent_v >= 0.0 { v_hi } else { v_lo };
            if intent_v > v_hi + EPS * v_hi.abs() || intent_v < v_lo - EPS * v_lo.abs() {
                let reason = Refusal::Rate { joint: i, quantity: "velocity", value: intent_v, limit: v_limit };
                if reject {
                    return Err(reason);
                }
                clamp(&mut t, reason);
            }
            if cmd.acceleration[i].abs() > self.a_max[i] * (1.0 + EPS) {
                let (value, limit) = (cmd.acceleration[i], self.a_max[i]);
                let reason = Refusal::Rate { joint: i, quantity: "acceleration", value, limit };
                if reject {
                    return Err(reason);
                }
                clamp(&mut t, reason);
            }
            // The step from the applied setpoint, differentiated like libfranka does, must be within limits, or
            // else one of the steps the controller meant (see the module doc) must.
            if let Some(excess) = self.step_excess(i, t.position[i]) {
                let content = if timing {
                    None
                } else {
                    self.intended_step_excess(i, cmd, t.position[i]).unwrap_or(Some(excess))
                };
                match content {
                    // Timing, not content: smoothed by `step`, counted by the caller.
                    None => t.late_step = true,
                    Some((quantity, value, limit)) => {
                        let reason = Refusal::Rate { joint: i, quantity, value, limit };
                        if reject {
                            return Err(reason);
                        }
                        // Clamped by `step`, which never exceeds the limits on the way to the target.
                        clamp(&mut t, reason);
                    }
                }
            }
        }
        if cmd.gripper < self.g_min || cmd.gripper > self.g_max {
            let reason = Refusal::Gripper { value: cmd.gripper, min: self.g_min, max: self.g_max };
            if reject {
                return Err(reason);
            }
            clamp(&mut t, reason);
            t.gripper = cmd.gripper.clamp(self.g_min, self.g_max);
        }
        Ok(t)
    }

    /// The first rate limit a one-tick step of joint `i` to `target` would exceed: (quantity, value, limit).
    fn step_excess(&self, i: usize, target: f64) -> Option<Excess> {
        self.step_excess_from(i, (self.q[i], self.v[i], self.a[i]), target)
    }

    /// [`Self::step_excess`] from the setpoint `(q, v, a)`.
    fn step_excess_from(&self, i: usize, (q, v0, a0): (f64, f64, f64), target: f64) -> Option<Excess> {
        let v = (target - q) / self.dt;
        let a = (v - v0) / self.dt;
        let j = (a - a0) / self.dt;
        let (v_lo, v_hi) = self.bound[i].hard(target);
        if v > v_hi + EPS * v_hi.abs() || v < v_lo - EPS * v_lo.abs() {
            return Some(("implied velocity", v, if v >= 0.0 { v_hi } else { v_lo }));
        }
        if a.abs() > self.a_max[i] * (1.0 + EPS) {
            return Some(("implied acceleration", a, self.a_max[i]));
        }
        if j.abs() > self.j_max[i] * (1.0 + EPS) {
            return Some(("implied jerk", j, self.j_max[i]));
        }
        None
    }

    /// The excess of a command whose step from the setpoint is too big, judged by the steps its controller
    /// meant: none if its step from the controller's previous command or from the setpoint published in the
    /// frame it answers is within the limits, else the first found; `None` (outer) when neither is known.
    #[allow(clippy::option_option)] // outer: whether it can be judged; inner: the verdict
    fn intended_step_excess(&self, i: usize, cmd: &JointCommand, target: f64) -> Option<Option<Excess>> {
        let from_stream = self.stream_excess(i, cmd, target);
        let from_frame = self.published[(cmd.state_seq % PUBLISHED_KEPT as u64) as usize]
            .filter(|p| p.frame == cmd.state_seq)
            .map(|p| self.step_excess_from(i, (p.q[i], p.v[i], p.a[i]), target));
        match (from_stream, from_frame) {
            (Some(None), _) | (_, Some(None)) => Some(None),
            (None, None) => None,
            (a, b) => Some(a.flatten().or(b.flatten())),
        }
    }

    /// The first rate limit the controller's own step to `target` exceeds, from its previous command (velocity
    /// and acceleration over the commands' seq interval: a HAL that missed a tick gets two ticks of the stream at
    /// once); `None` (outer) when the previous command is not of this stream.
    #[allow(clippy::option_option)] // outer: whether the stream can judge; inner: its verdict
    fn stream_excess(&self, i: usize, cmd: &JointCommand, target: f64) -> Option<Option<Excess>> {
        let p = self.stream.filter(|p| p.session == cmd.session && p.seq < cmd.seq)?;
        let v = (target - p.q[i]) / ((cmd.seq - p.seq) as f64 * self.dt);
        let (v_lo, v_hi) = self.bound[i].hard(target);
        if v > v_hi + EPS * v_hi.abs() || v < v_lo - EPS * v_lo.abs() {
            return Some(Some(("implied velocity", v, if v >= 0.0 { v_hi } else { v_lo })));
        }
        if let Some(pv) = p.v {
            // The two velocities are means over their intervals, whose middles lie (gap + 1)/2 ticks apart.
            let a = (v - pv[i]) / (0.5 * ((cmd.seq - p.seq) as f64 + 1.0) * self.dt);
            if a.abs() > self.a_max[i] * (1.0 + EPS) {
                return Some(Some(("implied acceleration", a, self.a_max[i])));
            }
        }
        Some(None)
    }

    fn reachable_in_one_tick(&self, t: &[f64; MAX_JOINTS]) -> bool {
        (0..self.n).all(|i| {
            let v = (t[i] - self.q[i]) / self.dt;
            let a = (v - self.v[i]) / self.dt;
            let (am, jm) = (self.a_max[i], self.j_max[i]);
            let (e_lo, e_hi) = self.plan[i].envelope(t[i], 0.5 * am);
            (self.q_min[i]..=self.q_max[i]).contains(&t[i])
                && self.step_excess(i, t[i]).is_none()
                // Within the envelope the cascade plans with, and within its velocity-dependent acceleration
                // bound (libfranka's), so that if a later target is not reachable in one tick, the cascade takes
                // over from a state it can handle…
                && v <= e_hi + EPS
                && v >= e_lo - EPS
                && a <= jm / am * (e_hi - v) + EPS
                && a >= jm / am * (e_lo - v) - EPS
                // … and one from which the cascade can still stop before the position limit it is heading for
                // (braking at half the acceleration limit after the jerk-limited ramp), should the stream end.
                && {
                    let room = if v >= 0.0 { self.q_max[i] - t[i] } else { t[i] - self.q_min[i] };
                    v * v / am + v.abs() * am / jm <= room
                }
        })
    }

    /// Whether joint `i`'s step to `t` is within the limits from each alternative heeded for it.
    fn within_heeded(&self, i: usize, t: f64, alts: &[Option<Alternative>], heeded: u8) -> bool {
        let a = ((t - self.q[i]) / self.dt - self.v[i]) / self.dt;
        alts.iter().enumerate().filter(|(k, _)| heeded & (1 << k) != 0).all(|(_, alt)| {
            alt.is_none_or(|alt| {
                let (lo, hi) = self.alternative_bound(i, &alt, 1.0);
                let slack = EPS * lo.abs().max(hi.abs()).max(1.0);
                a >= lo - slack && a <= hi + slack
            })
        })
    }

    /// Advance the applied setpoint one tick toward `target`, or to rest (zero velocity where it is) when
    /// `target` is `None`. Returns the new setpoint positions.
    pub fn step(&mut self, target: Option<&[f64; MAX_JOINTS]>) -> &[f64] {
        let dt = self.dt;
        // The other histories, and for each joint those a step within the planned limits from ours and them exists
        // for. Not for an arm held at rest: it stays where it is.
        let holding = target.is_none() && self.at_rest();
        let alts = std::mem::replace(&mut self.alternatives, [None; MAX_ALTERNATIVES]);
        let alts = if holding { [None; MAX_ALTERNATIVES] } else { alts };
        let heeded: [u8; MAX_JOINTS] =
            std::array::from_fn(|i| if i < self.n { self.heed(i, &mut self.own_bound(i), &alts, u8::MAX) } else { 0 });
        // A target the setpoint can reach this very tick within every limit is applied exactly, as libfranka
        // applies a compliant command: a controller that streams limit-respecting commands gets them unchanged
        // (and the next command's implied rates are its own finite differences, so it is never clamped).
        if let Some(t) = target
            && self.reachable_in_one_tick(t)
            && (0..self.n).all(|i| self.within_heeded(i, t[i], &alts, heeded[i]))
        {
            #[allow(clippy::needless_range_loop)] // q, v, a and t indexed by joint
            for i in 0..self.n {
                let v_new = (t[i] - self.q[i]) / dt;
                self.a[i] = (v_new - self.v[i]) / dt;
                self.v[i] = v_new;
                self.q[i] = t[i];
            }
            return &self.q[..self.n];
        }
        for i in 0..self.n {
            let (q, v, a) = (self.q[i], self.v[i], self.a[i]);
            // The filter's own trajectories (braking, bringing a clamped command inside) plan a margin inside the
            // limits: the robot checks the stream by finite differences of what it received (franka-sim of
            // float32-rounded states: a brake at exactly 10 rad/s² arrived as 10.008 and tripped the FR3's
            // velocity-discontinuity reflex). Compliant commands still pass exactly (above).
            let (am, jm) = (self.a_max[i] * OWN_PLAN_FACTOR, self.j_max[i] * OWN_PLAN_FACTOR);
            // This tick's velocity bounds: the envelope where the joint can get to this tick (it only narrows
            // toward a limit, so a velocity within it is within the envelope wherever the step ends).
            let (lo0, hi0) = self.plan[i].envelope(q, 0.5 * am);
            let v_hi = self.plan[i].envelope(q + hi0.max(0.0) * dt, 0.5 * am).1;
            let v_lo = self.plan[i].envelope(q + lo0.min(0.0) * dt, 0.5 * am).0;
            // Cascade toward the target, critically damped near it (ω = 2·kp) and, far from it, braking
            // along v = √(A·e), i.e. at half the acceleration limit, leaving room for the jerk-limited ramp.
            let v_des = match target {
                Some(t) => {
                    let e = t[i] - q;
                    e.signum() * (self.kp * e.abs()).min((am * e.abs()).sqrt())
                }
                None => 0.0,
            }
            .max(v_lo)
            .min(v_hi);
            // a = √(J·|Δv|) lets the acceleration ramp back to zero, at half the jerk limit, as v arrives.
            let ev = v_des - v;
            let a_des = ev.signum() * (self.kv * ev.abs()).min((jm * ev.abs()).sqrt()).min(am);
            // Feasible accelerations this tick: jerk bound, acceleration bound, and libfranka's
            // velocity-dependent bound a ≤ (J/A)(V − v), which keeps |v| ≤ V without a jerk spike.
            let hi = (a + jm * dt).min(am).min(jm / am * (v_hi - v));
            let lo = (a - jm * dt).max(-am).max(jm / am * (v_lo - v));
            let mut a_new = if lo <= hi {
                a_des.clamp(lo, hi)
            } else {
                self.infeasible_steps += 1;
                0.5 * (lo + hi)
            };
            // Braking ends in an exact stop (not an endless exponential creep), once the last step to zero
            // velocity, and the step back to zero acceleration after it, fit within the jerk limit.
            if target.is_none() && v.abs() + a.abs() * dt <= 0.5 * jm * dt * dt && v.abs() <= 0.5 * am * dt {
                a_new = -v / dt;
            }
            // Within the limits from the other histories too, where that leaves a step within ours.
            let mut bound = (lo, hi);
            if self.heed(i, &mut bound, &alts, heeded[i]) != 0 {
                a_new = a_new.clamp(bound.0, bound.1);
            }
            let mut v_new = v + a_new * dt;
            let mut q_new = q + v_new * dt;
            // Last line: a position limit is never crossed, even at the cost of an abrupt stop.
            if q_new > self.q_max[i] || q_new < self.q_min[i] {
                q_new = q_new.clamp(self.q_min[i], self.q_max[i]);
                v_new = 0.0;
                self.position_guard_hits += 1;
                self.a[i] = 0.0;
            } else {
                self.a[i] = a_new;
            }
            self.q[i] = q_new;
            self.v[i] = v_new;
        }
        &self.q[..self.n]
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::Path;

    fn fr3() -> Profile {
        Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")).unwrap()
    }

    fn cmd(q: &[f64]) -> JointCommand {
        JointCommand::position(1, 1, 0, q)
    }

    /// Tiny deterministic generator so the property tests need no extra dependency.
    struct Lcg(u64);
    impl Lcg {
        fn unit(&mut self) -> f64 {
            self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (self.0 >> 11) as f64 / (1u64 << 53) as f64
        }
    }

    #[test]
    fn nan_and_infinite_values_are_refused_under_every_policy() {
        for policy in [LimitPolicy::Clamp, LimitPolicy::Reject] {
            let mut p = fr3();
            p.limit_policy = policy;
            let mut f = SafetyFilter::new(&p, &p.home);
            let mut c = cmd(&p.home);
            c.position[3] = f64::NAN;
            assert_eq!(f.admit(&c, false), Err(Refusal::NotFinite { joint: 3, field: "position" }));
            let mut c = cmd(&p.home);
            c.velocity[0] = f64::INFINITY;
            assert_eq!(f.admit(&c, false), Err(Refusal::NotFinite { joint: 0, field: "velocity" }));
            let mut c = cmd(&p.home);
            c.gripper = f64::NAN;
            assert_eq!(f.admit(&c, false), Err(Refusal::GripperNotFinite));
            assert_eq!(f.rejected, 3);
        }
    }

    /// Found by mars-fuzz: a command whose seq is u64::MAX, then another of its session, overflowed the stream's
    /// "next command" test (a panic in a debug build of the HAL).
    #[test]
    fn the_largest_seq_is_judged_without_overflow() {
        let p = fr3();
        let mut f = SafetyFilter::new(&p, &p.home);
        for seq in [u64::MAX - 1, u64::MAX, u64::MAX, 0, 1] {
            assert!(f.admit(&JointCommand::position(1, seq, 0, &p.home), false).is_ok(), "seq {seq}");
        }
    }

    #[test]
    fn wrong_joint_count_and_unknown_mode_are_refused() {
        let p = fr3();
        let mut f = SafetyFilter::new(&p, &p.home);
        assert_eq!(f.admit(&cmd(&p.home[..6]), false), Err(Refusal::JointCount { expected: 7, found: 6 }));
        let mut c = cmd(&p.home);
        c.mode = 9;
        assert_eq!(f.admit(&c, false), Err(Refusal::UnknownMode(9)));
    }

    #[test]
    fn out_of_limit_position_is_rejected_or_clamped_per_policy() {
        let mut p = fr3();
        p.limit_policy = LimitPolicy::Reject;
        let mut f = SafetyFilter::new(&p, &p.home);
        let mut q = p.home.clone();
        q[3] = 0.0; // joint 4 of the FR3 must stay below −0.1169
        assert!(matches!(f.admit(&cmd(&q), false), Err(Refusal::Position { joint: 3, .. })));
        assert_eq!((f.rejected, f.clamped), (1, 0));

        p.limit_policy = LimitPolicy::Clamp;
        let mut f = SafetyFilter::new(&p, &p.home);
        let t = f.admit(&cmd(&q), false).unwrap();
        assert!(t.clamped);
        // Into the range where the FR3's joint 4 may rest: a little below its q_max of −0.1169 rad, where the
        // braking curve's bound, less the profile's headroom and the filter's lag margin, reaches zero.
        assert_eq!(t.position[3], f.position_range(3).1);
        assert!(t.position[3] < -0.1169 && t.position[3] > -0.19, "{}", t.position[3]);
        assert_eq!((f.rejected, f.clamped), (0, 1));
    }

    #[test]
    fn a_jump_is_refused_under_reject_and_a_smooth_step_is_accepted() {
        let mut p = fr3();
        p.limit_policy = LimitPolicy::Reject;
        let mut f = SafetyFilter::new(&p, &p.home);
        let mut q = p.home.clone();
        q[0] += 0.1; // 100 rad/s implied at 1 kHz
        assert!(matches!(f.admit(&cmd(&q), false), Err(Refusal::Rate { joint: 0, quantity: "implied velocity", .. })));
        q[0] = p.home[0] + 1e-3 * 1e-3 * 1e-3 * 1000.0; // 1e-6 rad: jerk 1000 rad/s³ from rest
        assert!(f.admit(&cmd(&q), false).is_ok());
        let mut c = cmd(&p.home);
        c.velocity[1] = 3.0;
        assert!(matches!(f.admit(&c, false), Err(Refusal::Rate { joint: 1, quantity: "velocity", .. })));
        let mut c = cmd(&p.home);
        c.gripper = 0.5;
        assert!(matches!(f.admit(&c, false), Err(Refusal::Gripper { .. })));
        for speed in [-0.1, f64::NAN] {
            let mut c = cmd(&p.home);
            c.gripper = 0.04;
            c.gripper_speed = speed;
            assert!(matches!(f.admit(&c, false), Err(Refusal::GripperSpeed(_))), "speed {speed}");
        }
    }

    /// A jump that is too big for one tick is the controller's fault when it is on time (clamped, or refused
    /// under `reject`), and timing's when it answered an old frame: then it is smoothed and not counted.
    #[test]
    fn a_late_jump_is_smoothed_but_not_counted_as_out_of_limits() {
        for policy in [LimitPolicy::Clamp, LimitPolicy::Reject] {
            let mut p = fr3();
            p.limit_policy = policy;
            let mut f = SafetyFilter::new(&p, &p.home);
            let mut q = p.home.clone();
            q[0] += 0.01;
            let t = f.admit(&cmd(&q), true).unwrap();
            assert!(t.late_step && !t.clamped, "{policy:?}");
            assert_eq!((f.clamped, f.rejected), (0, 0), "{policy:?}");
            assert_ne!(f.step(Some(&t.position))[0], q[0], "smoothed, not applied");
            // The same jump on time is out of limits.
            let on_time = f.admit(&cmd(&q), false);
            assert_eq!(f.clamped + f.rejected, 1, "{policy:?}: {on_time:?}");
        }
    }

    /// After the robot applied a setpoint of its own (a resync), or a tick the HAL missed, the setpoint is off the
    /// controller's stream: a command continuing the stream smoothly is timing's (smoothed, not counted) however
    /// far the setpoint lags, while a command that jumps from the controller's previous one is still out of limits.
    #[test]
    fn a_command_is_judged_by_the_step_its_controller_meant() {
        for policy in [LimitPolicy::Clamp, LimitPolicy::Reject] {
            let mut p = fr3();
            p.limit_policy = policy;
            let mut f = SafetyFilter::new(&p, &p.home);
            let at = |k: u64| {
                let mut q = p.home.clone();
                q[0] += 1e-6 * k as f64;
                JointCommand::position(1, k, k, &q)
            };
            for k in 1..=3 {
                let t = f.admit(&at(k), false).unwrap();
                assert!(!t.late_step && !t.clamped);
                f.step(Some(&t.position));
            }
            // The robot extrapolated elsewhere: 5 mrad off the stream (5 rad/s for a one-tick step).
            let mut q = f.position().to_vec();
            q[0] -= 5e-3;
            f.resync(&q, &[0.0; 7], &[0.0; 7]);
            for k in 4..=6 {
                let t = f.admit(&at(k), false).unwrap();
                assert!(t.late_step && !t.clamped, "{policy:?} seq {k}");
                f.step(Some(&t.position));
            }
            assert_eq!((f.clamped, f.rejected, f.timing_steps), (0, 0, 3), "{policy:?}");
            // A jump of the stream itself while the setpoint catches up: 20 mrad in one tick.
            let mut jump = at(7);
            jump.position[0] += 0.02;
            let r = f.admit(&jump, false);
            assert_eq!(f.clamped + f.rejected, 1, "{policy:?}: {r:?}");
            // A controller that re-synchronised to the setpoint frame 9 published (10 mrad off its own stream),
            // answering it after the robot moved the setpoint again: its step from that frame is what it meant.
            let mut q = p.home.clone();
            q[0] -= 0.01;
            f.resync(&q, &[0.0; 7], &[0.0; 7]);
            f.note_published(9);
            q[0] += 0.005;
            f.resync(&q, &[0.0; 7], &[0.0; 7]);
            let mut resynced = JointCommand::position(1, 8, 9, &p.home);
            resynced.position[0] = p.home[0] - 0.01 + 1e-6;
            let t = f.admit(&resynced, false).unwrap();
            assert!(t.late_step && !t.clamped, "{policy:?}");
            assert_eq!(f.clamped + f.rejected, 1, "{policy:?}");
            // A HAL that missed a tick: the stream at 2 rad/s, seq 12 right after seq 10 (4 mrad at once, a
            // 2 rad/s → 4 rad/s step for the setpoint) is timing; a jump of the same size on consecutive seqs is not.
            let mut f = SafetyFilter::new(&p, &p.home);
            let moving = |k: u64| {
                let mut q = p.home.clone();
                q[0] += 2e-3 * k as f64 - 2e-3 * 10.0;
                JointCommand::position(1, k, k, &q)
            };
            let mut q = p.home.clone();
            q[0] -= 2e-3;
            f.resync(&q, &[0.0; 7], &[0.0; 7]);
            f.v[0] = 2.0;
            let t = f.admit(&moving(10), false).unwrap();
            assert!(!t.late_step && !t.clamped, "{policy:?}");
            f.step(Some(&t.position));
            let t = f.admit(&moving(12), false).unwrap();
            assert!(t.late_step && !t.clamped, "{policy:?}");
            assert_eq!((f.clamped, f.rejected), (0, 0), "{policy:?}");
            let mut jump = moving(13);
            jump.position[0] += 2e-3;
            let r = f.admit(&jump, false);
            assert_eq!(f.clamped + f.rejected, 1, "{policy:?}: {r:?}");
        }
    }

    /// The FR3's velocity bound depends on position: a command whose stated velocity is fine in the middle of
    /// joint 1's range is out of limits near its end.
    #[test]
    fn the_fr3_velocity_intent_is_judged_at_the_target_position() {
        let mut p = fr3();
        p.limit_policy = LimitPolicy::Reject;
        let mut f = SafetyFilter::new(&p, &p.home);
        let mut c = cmd(&p.home);
        c.velocity[0] = 2.0;
        assert!(f.admit(&c, false).is_ok());
        c.position[0] = 2.7;
        match f.admit(&c, false) {
            Err(Refusal::Rate { joint: 0, quantity: "velocity", value, limit }) => {
                assert_eq!(value, 2.0);
                assert!(limit < 0.5, "{limit}");
            }
            other => panic!("{other:?}"),
        }
    }

    /// Random, often wild targets (inside the position limits after admission): the applied setpoint never
    /// leaves any limit and the position guard never has to intervene.
    #[test]
    fn applied_setpoint_respects_every_limit_for_random_targets() {
        let r1 = Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/r1_lite.toml")).unwrap();
        for mut p in [fr3(), r1] {
            p.limit_policy = LimitPolicy::Clamp;
            random_targets_stay_within_limits(&p, 20_000, 700, 7);
            // Targets switched often, mid-motion: the hardest case for a falling velocity bound.
            random_targets_stay_within_limits(&p, 20_000, 97, 11);
        }
    }

    /// Targets drawn over the whole range and up to 20 % beyond it (so clamping is exercised), switched every
    /// `hold` ticks, with braking phases; half of them at a position limit itself (where the FR3's velocity bound
    /// narrows). Every tick's finite differences are checked against the robot's own bounds, the velocity one at
    /// the position reached (independently of the filter's planning envelope).
    fn random_targets_stay_within_limits(p: &Profile, ticks: usize, hold: usize, seed: u64) {
        let mut f = SafetyFilter::new(p, &p.home);
        let bounds = p.velocity_bounds();
        let mut rng = Lcg(seed);
        let dt = p.period_s();
        let mut target = [0.0; MAX_JOINTS];
        let (mut v_prev, mut a_prev) = ([0.0; MAX_JOINTS], [0.0; MAX_JOINTS]);
        let mut q_prev = arr(&p.home);
        for tick in 0..ticks {
            if tick % hold == 0 {
                let mut q = vec![0.0; p.joints];
                #[allow(clippy::needless_range_loop)]
                for i in 0..p.joints {
                    let span = p.q_max[i] - p.q_min[i];
                    q[i] = match (rng.unit() * 4.0) as u32 {
                        0 => p.q_min[i] - 0.2 * span * rng.unit(),
                        1 => p.q_max[i] + 0.2 * span * rng.unit(),
                        _ => p.q_min[i] - 0.2 * span + 1.4 * span * rng.unit(),
                    };
                }
                target = f.admit(&cmd(&q), false).unwrap().position;
            }
            let braking = tick % 2900 > 2500;
            let q = arr(f.step(if braking { None } else { Some(&target) }));
            for i in 0..p.joints {
                let v = (q[i] - q_prev[i]) / dt;
                let a = (v - v_prev[i]) / dt;
                let j = (a - a_prev[i]) / dt;
                let (v_lo, v_hi) = bounds[i].hard(q[i]);
                assert!(q[i] >= p.q_min[i] && q[i] <= p.q_max[i], "tick {tick} joint {i}: q {}", q[i]);
                assert!(
                    v <= v_hi + 1e-9 && v >= v_lo - 1e-9,
                    "tick {tick} joint {i}: v {v} at q {} not in [{v_lo}, {v_hi}]",
                    q[i]
                );
                assert!(a.abs() <= p.ddq_max[i] * (1.0 + 1e-6), "tick {tick} joint {i}: a {a}");
                assert!(j.abs() <= p.jerk_max[i] * (1.0 + 1e-6), "tick {tick} joint {i}: j {j}");
                v_prev[i] = v;
                a_prev[i] = a;
            }
            q_prev = q;
        }
        assert_eq!((f.position_guard_hits, f.infeasible_steps), (0, 0));
    }

    /// The rate of change (v, a, j) of a step from `(q, v, a)` to `c`, as the robot differences it.
    fn rates_of(c: f64, (q, v, a): (f64, f64, f64), dt: f64) -> (f64, f64, f64) {
        let v1 = (c - q) / dt;
        let a1 = (v1 - v) / dt;
        (v1, a1, (a1 - a) / dt)
    }

    /// The arm at home but joint `i` at `(q, v, a)` (our history), the robot's guess `e` behind our late command
    /// there (its history, had it thrown that command away), and a target `jerk` rad/s³ from ours.
    #[allow(clippy::type_complexity)]
    fn late_by(
        p: &Profile,
        i: usize,
        (q_i, v_i, a_i): (f64, f64, f64),
        e: f64,
        jerk: f64,
    ) -> ([Vec<f64>; 3], [Vec<f64>; 3], [f64; MAX_JOINTS]) {
        let dt = p.period_s();
        let (mut q, mut v, mut a) = (p.home.clone(), vec![0.0; p.joints], vec![0.0; p.joints]);
        (q[i], v[i], a[i]) = (q_i, v_i, a_i);
        let (mut qb, mut vb, mut ab) = (q.clone(), v.clone(), a.clone());
        (qb[i], vb[i], ab[i]) = (q_i - e, v_i - e / dt, a_i - e / (dt * dt));
        let mut target = arr(&q);
        target[i] = q_i + (v_i + (a_i + jerk * dt) * dt) * dt;
        ([q, v, a], [qb, vb, ab], target)
    }

    /// After a state that showed our last command late, franka-sim may yet throw it away and judge the next command
    /// against its guess: the step is then kept within the limits from both histories (the case of 2026-11-27: a
    /// command at 4000 rad/s³ from ours, where the guess was 1.3 µrad behind our late command, reads 7900 from it).
    #[test]
    fn a_step_judged_from_two_histories_is_within_the_limits_from_both() {
        let p = fr3();
        let dt = p.period_s();
        // The target: 4000 rad/s³ from ours.
        let ([q, v, a], [qb, vb, ab], target) = late_by(&p, 0, (-0.1358503, 0.9393, -0.9), 1.3e-6, 4000.0);
        let from_b = (qb[0], vb[0], ab[0]);
        assert!(rates_of(target[0], from_b, dt).2 > 7800.0, "the premise: {:?}", rates_of(target[0], from_b, dt));

        let mut f = SafetyFilter::new(&p, &p.home);
        f.resync(&q, &v, &a);
        assert_eq!(f.step(Some(&target))[0], target[0], "without the other history: applied exactly");

        let mut f = SafetyFilter::new(&p, &p.home);
        f.resync(&q, &v, &a);
        f.also_judged_from(&qb, &vb, &ab, 1);
        let c = f.step(Some(&target))[0];
        for (name, from) in [("ours", (q[0], v[0], a[0])), ("the robot's guess", from_b)] {
            let (_, acc, jerk) = rates_of(c, from, dt);
            assert!(jerk.abs() <= p.jerk_max[0] && acc.abs() <= p.ddq_max[0], "from {name}: a {acc}, j {jerk}");
        }
        assert_eq!(f.infeasible_steps, 0);
        // For that step only: the next compliant target is applied exactly again.
        let (qn, vn, an) = (f.position()[0], f.velocity()[0], f.acceleration()[0]);
        let mut next = arr(f.position());
        next[0] = qn + (vn + an * dt) * dt;
        assert_eq!(f.step(Some(&next))[0], next[0]);
    }

    /// Where the two histories are too far apart for any step to be within the limits from both (the late command
    /// 4.5 µrad from the guess it replaced: 13500 rad/s³ between them), the step is ours alone: a step between them
    /// broke the limits from both and raised franka-sim's reflexes.
    #[test]
    fn where_no_step_is_within_the_limits_from_both_histories_ours_decide() {
        let p = fr3();
        let ([q, v, a], [qb, vb, ab], target) = late_by(&p, 2, (-0.3174507, -0.13396, 0.001), -4.5e-6, -4400.0);
        let mut f = SafetyFilter::new(&p, &p.home);
        f.resync(&q, &v, &a);
        f.also_judged_from(&qb, &vb, &ab, 1);
        assert_eq!(f.step(Some(&target))[2], target[2], "applied exactly: within the limits from ours");
        assert_eq!(f.infeasible_steps, 0);
    }

    /// An arm held at rest stays where it is, whatever other history the robot may judge the hold against.
    #[test]
    fn an_arm_held_at_rest_is_not_moved_for_another_history() {
        let p = fr3();
        let mut f = SafetyFilter::new(&p, &p.home);
        let other: Vec<f64> = p.home.iter().map(|q| q + 5e-6).collect();
        let zero = vec![0.0; p.joints];
        for _ in 0..10 {
            f.also_judged_from(&other, &zero, &zero, 1);
            assert_eq!(f.step(None), &p.home[..]);
        }
    }

    /// A stream that respects every limit (a slow sine) is applied exactly, tick for tick, and never counted as
    /// clamped; a skipped command (a late packet) is smoothed instead of applied.
    #[test]
    fn a_compliant_stream_is_applied_exactly() {
        let p = fr3();
        let mut f = SafetyFilter::new(&p, &p.home);
        let mut q = p.home.clone();
        for k in 0..2000 {
            q[0] = p.home[0] + 0.2 * (1.0 - (k as f64 * 1e-3 * std::f64::consts::PI).cos());
            let t = f.admit(&cmd(&q), false).unwrap().position;
            assert_eq!(f.step(Some(&t))[0], q[0], "tick {k}");
        }
        assert_eq!(f.clamped, 0);
        q[0] += 2.0 * (q[0] - f.position()[0]) + 1e-3; // a skipped tick: twice the step and more
        let t = f.admit(&cmd(&q), false).unwrap().position;
        assert_ne!(f.step(Some(&t))[0], q[0]);
        assert_eq!(f.clamped, 1);
    }

    #[test]
    fn the_setpoint_reaches_a_target_and_braking_brings_it_to_rest() {
        let p = fr3();
        let mut f = SafetyFilter::new(&p, &p.home);
        let mut q = p.home.clone();
        q[0] += 0.5;
        let t = f.admit(&cmd(&q), false).unwrap().position;
        for _ in 0..2000 {
            f.step(Some(&t));
        }
        assert!((f.position()[0] - q[0]).abs() < 1e-4, "{}", f.position()[0]);
        assert!(f.at_rest());
        // Start moving, then brake: at rest within a second at FR3's limits.
        q[0] -= 1.0;
        let t = f.admit(&cmd(&q), false).unwrap().position;
        for _ in 0..300 {
            f.step(Some(&t));
        }
        assert!(!f.at_rest());
        for _ in 0..1000 {
            f.step(None);
        }
        assert!(f.at_rest(), "{:?}", f.velocity());
        assert!(f.velocity().iter().all(|v| *v == 0.0), "braking ends in an exact stop: {:?}", f.velocity());
    }

    #[test]
    fn last_resorts_are_counted() {
        let p = fr3();
        // A setpoint far faster than the limit (no command can cause it; a corrupted state could) leaves no
        // acceleration within every bound: the filter takes the middle of the empty interval and counts it.
        let mut f = SafetyFilter::new(&p, &p.home);
        f.v[0] = 3.0 * p.dq_max[0];
        f.step(None);
        assert!(f.infeasible_steps >= 1, "{}", f.infeasible_steps);
        assert_eq!(f.position_guard_hits, 0);
        // A joint at full speed a micro-radian below its limit cannot stop in one tick: the guard stops it there.
        let mut g = SafetyFilter::new(&p, &p.home);
        g.q[0] = g.q_max[0] - 1e-6;
        g.v[0] = p.dq_max[0];
        g.step(None);
        assert_eq!(g.position_guard_hits, 1);
        assert_eq!(g.position()[0], g.q_max[0]);
    }
}
