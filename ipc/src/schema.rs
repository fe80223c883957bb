//! Schema version carried in every frame's iceoryx2 user header.
//!
//! iceoryx2 itself refuses to connect ports whose payload types differ in name, size or alignment. That does not
//! catch a change of *meaning* with the same layout (a field renamed from radians to degrees, a flag bit
//! re-assigned). So every frame also carries [`SCHEMA_VERSION`], and a receiver refuses any frame whose version
//! differs, with an error that names both versions. Bump it whenever a payload's layout or meaning changes.

use iceoryx2::prelude::ZeroCopySend;

/// The version of the frame layouts in this crate.
/// v2: `HoldReason::ControllerLost` and the `fault` bits of `RobotState`.
/// v3: `RobotState::applied_velocity` / `applied_acceleration`.
/// v4: late / last-resort / backend-error counters, `status::LAST_RESORT` and `BACKEND_ERROR`,
/// `HoldReason::HalError`, `RobotState::gripper_target`, `JointCommand::gripper_speed`.
/// v5: `fault::NO_MEASUREMENT`, `RobotState::duplicate_commands`; the gripper fields are a target, sent on change.
/// v6: the robot's own report (`RobotState::robot_errors`, `robot_reflex_errors`, `robot_success_rate`,
/// `robot_mode`), `fault::ROBOT_REFLEX` / `ROBOT_CONNECTION_LOST`, `HoldReason::RobotFault` / `HalStopping`.
/// v7: `RobotState::robot_cycles` (the robot's cycles since the previous frame) in place of the padding.
/// v8: `RobotState::ticks_blocked`, `overlong_ticks_*` (the HAL's ticks that blocked or overran its period).
/// v9: `LiveStats::camera` (the name of the camera whose frame ages the live view gives).
pub const SCHEMA_VERSION: u32 = 9;

/// The iceoryx2 user header of state and command frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("mars::FrameHeader")]
#[repr(C)]
pub struct FrameHeader {
    pub schema_version: u32,
}

impl Default for FrameHeader {
    /// A header of this build: what every writer in this crate sends.
    fn default() -> Self {
        Self { schema_version: SCHEMA_VERSION }
    }
}

/// A frame from a build with another schema: it must not be interpreted.
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
#[error(
    "schema version mismatch: this build speaks mars-ipc schema v{expected}, the peer sent v{found}; \
     rebuild the controller and mars-hal from the same revision"
)]
pub struct SchemaMismatch {
    pub expected: u32,
    pub found: u32,
}

/// Accept a frame only if it was written with this build's schema.
pub fn check_schema_version(found: u32) -> Result<(), SchemaMismatch> {
    if found == SCHEMA_VERSION { Ok(()) } else { Err(SchemaMismatch { expected: SCHEMA_VERSION, found }) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn own_version_is_accepted() {
        assert_eq!(check_schema_version(FrameHeader::default().schema_version), Ok(()));
    }

    #[test]
    fn other_version_is_refused_naming_both_versions() {
        let err = check_schema_version(SCHEMA_VERSION + 1).unwrap_err();
        assert_eq!(err, SchemaMismatch { expected: SCHEMA_VERSION, found: SCHEMA_VERSION + 1 });
        let msg = err.to_string();
        assert!(
            msg.contains(&format!("v{SCHEMA_VERSION}")) && msg.contains(&format!("v{}", SCHEMA_VERSION + 1)),
            "{msg}"
        );
    }
}
