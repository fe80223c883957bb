//! Joint velocity bounds that depend on where the joint is: constant for most robots, the FR3's braking curves
//! for the FR3.
//!
//! The FR3 lets a joint move fast only far from its position limits. Toward each limit its velocity bound shrinks
//! along a braking curve `v(q) = √(k·(q_lim − q)) − c`, capped by the joint's maximum speed. The formula and its
//! constants are Franka's: libfranka `include/franka/rate_limiting.h`, `computeUpperLimitsJointVelocity` and
//! `computeLowerLimitsJointVelocity` (libfranka 0.14; "implementation based on
//! https://frankaemika.github.io/docs/control_parameters.html#limits-for-franka-research-3"), with libfranka's
//! tolerance `kJointVelocityLimitsTolerance` = kLimitEps = 1e-3 rad/s taken off (kTolNumberPacketsLost is 0
//! for the FR3). The caps are the profile's `dq_max`, which for the FR3 are the same 2.62/5.26/4.18 rad/s.
//!
//! Two views of the same bound:
//! - [`JointVelocityBound::hard`]: the robot's bound at a position, what every command must meet;
//! - [`JointVelocityBound::envelope`]: a bound under it that can be *followed* with braking at `a_brake`. Near a
//!   limit the FR3's curve falls steeply (for joints 5 and 7 at up to k/2 = 17 rad/s², above the 10 rad/s²
//!   acceleration limit), so a joint riding the hard bound could not slow down as fast as the bound does. The
//!   envelope brakes at `a_brake` from the curve's point where the curve itself would need more, and follows
//!   the curve below it (where the curve's own deceleration, k/2·v/(v + c), is gentler).

use serde::Deserialize;

/// Which velocity bounds a profile's robot has.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum VelocityLimits {
    /// `±dq_max` everywhere.
    #[default]
    Constant,
    /// The FR3's position-dependent bounds (7 joints).
    Fr3,
}

/// libfranka's tolerance on the FR3 velocity bounds (rad/s).
const FR3_TOLERANCE: f64 = 1e-3;

/// One side of a braking curve: the bound is `√(k·d) − c` at distance `d` from `limit`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Curve {
    k: f64,
    c: f64,
    /// Where the curve's square root reaches zero (rad).
    limit: f64,
}

/// The FR3's curves per joint, (lower, upper), as in libfranka's rate_limiting.h.
const FR3: [(Curve, Curve); 7] = {
    const fn side(k: f64, c: f64, lower: f64, upper: f64) -> (Curve, Curve) {
        (Curve { k, c, limit: lower }, Curve { k, c, limit: upper })
    }
    [
        side(12.0, 0.30, -2.7501, 2.7501),
        side(5.17, 0.20, -1.7918, 1.7918),
        side(7.00, 0.20, -2.9065, 2.9065),
        side(8.00, 0.30, -3.0481, -0.1458),
        side(34.0, 0.35, -2.8101, 2.8101),
        side(11.0, 0.35, 0.54092, 4.5205),
        side(34.0, 0.35, -3.0196, 3.0196),
    ]
};

impl Curve {
    /// The curve's bound (≥ 0, before the cap and the tolerance) at distance `d` from the limit.
    fn at(&self, d: f64) -> f64 {
        (-self.c + (self.k * d.max(0.0)).sqrt()).max(0.0)
    }

    /// The distance from the limit at which the bound (after `tolerance`) reaches zero: inside it a joint
    /// may not even rest.
    fn rest_distance(&self, tolerance: f64) -> f64 {
        (self.c + tolerance).powi(2) / self.k
    }

    /// The envelope at distance `d`: the curve where following it needs at most `a_brake`, and a braking
    /// parabola at `a_brake` above the speed `v*` where the curve's deceleration k/2·v/(v + c) reaches it.
    fn envelope(&self, d: f64, a_brake: f64, tolerance: f64) -> f64 {
        let on_curve = self.at(d) - tolerance;
        let half_k = 0.5 * self.k;
        if half_k <= a_brake {
            return on_curve;
        }
        let v_star = a_brake * self.c / (half_k - a_brake);
        let d_star = (v_star + self.c).powi(2) / self.k;
        if d <= d_star {
            on_curve
        } else {
            // From (d*, v*) outward the parabola v² = v*² + 2·a_brake·(d − d*) lies under the curve, which rises
            // faster there (its deceleration exceeds a_brake); the tolerance is kept off it as off the curve.
            (v_star * v_star + 2.0 * a_brake * (d - d_star)).sqrt() - tolerance
        }
    }
}

