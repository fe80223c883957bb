//! Heap allocations on the real-time threads: counted in every run, and kept away from the system allocator.
//!
//! The binaries install [`CountingAlloc`] as the global allocator: a thread-local counter in front of the system
//! allocator, so `marsd` reports in every run (not only in a test) how many allocations its servo thread made
//! after warm-up. Our own tick code makes none. iceoryx2 0.10 does make one small allocation per published
//! sample (the reference-counted bookkeeping of a loaned chunk, `ChunkMutSharedState`), which no public API
//! avoids; so the servo loop wraps exactly its `send` in an [`RtPoolScope`], and only inside such a scope are
//! small blocks served from a preallocated pool: a fixed slab and an atomic bitmap of free blocks — no lock, no
//! syscall, no page fault (the slab is touched at [`init_rt_pool`] and locked by mlockall). Every other
//! allocation, on any thread, is a counted call to the system allocator. So the claim is exact: after warm-up
//! the servo thread makes 0 system-allocator calls and exactly one pooled allocation per sample sent.
//!
//! To find a loop's allocation, run with `MARS_ALLOC_TRACE=N` ([`TRACE_ENV`]): each loop thread prints the
//! backtrace of its first N system-allocator calls after warm-up (e.g. `MARS_ALLOC_TRACE=5 mars-hil demo …`).

use std::alloc::{GlobalAlloc, Layout, System};
use std::backtrace::Backtrace;
use std::cell::{Cell, UnsafeCell};
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, AtomicU32, AtomicU64, Ordering};

/// Size and alignment of a pool block: iceoryx2's per-sample state is well below this.
const BLOCK: usize = 128;
/// Words of the free bitmap; 64 blocks each. Far more blocks than are ever live at once (one per sample in
/// flight; the publisher keeps a handful).
const WORDS: usize = 4;
const BLOCKS: usize = WORDS * 64;

thread_local! {
    // `const` initialisation: reading these never allocates (no lazy init), which an allocator requires.
    static SYSTEM_ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    static POOLED_ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    static IN_SCOPE: Cell<bool> = const { Cell::new(false) };
    /// Backtraces still to print of this thread's system-allocator calls (see [`TRACE_ENV`]).
    static TRACE_LEFT: Cell<u32> = const { Cell::new(0) };
    /// Set while a backtrace is taken: its own allocations are the tracer's, neither traced nor counted.
    static TRACING: Cell<bool> = const { Cell::new(false) };
}

static INSTALLED: AtomicBool = AtomicBool::new(false);

#[repr(C, align(128))]
struct Block(UnsafeCell<[u8; BLOCK]>);

struct Pool {
    /// Written only through raw pointers from `UnsafeCell::get`, each block by its one current owner.
    slab: Box<[Block]>,
    /// Bit set = block in use. Taking a block is a compare-and-swap that only retries when another thread
    /// changed the word meanwhile (lock-free: nobody waits for a preempted thread); freeing is one `fetch_and`.
    used: [AtomicU64; WORDS],
}

// SAFETY: a block's bytes are reachable only through the pointer handed out by `take`, and the bitmap hands each
// block to one owner at a time (set by a successful CAS, cleared by that owner's dealloc).
unsafe impl Sync for Pool {}

static POOL: OnceLock<Pool> = OnceLock::new();

impl Pool {
    fn index_of(&self, ptr: *mut u8) -> Option<usize> {
        let start = self.slab.as_ptr() as usize;
        let p = ptr as usize;
        (p >= start && p < start + BLOCKS * BLOCK).then(|| (p - start) / BLOCK)
    }

    fn take(&self) -> Option<*mut u8> {
        for (w, word) in self.used.iter().enumerate() {
            let mut cur = word.load(Ordering::Relaxed);
            while cur != u64::MAX {
                let bit = (!cur).trailing_zeros() as usize;
                match word.compare_exchange_weak(cur, cur | 1 << bit, Ordering::Acquire, Ordering::Relaxed) {
                    Ok(_) => return Some(self.slab[w * 64 + bit].0.get().cast()),
                    Err(now) => cur = now,
                }
            }
        }
        None
    }

