//! Waiting for the HAL's state frames in a test: one loop for every test binary.

use std::time::{Duration, Instant};

use mars_ipc::{RobotState, StateReader};

/// Receives state frames until `pred` holds and returns that frame; each frame received is also pushed to
/// `frames` when given. Between polls `exited` may end the wait (a HAL that exited: its message); otherwise
/// the wait ends after `timeout`. The error says what was awaited and why it did not come.
pub fn wait_for(
    states: &StateReader,
    mut frames: Option<&mut Vec<RobotState>>,
    what: &str,
    timeout: Duration,
    mut pred: impl FnMut(&RobotState) -> bool,
    mut exited: impl FnMut() -> Option<String>,
) -> Result<RobotState, String> {
    let end = Instant::now() + timeout;
    while Instant::now() < end {
        while let Some(s) = states.receive().map_err(|e| format!("receiving states while waiting for {what}: {e}"))? {
            if let Some(frames) = frames.as_deref_mut() {
                frames.push(s);
            }
            if pred(&s) {
                return Ok(s);
            }
        }
        if let Some(why) = exited() {
            return Err(format!("{why} while waiting for {what}"));
        }
        std::thread::sleep(Duration::from_micros(200));
    }
    Err(format!("timed out after {timeout:?} waiting for {what}"))
}