/// The velocity bound of one joint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct JointVelocityBound {
    cap: f64,
    /// (lower, upper) braking curves, if the bound depends on position.
    curves: Option<(Curve, Curve)>,
    tolerance: f64,
}

impl JointVelocityBound {
    pub fn new(kind: VelocityLimits, joint: usize, cap: f64) -> Self {
        match kind {
            VelocityLimits::Constant => Self { cap, curves: None, tolerance: 0.0 },
            VelocityLimits::Fr3 => Self { cap, curves: FR3.get(joint).copied(), tolerance: FR3_TOLERANCE },
        }
    }

    /// The same bound `margin` (rad/s) further inside, where it depends on position (constant bounds stay):
    /// what a follower that may lag its bound by up to `margin` plans with.
    pub fn tightened(&self, margin: f64) -> Self {
        match self.curves {
            None => *self,
            Some(_) => Self { tolerance: self.tolerance + margin, ..*self },
        }
    }

    /// The bound `headroom` (rad/s) further inside everywhere, the cap included: what a planner keeps off the
    /// robot's bound when the robot judges the arm's *measured* velocity, which overshoots the commanded one while
    /// the arm tracks (see `velocity_headroom` in [`crate::Profile`]).
    pub fn with_headroom(&self, headroom: f64) -> Self {
        match self.curves {
            None => Self { cap: self.cap - headroom, ..*self },
            Some(_) => Self { tolerance: self.tolerance + headroom, ..*self },
        }
    }

    pub fn depends_on_position(&self) -> bool {
        self.curves.is_some()
    }

    /// The robot's bound at `q`: (lowest, highest) velocity allowed there.
    pub fn hard(&self, q: f64) -> (f64, f64) {
        match &self.curves {
            None => (-self.cap, self.cap),
            Some((lo, hi)) => (
                -lo.at(q - lo.limit).min(self.cap) + self.tolerance,
                hi.at(hi.limit - q).min(self.cap) - self.tolerance,
            ),
        }
    }

    /// A bound under [`Self::hard`] that a joint braking at `a_brake` can follow (see the module doc).
    pub fn envelope(&self, q: f64, a_brake: f64) -> (f64, f64) {
        match &self.curves {
            None => (-self.cap, self.cap),
            Some((lo, hi)) => {
                let t = self.tolerance;
                let up = hi.envelope(hi.limit - q, a_brake, t).min(self.cap - t);
                let down = lo.envelope(q - lo.limit, a_brake, t).min(self.cap - t);
                (-down, up)
            }
        }
    }

    /// The positions where the joint may rest (the hard bound admits 0 there), within `[q_min, q_max]`.
    pub fn rest_range(&self, q_min: f64, q_max: f64) -> (f64, f64) {
        match &self.curves {
            None => (q_min, q_max),
            Some((lo, hi)) => (
                q_min.max(lo.limit + lo.rest_distance(self.tolerance)),
                q_max.min(hi.limit - hi.rest_distance(self.tolerance)),
            ),
        }
    }
}

