//! `cargo bench -p mars-engine`: the engine against the candle model, per call at batch 1, single thread.
//!
//! Prints one table per section: latency for K = 1, 3, 10 (medians, engine vs the candle forward path, ratio
//! measured in this run), achieved FLOP/s against this machine's single-thread gemm peak measured in the
//! same run, heap allocations per call, the deadline behaviour, the MARS-vs-FM latency on trained nav2d
//! checkpoints with the demos' observations and histories replayed (so K varies as in use; over every training
//! seed found, `support/mars_vs_fm.rs`); and the image encoder (ResNet-18) against candle and ONNX Runtime at
//! each configured size (`support/image_encoder.rs`).

use candle_core::{Device, Tensor};
use mars_engine::{Engine, EngineConfig};
use mars_policy::checkpoint::{self, CheckpointMeta};
use mars_policy::config::PolicyConfig;
use mars_policy::model::MarsModel;
use mars_policy::normalize::{Normalizer, Stats};
use mars_policy::train::{Trained, init_model, randn};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

#[path = "../tests/counting/mod.rs"]
mod counting;

#[global_allocator]
static GLOBAL: counting::Counting = counting::Counting;

#[path = "support/image_encoder.rs"]
mod image_encoder;

#[path = "support/mars_vs_fm.rs"]
mod mars_vs_fm;

/// Runs `f`, returning its result and the allocations + reallocations it made on this thread.
fn counted<R>(f: impl FnOnce() -> R) -> (R, u64) {
    let (r, c) = counting::count(f);
    (r, (c.allocs + c.reallocs) as u64)
}

// ---- statistics ----

fn median(v: &mut [Duration]) -> Duration {
    v.sort();
    v[v.len() / 2]
}

fn mean(v: &[Duration]) -> Duration {
    v.iter().sum::<Duration>() / v.len().max(1) as u32
}

fn us(d: Duration) -> String {
    format!("{:.1} µs", d.as_secs_f64() * 1e6)
}

// ---- the candle reference ----

/// `MarsPolicy::predict`'s ops with a forced K: normalise, noise, encode, w, K(w), source, integrate,
/// unnormalise, copy out.
fn candle_call(
    model: &MarsModel,
    norm: &Normalizer,
    rng: &mut StdRng,
    obs: &[f32],
    hist: &[f32],
    k: usize,
) -> Vec<f32> {
    let cfg = &model.cfg;
    let (c, d) = (cfg.chunk_len, cfg.action_dim);
    let (mut o, mut h) = (obs.to_vec(), hist.to_vec());
    norm.obs.normalize(&mut o);
    norm.action.normalize(&mut h);
    let dev = Device::Cpu;
    let o = Tensor::from_vec(o, (1, cfg.obs_dim), &dev).unwrap();
    let h = Tensor::from_vec(h, (1, c, d), &dev).unwrap();
    let eps = randn(rng, &[1, c, d], &dev).unwrap();
    let emb = model.encode(&o).unwrap();
    let w = model.weights(&emb, &h).unwrap();
    let w_inf = w.flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap();
    std::hint::black_box(cfg.steps_for(w_inf));
    let a0 = MarsModel::source(&h, &w, &eps).unwrap();
    let mut chunk = model.integrate(&a0, &emb, k).unwrap().flatten_all().unwrap().to_vec1::<f32>().unwrap();
    norm.action.denormalize(&mut chunk);
    chunk
}

// ---- models ----

/// The nav2d MARS checkpoint, or the shipped config's network with random weights (timings do not depend on
/// the weights' values once K is forced).
/// Returns (directory, label, whether it is a temporary directory to remove).
fn model_dir(root: &Path) -> (PathBuf, String, bool) {
    let trained = root.join("runs/nav2d/mars");
    if trained.join(checkpoint::META_FILE).exists() {
        return (trained, "runs/nav2d/mars".into(), false);
    }
    let cfg = PolicyConfig::load(&root.join("configs/policy.toml")).expect("configs/policy.toml");
    let (model, varmap) = init_model(&cfg, &Device::Cpu).unwrap();
    let mut rng = StdRng::seed_from_u64(1);
    for var in varmap.all_vars() {
        let noise = randn(&mut rng, var.dims(), &Device::Cpu).unwrap();
        var.set(&(var.as_tensor() + (noise * 0.05).unwrap()).unwrap()).unwrap();
    }
    let stats = |n: usize| Stats { mean: vec![0.0; n], std: vec![1.0; n] };
    let normalizer = Normalizer { obs: stats(cfg.model.obs_dim), action: stats(cfg.model.action_dim) };
    let trained = Trained { cfg, model, varmap, normalizer, log: Vec::new(), epoch_seconds: Vec::new() };
    let dir = std::env::temp_dir().join(format!("mars-engine-bench-{}", std::process::id()));
    trained.save(&dir).unwrap();
    (dir, "configs/policy.toml network, random weights (runs/nav2d/mars absent)".into(), true)
}

