//! After load and one warm-up call, inference performs zero heap allocations: checked with a counting global
//! allocator over 1000+ calls per model, through every path a call can take (each policy kind, budgets that
//! cap K and that cannot fit one step, explicit noise, forced K, committed rows to continue, every kind of bad input, and a network that
//! overflows), and a vision policy whose calls encode a camera image.
//!
//! The allocator (`counting/`) counts only on threads that switched counting on (a thread-local flag), so the
//! test harness's own threads cannot disturb the count; and this binary holds this one test only.

mod common;
mod counting;

use common::{inputs, normal, perturbed_checkpoint, trained_checkpoint};
use counting::{Counting, Counts, count};
use mars_engine::{Engine, EngineConfig, EngineError};
use mars_policy::config::{PolicyConfig, PolicyKind};
use mars_policy::nn::resnet::ResNetHead;
use rand::SeedableRng;
use rand::rngs::StdRng;
use std::path::Path;
use std::time::Duration;

#[global_allocator]
static GLOBAL: Counting = Counting;

const CALLS: usize = 1000;

/// Warm-up call, then `CALLS` mixed calls measured; returns (calls made, K values seen).
fn measure(dir: &Path, cfg: EngineConfig) -> (usize, Vec<usize>) {
    let mut engine = Engine::load(dir, cfg).unwrap();
    let (obs_dim, action_dim) = (engine.obs_dim(), engine.action_dim());
    let cd = engine.chunk_len() * action_dim;
    let mut rng = StdRng::seed_from_u64(5);
    // All inputs exist before counting starts.
    let cases: Vec<(Vec<f32>, Vec<f32>)> = (0..16).map(|_| inputs(&mut rng, obs_dim, cd)).collect();
    let eps = normal(&mut rng, cd);
    let mut nan_obs = cases[0].0.clone();
    nan_obs[obs_dim - 1] = f32::NAN;
    let huge: Vec<f32> = (0..obs_dim).map(|i| if i % 2 == 0 { f32::MAX } else { -f32::MAX }).collect();
    let mut inf_hist = cases[0].1.clone();
    inf_hist[cd / 2] = f32::NEG_INFINITY;
    let budgets = [Duration::MAX, Duration::ZERO, Duration::from_micros(30), Duration::from_millis(1)];
    let mut ks = vec![0usize; engine.k_max() + 1];
    engine.infer(&cases[0].0, &cases[0].1, Duration::MAX).unwrap();

    let (calls, counts) = count(|| {
        let mut calls = 0;
        for i in 0..CALLS {
            let (obs, hist) = &cases[i % cases.len()];
            let out = match i % 8 {
                5 => engine.infer_after(obs, hist, &hist[..(1 + i % 3) * action_dim], budgets[i % budgets.len()]),
                6 => engine.infer_with(obs, hist, Some(&eps), Some(1 + i % engine.k_max())),
                7 => engine.infer_with(obs, hist, None, None),
                _ => engine.infer(obs, hist, budgets[i % budgets.len()]),
            };
            let k = out.unwrap().k_used;
            ks[k] += 1;
            calls += 1;
            // The error paths: each returns an error value, allocation-free.
            if i % 50 == 0 {
                let errs = [
                    engine.infer(&nan_obs, hist, Duration::MAX).err(),
                    engine.infer(obs, &inf_hist, Duration::MAX).err(),
                    engine.infer(&obs[..obs_dim - 1], hist, Duration::MAX).err(),
                    engine.infer(obs, &[], Duration::MAX).err(),
                    engine.infer_with(obs, hist, Some(&hist[1..]), None).err(),
                    engine.infer_with(obs, hist, None, Some(0)).err(),
                    engine.infer_with(obs, hist, None, Some(engine.k_max() + 1)).err(),
                    engine.infer_after(obs, hist, &hist[..action_dim + 1], Duration::MAX).err(),
                    engine.infer_after(obs, hist, hist, Duration::MAX).err(),
                ];
                assert!(errs.iter().all(Option::is_some));
                // Overflow inside the network (an error after the whole computation ran).
                let _ = std::hint::black_box(engine.infer(&huge, hist, Duration::MAX).err());
                assert!(matches!(errs[5], Some(EngineError::Steps { k: 0, .. })));
                calls += errs.len() + 1;
            }
        }
        calls
    });
    assert_eq!(counts, Counts::default(), "{}: over {calls} calls", dir.display());
    (calls, (0..ks.len()).filter(|&k| ks[k] > 0).collect())
}

#[test]
fn inference_never_allocates() {
    // The counter works: a Vec on this thread is seen.
    let (_, seen) = count(|| std::hint::black_box(vec![1u8; 64]));
    assert_eq!(seen.allocs, 1, "the counting allocator does not see this thread's allocations");
    // …and another thread's are not: 1000 allocations there, a few here for spawning it.
    let other_thread = || (0..1000).map(|i| std::hint::black_box(vec![1u8; 64 + i]).len()).sum::<usize>();
    let (_, other) = count(|| std::thread::spawn(other_thread).join());
    assert!(other.allocs < 100, "{other:?}");

    let mut dirs = Vec::new();
    for kind in PolicyKind::ALL {
        dirs.push(trained_checkpoint(kind, &format!("alloc-{kind}"), |_| {}));
    }
    // Scheduler and velocity field on the history, more tokens than a gemm row tile.
    dirs.push(trained_checkpoint(PolicyKind::Mars, "alloc-shapes", |cfg| {
        cfg.model.scheduler_uses_history = true;
        cfg.model.velocity_uses_history = true;
        cfg.model.chunk_len = 20;
        cfg.model.history_len = 20;
        cfg.model.dit_width = 48;
        cfg.model.dit_heads = 3;
    }));
    // The shipped (nav2d) network size.
    let shipped =
        PolicyConfig::load(Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/policy.toml"))).unwrap();
    dirs.push(perturbed_checkpoint(&shipped, "alloc-shipped"));
    // A vision policy: camera image + state through ResNet-18 (spatial softmax) and the MLP.
    let mut vision = common::tiny_config(PolicyKind::Mars);
    vision.model.obs_dim = 2 + 52 * 52 * 3;
    vision.model.encoder = common::vision_encoder(52, 48, ResNetHead::SpatialSoftmax { keypoints: 8 });
    dirs.push(common::perturbed_vision_checkpoint(&vision, 52, "alloc-vision"));

    let fast = EngineConfig::with_seed(1);
    let portable = EngineConfig { portable_kernels: true, ..fast };
    for (i, dir) in dirs.iter().enumerate() {
        // The portable kernels (chosen on CPUs without AVX2 + FMA) on the last two: the largest model and the
        // vision one.
        let configs: &[EngineConfig] = if i + 2 >= dirs.len() { &[fast, portable] } else { &[fast] };
        for &cfg in configs {
            let (calls, ks) = measure(dir, cfg);
            println!("{} ({cfg:?}): {calls} calls, 0 allocations; K used: {ks:?}", dir.display());
            assert!(ks.len() > 1, "the calls should run different step counts");
        }
        std::fs::remove_dir_all(dir).unwrap();
    }
}
