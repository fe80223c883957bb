//! The harness finds what it is there to find: a panic (named by where, its first input saved, its repeats
//! counted), an allocation above the cap, and the same failures again from the same seed.

use std::sync::Arc;
use std::time::Duration;

use mars_fuzz::runner::{Options, Target, run};
use rand::Rng;
use rand::rngs::StdRng;

#[global_allocator]
static ALLOC: mars_fuzz::guard::CappedAlloc = mars_fuzz::guard::CappedAlloc;

/// Panics on a first byte of 7, asks for 2 GiB (through `try_reserve`, which survives the refusal) on a 3.
struct Planted;

impl Target for Planted {
    fn name(&self) -> &'static str {
        "planted"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        vec![rng.random_range(0..16u8)]
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        vec![vec![0]]
    }

    fn run(&self, input: &[u8]) -> bool {
        match input[0] {
            7 => panic!("planted bug"),
            3 => {
                let mut v: Vec<u8> = Vec::new();
                assert!(v.try_reserve(2 << 30).is_err(), "the cap refuses 2 GiB");
            }
            _ => {}
        }
        true
    }
}

/// The allocation cap's refusals are counted process-wide, so this file's runs take turns.
static ONE_RUN_AT_A_TIME: std::sync::Mutex<()> = std::sync::Mutex::new(());

#[test]
fn a_planted_panic_and_a_huge_allocation_are_found_saved_and_reproducible() {
    let _turn = ONE_RUN_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let out = tempfile::tempdir().unwrap();
    let opts = Options {
        first_case: 0,
        cases: 400,
        seed: 5,
        out: out.path().to_owned(),
        case_timeout: Duration::from_secs(10),
        progress: None,
        time_limit: None,
    };
    let report = run(Arc::new(Planted), &opts);
    println!("{report}");
    assert_eq!(report.failures.len(), 2, "{report}");
    let panic = report.failures.iter().find(|f| f.what.contains("planted bug")).expect("the panic");
    assert!(panic.what.contains("harness.rs"), "named by where: {}", panic.what);
    assert_eq!(std::fs::read(&panic.input).unwrap(), [7]);
    assert!(panic.count > 5, "each of ~25 hits counted: {}", panic.count);
    let alloc = report.failures.iter().find(|f| f.what.contains("bytes at once")).expect("the allocation");
    assert_eq!(std::fs::read(&alloc.input).unwrap(), [3]);
    let again = run(Arc::new(Planted), &opts);
    let firsts = |r: &mars_fuzz::runner::Report| r.failures.iter().map(|f| (f.first_case, f.count)).collect::<Vec<_>>();
    assert_eq!(firsts(&report), firsts(&again), "the same seed, the same cases");
}

#[test]
fn a_run_resumed_from_its_next_case_makes_the_same_cases_as_one_unbroken_run() {
    let _turn = ONE_RUN_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    let out = tempfile::tempdir().unwrap();
    let opts = |first_case, cases| Options {
        first_case,
        cases,
        seed: 9,
        out: out.path().to_owned(),
        case_timeout: Duration::from_secs(10),
        progress: None,
        time_limit: None,
    };
    let hits = |r: &mars_fuzz::runner::Report| {
        let mut v: Vec<(String, u64)> = r.failures.iter().map(|f| (f.what.clone(), f.count)).collect();
        v.sort();
        v
    };
    let whole = run(Arc::new(Planted), &opts(0, 300));
    let (first, rest) = (run(Arc::new(Planted), &opts(0, 130)), run(Arc::new(Planted), &opts(130, 170)));
    assert_eq!((first.cases, rest.cases, rest.first_case), (130, 170, 130));
    assert!(rest.to_string().contains("[cases 130..300]"), "{rest}");
    let mut halves: Vec<(String, u64)> = hits(&first);
    for (what, n) in hits(&rest) {
        match halves.iter_mut().find(|(w, _)| *w == what) {
            Some(h) => h.1 += n,
            None => halves.push((what, n)),
        }
    }
    halves.sort();
    assert_eq!(hits(&whole), halves, "cases 0..130 and 130..300 are cases 0..300");
    let first_hit = |r: &mars_fuzz::runner::Report| r.failures.iter().map(|f| f.first_case).min();
    assert!(first_hit(&rest).is_some_and(|c| c >= 130), "the resumed run starts at its first case");
}
