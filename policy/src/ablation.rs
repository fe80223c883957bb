//! FM's two ablations from the paper's appendix, on nav2d, each one command (`mars ablate --knob …`):
//! Fig. S3, FM's loss and success against the variance of its Gaussian source (`source-std`), and Fig. S4, an
//! ungated reconstruction loss pulling FM toward the central passages (`fm-lambda-rec`). They explain the
//! method: a wide source keeps modes but learns slowly, and L_rec collapses modes unless gated by (1 − w).

use crate::benchmark::{demos_kept_or_made, trained_with};
use crate::cli::eval;
use crate::config::{PolicyConfig, PolicyKind};
use crate::demo_file::load_demos;
use crate::stats::MeanStd;
use crate::train::train_with_progress;
use anyhow::Context;
use mars_tasks::nav2d::layout::Layout;
use mars_tasks::stats::{Estimate, mean_over_seeds};
use serde::Serialize;
use std::fmt::Write;
use std::path::Path;

#[derive(Debug, Clone, Copy, PartialEq, Serialize, clap::ValueEnum)]
pub enum Knob {
    /// Standard deviation of FM's source ε (the paper's Fig. S3 sweeps its variance, std²).
    SourceStd,
    /// Weight of an ungated reconstruction loss added to FM (Fig. S4: 0 vs 1).
    FmLambdaRec,
}

impl Knob {
    fn apply(self, cfg: &mut PolicyConfig, value: f64) {
        match self {
            Knob::SourceStd => cfg.model.source_std = value as f32,
            Knob::FmLambdaRec => cfg.train.fm_lambda_rec = (value > 0.0).then_some(value),
        }
    }

    fn label(self, value: f64) -> String {
        match self {
            Knob::SourceStd => format!("std {value} (variance {:.2})", value * value),
            Knob::FmLambdaRec => format!("λ_rec {value}"),
        }
    }

    fn flag(self) -> &'static str {
        match self {
            Knob::SourceStd => "source-std",
            Knob::FmLambdaRec => "fm-lambda-rec",
        }
    }
}

pub struct AblateOptions {
    pub knob: Knob,
    pub values: Vec<f64>,
    pub demos: usize,
    pub epochs: Option<usize>,
    pub rollouts: usize,
    /// Training seeds 0..seeds (each also seeds its demos and its rollouts).
    pub seeds: u64,
    pub exec_horizon: usize,
    pub jobs: usize,
    /// Keep each value × seed already trained under `out` with this configuration (it is still evaluated).
    pub resume: bool,
}

/// One training: a value of the knob on one seed's demos.
#[derive(Debug, Clone, Serialize)]
pub struct AblationRun {
    pub value: f64,
    pub seed: u64,
    pub final_loss: f32,
    pub losses: Vec<f32>,
    pub success_pct: f32,
    pub passage_counts: Vec<usize>,
    pub gamma: f32,
    /// Total-variation distance between the successful rollouts' passage shares and the layout's demo shares.
    pub tv: f32,
}

/// A value of the knob over the seeds.
#[derive(Debug, Clone, Serialize)]
pub struct AblationRow {
    pub value: f64,
    pub label: String,
    pub epochs: usize,
    pub final_loss: MeanStd,
    /// Mean over seeds, epoch by epoch.
    pub losses: Vec<f32>,
    /// Mean over seeds with its 95 % t interval (unbounded with one seed).
    pub success_pct: Estimate,
    pub gamma: Estimate,
    pub tv: Estimate,
    /// Summed over seeds.
    pub passage_counts: Vec<usize>,
    pub runs: Vec<AblationRun>,
}