fn describe(meta: &CheckpointMeta) -> String {
    let m = &meta.model;
    format!(
        "{} W={} depth={} heads={} mlp×{} C={} D={} obs={} K_max={}",
        meta.kind,
        m.dit_width,
        m.dit_depth,
        m.dit_heads,
        m.dit_mlp_ratio,
        m.chunk_len,
        m.action_dim,
        m.obs_dim,
        m.k_max
    )
}

// ---- sections ----

/// Single-thread f32 gemm throughput on a 512³ product with the same crate: this machine's practical peak.
fn gemm_peak() -> f64 {
    let n = 512;
    let a: Vec<f32> = (0..n * n).map(|i| (i % 7) as f32 * 0.1).collect();
    let b = a.clone();
    let mut c = vec![0.0f32; n * n];
    let mut best = f64::MAX;
    for _ in 0..8 {
        let t = Instant::now();
        // SAFETY: three n×n row-major matrices.
        unsafe {
            gemm::gemm(
                n,
                n,
                n,
                c.as_mut_ptr(),
                1,
                n as isize,
                false,
                a.as_ptr(),
                1,
                n as isize,
                b.as_ptr(),
                1,
                n as isize,
                0.0,
                1.0,
                false,
                false,
                false,
                gemm::Parallelism::None,
            )
        };
        best = best.min(t.elapsed().as_secs_f64());
    }
    std::hint::black_box(&c);
    2.0 * (n * n * n) as f64 / best
}

struct Inputs {
    obs: Vec<Vec<f32>>,
    hist: Vec<Vec<f32>>,
}

fn random_inputs(meta: &CheckpointMeta, n: usize) -> Inputs {
    let mut rng = StdRng::seed_from_u64(3);
    let m = &meta.model;
    let norm = &meta.normalizer;
    let draw = |rng: &mut StdRng, s: &Stats, len: usize| -> Vec<f32> {
        (0..len).map(|i| s.mean[i % s.dim()] + s.std[i % s.dim()] * rng.random_range(-1.0f32..1.0)).collect()
    };
    Inputs {
        obs: (0..n).map(|_| draw(&mut rng, &norm.obs, m.obs_dim)).collect(),
        hist: (0..n).map(|_| draw(&mut rng, &norm.action, m.chunk_len * m.action_dim)).collect(),
    }
}

fn latency_table(dir: &Path, label: &str, peak: f64) {
    let loaded = checkpoint::load(dir, &Device::Cpu).unwrap();
    let (model, meta) = (loaded.model, loaded.meta);
    let mut engine = Engine::load(dir, EngineConfig::with_seed(0)).unwrap();
    let inputs = random_inputs(&meta, 64);
    let mut rng = StdRng::seed_from_u64(0);
    println!("\n## Latency per call, batch 1, one thread — model: {label}\n   ({})", describe(&meta));
    println!("   engine matrix products: {}", engine.kernels());
    println!("   gemm single-thread peak (512³ f32, Parallelism::None, best of 8): {:.1} GFLOP/s\n", peak / 1e9);
    println!(
        "| K  | engine median | candle median | speed-up (candle/engine) | engine FLOP/call | engine GFLOP/s | % of peak | allocs/call engine | allocs/call candle |"
    );
    println!("|----|---:|---:|---:|---:|---:|---:|---:|---:|");
    for k in [1usize, 3, 10] {
        let (n_engine, n_candle) = match k {
            1 => (2000, 400),
            3 => (1500, 200),
            _ => (1000, 100),
        };
        for i in 0..20 {
            let j = i % inputs.obs.len();
            engine.infer_with(&inputs.obs[j], &inputs.hist[j], None, Some(k)).unwrap();
            candle_call(&model, &meta.normalizer, &mut rng, &inputs.obs[j], &inputs.hist[j], k);
        }
        let (mut te, mut tc) = (Vec::with_capacity(n_engine), Vec::with_capacity(n_candle));
        let (mut allocs_e, mut allocs_c) = (0, 0);
        // Interleaved rounds, so both see the same machine state.
        let rounds = 10;
        for r in 0..rounds {
            let (_, a) = counted(|| {
                for i in 0..n_engine / rounds {
                    let j = (r * 131 + i) % inputs.obs.len();
                    let t = Instant::now();
                    let out = engine.infer_with(&inputs.obs[j], &inputs.hist[j], None, Some(k)).unwrap();
                    std::hint::black_box(out.chunk);
                    te.push(t.elapsed());
                }
            });
            allocs_e += a;
            let (_, a) = counted(|| {
                for i in 0..n_candle / rounds {
                    let j = (r * 131 + i) % inputs.obs.len();
                    let t = Instant::now();
                    std::hint::black_box(candle_call(
                        &model,
                        &meta.normalizer,
                        &mut rng,
                        &inputs.obs[j],
                        &inputs.hist[j],
                        k,
                    ));
                    tc.push(t.elapsed());
                }
            });
            allocs_c += a;
        }
        // `te`/`tc` pushes stay within the reserved capacity: they add no allocations to the count.
        let (me, mc) = (median(&mut te), median(&mut tc));
        let flops = engine.flops_per_call(k);
        let gflops = flops as f64 / me.as_secs_f64();
        println!(
            "| {k:<2} | {} | {} | {:.2}× | {:.2} M | {:.1} | {:.0}% | {} | {:.0} |",
            us(me),
            us(mc),
            mc.as_secs_f64() / me.as_secs_f64(),
            flops as f64 / 1e6,
            gflops / 1e9,
            100.0 * gflops / peak,
            allocs_e / te.len() as u64,
            allocs_c as f64 / tc.len() as f64,
        );
    }
}

