//! `mars-hal recover`: clear a reflex on a robot no HAL is driving (the robot serves one FCI client at a time;
//! a running HAL recovers on SIGUSR1 instead).

use std::time::Duration;

use franka::RobotMode;

use super::status::FciStatus;
use super::{FciError, connect};

/// Connects, runs the robot's automatic error recovery when it needs one, and reads the state after it. Returns
/// the state read last (whatever mode it is in: the caller judges it).
pub fn recover(addr: &str, timeout: Duration) -> Result<(bool, FciStatus), FciError> {
    let fci = connect(addr, timeout)?;
    let before = fci.read_once(timeout)?;
    let needed = before.robot_mode == RobotMode::Reflex || before.current_errors.any();
    if needed {
        fci.recover(timeout)?;
    }
    let after = fci.read_once(timeout)?;
    Ok((needed, FciStatus::of(&fci, &after)))
}
