//! When a franka-sim test may blame the machine for a reflex: only on the stall witness's evidence (crate
//! stall-witness, no code of the HAL's) of a stall in the robot's cycles before it. The HAL's own account of those
//! cycles (states unseen, bunched, the success rate) is the code under test and excuses nothing. (runtime's
//! franka-sim tests include this file too.)

#[allow(unused_imports)] // runtime's franka-sim tests take these from their own helpers
pub use stall_witness::{Attempt, Excuse, at_most_one_rerun, witness};

/// A stall of at least this long (two of the robot's cycles) ...
pub const REFLEX_STALL_MS: f64 = 2.0;
/// ... in the cycles before a reflex that the HAL's account of it covers (64), to its log line just after it.
pub const BEFORE_REFLEX_NS: u64 = 80_000_000;
pub const AFTER_REFLEX_NS: u64 = 5_000_000;

/// The excuse for every reflex the HAL logged ("the robot stopped itself", in `hal_log`: its stderr with tracing's
/// timestamps), if the stall witness saw the machine stall before each; `None` without a reflex or when one is not
/// excused.
pub fn reflex_excuse(hal_log: &str) -> Option<Excuse> {
    let reflexes = hal_log.lines().filter(|l| l.contains("the robot stopped itself"));
    witness().excuse_logged(reflexes, BEFORE_REFLEX_NS, AFTER_REFLEX_NS, REFLEX_STALL_MS)
}
