//! A machine-wide exclusive lock held by every test that starts real-time processes (a SCHED_FIFO HAL, marsd),
//! for the whole test: at most one such rig runs at a time, across the tests of one binary (cargo runs them in
//! parallel threads) and across test binaries and `cargo test` invocations (other processes). Two rigs at
//! SCHED_FIFO on a 2-core machine take each other's cores, and a test would then see a stall of its own making.
//!
//! One file, included with `#[path]` by `hal/tests/process.rs` and `runtime/tests/common` (no crate, no
//! feature: it is a few lines on std's `File::lock`, an flock(2) that the kernel releases when the holding
//! process dies, so a killed test run never leaves it locked). The lock is re-entrant per thread (a test may
//! start two rigs), and [`rt_rig_lock_held`] lets a spawner check that its test took it.

use std::cell::RefCell;
use std::fs::{File, OpenOptions, TryLockError};
use std::marker::PhantomData;
use std::path::PathBuf;
use std::time::Instant;

thread_local! {
    /// The locked file and how many guards of this thread hold it.
    static HELD: RefCell<Option<(File, u32)>> = const { RefCell::new(None) };
}

/// Holds the lock until dropped (on the thread that took it).
#[must_use = "the lock is released when the guard is dropped"]
pub struct RtRigLock {
    /// Not `Send`: the count lives in the taking thread.
    _thread_bound: PhantomData<*const ()>,
}

/// The lock file: one per machine (per temp dir), not the `/tmp/mars-rt-tests.lock` a developer may hold
/// around the whole `cargo test` with flock(1): a test taking that one would wait for itself.
pub fn rt_rig_lock_path() -> PathBuf {
    std::env::temp_dir().join("mars-rt-rig.lock")
}

/// Takes the lock, waiting (and saying so on stderr) while another test or process holds it.
pub fn rt_rig_lock() -> RtRigLock {
    HELD.with_borrow_mut(|held| match held {
        Some((_, n)) => *n += 1,
        None => {
            let path = rt_rig_lock_path();
            let file = OpenOptions::new()
                .create(true)
                .truncate(false)
                .write(true)
                .open(&path)
                .unwrap_or_else(|e| panic!("opening {}: {e}", path.display()));
            match file.try_lock() {
                Ok(()) => {}
                Err(TryLockError::WouldBlock) => {
                    let waited = Instant::now();
                    file.lock().unwrap_or_else(|e| panic!("locking {}: {e}", path.display()));
                    eprintln!(
                        "waited {:.1} s for {} (another real-time rig was running)",
                        waited.elapsed().as_secs_f64(),
                        path.display()
                    );
                }
                Err(TryLockError::Error(e)) => panic!("locking {}: {e}", path.display()),
            }
            *held = Some((file, 1));
        }
    });
    RtRigLock { _thread_bound: PhantomData }
}

/// Whether this thread holds the lock.
pub fn rt_rig_lock_held() -> bool {
    HELD.with_borrow(Option::is_some)
}

impl Drop for RtRigLock {
    fn drop(&mut self) {
        HELD.with_borrow_mut(|held| {
            if let Some((_, n)) = held {
                *n -= 1;
                if *n == 0 {
                    // Closing the file releases the flock.
                    *held = None;
                }
            }
        });
    }
}
