//! ns per servo tick of the ruckig smoother (7 DoF, FR3 limits, 1 kHz) against the official ruckig crate on the same
//! target stream: a new target every tick (the servo's moving reference), so every tick re-plans. Also counts
//! heap allocations per update on both sides: Rust's through a counting global allocator, and every `malloc`
//! call of the process (Rust's and the official crate's C++ core alike) through a `malloc` defined in this
//! binary, which the dynamic linker binds ahead of glibc's for every library (the C++ core's `operator new`
//! included); it forwards to glibc's `__libc_malloc`.
//!
//! `nice -n 19 cargo bench -p mars-runtime --bench smoothing`

use std::alloc::{GlobalAlloc, Layout, System};
use std::hint::black_box;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use mars_profile::Profile;
use mars_runtime::servo::smoothing::{DEFAULT_SAFETY_FACTOR, Limits, Smoother};

const TICKS: usize = 20_000;
const ROUNDS: usize = 3;

/// One smoother under test, fed (position, velocity) targets tick by tick.
type Tracker = Box<dyn FnMut(&[f64; 7], &[f64; 7])>;

/// A seeded moving reference: new linear segment every 200 ticks (xorshift, so no dev-dependency).
fn targets(home: &[f64], dq_max: &[f64]) -> Vec<([f64; 7], [f64; 7])> {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut sym = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let (mut q, mut v) = ([0.0; 7], [0.0; 7]);
    (0..TICKS)
        .map(|k| {
            if k % 200 == 0 {
                for i in 0..7 {
                    q[i] = home[i] + sym();
                    v[i] = 0.5 * DEFAULT_SAFETY_FACTOR * dq_max[i] * sym();
                }
            }
            for i in 0..7 {
                q[i] += v[i] * 1e-3;
            }
            (q, v)
        })
        .collect()
}

static RUST_ALLOCATIONS: AtomicU64 = AtomicU64::new(0);
static MALLOC_CALLS: AtomicU64 = AtomicU64::new(0);

struct CountingRust;

unsafe impl GlobalAlloc for CountingRust {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        RUST_ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: forwarded unchanged.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: forwarded unchanged.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        RUST_ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: forwarded unchanged.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: CountingRust = CountingRust;

unsafe extern "C" {
    fn __libc_malloc(size: usize) -> *mut libc::c_void;
}

/// Every `malloc` of the process, counted (Rust's `System` allocator calls it too, for small alignments).
///
/// # Safety
/// The C `malloc` contract; forwards to glibc's implementation, so glibc's `free` releases the block.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn malloc(size: usize) -> *mut libc::c_void {
    MALLOC_CALLS.fetch_add(1, Ordering::Relaxed);
    // SAFETY: glibc's own malloc, same contract.
    unsafe { __libc_malloc(size) }
}

/// Allocations per call of `f` over `calls` calls: (Rust allocator, all `malloc` calls).
fn allocations_per_call(calls: usize, mut f: impl FnMut(usize)) -> (f64, f64) {
    let (r0, m0) = (RUST_ALLOCATIONS.load(Ordering::Relaxed), MALLOC_CALLS.load(Ordering::Relaxed));
    for i in 0..calls {
        f(i);
    }
    let (r1, m1) = (RUST_ALLOCATIONS.load(Ordering::Relaxed), MALLOC_CALLS.load(Ordering::Relaxed));
    ((r1 - r0) as f64 / calls as f64, (m1 - m0) as f64 / calls as f64)
}

fn report(name: &str, mut ns: Vec<u64>) {
    ns.sort_unstable();
    let at = |f: f64| ns[((ns.len() - 1) as f64 * f) as usize];
    println!(
        "{name:<40} median {:>6} ns   p99 {:>6} ns   max {:>8} ns   ({} ticks)",
        at(0.5),
        at(0.99),
        at(1.0),
        ns.len()
    );
}

/// marsd's smoother at rest at the profile's home.
fn ours(p: &Profile) -> Smoother {
    let mut s = Smoother::new(7, p.period_s(), &Limits::from_profile(p)).unwrap();
    s.reset(&p.home).expect("the profile's home is a valid start");
    s
}

/// The official crate on the same problem: one online update per tick, as marsd would use it.
struct Official {
    otg: ruckig::Ruckig,
    inp: ruckig::InputParameter,
    out: ruckig::OutputParameter,
}

impl Official {
    fn new(p: &Profile) -> Self {
        let mut inp = ruckig::InputParameter::new(7);
        for i in 0..7 {
            inp.current_position[i] = p.home[i];
            inp.max_velocity[i] = DEFAULT_SAFETY_FACTOR * p.dq_max[i];
            inp.max_acceleration[i] = DEFAULT_SAFETY_FACTOR * p.ddq_max[i];
            inp.max_jerk[i] = DEFAULT_SAFETY_FACTOR * p.jerk_max[i];
        }
        let (otg, out) = (ruckig::Ruckig::new_direct(7, p.period_s()), ruckig::OutputParameter::new_direct(7));
        Self { otg, inp, out }
    }

    fn step(&mut self, q: &[f64; 7], v: &[f64; 7]) {
        self.inp.target_position.copy_from_slice(q);
        self.inp.target_velocity.copy_from_slice(v);
        black_box(self.otg.update(&mut self.inp, &mut self.out));
        self.out.pass_to_input(&mut self.inp);
    }
}

/// ns per tick over [`ROUNDS`] passes of the stream, each from a fresh smoother.
fn time_per_tick(
    stream: &[([f64; 7], [f64; 7])],
    mut fresh: impl FnMut() -> Box<dyn FnMut(&[f64; 7], &[f64; 7])>,
) -> Vec<u64> {
    let mut ns = Vec::with_capacity(TICKS * ROUNDS);
    for _ in 0..ROUNDS {
        let mut step = fresh();
        for (q, v) in stream {
            let t = Instant::now();
            step(black_box(q), black_box(v));
            ns.push(t.elapsed().as_nanos() as u64);
        }
    }
    ns
}

fn print_allocations(rust: f64, all: f64) {
    println!("{:<40} allocations per update: {rust:.2} Rust, {all:.2} malloc calls in all", "");
}

fn main() {
    let p = Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")).unwrap();
    let stream = targets(&p.home, &p.dq_max);

    let fresh_ours = || -> Tracker {
        let mut s = ours(&p);
        Box::new(move |q, v| {
            black_box(s.track(q, v).unwrap());
        })
    };
    let fresh_official = || -> Tracker {
        let mut o = Official::new(&p);
        Box::new(move |q, v| o.step(q, v))
    };
    report("marsd Smoother::track (rsruckig, 8 slots)", time_per_tick(&stream, fresh_ours));
    let mut step = fresh_ours();
    let (rust, all) = allocations_per_call(stream.len(), |k| step(&stream[k].0, &stream[k].1));
    print_allocations(rust, all);

    report("official ruckig 0.19 update+pass_to_input", time_per_tick(&stream, fresh_official));
    let mut step = fresh_official();
    let (rust, all) = allocations_per_call(stream.len(), |k| step(&stream[k].0, &stream[k].1));
    print_allocations(rust, all);

    // The malloc counter is live (a C-side allocation shows up even when Rust's counter does not move).
    let (rust, all) = allocations_per_call(1, |_| {
        // SAFETY: plain malloc/free pair.
        unsafe { libc::free(black_box(libc::malloc(64))) };
    });
    assert_eq!((rust, all), (0.0, 1.0), "the malloc counter does not see C allocations");
}
