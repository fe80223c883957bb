//! FM's two ablations from the paper's appendix, on nav2d, each one command (`mars ablate --knob …`):
//! Fig. S3, FM's loss and success against the variance of its Gaussian source (`source-std`), and Fig. S4, an
//! ungated reconstruction loss pulling FM toward the central passages (`fm-lambda-rec`). They explain the
//! method: a wide source keeps modes but learns slowly, and L_rec collapses modes unless gated by (1 − w).

use crate::cli::{demos, eval, load_demos};
use crate::config::{PolicyConfig, PolicyKind};
use crate::train::train_with_progress;
use anyhow::Context;
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
    pub seed: u64,
    pub exec_horizon: usize,
    pub jobs: usize,
}

#[derive(Debug, Clone, Serialize)]
pub struct AblationRow {
    pub value: f64,
    pub label: String,
    pub epochs: usize,
    pub final_loss: f32,
    pub losses: Vec<f32>,
    pub success_pct: f32,
    pub passage_counts: Vec<usize>,
    pub gamma: f32,
}

/// Trains FM once per value of the knob on the same demos (`jobs` at a time), rolls each out, and writes
/// `out/ablation.md`, `out/ablation.json` and the loss curves `out/losses.png`.
pub fn run(out: &Path, config: &Path, layout: &Path, o: &AblateOptions) -> anyhow::Result<Vec<AblationRow>> {
    anyhow::ensure!(!o.values.is_empty(), "--values names no value");
    let demos_path = out.join("demos.json");
    demos(layout, o.demos, o.seed, &demos_path)?;
    let set = load_demos(&demos_path)?;
    let mut base = PolicyConfig::load(config)?;
    base.kind = PolicyKind::Fm;
    base.train.seed = o.seed;
    base.train.epochs = o.epochs.unwrap_or(base.train.epochs);
    let cfgs: Vec<(f64, PolicyConfig)> = o
        .values
        .iter()
        .map(|&v| {
            let mut cfg = base.clone();
            o.knob.apply(&mut cfg, v);
            cfg.validate().with_context(|| format!("--values {v}"))?;
            Ok((v, cfg))
        })
        .collect::<anyhow::Result<_>>()?;
    let rows = crate::curve::parallel(&cfgs, o.jobs, &|(value, cfg)| {
        let dir = out.join(format!("{}_{value}", o.knob.flag()));
        let t = train_with_progress(cfg, &set.demos, indicatif::ProgressBar::hidden())?;
        crate::checkpoint::save(&dir, &t)?;
        let losses: Vec<f32> = t.log.iter().map(|e| e.total).collect();
        let r = eval(&dir, layout, o.rollouts, o.seed + 1000, o.exec_horizon)?;
        Ok(AblationRow {
            value: *value,
            label: o.knob.label(*value),
            epochs: cfg.train.epochs,
            final_loss: losses.last().copied().unwrap_or(f32::NAN),
            losses,
            success_pct: 100.0 * r.success_rate(),
            passage_counts: r.passage_counts.clone(),
            gamma: r.modal_balance,
        })
    })?;
    let md = render(&rows, o, config, layout);
    std::fs::write(out.join("ablation.md"), &md).with_context(|| format!("cannot write {}", out.display()))?;
    std::fs::write(out.join("ablation.json"), serde_json::to_string_pretty(&rows)?)
        .with_context(|| format!("cannot write {}", out.display()))?;
    let series: Vec<(String, Vec<f32>)> = rows.iter().map(|r| (r.label.clone(), r.losses.clone())).collect();
    crate::plots::plot_losses(&series, &out.join("losses.png"))?;
    println!("\n{md}");
    Ok(rows)
}

pub fn render(rows: &[AblationRow], o: &AblateOptions, config: &Path, layout: &Path) -> String {
    let values: Vec<String> = o.values.iter().map(|v| v.to_string()).collect();
    let mut s = format!("# FM ablation: {}\n\n", o.knob.flag());
    let _ = writeln!(
        s,
        "Command: `mars ablate --knob {} --values {} --config {} --layout {} --demos {}{} --rollouts {} --seed {}`; \
         one training seed, FM on the same demos for every value.\n",
        o.knob.flag(),
        values.join(","),
        config.display(),
        layout.display(),
        o.demos,
        o.epochs.map_or(String::new(), |e| format!(" --epochs {e}")),
        o.rollouts,
        o.seed
    );
    let _ = writeln!(s, "| setting | epochs | final loss | success % | passages | γ |");
    let _ = writeln!(s, "|---|---:|---:|---:|---|---:|");
    for r in rows {
        let counts: Vec<String> = r.passage_counts.iter().map(|c| c.to_string()).collect();
        let _ = writeln!(
            s,
            "| {} | {} | {:.4} | {:.0} | {} | {:.2} |",
            r.label,
            r.epochs,
            r.final_loss,
            r.success_pct,
            counts.join("/"),
            r.gamma
        );
    }
    s
}
