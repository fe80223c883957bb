//! `mars-hal fci-status`: reach the robot, read one state, say what it is doing. Commands nothing, so it is safe
//! to run first against a real arm ("can I reach my robot, and is it in reflex?"), and before every session.

use std::fmt;
use std::time::{Duration, Instant};

use franka::{FciVersion, RobotMode};

use super::JOINTS;
use super::connect::{Fci, connect};
use super::error::FciError;
use super::state::{RobotStatus, measurement};

/// One look at the robot.
#[derive(Debug, Clone)]
pub struct FciStatus {
    pub addr: String,
    pub fci_version: FciVersion,
    pub server_version: u16,
    /// Measured joint positions (rad).
    pub q: [f64; JOINTS],
    pub status: RobotStatus,
}

/// Connects to `addr` and reads one state, all within `timeout` (the read gets what the connection left of it).
pub fn probe(addr: &str, timeout: Duration) -> Result<FciStatus, FciError> {
    let deadline = Instant::now() + timeout;
    let fci = connect(addr, timeout)?;
    let state = fci.read_once(deadline.saturating_duration_since(Instant::now()))?;
    Ok(FciStatus::of(&fci, &state))
}

impl FciStatus {
    /// What `state`, read over `fci`, says.
    pub fn of(fci: &Fci, state: &franka::RobotState) -> Self {
        let m = measurement(state);
        let mut q = [0.0; JOINTS];
        q.copy_from_slice(&m.position[..JOINTS]);
        FciStatus {
            addr: fci.addr().to_string(),
            fci_version: fci.fci_version(),
            server_version: fci.server_version(),
            q,
            status: RobotStatus::of(state),
        }
    }
}

/// A list of error names, or "none".
struct Names<'a>(&'a [&'static str]);
impl fmt::Display for Names<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0.is_empty() { f.write_str("none") } else { f.write_str(&self.0.join(", ")) }
    }
}

/// One fact per line, `name: value`, so a person reads it and a script greps it.
impl fmt::Display for FciStatus {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let s = &self.status;
        writeln!(f, "robot: {} (FCI {:?}, server version {})", self.addr, self.fci_version, self.server_version)?;
        write!(f, "joint positions (rad):")?;
        for q in &self.q {
            write!(f, " {q:.6}")?;
        }
        writeln!(f)?;
        writeln!(f, "robot mode: {}", s.mode)?;
        writeln!(f, "control command success rate: {:.3}", s.control_command_success_rate)?;
        writeln!(f, "current errors: {}", Names(&s.current_errors))?;
        writeln!(f, "last motion errors: {}", Names(&s.last_motion_errors))?;
        // What a person at the robot does next, for the modes that stop a session from starting.
        match s.mode {
            RobotMode::Reflex => writeln!(
                f,
                "note: the robot is in reflex (the last motion errors say why); clear it with an error recovery \
                 (`mars-hal recover --robot-ip {}`, or Desk) before a run",
                self.addr
            )?,
            RobotMode::UserStopped => writeln!(f, "note: the user stop is pressed; release it before a run")?,
            RobotMode::Guiding => writeln!(f, "note: the robot is in hand-guiding mode")?,
            _ => {}
        }
        Ok(())
    }
}
