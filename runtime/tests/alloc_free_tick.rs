//! The servo tick makes no heap allocation: the very daemon code `marsd` runs (`daemon::prepare` +
//! `daemon::run`), in this process under the counting allocator, against the HAL loop in a thread of this
//! process, for two whole episodes (reset, ready, running, chunk handoffs, stop, hold).

use std::path::{Path, PathBuf};
use std::time::Duration;

use mars_hal::profile::Profile;
use mars_hal::runner::RunOptions;
use mars_hal::sim::SimBackend;
use mars_runtime::alloc_count::{self, CountingAlloc, Counts};
use mars_runtime::config::DaemonConfig;
use mars_runtime::daemon;

// One real-time rig at a time on this machine, across test binaries (see the file).
#[path = "../../testing/rt_rig_lock.rs"]
#[allow(dead_code)] // not every helper is used here
mod rt_rig_lock;

#[global_allocator]
static ALLOC: CountingAlloc = CountingAlloc;

fn root() -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/..")).canonicalize().unwrap()
}

/// The control: the counter sees allocations made on purpose, on the system allocator or, on a thread armed
/// for it, from the real-time pool.
#[test]
fn the_counter_sees_allocations_made_on_purpose() {
    let before = alloc_count::thread_counts().expect("CountingAlloc is this binary's global allocator");
    let v: Vec<u64> = std::hint::black_box(Vec::with_capacity(1000));
    let after = alloc_count::thread_counts().unwrap();
    drop(v);
    assert_eq!(after.system, before.system + 1, "{before:?} → {after:?}");

    let pooled = std::thread::spawn(|| {
        alloc_count::arm_rt_pool();
        let before = alloc_count::thread_counts().unwrap();
        let small = std::hint::black_box(Box::new([0u8; 64]));
        let mid = alloc_count::thread_counts().unwrap();
        let big: Vec<u8> = std::hint::black_box(Vec::with_capacity(4096));
        let after = alloc_count::thread_counts().unwrap();
        drop((small, big));
        (before, mid, after)
    })
    .join()
    .unwrap();
    let (b, m, a) = pooled;
    assert_eq!((m.system - b.system, m.pooled - b.pooled), (0, 1), "a small block on an armed thread is pooled");
    assert_eq!((a.system - m.system, a.pooled - m.pooled), (1, 0), "a large one goes to the system allocator");
}

#[test]
fn servo_tick_makes_no_heap_allocation_over_two_episodes() {
    let _rt = rt_rig_lock::rt_rig_lock();
    let root = root();
    let robot = format!("t{}-alloc", std::process::id());
    let profile = Profile::load(&root.join("configs/fr3.toml")).unwrap();
    profile.validate().unwrap();
    {
        let (profile, robot) = (profile.clone(), robot.clone());
        // Runs until this process ends (the test does not wait for it).
        std::thread::Builder::new()
            .name("hal".into())
            .spawn(move || {
                let opts =
                    RunOptions { robot, duration: Some(Duration::from_secs(600)), core: None, rt_priority: None };
                mars_hal::runner::run(&profile, &mut SimBackend::new(&profile), &opts)
            })
            .unwrap();
    }
    let mut cfg = DaemonConfig::load(&root.join("configs/marsd.toml")).unwrap();
    for p in [&mut cfg.profile, &mut cfg.task, &mut cfg.checkpoint] {
        *p = root.join(&p);
    }
    let out = std::env::temp_dir().join(format!("mars-alloc-test-{}", std::process::id()));
    cfg.out = out.clone();
    cfg.robot = robot;
    cfg.episodes = 2;
    let prepared = daemon::prepare(cfg).unwrap();
    let outcome = daemon::run(prepared).unwrap();
    let s = &outcome.summary; // (daemon::run printed it)
    assert_eq!(outcome.exit, daemon::exit::OK, "trip {:?}", s.trip);
    assert_eq!(s.episodes, 2);
    assert!(s.servo_ticks_counted > 5000, "only {} ticks counted", s.servo_ticks_counted);
    assert!(
        matches!(s.servo_allocations, Some(Counts { system: 0, .. })),
        "the servo thread called the system allocator after warm-up: {:?}",
        s.servo_allocations
    );
    let _ = std::fs::remove_dir_all(out);
}
