//! A global allocator that counts allocations, reallocations and deallocations made on threads that switched
//! counting on. Counting per thread (a thread-local flag) keeps the test harness's and other libraries'
//! threads out of the count. Shared by `tests/alloc_free.rs` and the benchmark; each declares
//! `#[global_allocator] static A: Counting = Counting;` itself.

#![allow(dead_code)]

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};

pub struct Counting;

static ALLOCS: AtomicUsize = AtomicUsize::new(0);
static REALLOCS: AtomicUsize = AtomicUsize::new(0);
static DEALLOCS: AtomicUsize = AtomicUsize::new(0);

thread_local! {
    // `const` and drop-free: reading it never allocates or registers a destructor, so it is safe inside the
    // allocator itself.
    static COUNTING: Cell<bool> = const { Cell::new(false) };
}

fn counting() -> bool {
    COUNTING.try_with(Cell::get).unwrap_or(false)
}

fn bump(counter: &AtomicUsize) {
    if counting() {
        counter.fetch_add(1, Ordering::Relaxed);
    }
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        bump(&ALLOCS);
        unsafe { System.alloc(layout) }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        bump(&ALLOCS);
        unsafe { System.alloc_zeroed(layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        bump(&REALLOCS);
        unsafe { System.realloc(ptr, layout, new_size) }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        bump(&DEALLOCS);
        unsafe { System.dealloc(ptr, layout) }
    }
}

/// What a piece of code did to the heap on its thread.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct Counts {
    pub allocs: usize,
    pub reallocs: usize,
    pub deallocs: usize,
}

/// Runs `f` with counting switched on for this thread.
pub fn count<R>(f: impl FnOnce() -> R) -> (R, Counts) {
    let read = || [&ALLOCS, &REALLOCS, &DEALLOCS].map(|c| c.load(Ordering::SeqCst));
    let before = read();
    COUNTING.with(|c| c.set(true));
    let r = f();
    COUNTING.with(|c| c.set(false));
    let after = read();
    let counts =
        Counts { allocs: after[0] - before[0], reallocs: after[1] - before[1], deallocs: after[2] - before[2] };
    (r, counts)
}