    fn give_back(&self, i: usize) {
        self.used[i / 64].fetch_and(!(1 << (i % 64)), Ordering::Release);
    }
}

/// The system allocator, counting per thread; small blocks inside an [`RtPoolScope`] come from the pool.
pub struct CountingAlloc;

unsafe impl GlobalAlloc for CountingAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if let Some(p) = pooled(layout) {
            return p;
        }
        count_system();
        // SAFETY: forwarded unchanged to the system allocator.
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if let Some(p) = pooled(layout) {
            // SAFETY: a pool block is BLOCK ≥ layout.size() bytes, exclusively ours.
            unsafe { p.write_bytes(0, layout.size()) };
            return p;
        }
        count_system();
        // SAFETY: as above.
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if POOL.get().and_then(|pool| pool.index_of(ptr)).is_some() {
            // Rare (a pooled block growing): move it to the system allocator.
            count_system();
            // SAFETY: the new layout is valid (GlobalAlloc contract); both regions are valid for the copy.
            unsafe {
                let new = System.alloc(Layout::from_size_align_unchecked(new_size, layout.align()));
                if !new.is_null() {
                    std::ptr::copy_nonoverlapping(ptr, new, layout.size().min(new_size));
                    self.dealloc(ptr, layout);
                }
                return new;
            }
        }
        count_system();
        // SAFETY: as above.
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // Any thread may free a pooled block (in or out of a scope): the address says where it came from.
        if let Some(pool) = POOL.get()
            && let Some(i) = pool.index_of(ptr)
        {
            pool.give_back(i);
            return;
        }
        // SAFETY: not a pool block, so the system allocator's.
        unsafe { System.dealloc(ptr, layout) }
    }
}

fn pooled(layout: Layout) -> Option<*mut u8> {
    if layout.size() > BLOCK || layout.align() > BLOCK || !IN_SCOPE.try_with(Cell::get).unwrap_or(false) {
        return None;
    }
    let p = POOL.get()?.take()?;
    let _ = POOLED_ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
    Some(p)
}

fn count_system() {
    if TRACING.try_with(Cell::get).unwrap_or(false) {
        return;
    }
    // `try_with`: during thread teardown the slot may be gone; such allocations are not in any loop.
    let _ = SYSTEM_ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
    if TRACE_LEFT.try_with(Cell::get).unwrap_or(0) > 0 {
        trace_this_call();
    }
    if !INSTALLED.load(Ordering::Relaxed) {
        INSTALLED.store(true, Ordering::Relaxed);
    }
}

/// A debug aid: with `MARS_ALLOC_TRACE=N` in the environment, a real-time thread's first N system-allocator calls
/// after its warm-up ([`warmed_up`]) each print their backtrace to stderr (`RUST_BACKTRACE` is not needed). Unset,
/// it costs the loop nothing: only a call that already broke the rule reads a thread-local.
pub const TRACE_ENV: &str = "MARS_ALLOC_TRACE";

/// N of [`TRACE_ENV`], read once at [`init_rt_pool`] (reading the environment allocates).
static TRACE_LIMIT: AtomicU32 = AtomicU32::new(0);

#[cold]
fn trace_this_call() {
    let _ = TRACING.try_with(|t| t.set(true));
    // The tracer's own blocks come from the system allocator, never from the pool a scope lent.
    let in_scope = IN_SCOPE.try_with(|s| s.replace(false)).unwrap_or(false);
    let _ = TRACE_LEFT.try_with(|c| c.set(c.get() - 1));
    let name = std::thread::current().name().map(str::to_owned).unwrap_or_default();
    eprintln!("{TRACE_ENV}: system-allocator call on thread {name:?} after warm-up:\n{}", Backtrace::force_capture());
    let _ = IN_SCOPE.try_with(|s| s.set(in_scope));
    let _ = TRACING.try_with(|t| t.set(false));
}

