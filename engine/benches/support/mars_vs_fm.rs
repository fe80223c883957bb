//! The MARS-vs-FM section of `cargo bench -p mars-engine` (included by `engine.rs`): the engine's latency per
//! call on trained nav2d checkpoints, the demos' observations and histories replayed so that K = K(w) varies as
//! in use, over every training seed found, with the ratio's 95 % interval over the seeds.
//!
//! A seed is a folder holding `mars/`, `fm/` and `demos.json`: `runs/nav2d` as `mars benchmark` writes it, or
//! each `<layout>/seed<N>` of a `mars family` run and each `seed<N>` of a `mars curve` run
//! (`cargo bench -p mars-engine -- mars-vs-fm runs/curve_nav2d5`). A folder that cannot be read or loaded is named
//! with its error and left out; the rest are measured.
//! The two policies' calls alternate, one of each per replayed sample, the order swapped every sample, so a
//! slow spell of the host lands on both alike and the ratio is measured side by side.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use mars_engine::{Engine, EngineConfig};
use mars_policy::checkpoint;
use mars_policy::dataset::history_window;
use mars_tasks::stats::{Estimate, Verdict, mean_over_seeds};

use super::{mean, median, us};

/// The paper's claim (Table 1): MARS's inference latency is 83.2 % below FM's, i.e. MARS/FM ≤ 0.168.
const PAPER_RATIO: f64 = 1.0 - 0.832;
/// Replayed samples per seed, evenly spaced over the demos: stable means in bounded time.
const CALLS: usize = 2000;
/// Calls of each policy before timing: caches, page faults and the engine's first-call costs out of the figures.
const WARM_UP: usize = 20;

/// One seed's side-by-side measurement.
struct SeedTiming {
    mars_k: f64,
    mars_median: Duration,
    fm_median: Duration,
    mars_mean: Duration,
    fm_mean: Duration,
}

impl SeedTiming {
    fn median_ratio(&self) -> f64 {
        self.mars_median.as_secs_f64() / self.fm_median.as_secs_f64()
    }
    fn mean_ratio(&self) -> f64 {
        self.mars_mean.as_secs_f64() / self.fm_mean.as_secs_f64()
    }
}

/// Every folder under `dir` (itself, or up to two levels down) that holds `mars/`, `fm/` and `demos.json`.
fn seed_dirs(dir: &Path) -> Vec<PathBuf> {
    let is_seed = |d: &Path| ["mars", "fm", "demos.json"].iter().all(|f| d.join(f).exists());
    if is_seed(dir) {
        return vec![dir.to_path_buf()];
    }
    let children = |d: &Path| -> Vec<PathBuf> {
        let mut v: Vec<PathBuf> = std::fs::read_dir(d)
            .map(|r| r.filter_map(|e| e.ok().map(|e| e.path())).filter(|p| p.is_dir()).collect())
            .unwrap_or_default();
        v.sort();
        v
    };
    let mut found = Vec::new();
    for child in children(dir) {
        if is_seed(&child) {
            found.push(child);
        } else {
            found.extend(children(&child).into_iter().filter(|g| is_seed(g)));
        }
    }
    found
}

/// Observations and the histories beside them, one of each per replayed demo step.
type Inputs = (Vec<Vec<f32>>, Vec<Vec<f32>>);

/// The demos' (observation, history) pairs, at most `CALLS` evenly spaced.
fn replayed_inputs(seed: &Path, history_len: usize) -> Result<Inputs, String> {
    let set = mars_policy::demo_file::load_demos(&seed.join("demos.json")).map_err(|e| format!("demos.json: {e:#}"))?;
    let (mut obs, mut hist) = (Vec::new(), Vec::new());
    for demo in &set.demos {
        for t in 0..demo.len() {
            let mut w = Vec::with_capacity(history_len * demo.rest_action.len());
            history_window(&demo.actions, &demo.rest_action, t, history_len, &mut w);
            obs.push(demo.observations[t].clone());
            hist.push(w);
        }
    }
    let stride = obs.len().div_ceil(CALLS).max(1);
    Ok((obs.into_iter().step_by(stride).collect(), hist.into_iter().step_by(stride).collect()))
}

