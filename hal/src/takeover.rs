//! Taking over an arm: the HAL starts only from a measurement it may hold — finite, not faulty, inside the
//! position range, at rest, the gripper within its range — and otherwise says why and commands nothing.

use crate::backend::{BackendError, Measurement};
use crate::safety::SafetyFilter;
use mars_profile::Profile;

/// Above this measured joint speed (rad/s) the arm is moving: the HAL does not take it over.
pub const START_MAX_SPEED: f64 = 0.05;
/// Why the HAL refused to start: nothing was commanded.
#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum StartError {
    #[error("the first read of the robot failed ({0}): nothing was commanded")]
    Read(BackendError),
    #[error("the robot reports a sensor fault (bits {0:#x}) at start: nothing was commanded")]
    Faulty(u32),
    #[error("joint {joint} measures {value} at start, not a finite number: nothing was commanded")]
    NotFinite { joint: usize, value: f64 },
    #[error(
        "joint {joint} is at {q:.4} rad, outside the range the HAL may hold it in [{min:.4}, {max:.4}]: nothing \
         was commanded; move the arm inside its limits (e.g. by hand in guiding mode) and start again"
    )]
    OutsideLimits { joint: usize, q: f64, min: f64, max: f64 },
    #[error(
        "joint {joint} moves at {speed:.3} rad/s at start (more than {START_MAX_SPEED} rad/s): the HAL takes over \
         only an arm at rest; nothing was commanded"
    )]
    Moving { joint: usize, speed: f64 },
    #[error("the gripper measures {width} m at start, outside [{min}, {max}]: nothing was commanded")]
    Gripper { width: f64, min: f64, max: f64 },
}

/// Whether the HAL may take over an arm measured as `m` (the filter holds the limits): within the position range,
/// at rest, the gripper within its range.
pub(crate) fn check_takeover(filter: &SafetyFilter, profile: &Profile, m: &Measurement) -> Result<(), StartError> {
    let n = profile.joints;
    if m.fault != 0 {
        return Err(StartError::Faulty(m.fault));
    }
    for (joint, &value) in m.position[..n].iter().chain(&m.velocity[..n]).enumerate() {
        if !value.is_finite() {
            return Err(StartError::NotFinite { joint: joint % n, value });
        }
    }
    if !m.gripper.is_finite() {
        return Err(StartError::NotFinite { joint: n, value: m.gripper });
    }
    for joint in 0..n {
        let (min, max) = filter.position_range(joint);
        let q = m.position[joint];
        if !(min..=max).contains(&q) {
            return Err(StartError::OutsideLimits { joint, q, min, max });
        }
        let speed = m.velocity[joint].abs();
        if speed > START_MAX_SPEED {
            return Err(StartError::Moving { joint, speed });
        }
    }
    // A gripper a hair beyond its range (a measurement, not a command) is held where it is, clamped.
    let (g_min, g_max, tol) = (profile.gripper_min, profile.gripper_max, profile.gripper_deadband);
    if !(g_min - tol..=g_max + tol).contains(&m.gripper) {
        return Err(StartError::Gripper { width: m.gripper, min: g_min, max: g_max });
    }
    Ok(())
}
