//! What a panic cannot report: an abort (an allocation that failed, a stack overflow, `abort()`) or a request for
//! more memory than any input should cause. The input of the case in flight is registered here before it runs;
//! an allocation above [`ALLOCATION_CAP`] is refused and remembered (the runner makes the case a failure); when
//! the process is about to abort (SIGABRT), that input is written to the target's crash file with plain syscalls
//! (nothing here allocates or locks, so it works inside a signal handler) and the reason is printed.

use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicBool, AtomicPtr, AtomicUsize, Ordering};

/// The largest single allocation a case may ask for (1 GiB: the engine's own cap on its buffers). A larger request
/// is refused (null); Rust then aborts unless the caller handles it, and the case counts as a failure either way.
pub const ALLOCATION_CAP: usize = 1 << 30;

/// The global allocator of the fuzzer's binaries: the system's, with the cap.
pub struct CappedAlloc;

static INPUT_PTR: AtomicPtr<u8> = AtomicPtr::new(std::ptr::null_mut());
static INPUT_LEN: AtomicUsize = AtomicUsize::new(0);
/// A NUL-terminated path, written only between cases ([`arm`]) while `PATH_READY` is false.
static PATH: PathBuf = PathBuf(std::cell::UnsafeCell::new([0; 4096]));
static PATH_READY: AtomicBool = AtomicBool::new(false);
/// The size of the last refused allocation (0: none since [`take_refused`]).
static REFUSED: AtomicUsize = AtomicUsize::new(0);

struct PathBuf(std::cell::UnsafeCell<[u8; 4096]>);
// Safety: written only by `set_crash_path` while no reader may look (`PATH_READY` false), read-only afterwards.
unsafe impl Sync for PathBuf {}

/// Where the input of a case that aborts is written. Call between cases, from the thread that runs them.
pub fn set_crash_path(path: &std::path::Path) {
    PATH_READY.store(false, Ordering::SeqCst);
    let bytes = path.as_os_str().as_encoded_bytes();
    let n = bytes.len().min(4095);
    // Safety: no reader while PATH_READY is false (see `PathBuf`).
    let buf = unsafe { &mut *PATH.0.get() };
    buf[..n].copy_from_slice(&bytes[..n]);
    buf[n] = 0;
    PATH_READY.store(true, Ordering::SeqCst);
    install_abort_handler();
}

/// Registers `input` as the case in flight (it must stay alive until [`disarm`]).
pub fn arm(input: &[u8]) {
    INPUT_LEN.store(input.len(), Ordering::SeqCst);
    INPUT_PTR.store(input.as_ptr().cast_mut(), Ordering::SeqCst);
}

pub fn disarm() {
    INPUT_PTR.store(std::ptr::null_mut(), Ordering::SeqCst);
}

/// The size of an allocation refused since the last call, if any.
pub fn take_refused() -> Option<usize> {
    Some(REFUSED.swap(0, Ordering::SeqCst)).filter(|&n| n > 0)
}

/// Writes the input in flight to the crash path and `why` (and `n`, if any) to stderr. Signal- and
/// allocator-safe: plain syscalls on static data.
fn save_input(why: &[u8], n: Option<usize>) {
    let ptr = INPUT_PTR.load(Ordering::SeqCst);
    if ptr.is_null() || !PATH_READY.load(Ordering::SeqCst) {
        return;
    }
    let len = INPUT_LEN.load(Ordering::SeqCst);
    // Safety: the path is NUL-terminated and stays unchanged while PATH_READY; the input lives until `disarm`.
    unsafe {
        let path = PATH.0.get().cast::<libc::c_char>();
        let fd = libc::open(path, libc::O_WRONLY | libc::O_CREAT | libc::O_TRUNC, 0o644);
        if fd >= 0 {
            libc::write(fd, ptr.cast(), len);
            libc::close(fd);
        }
        let err = |b: &[u8]| libc::write(2, b.as_ptr().cast(), b.len());
        err(b"\nmars-fuzz: ");
        err(why);
        if let Some(n) = n {
            let mut digits = [0u8; 20];
            let mut i = digits.len();
            let mut v = n;
            loop {
                i -= 1;
                digits[i] = b'0' + (v % 10) as u8;
                v /= 10;
                if v == 0 {
                    break;
                }
            }
            err(&digits[i..]);
            err(b" bytes");
        }
        err(b"; the input is in ");
        err(std::slice::from_raw_parts(PATH.0.get().cast::<u8>(), libc::strlen(path)));
        err(b"\n");
    }
}

extern "C" fn on_abort(_: libc::c_int) {
    match REFUSED.load(Ordering::SeqCst) {
        0 => save_input(b"the process aborted (a failed allocation, a stack overflow or abort())", None),
        n => save_input(b"the process aborted on an allocation above the cap: ", Some(n)),
    }
    // Safety: restore the default action and re-raise, so the process still dies of SIGABRT.
    unsafe {
        libc::signal(libc::SIGABRT, libc::SIG_DFL);
        libc::raise(libc::SIGABRT);
    }
}

fn install_abort_handler() {
    static INSTALLED: AtomicBool = AtomicBool::new(false);
    if !INSTALLED.swap(true, Ordering::SeqCst) {
        // Safety: `on_abort` only makes async-signal-safe calls.
        unsafe { libc::signal(libc::SIGABRT, on_abort as *const () as libc::sighandler_t) };
    }
}

/// Refuses an allocation above the cap: remembered (the runner counts the case as a failure), and said with the
/// input saved should the process abort for it (Rust aborts on a refused allocation unless the caller handles it).
fn refuse(size: usize) -> *mut u8 {
    REFUSED.store(size, Ordering::SeqCst);
    std::ptr::null_mut()
}

// Safety: every call goes to `System` unchanged, or returns null (which `GlobalAlloc` allows for any request).
unsafe impl GlobalAlloc for CappedAlloc {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        if layout.size() > ALLOCATION_CAP { refuse(layout.size()) } else { unsafe { System.alloc(layout) } }
    }

    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        if layout.size() > ALLOCATION_CAP { refuse(layout.size()) } else { unsafe { System.alloc_zeroed(layout) } }
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        if new_size > ALLOCATION_CAP { refuse(new_size) } else { unsafe { System.realloc(ptr, layout, new_size) } }
    }
}

/// Copies the input in flight to `file` (from another thread, while the case's thread is stuck in it).
pub fn copy_input_to(file: &std::path::Path) {
    let ptr = INPUT_PTR.load(Ordering::SeqCst);
    if ptr.is_null() {
        return;
    }
    // Safety: the input stays alive until `disarm`, which the stuck thread has not reached.
    let input = unsafe { std::slice::from_raw_parts(ptr, INPUT_LEN.load(Ordering::SeqCst)) };
    let _ = std::fs::write(file, input);
}
