//! The FR3's joint velocity limits, which depend on where the joint is, written here from Franka's documented
//! formula and nothing else of this workspace. The FCI documentation ("Limits for Franka Research 3") and
//! libfranka's `JointVelocityLimitsConfig` (which reads the numbers from the robot's URDF,
//! `<position_based_velocity_limits velocity_offset= deceleration_limit=>`) state it per joint as
//!
//! ```text
//! upper(q) = min(max_velocity, max(0, −velocity_offset + √max(0, 2·deceleration_limit·(q_upper − q))))
//! lower(q) = max(−max_velocity, min(0, velocity_offset − √max(0, 2·deceleration_limit·(q − q_lower))))
//! ```
//!
//! `max_velocity` is the joint's maximum speed (the profile's `dq_max`, 2.62/5.26/4.18 rad/s for the FR3).
//! libfranka's own rate limiter keeps a further tolerance inside; that is a margin of the library, not the robot's
//! limit, so it is not taken off here.

/// Per joint, from the FR3's URDF: `deceleration_limit` (rad/s²) ...
const DECELERATION: [f64; 7] = [6.0, 2.585, 3.5, 4.0, 17.0, 5.5, 17.0];
/// ... `velocity_offset` (rad/s) ...
const OFFSET: [f64; 7] = [0.30, 0.20, 0.20, 0.30, 0.35, 0.35, 0.35];
/// ... and the joint's position range (rad), where the square root reaches zero.
const Q_UPPER: [f64; 7] = [2.7501, 1.7918, 2.9065, -0.1458, 2.8101, 4.5205, 3.0196];
const Q_LOWER: [f64; 7] = [-2.7501, -1.7918, -2.9065, -3.0481, -2.8101, 0.54092, -3.0196];

/// The joints the formula covers.
pub const JOINTS: usize = 7;

/// The highest velocity joint `joint` may have at `q` (rad/s), capped at `cap`.
pub fn upper(joint: usize, q: f64, cap: f64) -> f64 {
    let ramp = (2.0 * DECELERATION[joint] * (Q_UPPER[joint] - q)).max(0.0).sqrt();
    (ramp - OFFSET[joint]).max(0.0).min(cap)
}

/// The lowest (most negative) velocity joint `joint` may have at `q` (rad/s), capped at `-cap`.
pub fn lower(joint: usize, q: f64, cap: f64) -> f64 {
    let ramp = (2.0 * DECELERATION[joint] * (q - Q_LOWER[joint])).max(0.0).sqrt();
    (OFFSET[joint] - ramp).min(0.0).max(-cap)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn far_from_its_limits_a_joint_may_reach_its_cap() {
        for j in 0..JOINTS {
            let mid = 0.5 * (Q_UPPER[j] + Q_LOWER[j]);
            assert_eq!(upper(j, mid, 2.62), 2.62, "joint {j}");
            assert_eq!(lower(j, mid, 2.62), -2.62, "joint {j}");
        }
    }

    #[test]
    fn at_a_limit_the_joint_may_only_move_away_from_it() {
        for j in 0..JOINTS {
            assert_eq!(upper(j, Q_UPPER[j], 5.0), 0.0, "joint {j}");
            assert!(lower(j, Q_UPPER[j], 5.0) < 0.0, "joint {j}");
            assert_eq!(lower(j, Q_LOWER[j], 5.0), 0.0, "joint {j}");
            assert!(upper(j, Q_LOWER[j], 5.0) > 0.0, "joint {j}");
        }
    }

    /// One point worked by hand: joint 1 at 2.0 rad, √(2·6·0.7501) − 0.3 = 2.7001… capped at 2.62; at 2.5 rad
    /// √(2·6·0.2501) − 0.3 = 1.4324….
    #[test]
    fn a_point_worked_by_hand() {
        assert_eq!(upper(0, 2.0, 2.62), 2.62);
        assert!((upper(0, 2.5, 2.62) - (3.0012f64.sqrt() - 0.3)).abs() < 1e-12);
        assert!((lower(0, -2.5, 2.62) + (3.0012f64.sqrt() - 0.3)).abs() < 1e-12);
    }
}
