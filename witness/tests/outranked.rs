//! A thread of the code under test above the witness (as SVT-AV1's encoder threads at SCHED_FIFO 99 were, inside
//! marsd) takes a core as the machine would: the witness then excuses nothing. A test binary of its own: once
//! outranked, a process's witness stays so.

use std::time::Duration;

use stall_witness::{core_watch, hog, monotonic_ns, outrank, witness};

/// A thread named like the product's, pinned to `core` at SCHED_FIFO 99 for `ms`. False if it could not be.
fn product_thread_above_the_witness(core: usize, ms: u64) -> bool {
    let spawned = std::thread::Builder::new().name("marsd-record".into()).spawn(move || {
        let raised = hog::pin_at_fifo_99(core);
        if raised {
            hog::spin_for(ms);
        }
        // Then asleep, still above the witness, for its scan to see.
        std::thread::sleep(Duration::from_millis(3 * outrank::SCAN_MS));
        raised
    });
    spawned.is_ok_and(|t| t.join().unwrap_or(false))
}

#[test]
fn a_stall_made_by_a_thread_above_the_witness_excuses_nothing() {
    let w = witness();
    if let Some(why) = w.unable() {
        eprintln!("the witness cannot witness here: {why}");
        return;
    }
    std::thread::sleep(Duration::from_millis(20));
    let from = monotonic_ns();
    assert!(product_thread_above_the_witness(0, 40), "a root test run can take SCHED_FIFO 99");
    let to = monotonic_ns();
    let seen = w.seen_in(from, to).expect("watched");
    eprintln!("{seen}");
    assert!(seen.lateness.unwrap().longest_ms >= 30.0, "the witness was late: {seen}");
    let o = seen.outranked.expect("the thread above the witness was seen");
    assert_eq!((o.name().as_str(), o.priority, o.pid), ("marsd-record", 99, std::process::id() as i32));
    assert_eq!(seen.stalled_ms(), 0.0);
    assert!(w.excuse("a failure", from, to, 1.0).is_none(), "{seen}");
    assert_eq!(w.lost_periods(0, from, to, core_watch::PERIOD_NS), 0);
    assert!(seen.to_string().contains("no evidence: pid"), "{seen}");
}
