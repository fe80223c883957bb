//! Jerk-limited smoothing of the servo's reference with ruckig, one online step per servo tick.
//!
//! Why `rsruckig` with a compile-time DoF: its `update` works on fixed arrays and, once constructed, makes 0 heap
//! allocations per update (`tests/smoothing.rs` asserts it with a counting allocator; `cargo bench -p
//! mars-runtime --bench smoothing` prints it, counting Rust allocations and every `malloc` of the process over
//! 20 000 ticks with a new target each tick), at ~8 µs median per 7-DoF re-plan. The official `ruckig` crate (a
//! cxx wrapper of the C++ core) computes the same trajectories to within 1e-9 rad (the tests' bound) but its
//! wrapper copies every field into fresh `std::vector`s and back into fresh `Vec`s: the same bench prints 15 Rust
//! allocations and 26 `malloc` calls in all per update. It stays a dev-dependency, as the test oracle.
//!
//! Storage is `Ruckig<MAX_JOINTS>` with the joints beyond `n` disabled, so one type serves 6- and 7-joint robots.
//!
//! Position-dependent velocity bounds (the FR3's, `mars_profile::velocity_limits`): ruckig takes constant limits, so
//! before every step the smoother hands it the bounds at the current position, from their braking envelope
//! (which falls no faster than half the acceleration limit, so ruckig, braking at up to 90 % of it, keeps up)
//! tightened by A²/J for ruckig's jerk-limited lag, scaled like every other limit. All velocity limits are the
//! profile's planning bounds: the robot's, less its `velocity_headroom` (the FR3 judges the *measured* velocity).
//!
//! Allocation caveat: rsruckig formats a `String` when *it* reports an error. [`Smoother`] validates, clamps and
//! range-checks every input first so ruckig's validation never fails; only a numerical failure inside ruckig would
//! allocate, on that error path alone. With time synchronisation such failures did occur (see `Smoother::new`);
//! without it none is seen in the randomized tests here and in `tests/servo_hal_timing.rs`.

use mars_ipc::MAX_JOINTS;
use mars_profile::Profile;
use mars_profile::velocity_limits::JointVelocityBound;
use rsruckig::prelude::*;

/// Fraction of the robot's limits handed to ruckig. Ruckig meets its limits only up to floating-point rounding and
/// the commanded stream is checked by finite differences downstream, so planning at 90 % keeps every rounding
/// error far inside the robot's hard limits.
pub const DEFAULT_SAFETY_FACTOR: f64 = 0.9;

/// Targets beyond this (rad or m) are refused: no joint gets there, and ruckig fails on them (its trajectories are
/// capped in duration; from ~1e4 rad on it errors, and its error path allocates).
pub const MAX_ABS_POSITION: f64 = 1e3;

/// A state counts as at rest below these (rad/s, rad/s²): ruckig's stop ends at zero up to rounding.
const REST_VELOCITY: f64 = 1e-9;
const REST_ACCELERATION: f64 = 1e-6;
/// Ruckig refuses a velocity limit of 0: where the bound is 0 (at a position limit), this is the limit.
const MIN_VELOCITY_LIMIT: f64 = 1e-9;
/// A position-dependent velocity limit is raised only once the bound exceeds ruckig's by this fraction.
const LIMIT_HYSTERESIS: f64 = 0.01;

/// Per-joint kinematic limits of the robot (absolute values; only the first `n` entries are used).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    pub velocity: [f64; MAX_JOINTS],
    pub acceleration: [f64; MAX_JOINTS],
    pub jerk: [f64; MAX_JOINTS],
    /// Velocity bounds that depend on position (capped by `velocity`), if the robot has them.
    pub position_dependent: Option<[JointVelocityBound; MAX_JOINTS]>,
}

