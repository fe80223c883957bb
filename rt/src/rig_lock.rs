//! A machine-wide exclusive lock held by everything that runs a real-time rig (a SCHED_FIFO HAL with marsd: the
//! demo, the benchmark, every test that starts them) for as long as the rig runs: at most one such rig runs at
//! a time, across the threads of one process (cargo runs a binary's tests in parallel threads) and across
//! processes (test binaries, `cargo test` invocations, a demo started beside the tests). Two rigs at SCHED_FIFO
//! on a 2-core machine take each other's cores, and each would then see a stall of the other's making.
//!
//! It is std's `File::lock`, an flock(2) that the kernel releases when the holding process dies, so a killed run
//! never leaves it locked. The lock is re-entrant per thread (a test may start two rigs), and
//! [`rt_rig_lock_held`] lets a spawner check that its caller took it. A process started by one that holds the
//! lock for it (a test running `mars-hil demo`) is told so by [`HELD_BY_PARENT`] naming its parent's pid: its
//! own `rt_rig_lock` then returns at once instead of waiting for its parent forever.

use std::cell::RefCell;
use std::fs::{File, OpenOptions, TryLockError};
use std::marker::PhantomData;
use std::path::PathBuf;
use std::time::Instant;

/// Environment variable a lock holder sets, to its own pid, for the children it runs under its lock.
pub const HELD_BY_PARENT: &str = "MARS_RT_RIG_LOCK_HELD_BY_PID";

thread_local! {
    /// The locked file (`None` when the parent holds it for us) and how many guards of this thread hold it.
    static HELD: RefCell<Option<(Option<File>, u32)>> = const { RefCell::new(None) };
}

/// Whether this process's parent holds the lock for it (see [`HELD_BY_PARENT`]).
fn held_by_parent() -> bool {
    // SAFETY: getppid cannot fail.
    let parent = unsafe { libc::getppid() };
    std::env::var(HELD_BY_PARENT).ok().and_then(|v| v.parse::<i32>().ok()) == Some(parent)
}

/// Holds the lock until dropped (on the thread that took it).
#[must_use = "the lock is released when the guard is dropped"]
pub struct RtRigLock {
    /// Not `Send`: the count lives in the taking thread.
    _thread_bound: PhantomData<*const ()>,
}

/// The lock file: one per machine (per temp dir).
pub fn rt_rig_lock_path() -> PathBuf {
    std::env::temp_dir().join("mars-rt-rig.lock")
}

/// Takes the lock, waiting (and saying so on stderr) while another rig holds it.
pub fn rt_rig_lock() -> std::io::Result<RtRigLock> {
    HELD.with_borrow_mut(|held| {
        match held {
            Some((_, n)) => *n += 1,
            None if held_by_parent() => *held = Some((None, 1)),
            None => {
                let path = rt_rig_lock_path();
                let named = |e: std::io::Error| std::io::Error::new(e.kind(), format!("{}: {e}", path.display()));
                let file = OpenOptions::new().create(true).truncate(false).write(true).open(&path).map_err(named)?;
                match file.try_lock() {
                    Ok(()) => {}
                    Err(TryLockError::WouldBlock) => {
                        let waited = Instant::now();
                        eprintln!("waiting for {}: another real-time rig is running", path.display());
                        file.lock().map_err(named)?;
                        eprintln!("waited {:.1} s for {}", waited.elapsed().as_secs_f64(), path.display());
                    }
                    Err(TryLockError::Error(e)) => return Err(named(e)),
                }
                *held = Some((Some(file), 1));
            }
        }
        Ok(RtRigLock { _thread_bound: PhantomData })
    })
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
