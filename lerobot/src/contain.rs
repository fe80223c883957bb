//! A panic inside the parquet reader, contained: the parquet and arrow crates still panic on some corrupt files (an
//! `expect` in the column reader that a damaged page reaches; fuzzing finds them, see README's "Fuzzing"). A file
//! is the user's input, so such a panic becomes the file's error — with no panic message on stderr (the
//! previous panic hook is skipped while a decode runs on this thread) — and is counted, so the fuzzer can say how
//! many it contained.

use std::cell::Cell;
use std::panic::{AssertUnwindSafe, catch_unwind};
use std::sync::Once;
use std::sync::atomic::{AtomicU64, Ordering};

thread_local! {
    static DECODING: Cell<bool> = const { Cell::new(false) };
}

static CONTAINED: AtomicU64 = AtomicU64::new(0);

/// Panics of the parquet reader contained so far in this process.
pub fn contained_panics() -> u64 {
    CONTAINED.load(Ordering::Relaxed)
}

/// Runs `decode`; a panic in it is returned as its message.
pub(crate) fn decode<T>(decode: impl FnOnce() -> T) -> Result<T, String> {
    static HOOK: Once = Once::new();
    HOOK.call_once(|| {
        let previous = std::panic::take_hook();
        std::panic::set_hook(Box::new(move |info| {
            if !DECODING.with(Cell::get) {
                previous(info);
            }
        }));
    });
    let was = DECODING.with(|d| d.replace(true));
    let out = catch_unwind(AssertUnwindSafe(decode));
    DECODING.with(|d| d.set(was));
    out.map_err(|payload| {
        CONTAINED.fetch_add(1, Ordering::Relaxed);
        payload
            .downcast_ref::<&str>()
            .map(|s| (*s).to_owned())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "a panic without a message".into())
    })
}
