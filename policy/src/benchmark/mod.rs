//! `mars benchmark`: demos → the policies trained (`jobs` at a time) → each evaluated from its checkpoint →
//! `results.md` ([`report`]) and the plots. `mars family` runs it per layout × seed.

mod options;
pub mod report;

pub use options::BenchmarkOptions;
pub use report::Row;

use crate::checkpoint;
use crate::cli::{StepsAblation, demos, eval_with_steps, mean_w_in_region, plot};
use crate::config::{PolicyConfig, PolicyKind};
use crate::demo_file::load_demos;
use crate::evaluation::{DEFAULT_BATCH, Evaluation};
use crate::inference::MarsPolicy;
use anyhow::Context;
use mars_tasks::nav2d::layout::Layout;
use std::path::Path;
use std::time::Instant;

/// Where `benchmark` records a policy's training wall time next to its checkpoint.
const TRAIN_SECONDS_FILE: &str = "train_seconds";

/// Writes the demos to `path`; under `resume`, demos already there are kept if they are exactly what `n` and `seed`
/// make (regenerated beside them and compared), and refused otherwise: checkpoints kept beside them were trained
/// on those, and a mismatch must neither be mixed in silently nor overwrite them.
pub(crate) fn demos_kept_or_made(layout: &Path, n: usize, seed: u64, path: &Path, resume: bool) -> anyhow::Result<()> {
    match std::fs::read(path) {
        Ok(before) if resume => {
            let fresh = path.with_extension("json.resume");
            demos(layout, n, seed, &fresh)?;
            let same = std::fs::read(&fresh).ok().as_deref() == Some(&before[..]);
            let _ = std::fs::remove_file(&fresh);
            anyhow::ensure!(
                same,
                "--resume: {} holds other demos than {n} demos of seed {seed} (or the expert changed): the \
                 checkpoints beside it were trained on those; run without --resume or into another --out",
                path.display(),
            );
            Ok(())
        }
        _ => demos(layout, n, seed, path),
    }
}

/// `dir` holds a checkpoint of `cfg` (the calibrated `model.k_full_w` aside: training sets it). Compared through
/// their JSON form: the configs have f32 fields and no `PartialEq`, and a field added since with a serde default
/// compares equal to a checkpoint written before it.
pub(crate) fn trained_with(dir: &Path, cfg: &PolicyConfig) -> bool {
    let Ok(meta) = checkpoint::load_meta(dir) else { return false };
    let mut model = meta.model.clone();
    model.k_full_w = cfg.model.k_full_w;
    let same = |a: serde_json::Result<serde_json::Value>, b: serde_json::Result<serde_json::Value>| matches!((a, b), (Ok(a), Ok(b)) if a == b);
    meta.kind == cfg.kind
        && same(serde_json::to_value(&model), serde_json::to_value(&cfg.model))
        && same(serde_json::to_value(&meta.train), serde_json::to_value(&cfg.train))
}

/// Demos → train the policies (`jobs` at a time) → evaluate each, one after the other so that latencies are
/// measured on an otherwise idle machine → `results.md` (the table and the paper's claims, checked) and the
/// plots, all under `out`.
pub fn benchmark(out: &Path, config: &Path, layout_path: &Path, o: &BenchmarkOptions) -> anyhow::Result<Vec<Row>> {
    if let Some(w) = o.k_full_w {
        // Refused before hours of training, not at the first evaluation after them.
        anyhow::ensure!(w > 0.0 && w <= 1.0, "--k-full-w is {w}, must lie in (0, 1]");
    }
    let demos_path = out.join("demos.json");
    demos_kept_or_made(layout_path, o.demos, o.seed, &demos_path, o.resume)?;
    let set = load_demos(&demos_path)?;
    let layout = Layout::load(layout_path)?;
    let mut base = PolicyConfig::load(config)?;
    base.train.epochs = o.epochs.unwrap_or(base.train.epochs);
    base.train.seed = o.seed;
    if o.history_conditioning {
        (base.model.velocity_uses_history, base.model.scheduler_uses_history) = (true, true);
    }

    let config_of = |kind| {
        let mut cfg = base.clone();
        cfg.kind = kind;
        cfg
    };
    let to_train: Vec<PolicyKind> = o
        .policies
        .iter()
        .copied()
        .filter(|&kind| {
            let keep = o.resume && trained_with(&out.join(kind.name()), &config_of(kind));
            if keep {
                println!("{kind}: trained already under {} with this configuration, kept", out.display());
            }
            !keep
        })
        .collect();
    let bars = indicatif::MultiProgress::new();
    crate::jobs::parallel(&to_train, o.jobs, &|&kind| {
        let started = Instant::now();
        let t = crate::train::train_with_progress(
            &config_of(kind),
            &set.demos,
            bars.add(crate::train::progress_bar(kind)),
        )?;
        let dir = out.join(kind.name());
        t.save(&dir)?;
        let secs = started.elapsed().as_secs_f32();
        std::fs::write(dir.join(TRAIN_SECONDS_FILE), format!("{secs}\n"))
            .with_context(|| format!("cannot write {}", dir.display()))
    })?;
    // Every policy is evaluated from its checkpoint on disk, trained now or kept: one path for both.
    let mut rows = Vec::new();
    for &kind in &o.policies {
        let dir = out.join(kind.name());
        let (policy, meta) = MarsPolicy::load(&dir, o.seed)?;
        let train_s = std::fs::read_to_string(dir.join(TRAIN_SECONDS_FILE)).ok().and_then(|t| t.trim().parse().ok());
        let w_regions = ["entry_gate", "junction", "exit_gate"]
            .iter()
            .map(|name| {
                let r = layout.region(name).with_context(|| format!("layout has no region `{name}`"))?;
                Ok((name.to_string(), mean_w_in_region(&policy, &set.demos, r)?))
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        drop(policy);
        // Only a learned w has a K(w) to change: FM and the A2As keep their fixed step counts.
        let k_full_w = if kind == PolicyKind::Mars { o.k_full_w } else { None };
        let ablation = StepsAblation { steps: None, k_full_w };
        let Evaluation { report, intervals } =
            eval_with_steps(&dir, layout_path, o.rollouts, o.seed + 1000, o.exec_horizon, DEFAULT_BATCH, ablation)?;
        rows.push(Row { kind, epochs: meta.train.epochs, train_s, report, intervals, w_regions });
    }
    let md = report::render(&rows, o, (config, layout_path), &layout);
    std::fs::write(out.join("results.md"), &md).with_context(|| format!("cannot write {}", out.display()))?;
    plot(out, layout_path)?;
    println!("\n{md}");
    Ok(rows)
}
