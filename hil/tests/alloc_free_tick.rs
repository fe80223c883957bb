//! The servo tick makes no heap allocation: the very daemon code `marsd` runs (`daemon::prepare` +
//! `daemon::run`), in this process under the counting allocator, against the HAL loop in a thread of this
//! process, for two whole episodes (reset, ready, running, chunk handoffs, stop, hold). The only blocks the
//! servo thread may take are iceoryx2's one per sent sample, from the RT pool, inside `send`: anything else,
//! however small, is a system-allocator call and fails the test.

// The stall witness's rerun rule (and helpers this file does not use).
#[allow(unused_imports)]
mod common;

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use mars_hal::runner::RunOptions;
use mars_hal::sim::SimBackend;
use mars_profile::Profile;
use mars_runtime::alloc_count::{self, CountingAlloc, Counts};
use mars_runtime::config::DaemonConfig;
use mars_runtime::daemon;

// One real-time rig at a time on this machine, across test binaries (see the file).

#[global_allocator]
static ALLOC: CountingAlloc = CountingAlloc;

/// The control: the counter sees allocations made on purpose, on the system allocator or, inside an
/// `RtPoolScope`, from the real-time pool — and a small block on a real-time thread outside a scope is a
/// system allocation (the old pool served every small block of an armed thread, unnoticed).
#[test]
fn the_counter_sees_allocations_made_on_purpose() {
    let before = alloc_count::thread_counts().expect("CountingAlloc is this binary's global allocator");
    let v: Vec<u64> = std::hint::black_box(Vec::with_capacity(1000));
    let after = alloc_count::thread_counts().unwrap();
    drop(v);
    assert_eq!(after.system, before.system + 1, "{before:?} → {after:?}");

    let delta = |a: Counts, b: Counts| (b.system - a.system, b.pooled - a.pooled);
    let (outside, inside, big, freed_elsewhere) = std::thread::spawn(move || {
        alloc_count::init_rt_pool();
        let c0 = alloc_count::thread_counts().unwrap();
        let stray = std::hint::black_box(Box::new([0u8; 64]));
        let c1 = alloc_count::thread_counts().unwrap();
        let (small, c2) = {
            let _scope = alloc_count::RtPoolScope::enter();
            let small = std::hint::black_box(Box::new([0u8; 64]));
            (small, alloc_count::thread_counts().unwrap())
        };
        let big = {
            let _scope = alloc_count::RtPoolScope::enter();
            let big: Vec<u8> = std::hint::black_box(Vec::with_capacity(4096));
            big
        };
        let c3 = alloc_count::thread_counts().unwrap();
        // A pooled block freed on another thread goes back to the pool: the next scoped block is pooled again.
        std::thread::spawn(move || drop(small)).join().unwrap();
        let c3b = alloc_count::thread_counts().unwrap(); // (spawning the thread allocated)
        let again = {
            let _scope = alloc_count::RtPoolScope::enter();
            std::hint::black_box(Box::new([0u8; 64]))
        };
        let c4 = alloc_count::thread_counts().unwrap();
        drop((stray, big, again));
        (delta(c0, c1), delta(c1, c2), delta(c2, c3), delta(c3b, c4))
    })
    .join()
    .unwrap();
    assert_eq!(outside, (1, 0), "a small block outside a scope is a system allocation, even on an RT thread");
    assert_eq!(inside, (0, 1), "a small block inside a scope is pooled");
    assert_eq!(big, (1, 0), "a large one goes to the system allocator, scope or not");
    assert_eq!(freed_elsewhere, (0, 1));
}

/// Both real-time loops of a demo run, marsd's servo tick and the HAL's, as the demo runs them (the HAL in a
/// thread of this process, so its allocations are counted too).
#[test]
fn servo_tick_and_hal_loop_make_no_heap_allocation_over_two_episodes() {
    alloc_test(Start::Together);
}

/// The HAL appears after the servo loop's first ALLOC_WARMUP_TICKS ticks, as the fci HAL does (it connects to the
/// robot before it opens its ports: ~1.5 s on franka-sim) and the ros2 HAL (it waits for the robot's feedback):
/// iceoryx2's connection to it is set up in the servo's receive and send then, and belongs to the warm-up.
#[test]
fn a_hal_that_appears_after_the_servo_s_first_ticks_costs_the_servo_no_allocation_after_warm_up() {
    alloc_test(Start::HalLate);
}

/// marsd connects after the HAL loop's first WARMUP_TICKS ticks, as to a HAL that runs as a service: the same for
/// the HAL's loop.
#[test]
fn a_controller_that_connects_after_the_hal_s_first_ticks_costs_the_hal_no_allocation_after_warm_up() {
    alloc_test(Start::ControllerLate);
}

/// Which side of the rig starts first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Start {
    /// As the demo starts them: the HAL, then marsd at once.
    Together,
    /// The HAL [`LATE`] after marsd.
    HalLate,
    /// marsd's loops [`LATE`] after the HAL.
    ControllerLate,
}

impl Start {
    /// For the robot's namespace and the output directory.
    fn name(self) -> &'static str {
        match self {
            Start::Together => "together",
            Start::HalLate => "hal-late",
            Start::ControllerLate => "controller-late",
        }
    }
}

/// Well past either loop's warm-up (500 ticks at 1 kHz).
const LATE: Duration = Duration::from_secs(2);