fn measure(seed: &Path) -> Result<SeedTiming, String> {
    let h = checkpoint::load_meta(&seed.join("mars")).map_err(|e| format!("mars/: {e:#}"))?.model.history_len;
    let (obs, hist) = replayed_inputs(seed, h)?;
    if obs.is_empty() {
        return Err("demos.json holds no step".into());
    }
    let load = |p: &str| Engine::load(&seed.join(p), EngineConfig::with_seed(0)).map_err(|e| format!("{p}/: {e}"));
    let (mut mars, mut fm) = (load("mars")?, load("fm")?);
    let timed = |engine: &mut Engine, i: usize| {
        let t = Instant::now();
        let k = engine.infer(&obs[i], &hist[i], Duration::MAX).unwrap().k_used;
        (t.elapsed(), k)
    };
    for i in 0..WARM_UP.min(obs.len()) {
        timed(&mut mars, i);
        timed(&mut fm, i);
    }
    let (mut tm, mut tf, mut k_sum) = (Vec::with_capacity(obs.len()), Vec::with_capacity(obs.len()), 0);
    for i in 0..obs.len() {
        let ((m, k), f) = if i % 2 == 0 {
            let m = timed(&mut mars, i);
            (m, timed(&mut fm, i).0)
        } else {
            let f = timed(&mut fm, i).0;
            (timed(&mut mars, i), f)
        };
        tm.push(m);
        tf.push(f);
        k_sum += k;
    }
    Ok(SeedTiming {
        mars_k: k_sum as f64 / obs.len() as f64,
        mars_mean: mean(&tm),
        fm_mean: mean(&tf),
        mars_median: median(&mut tm),
        fm_median: median(&mut tf),
    })
}

/// Prints one row per seed folder found under `dir`, then the ratios' means over the seeds with their 95 % t
/// intervals and the paper's claim judged by the means' interval (its latency is a mean per inference).
pub fn mars_vs_fm(dir: &Path) {
    println!("\n## MARS vs FM on nav2d (demo observations and histories replayed, K = K(w), no deadline)\n");
    let seeds = seed_dirs(dir);
    if seeds.is_empty() {
        println!(
            "NOTE: skipped — no folder with mars/, fm/ and demos.json under {}. Run `mars benchmark` or \
             `mars family` (or `mars curve`) first.",
            dir.display()
        );
        return;
    }
    println!(
        "| seed folder | MARS mean K | MARS median | FM median | MARS/FM medians | MARS mean | FM mean | MARS/FM means |"
    );
    println!("|---|---:|---:|---:|---:|---:|---:|---:|");
    let mut rows = Vec::new();
    for seed in &seeds {
        let r = match measure(seed) {
            Ok(r) => r,
            Err(e) => {
                println!("| {} | left out: {e} |||||||", seed.display());
                continue;
            }
        };
        println!(
            "| {} | {:.2} | {} | {} | {:.3} | {} | {} | {:.3} |",
            seed.strip_prefix(dir.parent().unwrap_or(dir)).unwrap_or(seed).display(),
            r.mars_k,
            us(r.mars_median),
            us(r.fm_median),
            r.median_ratio(),
            us(r.mars_mean),
            us(r.fm_mean),
            r.mean_ratio()
        );
        rows.push(r);
    }
    let over_seeds = |f: fn(&SeedTiming) -> f64| mean_over_seeds(&rows.iter().map(f).collect::<Vec<_>>());
    let (medians, means) = (over_seeds(SeedTiming::median_ratio), over_seeds(SeedTiming::mean_ratio));
    let show = |e: Option<Estimate>| e.map_or("none".into(), |e| format!("{e:.3}"));
    println!("\nMARS/FM latency over {} seed(s), mean of the per-seed ratios (95 % t interval):", rows.len());
    println!("  medians {}; means {}", show(medians), show(means));
    if let Some(m) = means {
        println!("  the paper's −83.2 % (MARS/FM means ≤ {PAPER_RATIO:.3}): {}", Verdict::at_most(m, PAPER_RATIO));
    }
}
