//! Heap allocations on the real-time threads: counted in every run, and kept away from the system allocator.
//!
//! The binaries install [`CountingAlloc`] as the global allocator: a thread-local counter in front of the system
//! allocator, so `marsd` reports in every run (not only in a test) how many allocations its servo thread made
//! after warm-up. Our own tick code makes none. iceoryx2 0.10 does make one small allocation per published
//! sample (the reference-counted bookkeeping of a loaned chunk, `ChunkMutSharedState`), which no public API
//! avoids; so a thread that calls [`arm_rt_pool`] gets such small blocks from a preallocated pool instead —
//! a lock-free queue of free block indices over a fixed slab: O(1), no lock, no syscall, no page fault (the slab
//! is touched at arming and locked by mlockall). The report counts both: system-allocator calls on the servo
//! thread after warm-up must be 0; pooled blocks are reported beside them.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::OnceLock;
use std::sync::atomic::{AtomicBool, Ordering};

use crossbeam_queue::ArrayQueue;

/// Size and alignment of a pool block: iceoryx2's per-sample state is well below this.
const BLOCK: usize = 128;
/// Blocks in the pool: far more than are ever live at once (one per sample in flight).
const BLOCKS: usize = 1024;

thread_local! {
    // `const` initialisation: reading these never allocates (no lazy init), which an allocator requires.
    static SYSTEM_ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    static POOLED_ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
    static USES_POOL: Cell<bool> = const { Cell::new(false) };
}

static INSTALLED: AtomicBool = AtomicBool::new(false);

#[repr(C, align(128))]
struct Block([u8; BLOCK]);

struct Pool {
    slab: Box<[Block]>,
    free: ArrayQueue<u16>,
}

static POOL: OnceLock<Pool> = OnceLock::new();

impl Pool {
    fn contains(&self, ptr: *mut u8) -> Option<usize> {
        let start = self.slab.as_ptr() as usize;
        let p = ptr as usize;
        (p >= start && p < start + BLOCKS * BLOCK).then(|| (p - start) / BLOCK)
    }
}

/// The system allocator, counting per thread; small blocks of armed threads come from the pool.
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
        if POOL.get().and_then(|pool| pool.contains(ptr)).is_some() {
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
        if let Some(pool) = POOL.get()
            && let Some(i) = pool.contains(ptr)
        {
            // Never full: it holds every index and each is pushed once per pop.
            let _ = pool.free.push(i as u16);
            return;
        }
        // SAFETY: not a pool block, so the system allocator's.
        unsafe { System.dealloc(ptr, layout) }
    }
}

fn pooled(layout: Layout) -> Option<*mut u8> {
    if layout.size() > BLOCK || layout.align() > BLOCK || !USES_POOL.try_with(Cell::get).unwrap_or(false) {
        return None;
    }
    let pool = POOL.get()?;
    let i = pool.free.pop()? as usize;
    let _ = POOLED_ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
    Some(pool.slab[i].0.as_ptr().cast_mut())
}

fn count_system() {
    // `try_with`: during thread teardown the slot may be gone; such allocations are not in any loop.
    let _ = SYSTEM_ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
    if !INSTALLED.load(Ordering::Relaxed) {
        INSTALLED.store(true, Ordering::Relaxed);
    }
}

/// Small allocations of the calling thread come from the preallocated pool from now on. Call at a real-time
/// thread's setup (it allocates the pool the first time).
pub fn arm_rt_pool() {
    POOL.get_or_init(|| {
        let slab: Box<[Block]> = (0..BLOCKS).map(|_| Block([0; BLOCK])).collect();
        let free = ArrayQueue::new(BLOCKS);
        for i in 0..BLOCKS {
            let _ = free.push(i as u16);
        }
        Pool { slab, free }
    });
    USES_POOL.with(|u| u.set(true));
}

/// The calling thread's counts so far, or `None` if [`CountingAlloc`] is not this process's global allocator
/// (then nothing is counted and no claim can be made).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize)]
pub struct Counts {
    /// Calls that reached the system allocator.
    pub system: u64,
    /// Small blocks served from the real-time pool.
    pub pooled: u64,
}

pub fn thread_counts() -> Option<Counts> {
    INSTALLED
        .load(Ordering::Relaxed)
        .then(|| Counts { system: SYSTEM_ALLOCATIONS.with(Cell::get), pooled: POOLED_ALLOCATIONS.with(Cell::get) })
}
