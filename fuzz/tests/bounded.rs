//! CI's share of the fuzzing: a bounded number of cases of every target (seeded, so the same cases every run),
//! none of which may panic, abort, ask for more than the allocation cap, or hang. The long runs are
//! `cargo run --release -p mars-fuzz -- all --cases 10000000 --seed 1` (README's "Fuzzing").

use std::time::Duration;

use mars_fuzz::runner::{Options, run};

#[global_allocator]
static ALLOC: mars_fuzz::guard::CappedAlloc = mars_fuzz::guard::CappedAlloc;

/// Cases per target: the slowest targets (a whole checkpoint, a dataset on disk) take about a millisecond a case
/// in a test build, so this keeps the whole test to well under a minute on two cores.
const CASES: u64 = 1500;

#[test]
fn no_decoder_panics_aborts_or_hangs_on_a_mutated_input() {
    let out = std::env::temp_dir().join(format!("mars-fuzz-ci-{}", std::process::id()));
    let opts = Options {
        first_case: 0,
        cases: CASES,
        seed: 1,
        out: out.clone(),
        case_timeout: Duration::from_secs(30),
        progress: None,
        time_limit: None,
    };
    let mut failed = Vec::new();
    for target in mars_fuzz::targets::all() {
        let report = run(target, &opts);
        println!("{report}");
        assert_eq!(report.cases, CASES);
        if !report.failures.is_empty() {
            failed.push(report.to_string());
        }
    }
    assert!(failed.is_empty(), "failures (inputs saved under {}):\n{}", out.display(), failed.join("\n"));
    let _ = std::fs::remove_dir_all(out);
}

/// The mutants start from inputs every check accepts: an unmutated seed refused would mean the target fuzzes a
/// decoder's first refusal, not its depth.
#[test]
fn every_target_accepts_its_seeds_as_they_are() {
    for target in mars_fuzz::targets::all() {
        let seeds = target.seeds();
        assert!(!seeds.is_empty(), "{}", target.name());
        for (i, seed) in seeds.iter().enumerate() {
            assert!(target.run(seed), "{}: seed {i} ({} bytes) is refused", target.name(), seed.len());
        }
    }
}