impl Limits {
    /// The profile's `dq_max` (less its `velocity_headroom`), `ddq_max`, `jerk_max` and position-dependent
    /// planning velocity bounds. Entries the profile lacks stay 0, which [`Smoother::new`] rejects.
    pub fn from_profile(profile: &Profile) -> Self {
        let mut l = Limits {
            velocity: [0.0; MAX_JOINTS],
            acceleration: [0.0; MAX_JOINTS],
            jerk: [0.0; MAX_JOINTS],
            position_dependent: None,
        };
        for (dst, src) in [
            (&mut l.velocity, &profile.dq_max),
            (&mut l.acceleration, &profile.ddq_max),
            (&mut l.jerk, &profile.jerk_max),
        ] {
            let k = src.len().min(MAX_JOINTS);
            dst[..k].copy_from_slice(&src[..k]);
        }
        for v in &mut l.velocity[..profile.dq_max.len().min(MAX_JOINTS)] {
            *v -= profile.velocity_headroom;
        }
        let bounds = profile.planning_velocity_bounds();
        if bounds.iter().any(JointVelocityBound::depends_on_position) {
            let mut b = [bounds[0]; MAX_JOINTS];
            b[..bounds.len().min(MAX_JOINTS)].copy_from_slice(&bounds[..bounds.len().min(MAX_JOINTS)]);
            l.position_dependent = Some(b);
        }
        l
    }
}

/// The smoothed state for the next tick (entries beyond the active joints are 0).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Kinematics {
    pub position: [f64; MAX_JOINTS],
    pub velocity: [f64; MAX_JOINTS],
    pub acceleration: [f64; MAX_JOINTS],
}

