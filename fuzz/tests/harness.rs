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

#[test]
fn a_planted_panic_and_a_huge_allocation_are_found_saved_and_reproducible() {
    let out = tempfile::tempdir().unwrap();
    let opts = Options {
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