fn deadline_table(dir: &Path) {
    let mut engine = Engine::load(dir, EngineConfig::with_seed(0)).unwrap();
    let meta = engine.meta().clone();
    let inputs = random_inputs(&meta, 64);
    let est = engine.cost_estimate();
    println!(
        "\n## Deadline: budget → steps ({} model; budget = estimated cost of N steps + ½ step)\n   estimate after load: fixed {}, per step {}\n",
        meta.kind,
        us(est.fixed),
        us(est.per_step)
    );
    println!(
        "| N | budget | mean K(w) | mean k_used | capped | over budget | median time | p99 time | calls over budget |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    for steps in [1usize, 3, 6] {
        let budget = est.call(steps) + est.per_step / 2;
        let n = 2000;
        let (mut times, mut k_req, mut k_used, mut capped, mut over) = (Vec::with_capacity(n), 0, 0, 0, 0);
        for i in 0..n {
            let j = i % inputs.obs.len();
            let t = Instant::now();
            let out = engine.infer(&inputs.obs[j], &inputs.hist[j], budget).unwrap();
            let dt = t.elapsed();
            k_req += out.k_requested;
            k_used += out.k_used;
            capped += out.capped as usize;
            over += out.over_budget as usize;
            times.push(dt);
        }
        let late = times.iter().filter(|t| **t > budget).count();
        times.sort();
        println!(
            "| {steps} | {} | {:.2} | {:.2} | {:.0}% | {:.0}% | {} | {} | {:.1}% |",
            us(budget),
            k_req as f64 / n as f64,
            k_used as f64 / n as f64,
            100.0 * capped as f64 / n as f64,
            100.0 * over as f64 / n as f64,
            us(times[n / 2]),
            us(times[n * 99 / 100]),
            100.0 * late as f64 / n as f64,
        );
    }
}

fn main() {
    // SAFETY: the first statement of main, before any thread exists; candle reads it at its first matmul.
    unsafe { std::env::set_var("RAYON_NUM_THREADS", "1") };
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let root = root.canonicalize().unwrap_or(root);
    println!("# mars-engine benchmark (RAYON_NUM_THREADS=1; engine: Parallelism::None, one thread)");
    // `cargo bench -p mars-engine -- mars-vs-fm [DIR]`: that section only, on the seeds found under DIR.
    let args: Vec<String> = std::env::args().collect();
    if let Some(i) = args.iter().position(|a| a == "mars-vs-fm") {
        // Relative to the workspace, not to engine/ where cargo runs benchmarks.
        let dir = root.join(args.get(i + 1).filter(|a| !a.starts_with('-')).map_or("runs/nav2d", String::as_str));
        mars_vs_fm::mars_vs_fm(&dir);
        return;
    }
    let peak = gemm_peak();
    // `cargo bench -p mars-engine -- encoder`: the image-encoder section only.
    if std::env::args().any(|a| a == "encoder") {
        println!("   gemm single-thread peak (512³ f32, Parallelism::None, best of 8): {:.1} GFLOP/s", peak / 1e9);
        image_encoder::encoder_table(peak, |f| counted(f).1);
        return;
    }
    let (dir, label, temporary) = model_dir(&root);
    latency_table(&dir, &label, peak);
    // FM asks for K_max on every input, so the deadline's effect shows at every budget.
    let fm = root.join("runs/nav2d/fm");
    deadline_table(if fm.join(checkpoint::META_FILE).exists() { &fm } else { &dir });
    mars_vs_fm::mars_vs_fm(&root.join("runs/nav2d"));
    image_encoder::encoder_table(peak, |f| counted(f).1);
    if temporary {
        let _ = std::fs::remove_dir_all(&dir);
    }
}