/// Trains FM once per value of the knob and seed (`jobs` at a time; all values of a seed on the same demos), rolls
/// each out, and writes `out/ablation.md`, `out/ablation.json` and the mean loss curves `out/losses.png`.
pub fn run(out: &Path, config: &Path, layout: &Path, o: &AblateOptions) -> anyhow::Result<Vec<AblationRow>> {
    anyhow::ensure!(!o.values.is_empty(), "--values names no value");
    anyhow::ensure!(o.seeds >= 1, "--seeds must be at least 1");
    let mut base = PolicyConfig::load(config)?;
    base.kind = PolicyKind::Fm;
    base.train.epochs = o.epochs.unwrap_or(base.train.epochs);
    let mut jobs = Vec::new();
    let mut demo_sets = Vec::new();
    for seed in 0..o.seeds {
        let demos_path = out.join(format!("seed{seed}")).join("demos.json");
        demos_kept_or_made(layout, o.demos, seed, &demos_path, o.resume)?;
        demo_sets.push(load_demos(&demos_path)?);
        for &v in &o.values {
            let mut cfg = base.clone();
            cfg.train.seed = seed;
            o.knob.apply(&mut cfg, v);
            cfg.validate().with_context(|| format!("--values {v}"))?;
            jobs.push((seed, v, cfg));
        }
    }
    let runs = crate::jobs::parallel(&jobs, o.jobs, &|(seed, value, cfg)| {
        let dir = out.join(format!("seed{seed}")).join(format!("{}_{value}", o.knob.flag()));
        let losses: Vec<f32> = if o.resume && trained_with(&dir, cfg) {
            println!("{} {value}, seed {seed}: trained already under {}, kept", o.knob.flag(), dir.display());
            crate::checkpoint::load_meta(&dir)?.log.iter().map(|e| e.total).collect()
        } else {
            let t = train_with_progress(cfg, &demo_sets[*seed as usize].demos, indicatif::ProgressBar::hidden())?;
            t.save(&dir)?;
            t.log.iter().map(|e| e.total).collect()
        };
        let r = eval(&dir, layout, o.rollouts, seed + 1000, o.exec_horizon)?.report;
        let demo_shares: Vec<f64> = Layout::load(layout)?.demo_shares().iter().map(|&p| f64::from(p)).collect();
        Ok(AblationRun {
            value: *value,
            seed: *seed,
            final_loss: losses.last().copied().unwrap_or(f32::NAN),
            losses,
            success_pct: 100.0 * r.success_rate(),
            passage_counts: r.passage_counts.clone(),
            gamma: r.modal_balance,
            tv: mars_tasks::stats::modes::tv_to(&r.passage_counts, &demo_shares) as f32,
        })
    })?;
    let rows: Vec<AblationRow> = o.values.iter().map(|&v| aggregate(o, base.train.epochs, v, &runs)).collect();
    let md = render(&rows, o, config, layout);
    std::fs::write(out.join("ablation.md"), &md).with_context(|| format!("cannot write {}", out.display()))?;
    std::fs::write(out.join("ablation.json"), serde_json::to_string_pretty(&rows)?)
        .with_context(|| format!("cannot write {}", out.display()))?;
    let series: Vec<(String, Vec<f32>)> = rows.iter().map(|r| (r.label.clone(), r.losses.clone())).collect();
    crate::plots::plot_losses(&series, &out.join("losses.png"))?;
    println!("\n{md}");
    Ok(rows)
}

fn aggregate(o: &AblateOptions, epochs: usize, value: f64, runs: &[AblationRun]) -> AblationRow {
    let runs: Vec<AblationRun> = runs.iter().filter(|r| r.value == value).cloned().collect();
    let of = |f: &dyn Fn(&AblationRun) -> f32| MeanStd::of(&runs.iter().map(f).collect::<Vec<_>>());
    let over_seeds = |f: &dyn Fn(&AblationRun) -> f32| {
        let v: Vec<f64> = runs.iter().map(|r| f64::from(f(r))).collect();
        mean_over_seeds(&v).unwrap_or(Estimate::new(f64::NAN, f64::NAN, f64::NAN))
    };
    let n = runs.len().max(1) as f32;
    let losses = (0..runs.iter().map(|r| r.losses.len()).min().unwrap_or(0))
        .map(|e| runs.iter().map(|r| r.losses[e]).sum::<f32>() / n)
        .collect();
    let passages = runs.first().map_or(0, |r| r.passage_counts.len());
    AblationRow {
        value,
        label: o.knob.label(value),
        epochs,
        final_loss: of(&|r| r.final_loss),
        losses,
        success_pct: over_seeds(&|r| r.success_pct),
        gamma: over_seeds(&|r| r.gamma),
        tv: over_seeds(&|r| r.tv),
        passage_counts: (0..passages).map(|k| runs.iter().map(|r| r.passage_counts[k]).sum()).collect(),
        runs,
    }
}

pub fn render(rows: &[AblationRow], o: &AblateOptions, config: &Path, layout: &Path) -> String {
    let values: Vec<String> = o.values.iter().map(|v| v.to_string()).collect();
    let mut s = format!("# FM ablation: {}\n\n", o.knob.flag());
    let _ = writeln!(
        s,
        "Command: `mars ablate --knob {} --values {} --config {} --layout {} --demos {}{} --rollouts {} --seeds {}`; \
         FM over training seeds 0..{} (each seeds its demos, shared by every value, and its rollouts): the final \
         loss as mean ± std, success, γ and the TV distance to the layout's demo shares as the mean with its 95 % t \
         interval over seeds; passages summed over the seeds.\n",
        o.knob.flag(),
        values.join(","),
        config.display(),
        layout.display(),
        o.demos,
        o.epochs.map_or(String::new(), |e| format!(" --epochs {e}")),
        o.rollouts,
        o.seeds,
        o.seeds
    );
    let _ = writeln!(
        s,
        "| setting | epochs | final loss | success % | passages | γ | TV to the demos | success % per seed |"
    );
    let _ = writeln!(s, "|---|---:|---:|---:|---|---:|---:|---|");
    for r in rows {
        let counts: Vec<String> = r.passage_counts.iter().map(|c| c.to_string()).collect();
        let per_seed: Vec<String> = r.runs.iter().map(|x| format!("{:.0}", x.success_pct)).collect();
        let _ = writeln!(
            s,
            "| {} | {} | {:.4} | {:.1} | {} | {:.2} | {:.2} | {} |",
            r.label,
            r.epochs,
            r.final_loss,
            r.success_pct,
            counts.join("/"),
            r.gamma,
            r.tv,
            per_seed.join(", ")
        );
    }
    s
}
