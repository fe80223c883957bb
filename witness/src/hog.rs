//! A stall made on purpose, for tests of what should see one (the witness itself, `marsd doctor`).

use std::time::{Duration, Instant};

/// Takes `core` for `ms` from everything below SCHED_FIFO 99 (the witness's 95, the loops' 85/80/70/60), from a
/// thread of its own pinned there; returns when done. False if this process may not pin or raise a thread.
pub fn take_core(core: usize, ms: u64) -> bool {
    take_core_for(core, Duration::from_millis(ms))
}

/// [`take_core`] for any span (a stall shorter than a millisecond).
pub fn take_core_for(core: usize, span: Duration) -> bool {
    // Named so the witness knows it for a stall made on purpose, not a thread of the code under test above it.
    let hog = std::thread::Builder::new().name(crate::outrank::HOG_NAME.into());
    let Ok(hog) = hog.spawn(move || {
        let raised = pin_at_fifo_99(core);
        if raised {
            spin(span);
        }
        raised
    }) else {
        return false;
    };
    hog.join().unwrap_or(false)
}

/// Pins the calling thread to `core` and raises it to SCHED_FIFO 99; false if either was refused.
pub fn pin_at_fifo_99(core: usize) -> bool {
    crate::core_watch::pin(core).is_ok() && crate::core_watch::sched_fifo(99).is_ok()
}

/// Busy for `ms`, never yielding.
pub fn spin_for(ms: u64) {
    spin(Duration::from_millis(ms))
}

/// Busy for `span`, never yielding.
fn spin(span: Duration) {
    let end = Instant::now() + span;
    while Instant::now() < end {
        std::hint::spin_loop();
    }
}