impl VelocityLimits {
    /// Whether a robot with `joints` joints can have these bounds.
    pub fn check_joints(self, joints: usize) -> Result<(), String> {
        match self {
            VelocityLimits::Fr3 if joints != FR3.len() => {
                Err(format!("velocity_limits = \"fr3\" needs the FR3's 7 joints, the profile has {joints}"))
            }
            _ => Ok(()),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FR3_CAPS: [f64; 7] = [2.62, 2.62, 2.62, 2.62, 5.26, 4.18, 5.26];

    fn fr3(joint: usize) -> JointVelocityBound {
        JointVelocityBound::new(VelocityLimits::Fr3, joint, FR3_CAPS[joint])
    }

    /// libfranka's formula written out independently, term for term, for a few positions.
    #[test]
    fn the_fr3_bound_is_libfrankas_formula() {
        let upper = |q: f64| (-0.30 + (12.0 * (2.75010 - q)).max(0.0).sqrt()).clamp(0.0, 2.62) - 1e-3;
        let lower = |q: f64| (0.30 - (12.0 * (2.750100 + q)).max(0.0).sqrt()).clamp(-2.62, 0.0) + 1e-3;
        for q in [-2.9, -2.7, -1.0, 0.0, 1.5, 2.7, 2.74, 2.9] {
            assert_eq!(fr3(0).hard(q), (lower(q), upper(q)), "q {q}");
        }
        // Joint 6's lower side sits at +0.54092 rad, not at a negative limit.
        let lower5 = |q: f64| (0.35 - (11.0 * (-0.54092 + q)).max(0.0).sqrt()).clamp(-4.18, 0.0) + 1e-3;
        for q in [0.5, 0.6, 1.0, 3.0] {
            assert_eq!(fr3(5).hard(q).0, lower5(q), "q {q}");
        }
    }

    #[test]
    fn far_from_the_limits_the_fr3_bound_is_the_cap_less_the_tolerance() {
        assert_eq!(fr3(0).hard(0.0), (-2.62 + 1e-3, 2.62 - 1e-3));
        assert_eq!(fr3(4).hard(0.0), (-5.26 + 1e-3, 5.26 - 1e-3));
    }

    #[test]
    fn the_rest_range_is_where_the_bound_admits_standing_still() {
        for j in 0..7 {
            let b = fr3(j);
            let (lo, hi) = b.rest_range(-10.0, 10.0);
            assert!(lo < hi, "joint {j}");
            let (v_lo, v_hi) = b.hard(hi);
            assert!(v_hi.abs() < 1e-9 && v_lo < 0.0, "joint {j} at its upper rest limit: {v_lo} {v_hi}");
            assert!(b.hard(hi + 1e-6).1 < 0.0, "joint {j}: beyond it the joint must move back");
            let (v_lo, v_hi) = b.hard(lo);
            assert!(v_lo.abs() < 1e-9 && v_hi > 0.0, "joint {j} at its lower rest limit: {v_lo} {v_hi}");
        }
        // Close to the FR3's datasheet range, e.g. joint 1 within ±2.7437 rad.
        let (lo, hi) = fr3(0).rest_range(-2.9007, 2.9007);
        assert!((hi - 2.7426).abs() < 1e-3 && (lo + 2.7426).abs() < 1e-3, "{lo} {hi}");
    }

    /// The envelope never exceeds the hard bound, and following it never needs more than `a_brake`.
    #[test]
    fn the_envelope_lies_under_the_bound_and_can_be_followed_braking_at_a_brake() {
        let a_brake = 5.0;
        for j in 0..7 {
            let b = fr3(j);
            let (lo, hi) = b.rest_range(-10.0, 10.0);
            let steps = 20_000;
            let mut prev: Option<(f64, f64)> = None;
            for s in 0..=steps {
                let q = lo + (hi - lo) * s as f64 / steps as f64;
                let (e_lo, e_hi) = b.envelope(q, a_brake);
                let (h_lo, h_hi) = b.hard(q);
                assert!(
                    e_hi <= h_hi + 1e-12 && e_lo >= h_lo - 1e-12,
                    "joint {j} q {q}: {e_lo} {e_hi} vs {h_lo} {h_hi}"
                );
                assert!(e_hi >= -1e-9 && e_lo <= 1e-9, "joint {j} q {q}: standing still is inside");
                // Moving up at the envelope's speed, the speed may drop by at most a_brake·dt over the step
                // dq = v·dt, i.e. d(v²)/dq ≥ −2·a_brake.
                if let Some((q0, v0)) = prev
                    && v0 > 0.0
                {
                    let slope = (e_hi * e_hi - v0 * v0) / (q - q0);
                    assert!(slope >= -2.0 * a_brake * (1.0 + 1e-3), "joint {j} q {q}: d(v²)/dq = {slope}");
                }
                prev = Some((q, e_hi.max(0.0)));
            }
        }
    }

    #[test]
    fn constant_bounds_do_not_depend_on_position() {
        let b = JointVelocityBound::new(VelocityLimits::Constant, 0, 1.5);
        assert_eq!(b.hard(-100.0), (-1.5, 1.5));
        assert_eq!(b.envelope(3.0, 1.0), (-1.5, 1.5));
        assert_eq!(b.rest_range(-2.0, 2.0), (-2.0, 2.0));
        assert!(VelocityLimits::Fr3.check_joints(6).is_err());
        assert!(VelocityLimits::Fr3.check_joints(7).is_ok());
    }
}
