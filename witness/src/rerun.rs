//! The rerun rule of the timing tests: a failure the stall witness explains — its evidence for that very
//! failure's time — may be run once more; a second failure fails, explained or not.
//!
//! An [`Excuse`] can only be made by [`crate::Witness::excuse`] or, for a failure only a peer simulator's pace can
//! cause, from that peer's own account of its pace ([`crate::peer`]), so no test can rerun on its own evidence.
//! Every rerun is printed to the real stderr (libtest's capture does not hide it) and appended, one line each, to
//! the file `$MARS_RERUN_LOG` names, if any (`.ci/run` sums it up in its last line).
//!
//! The same goes for the one correction a test makes without a rerun ([`report_machine_time`]): a loop tick whose
//! thread clock counted time the machine took, by the kernel's interrupt trace and the witness
//! ([`crate::Witness::machine_time_in_ticks`]). It is a measurement, not an excuse: printed as `TAKEN`, summed by
//! `.ci/run` apart from the reruns.

use std::fmt;
use std::io::Write;

use crate::Evidence;
use crate::peer::PeerAccount;

/// A failure and the evidence that the machine stalled at its time.
#[derive(Debug, Clone)]
pub struct Excuse {
    failure: String,
    grounds: Grounds,
}

/// Whose account excuses a failure.
#[derive(Debug, Clone)]
enum Grounds {
    Witness(Box<Evidence>),
    Peer(PeerAccount),
}

impl Excuse {
    pub(crate) fn new(failure: String, evidence: Evidence) -> Self {
        Self { failure, grounds: Grounds::Witness(Box::new(evidence)) }
    }

    pub(crate) fn by_peer(failure: String, account: PeerAccount) -> Self {
        Self { failure, grounds: Grounds::Peer(account) }
    }

    /// How long the machine stalled by the evidence (ms).
    pub fn stalled_ms(&self) -> f64 {
        match &self.grounds {
            Grounds::Witness(e) => e.stalled_ms(),
            Grounds::Peer(a) => a.lost_ms(),
        }
    }
}

impl fmt::Display for Excuse {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.grounds {
            Grounds::Witness(e) => write!(f, "{} — {e}", self.failure),
            Grounds::Peer(a) => write!(f, "{} — {a}", self.failure),
        }
    }
}

/// How an attempt of a timing test ended, when it did not panic: passed, or failed with the witness's excuse
/// (an attempt returns `Err` only where it would otherwise fail; `?` passes an excuse on).
pub type Attempt = Result<(), Excuse>;

/// How long a calm machine the witness must watch before a rerun, and how long to wait for one at most.
const CALM_WINDOW_NS: u64 = 2_000_000_000;
const CALM_WAIT_MAX_NS: u64 = 20_000_000_000;

/// Runs `attempt(1)`; if it was excused, reports the rerun, waits for the witness to see a calm machine (at most
/// 20 s: [`crate::Witness::wait_for_calm`]), and runs `attempt(2)`, which must pass.
pub fn at_most_one_rerun(test: &str, mut attempt: impl FnMut(u32) -> Attempt) {
    let Err(first) = attempt(1) else { return };
    report(test, &first);
    let (waited_ns, calm) = crate::witness().wait_for_calm(CALM_WINDOW_NS, CALM_WAIT_MAX_NS);
    let seen = if calm { "calm" } else { "still not calm" };
    let _ = writeln!(
        std::io::stderr(),
        "{test}: rerun after {:.1} s, the witness saw the machine {seen}",
        waited_ns as f64 * 1e-9
    );
    if let Err(second) = attempt(2) {
        panic!("{test}: failed on its one rerun too ({second}); a test is rerun at most once");
    }
}

/// Prints `RERUN <test>: <excuse>` past libtest's capture and appends it to `$MARS_RERUN_LOG` (an absolute path; a
/// rerun that cannot be recorded there fails the test).
pub fn report(test: &str, excuse: &Excuse) {
    // Not the line in the panic: `.ci/stress` counts lines that start with "RERUN", and it is printed already.
    print_and_record(test, &format!("RERUN {test}: {excuse}"), "its rerun");
}

/// Prints `TAKEN <test>: <what>` past libtest's capture and appends it to `$MARS_RERUN_LOG`, as [`report`] does a
/// rerun: what the machine took from a loop tick that the test therefore did not count as the loop's.
pub fn report_machine_time(test: &str, what: &str) {
    print_and_record(test, &format!("TAKEN {test}: {what}"), "what the machine took");
}

/// `line` to the real stderr and to `$MARS_RERUN_LOG`, if set. What the summary would not count is hidden: the
/// test fails instead, saying which `record` could not be kept.
fn print_and_record(test: &str, line: &str, record: &str) {
    let _ = writeln!(std::io::stderr(), "{line}");
    if let Some(path) = std::env::var_os("MARS_RERUN_LOG")
        && let Err(e) = append(std::path::Path::new(&path), line)
    {
        panic!("{test}: {record} cannot be recorded in MARS_RERUN_LOG {}: {e}", path.to_string_lossy());
    }
}

/// Appends `line` to the rerun log, which must be an absolute path (the tests run in their crate's folder).
fn append(path: &std::path::Path, line: &str) -> std::io::Result<()> {
    if !path.is_absolute() {
        return Err(std::io::Error::other("not an absolute path (the tests run in their crate's folder)"));
    }
    let mut f = std::fs::OpenOptions::new().create(true).append(true).open(path)?;
    writeln!(f, "{line}")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rerun_log_takes_an_absolute_path_only_and_appends_one_line_per_rerun() {
        let err = append(std::path::Path::new("target/reruns.log"), "RERUN x: y").unwrap_err();
        assert!(err.to_string().contains("absolute"), "{err}");
        let path = std::env::temp_dir().join(format!("stall-witness-reruns-{}.log", std::process::id()));
        let _ = std::fs::remove_file(&path);
        append(&path, "RERUN a: one").unwrap();
        append(&path, "RERUN b: two").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "RERUN a: one\nRERUN b: two\n");
        std::fs::remove_file(&path).unwrap();
    }
}