/// The calling real-time thread's counts at the end of its warm-up (as [`thread_counts`]); arms [`TRACE_ENV`]'s
/// backtraces for what it allocates from here on, until [`loop_ended`].
pub fn warmed_up() -> Option<Counts> {
    TRACE_LEFT.set(TRACE_LIMIT.load(Ordering::Relaxed));
    thread_counts()
}

/// The calling real-time thread's counts at the end of its loop (as [`thread_counts`]); what it allocates after
/// (its report) is not traced.
pub fn loop_ended() -> Option<Counts> {
    TRACE_LEFT.set(0);
    thread_counts()
}

/// Allocates and touches the pool (once per process). Call at a real-time thread's setup, not in its loop.
pub fn init_rt_pool() {
    if let Some(n) = std::env::var(TRACE_ENV).ok().and_then(|v| v.parse().ok()) {
        TRACE_LIMIT.store(n, Ordering::Relaxed);
    }
    POOL.get_or_init(|| Pool {
        slab: (0..BLOCKS).map(|_| Block(UnsafeCell::new([0; BLOCK]))).collect(),
        used: [const { AtomicU64::new(0) }; WORDS],
    });
}

/// While alive, small allocations of the calling thread come from the pool (once [`init_rt_pool`] ran).
/// Wrap exactly the call that must allocate (iceoryx2's `send`), so nothing else is served unnoticed.
#[must_use = "the pool is used only while the scope is alive"]
pub struct RtPoolScope {
    /// The thread's previous setting (scopes nest).
    was: bool,
    /// Bound to the thread whose flag it set.
    _not_send: std::marker::PhantomData<*const ()>,
}

impl RtPoolScope {
    pub fn enter() -> Self {
        let was = IN_SCOPE.with(|s| s.replace(true));
        Self { was, _not_send: std::marker::PhantomData }
    }
}

impl Drop for RtPoolScope {
    fn drop(&mut self) {
        IN_SCOPE.with(|s| s.set(self.was));
    }
}

/// The calling thread's counts so far, or `None` if [`CountingAlloc`] is not this process's global allocator
/// (then nothing is counted and no claim can be made).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct Counts {
    /// Calls that reached the system allocator.
    pub system: u64,
    /// Small blocks served from the real-time pool (inside an [`RtPoolScope`]).
    pub pooled: u64,
}

pub fn thread_counts() -> Option<Counts> {
    INSTALLED
        .load(Ordering::Relaxed)
        .then(|| Counts { system: SYSTEM_ALLOCATIONS.with(Cell::get), pooled: POOLED_ALLOCATIONS.with(Cell::get) })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[global_allocator]
    static ALLOC: CountingAlloc = CountingAlloc;

    /// The trace aid prints the first N calls after warm-up, and counts each exactly once: the tracer's own
    /// allocations (the backtrace, its text) are neither counted nor traced.
    #[test]
    fn a_traced_allocation_is_counted_once_and_the_tracer_s_own_are_not() {
        let counted = std::thread::spawn(|| {
            init_rt_pool();
            TRACE_LIMIT.store(1, Ordering::Relaxed);
            let c0 = warmed_up().expect("CountingAlloc is this binary's global allocator");
            let traced = std::hint::black_box(Box::new([0u8; 4096]));
            let c1 = thread_counts().unwrap();
            let untraced = std::hint::black_box(Box::new([0u8; 4096]));
            let c2 = loop_ended().unwrap();
            drop((traced, untraced));
            (c1.system - c0.system, c2.system - c1.system, TRACE_LEFT.with(Cell::get))
        })
        .join()
        .unwrap();
        assert_eq!(counted, (1, 1, 0));
    }
}
