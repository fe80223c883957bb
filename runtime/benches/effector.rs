//! ns per servo tick of the end-effector map Push-T adds to the tick: (x, y) on the table → joints by IK from the
//! previous tick, q̇ by the Jacobian (`mars_runtime::servo::effector`), on the expert's own paths (both routes, several
//! starts) interpolated at 1 kHz, as the servo samples a chunk; next to one ruckig step of the smoother on the
//! joint stream it produced, for scale. Counts heap allocations per tick (the binary's counting allocator).
//!
//! `nice -n 19 cargo bench -p mars-runtime --bench effector`

use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use mars_profile::Profile;
use mars_runtime::alloc_count::{CountingAlloc, thread_counts};
use mars_runtime::servo::smoothing::{Limits, Smoother};
use mars_runtime::task::PushTHil;
use mars_tasks::push_t::PushT;
use mars_tasks::push_t::expert::{Expert, Route};

#[global_allocator]
static ALLOC: CountingAlloc = CountingAlloc;

/// The expert's pusher positions, one per control period, for a few episodes of each route.
fn paths(task: &PushTHil) -> Vec<Vec<[f64; 2]>> {
    let cfg = &task.cfg.world;
    let mut out = Vec::new();
    for seed in 0..4 {
        for route in [Route::Upper, Route::Lower] {
            let (mut world, mut expert) = (PushT::new(cfg, seed), Expert::new(cfg, route));
            let mut path = vec![world.state().pusher.map(f64::from)];
            while !world.done() {
                world.step(expert.act(&world.state()));
                path.push(world.state().pusher.map(f64::from));
            }
            out.push(path);
        }
    }
    out
}

fn quantiles(mut ns: Vec<u64>) -> (u64, u64, u64) {
    ns.sort_unstable();
    let at = |q: f64| ns[((ns.len() - 1) as f64 * q).round() as usize];
    (at(0.5), at(0.99), *ns.last().unwrap())
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let profile = Profile::load(&root.join("configs/fr3.toml")).unwrap();
    let task = PushTHil::load(&root.join("configs/push_t.toml"), &profile).unwrap();
    let period_ticks = (f64::from(task.cfg.world.control_period) * 1e3).round() as usize;
    let (mut ik_ns, mut smooth_ns) = (Vec::new(), Vec::new());
    let mut allocations = 0;
    let mut effector = task.effector();
    let mut smoother = Smoother::new(7, profile.period_s(), &Limits::from_profile(&profile)).unwrap();
    for path in paths(&task) {
        effector.seed(&task.start_pose);
        smoother.reset(&task.start_pose).unwrap();
        let (mut q, mut v) = ([0.0; 7], [0.0; 7]);
        for w in path.windows(2) {
            let vel =
                [(w[1][0] - w[0][0]) * 1e3 / period_ticks as f64, (w[1][1] - w[0][1]) * 1e3 / period_ticks as f64];
            for k in 1..=period_ticks {
                let s = k as f64 / period_ticks as f64;
                let xy = [w[0][0] + s * (w[1][0] - w[0][0]), w[0][1] + s * (w[1][1] - w[0][1])];
                let before = thread_counts().unwrap();
                let t0 = Instant::now();
                effector.joints(black_box(xy), vel, &mut q, &mut v);
                let t1 = Instant::now();
                black_box(smoother.track(&q, &v).unwrap());
                let t2 = Instant::now();
                let after = thread_counts().unwrap();
                allocations += after.system - before.system;
                ik_ns.push((t1 - t0).as_nanos() as u64);
                smooth_ns.push((t2 - t1).as_nanos() as u64);
            }
        }
    }
    let ticks = ik_ns.len();
    let (ik, sm) = (quantiles(ik_ns), quantiles(smooth_ns));
    println!("Push-T's end-effector map in the servo tick, {ticks} ticks of the expert's paths (8 episodes):");
    println!("| per tick | median | p99 | max |");
    println!("|---|---:|---:|---:|");
    println!(
        "| IK + Jacobian velocity (effector.rs) | {:.1} µs | {:.1} µs | {:.1} µs |",
        ik.0 as f64 / 1e3,
        ik.1 as f64 / 1e3,
        ik.2 as f64 / 1e3
    );
    println!(
        "| ruckig step (smoothing.rs), for scale | {:.1} µs | {:.1} µs | {:.1} µs |",
        sm.0 as f64 / 1e3,
        sm.1 as f64 / 1e3,
        sm.2 as f64 / 1e3
    );
    println!(
        "heap allocations in {ticks} ticks: {allocations}; references not reached: {}, clamped: {}",
        effector.counts.unreachable, effector.counts.outside_workspace
    );
}