fn alloc_test(start: Start) {
    let _rt = common::rt_rig_lock();
    let test = format!("allocation-free servo tick and HAL loop ({})", start.name());
    common::at_most_one_rerun(&test, |attempt| alloc_attempt(start, attempt));
}

/// One run; its excuse if marsd tripped on a timing check while the stall witness saw the machine stall around
/// the trip.
fn alloc_attempt(start: Start, attempt: u32) -> common::Attempt {
    let root = common::root();
    let robot = format!("t{}-alloc-{}{attempt}", std::process::id(), start.name());
    let profile = Profile::load(&root.join("configs/fr3.toml")).unwrap();
    profile.validate().unwrap();
    let stop_hal = Arc::new(AtomicBool::new(false));
    let hal = {
        let (profile, robot, stop) = (profile.clone(), robot.clone(), stop_hal.clone());
        let hal_core = DaemonConfig::load(&root.join("configs/marsd.toml")).unwrap().servo.core;
        std::thread::Builder::new()
            .name("hal".into())
            .spawn(move || {
                if start == Start::HalLate {
                    std::thread::sleep(LATE);
                }
                // As the demo runs it: a robot's own loop, real-time and above the servo loop on the servo's core
                // (at normal priority a busy machine starves it into a stale-state trip), its memory locked.
                let opts = RunOptions {
                    robot,
                    duration: Some(Duration::from_secs(600)),
                    core: hal_core,
                    rt_priority: Some(85),
                    lock_memory: true,
                    stop: Some(stop),
                    brake_before_exit: false,
                };
                mars_hal::runner::run(&profile, &mut SimBackend::new(&profile), &opts)
            })
            .unwrap()
    };
    let mut cfg = DaemonConfig::load(&root.join("configs/marsd.toml")).unwrap();
    for p in [&mut cfg.profile, &mut cfg.task, &mut cfg.checkpoint] {
        *p = root.join(&p);
    }
    let hal_spawned = std::time::Instant::now();
    let out = std::env::temp_dir().join(format!("mars-alloc-test-{}-{}", std::process::id(), start.name()));
    cfg.out = out.clone();
    cfg.robot = robot;
    cfg.episodes = 2;
    let prepared = daemon::prepare(cfg).unwrap();
    if start == Start::ControllerLate {
        // (marsd's servo opens its ports in `run`.)
        std::thread::sleep(LATE.saturating_sub(hal_spawned.elapsed()));
    }
    let outcome = daemon::run(prepared).unwrap();
    let s = &outcome.summary; // (daemon::run printed it)
    if outcome.exit == daemon::exit::TRIPPED
        && let (Some(trip), Some(trip_ns)) = (&s.trip, s.trip_seen_ns)
        && let Some(e) = common::trip_excuse(trip, trip_ns)
    {
        stop_hal.store(true, Ordering::Release);
        let _ = hal.join();
        let _ = std::fs::remove_dir_all(out);
        return Err(e);
    }
    assert_eq!(outcome.exit, daemon::exit::OK, "trip {:?}", s.trip);
    assert_eq!(s.episodes, 2);
    assert!(s.servo_ticks_counted > 5000, "only {} ticks counted", s.servo_ticks_counted);
    assert!(s.servo_samples_sent > 5000, "only {} samples sent", s.servo_samples_sent);
    assert_eq!(
        s.servo_allocations,
        Some(Counts { system: 0, pooled: s.servo_samples_sent }),
        "after warm-up the servo thread may take exactly one pooled block per sample sent ({}) and nothing else",
        s.servo_samples_sent
    );
    // summary.json says what real-time setup each loop thread got (the benchmark reads it from there), and the
    // wire's error counts, each class apart.
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let threads: Vec<&str> =
        json["realtime"].as_array().unwrap().iter().map(|t| t["thread"].as_str().unwrap()).collect();
    // The supervisor (which logs a trip) runs at watchdog.priority while the loops run: granted as the servo's was.
    assert_eq!(threads, ["servo", "policy", "supervisor"]);
    assert_eq!(json["realtime"][2]["sched_fifo"], json["realtime"][0]["sched_fifo"]);
    for key in ["sched_fifo", "memory_locked", "core", "pin_error"] {
        assert!(json["realtime"][0].get(key).is_some(), "no {key} in {}", json["realtime"][0]);
    }
    for ptr in ["/wire/schema_refusals", "/wire/receive_port_errors", "/wire/send_errors", "/wire/heartbeat/errors"] {
        assert_eq!(json.pointer(ptr).and_then(|v| v.as_u64()), Some(0), "{ptr}");
    }
    assert!(json.pointer("/wire/heartbeat/beats").and_then(|v| v.as_u64()).unwrap() > 100);
    let _ = std::fs::remove_dir_all(out);

    // The HAL's loop: after warm-up, one pooled block per state frame it published and nothing else.
    stop_hal.store(true, Ordering::Release);
    let report = hal.join().unwrap().unwrap();
    println!("{report}");
    let (counts, frames) = report.allocations_after_warmup.expect("the counting allocator is installed");
    assert!(frames > 5000, "only {frames} frames after warm-up");
    assert_eq!(
        counts,
        Counts { system: 0, pooled: frames },
        "after warm-up the HAL loop may take exactly one pooled block per frame published ({frames}) and nothing else"
    );
    assert_eq!(report.errors.total(), 0);
    Ok(())
}
