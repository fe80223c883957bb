//! When a reflex on franka-sim is the simulator's timing rather than the HAL: the rule the franka-sim tests (the
//! HAL's and the runtime's) run again by, read from the HAL's own report, so both apply it alike.
//!
//! franka-sim is a Python process; on a loaded 2-core machine it runs at a third to two thirds of real time some
//! days and delivers states irregularly. After such states the HAL can only guess which command franka-sim applied
//! (it applies late commands, unlike an FR3 — `setpoint_sync`), and a wrong guess reads to the robot as a
//! discontinuity. The evidence is tied to each reflex: its report gives how regularly the states came in the 64
//! cycles before it ([`super::recent_cycles::Regularity`]).

/// What a test did to the robot's state stream itself, so that only the rest counts as evidence.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Injected {
    Nothing,
    /// The HAL stopped for several ms at a time: the states it never saw then come in stretches of more than
    /// [`super::recent_cycles::SHORT_STRETCH`], and commands reach the robot after their cycle.
    LongStalls,
}

/// Whether every reflex in the HAL's report (`hal_out`, its stdout) followed irregular states the test did not
/// make: in the 64 cycles before it the simulator delivered states bunched (two within half a period: it caught up
/// after a pause of its own), or, beyond what the test injected, states the HAL never saw or commands that reached
/// it after their cycle (its success rate fell). The reflex lines, or `None` without a reflex or when any reflex
/// lacks that evidence.
pub fn reflexes_follow_irregular_states(hal_out: &str, injected: Injected) -> Option<String> {
    let reflexes: Vec<&str> = hal_out.lines().filter(|l| l.trim_start().starts_with("reflex ")).collect();
    if reflexes.is_empty() {
        return None;
    }
    for line in &reflexes {
        let tail = &line[line.find("cycles before it:")?..];
        let unseen = number_after(tail, "cycles before it:")?;
        let short = number_after(tail, "at once;")?;
        let bunched = number_after(tail, "),")?;
        let rate_falls = number_after(tail, "success rate fell")?;
        let explained = bunched > 0.0
            || match injected {
                Injected::Nothing => unseen > 0.0 || rate_falls > 0.0,
                Injected::LongStalls => short > 0.0,
            };
        if !explained {
            return None;
        }
    }
    Some(reflexes.iter().map(|l| l.trim()).collect::<Vec<_>>().join("\n"))
}

/// The number after `name` in `text` ("min 0.970" → 0.97), as the HAL's report prints it.
pub fn number_after(text: &str, name: &str) -> Option<f64> {
    let rest = &text[text.find(name)? + name.len()..];
    rest.split_whitespace().next()?.trim_end_matches([',', ';']).parse().ok()
}

/// Attempts a franka-sim test may take: a reflex explained as above came in about one run of the runtime's
/// franka-sim tests in three on the slow days (README).
pub const ATTEMPTS: u32 = 3;

/// Runs `attempt` (given its number) up to [`ATTEMPTS`] times: an attempt that returns false (spoiled by
/// franka-sim's timing, its evidence printed) is run again; the last must pass.
pub fn with_reruns(what: &str, attempt: impl Fn(u32) -> bool) {
    for n in 1..=ATTEMPTS {
        if attempt(n) {
            return;
        }
    }
    panic!("{what}: {ATTEMPTS} runs in a row were spoiled by franka-sim's timing (see above)");
}

/// On an attempt before the last whose HAL report (`hal_out`) shows reflexes that franka-sim's irregular states
/// explain: prints the evidence, with the cycles before each reflex from the HAL's log (`hal_log`), and says so
/// (the caller returns false to run again).
pub fn rerun_for_irregular_states(attempt: u32, what: &str, hal_out: &str, hal_log: &str, injected: Injected) -> bool {
    let why = if attempt < ATTEMPTS { reflexes_follow_irregular_states(hal_out, injected) } else { None };
    if let Some(why) = &why {
        let cycles: Vec<&str> =
            hal_log.lines().filter(|l| l.contains("before the reflex") || l.contains("    period ")).collect();
        eprintln!(
            "RERUN {what}: attempt {attempt} is inconclusive: franka-sim's states came irregularly before each \
             reflex:\n{why}\n{}",
            cycles.join("\n")
        );
    }
    why.is_some()
}

#[cfg(test)]
mod tests {
    use super::super::recent_cycles::Regularity;
    use super::*;

    /// The rule on the HAL's own report text (its `Regularity`), without a simulator.
    #[test]
    fn a_reflex_counts_as_franka_sims_only_after_states_the_test_did_not_make_irregular() {
        let report = |r: Regularity| {
            format!(
                "  robot 127.0.0.1: 900 cycles, 1 reflexes\n  reflex 1: \
                 joint_motion_generator_acceleration_discontinuity (27 cycles after the last setpoint resync, over 0 \
                 unseen states, from LateOverCycles(4)); {r}\n"
            )
        };
        let regular = Regularity { cycles: 64, ..Default::default() };
        let stall = Regularity { unseen: 7, longest_unseen: 7, ..regular };
        let hiccup = Regularity { unseen: 8, longest_unseen: 7, short_unseen: 1, ..regular };
        let bunched = Regularity { bunched: 1, ..stall };
        let late_command = Regularity { rate_falls: 1, ..regular };
        // A command that reached franka-sim late: the machine's, unless the test stopped the HAL itself.
        assert!(reflexes_follow_irregular_states(&report(late_command), Injected::Nothing).is_some());
        assert!(reflexes_follow_irregular_states(&report(late_command), Injected::LongStalls).is_none());
        for injected in [Injected::Nothing, Injected::LongStalls] {
            assert!(reflexes_follow_irregular_states(&report(regular), injected).is_none());
            assert!(reflexes_follow_irregular_states(&report(hiccup), injected).is_some());
            assert!(reflexes_follow_irregular_states(&report(bunched), injected).is_some());
        }
        // An 8 ms stop the test injected explains nothing in that test; elsewhere it is the machine's.
        assert!(reflexes_follow_irregular_states(&report(stall), Injected::LongStalls).is_none());
        assert!(reflexes_follow_irregular_states(&report(stall), Injected::Nothing).is_some());
        // No reflex, or one without the account: no evidence.
        let none = "  robot 127.0.0.1: 900 cycles, 0 reflexes";
        assert!(reflexes_follow_irregular_states(none, Injected::Nothing).is_none());
        assert!(reflexes_follow_irregular_states("  reflex 1: joint_reflex", Injected::Nothing).is_none());
    }
}