/// Every variant is `Copy` so that reporting an error never allocates.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum SmoothingError {
    #[error("joint count {0} must be in 1..={MAX_JOINTS}")]
    JointCount(usize),
    #[error("time step {0} s must be finite and positive")]
    TimeStep(f64),
    #[error("safety factor {0} must be finite and in (0, 1]")]
    SafetyFactor(f64),
    #[error("speed {0} must be finite and in (0, 1]")]
    Speed(f64),
    #[error("joint {joint}: {kind} limit {value} must be finite and positive")]
    Limit { joint: usize, kind: &'static str, value: f64 },
    #[error("{what} has {got} values but the smoother drives {expected} joints")]
    Length { what: &'static str, expected: usize, got: usize },
    #[error("{what}[{joint}] = {value} is not finite")]
    NonFinite { what: &'static str, joint: usize, value: f64 },
    #[error("{what}[{joint}] = {value} is beyond ±{MAX_ABS_POSITION}")]
    OutOfRange { what: &'static str, joint: usize, value: f64 },
    #[error("ruckig found no trajectory (numerical failure); the previous state is kept")]
    Ruckig,
}

/// Online jerk-limited trajectory generator for up to [`MAX_JOINTS`] joints; all storage is allocated in [`new`].
///
/// The current state fed to ruckig is always its own previous output, never the measurement: the command stream
/// must be smooth on its own, and feeding back measurement noise would re-plan from a jittering state.
///
/// [`new`]: Smoother::new
pub struct Smoother {
    n: usize,
    /// Scaled limits, as given to ruckig (times `speed`).
    max_velocity: [f64; MAX_JOINTS],
    /// The same at full speed.
    full_velocity: [f64; MAX_JOINTS],
    safety_factor: f64,
    /// Position-dependent velocity bounds, tightened for ruckig's lag, and the braking their envelope allows.
    position_dependent: Option<([JointVelocityBound; MAX_JOINTS], [f64; MAX_JOINTS])>,
    otg: Ruckig<MAX_JOINTS, ThrowErrorHandler>,
    input: InputParameter<MAX_JOINTS>,
    output: OutputParameter<MAX_JOINTS>,
    state: Kinematics,
}

impl Smoother {
    /// `n` active joints at `dt_s` seconds per tick, planning within [`DEFAULT_SAFETY_FACTOR`] of `limits`;
    /// at rest at 0 until [`reset`](Self::reset).
    pub fn new(n: usize, dt_s: f64, limits: &Limits) -> Result<Self, SmoothingError> {
        Self::with_safety_factor(n, dt_s, limits, DEFAULT_SAFETY_FACTOR)
    }

    /// Like [`new`](Self::new) with the limits scaled by `safety_factor` instead.
    pub fn with_safety_factor(
        n: usize,
        dt_s: f64,
        limits: &Limits,
        safety_factor: f64,
    ) -> Result<Self, SmoothingError> {
        if !(1..=MAX_JOINTS).contains(&n) {
            return Err(SmoothingError::JointCount(n));
        }
        if !(dt_s.is_finite() && dt_s > 0.0) {
            return Err(SmoothingError::TimeStep(dt_s));
        }
        if !(safety_factor.is_finite() && safety_factor > 0.0 && safety_factor <= 1.0) {
            return Err(SmoothingError::SafetyFactor(safety_factor));
        }
        for (kind, values) in
            [("velocity", &limits.velocity), ("acceleration", &limits.acceleration), ("jerk", &limits.jerk)]
        {
            if let Some(joint) = values[..n].iter().position(|v| !(v.is_finite() && *v > 0.0)) {
                return Err(SmoothingError::Limit { joint, kind, value: values[joint] });
            }
        }

        let mut input = InputParameter::<MAX_JOINTS>::new(None);
        let mut max_velocity = [0.0; MAX_JOINTS];
        #[allow(clippy::needless_range_loop)] // several arrays indexed by joint
        for i in 0..MAX_JOINTS {
            let active = i < n;
            // Disabled DoFs are skipped by the calculation but still validated, so they get harmless limits.
            let scaled = |x: f64| if active { safety_factor * x } else { 1.0 };
            max_velocity[i] = scaled(limits.velocity[i]);
            input.max_velocity[i] = max_velocity[i];
            input.max_acceleration[i] = scaled(limits.acceleration[i]);
            input.max_jerk[i] = scaled(limits.jerk[i]);
            input.enabled[i] = active;
        }
        input.control_interface = ControlInterface::Position;
        // Every joint time-optimal on its own, not stretched to end with the slowest: the servo re-plans every
        // tick toward a moving reference, where a shared end time buys nothing, and ruckig (rsruckig and the C++
        // original alike) can fail to find one from a state at the very end of a motion when its input changes
        // there ("error in step 2", reproduced in tests/servo_hal_timing.rs) — a trip on a healthy robot, and an
        // allocation on its error path.
        input.synchronization = Synchronization::None;
        let position_dependent = limits.position_dependent.map(|bounds| {
            let (mut tight, mut brake) = (bounds, [0.0; MAX_JOINTS]);
            for i in 0..n {
                let (a, j) = (limits.acceleration[i], limits.jerk[i]);
                tight[i] = bounds[i].tightened(a * a / j);
                brake[i] = 0.5 * a;
            }
            input.min_velocity = Some(DataArrayOrVec::Stack(max_velocity.map(|v| -v)));
            (tight, brake)
        });
        let mut s = Smoother {
            n,
            max_velocity,
            full_velocity: max_velocity,
            safety_factor,
            position_dependent,
            otg: Ruckig::new(None, dt_s),
            input,
            output: OutputParameter::new(None),
            state: Kinematics::default(),
        };
        s.reset(&[0.0; MAX_JOINTS])?;
        Ok(s)
    }

    /// Plans the next motions at `speed` (0 < speed ≤ 1) of the velocity limits (e.g. slower moves to a start pose,
    /// as libfranka's examples make them). A motion faster than the new limit is brought down to it within the
    /// acceleration and jerk limits. Allocation-free.
    pub fn set_speed(&mut self, speed: f64) -> Result<(), SmoothingError> {
        if !(speed.is_finite() && speed > 0.0 && speed <= 1.0) {
            return Err(SmoothingError::Speed(speed));
        }
        for i in 0..self.n {
            self.max_velocity[i] = (speed * self.full_velocity[i]).max(MIN_VELOCITY_LIMIT);
            if self.position_dependent.is_none() {
                self.input.max_velocity[i] = self.max_velocity[i];
            }
        }
        // Position-dependent bounds: `velocity_limits_here` caps the envelope at the new limit from the next step.
        Ok(())
    }

    pub fn joints(&self) -> usize {
        self.n
    }

    /// The last output (what `track`/`brake` returned, or the rest state after `reset`).
    pub fn state(&self) -> &Kinematics {
        &self.state
    }

    /// At rest at `position` (its first `n` values). A short, non-finite or out-of-range position is refused
    /// and nothing changes: a substitute value (such as 0, outside FR3 joint 4's range) would make the next
    /// command jump to a pose nobody asked for.
    pub fn reset(&mut self, position: &[f64]) -> Result<(), SmoothingError> {
        let n = self.n;
        check("position", position, n)?;
        if let Some(joint) = position[..n].iter().position(|q| q.abs() > MAX_ABS_POSITION) {
            return Err(SmoothingError::OutOfRange { what: "position", joint, value: position[joint] });
        }
        self.state = Kinematics::default();
        self.state.position[..n].copy_from_slice(&position[..n]);
        for i in 0..MAX_JOINTS {
            let q = self.state.position[i];
            self.input.current_position[i] = q;
            self.input.current_velocity[i] = 0.0;
            self.input.current_acceleration[i] = 0.0;
            self.input.target_position[i] = q;
            self.input.target_velocity[i] = 0.0;
            self.input.target_acceleration[i] = 0.0;
        }
        self.otg.reset();
        Ok(())
    }

    /// One online step towards (`target_position`, `target_velocity`) from the previous output; returns the state
    /// for the next tick. Target velocities are clamped inside the scaled limits. Slices need at least `n` values
    /// (extra ones are ignored); on any error nothing changes.
    pub fn track(&mut self, target_position: &[f64], target_velocity: &[f64]) -> Result<&Kinematics, SmoothingError> {
        let n = self.n;
        check("target_position", target_position, n)?;
        check("target_velocity", target_velocity, n)?;
        if let Some(joint) = target_position[..n].iter().position(|q| q.abs() > MAX_ABS_POSITION) {
            return Err(SmoothingError::OutOfRange { what: "target_position", joint, value: target_position[joint] });
        }
        let saved = (self.input.control_interface, self.targets());
        self.input.control_interface = ControlInterface::Position;
        self.velocity_limits_here();
        for i in 0..n {
            let (v_min, v_max) = self.velocity_range(i);
            self.input.target_position[i] = target_position[i];
            self.input.target_velocity[i] = target_velocity[i].clamp(v_min, v_max);
            self.input.target_acceleration[i] = 0.0;
        }
        self.step(saved)
    }

    /// This step's velocity limits of joint `i` as handed to ruckig.
    fn velocity_range(&self, i: usize) -> (f64, f64) {
        let lo = self.input.min_velocity.as_ref().map_or(-self.input.max_velocity[i], |v| v[i]);
        (lo, self.input.max_velocity[i])
    }

    /// Position-dependent bounds: ruckig gets this step's limits at the current position. A change of a limit
    /// makes ruckig plan anew, so a limit moves only once the bound is [`LIMIT_HYSTERESIS`] away from the one
    /// ruckig has (a lag the 10 % safety factor covers: ruckig's limit stays below 0.9 / 0.99 of the bound).
    /// (Handing ruckig the bound every tick instead was tried: a joint braking along a falling bound then brakes
    /// in a short pulse each tick rather than a full jerk-limited pulse each step, but in 12 runs of the franka-sim
    /// stall test franka-sim raised its velocity-discontinuity reflex 3 times, against 0 of 12 with the steps.)
    fn velocity_limits_here(&mut self) {
        let Some((bounds, brake)) = &self.position_dependent else { return };
        let sf = self.safety_factor;
        let far = |new: f64, old: f64| (new - old).abs() > LIMIT_HYSTERESIS * old.abs();
        for i in 0..self.n {
            let (lo, hi) = bounds[i].envelope(self.state.position[i], brake[i]);
            let hi = (sf * hi).clamp(MIN_VELOCITY_LIMIT, self.max_velocity[i]);
            if far(hi, self.input.max_velocity[i]) {
                self.input.max_velocity[i] = hi;
            }
            if let Some(min) = self.input.min_velocity.as_mut() {
                let lo = (sf * lo).clamp(-self.max_velocity[i], -MIN_VELOCITY_LIMIT);
                if far(lo, min[i]) {
                    min[i] = lo;
                }
            }
        }
    }

    /// One step of a time-optimal jerk-limited stop (velocity interface to v = 0, a = 0), from the previous output.
    pub fn brake(&mut self) -> Result<&Kinematics, SmoothingError> {
        let saved = (self.input.control_interface, self.targets());
        self.input.control_interface = ControlInterface::Velocity;
        self.velocity_limits_here();
        for i in 0..self.n {
            self.input.target_velocity[i] = 0.0;
            self.input.target_acceleration[i] = 0.0;
        }
        self.step(saved)
    }

    /// Continue from `state` (e.g. the setpoint the robot actually applied, when it did not apply the last
    /// output) as if it had been the last output. Non-finite entries are refused and nothing changes.
    pub fn continue_from(&mut self, state: &Kinematics) -> Result<(), SmoothingError> {
        check("position", &state.position, self.n)?;
        check("velocity", &state.velocity, self.n)?;
        check("acceleration", &state.acceleration, self.n)?;
        for i in 0..self.n {
            self.state.position[i] = state.position[i];
            self.state.velocity[i] = state.velocity[i];
            self.state.acceleration[i] = state.acceleration[i];
            self.input.current_position[i] = state.position[i];
            self.input.current_velocity[i] = state.velocity[i];
            self.input.current_acceleration[i] = state.acceleration[i];
        }
        Ok(())
    }

    /// Whether the last output has (numerically) zero velocity and acceleration on every active joint.
    pub fn is_at_rest(&self) -> bool {
        (0..self.n).all(|i| {
            self.state.velocity[i].abs() <= REST_VELOCITY && self.state.acceleration[i].abs() <= REST_ACCELERATION
        })
    }

    fn targets(&self) -> [[f64; MAX_JOINTS]; 3] {
        let mut t = [[0.0; MAX_JOINTS]; 3];
        t[0].copy_from_slice(&self.input.target_position);
        t[1].copy_from_slice(&self.input.target_velocity);
        t[2].copy_from_slice(&self.input.target_acceleration);
        t
    }

    fn step(&mut self, saved: (ControlInterface, [[f64; MAX_JOINTS]; 3])) -> Result<&Kinematics, SmoothingError> {
        let r = self.otg.update(&self.input, &mut self.output);
        let ok = r.is_ok_and(|r| matches!(r, RuckigResult::Working | RuckigResult::Finished))
            && (0..self.n).all(|i| {
                self.output.new_position[i].is_finite()
                    && self.output.new_velocity[i].is_finite()
                    && self.output.new_acceleration[i].is_finite()
            });
        if !ok {
            // Put the targets back and drop ruckig's cached plan: `calculate` may have half-written the
            // trajectory, and an unchanged input would otherwise be sampled from it next tick.
            self.input.control_interface = saved.0;
            self.input.target_position.copy_from_slice(&saved.1[0]);
            self.input.target_velocity.copy_from_slice(&saved.1[1]);
            self.input.target_acceleration.copy_from_slice(&saved.1[2]);
            self.otg.reset();
            return Err(SmoothingError::Ruckig);
        }
        // Current state for the next tick = this output (online OTG), not the measurement.
        self.output.pass_to_input(&mut self.input);
        for i in 0..self.n {
            self.state.position[i] = self.output.new_position[i];
            self.state.velocity[i] = self.output.new_velocity[i];
            self.state.acceleration[i] = self.output.new_acceleration[i];
        }
        Ok(&self.state)
    }
}

fn check(what: &'static str, values: &[f64], n: usize) -> Result<(), SmoothingError> {
    if values.len() < n {
        return Err(SmoothingError::Length { what, expected: n, got: values.len() });
    }
    match values[..n].iter().position(|v| !v.is_finite()) {
        Some(joint) => Err(SmoothingError::NonFinite { what, joint, value: values[joint] }),
        None => Ok(()),
    }
}
