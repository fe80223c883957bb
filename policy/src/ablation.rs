//! FM's two ablations from the paper's appendix, on nav2d, each one command (`mars ablate --knob …`):
//! Fig. S3, FM's loss and success against the variance of its Gaussian source (`source-std`), and Fig. S4, an
//! ungated reconstruction loss pulling FM toward the central passages (`fm-lambda-rec`). They explain the
//! method: a wide source keeps modes but learns slowly, and L_rec collapses modes unless gated by (1 − w).

use crate::benchmark::{demos_kept_or_made, trained_with};
use crate::cli::eval;
use crate::config::{PolicyConfig, PolicyKind};
use crate::demo_file::load_demos;
use crate::family_diff::verdict;
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
    if let Some((base, rest)) = rows.split_first()
        && !rest.is_empty()
    {
        render_paired(&mut s, base, rest);
    }
    s
}

/// A figure of one run that settings are compared by: its heading, how it is read, the decimal places printed.
type Figure = (&'static str, fn(&AblationRun) -> f64, usize);

/// What each setting is compared with the first by. The outer passages' share is Fig. S4's claim (an ungated
/// L_rec pulls FM from the outer passages to the central ones: 20 + 24 % → 10 + 4 % in the paper).
const PAIRED: [Figure; 4] = [
    ("success (points)", |r| f64::from(r.success_pct), 1),
    ("outer passages' share", |r| outer_share(&r.passage_counts), 3),
    ("γ", |r| f64::from(r.gamma), 2),
    ("TV to the demos", |r| f64::from(r.tv), 3),
];

/// The share of the successful rollouts through the layout's first and last passages (NaN with none).
pub fn outer_share(counts: &[usize]) -> f64 {
    let total: usize = counts.iter().sum();
    match counts {
        [first, .., last] if total > 0 => (first + last) as f64 / total as f64,
        _ => f64::NAN,
    }
}

/// `row` − `base` of one figure, seed by seed (both trained on that seed's demos); `None` when a seed has no
/// value (no successful rollout) or no seed pairs.
fn paired(base: &AblationRow, row: &AblationRow, figure: fn(&AblationRun) -> f64) -> Option<Estimate> {
    let d: Vec<f64> = row
        .runs
        .iter()
        .filter_map(|r| base.runs.iter().find(|b| b.seed == r.seed).map(|b| figure(r) - figure(b)))
        .collect();
    mean_over_seeds(&d)
}

/// Every setting against the first, paired by seed: the difference's mean with its 95 % t interval and a verdict.
fn render_paired(s: &mut String, base: &AblationRow, rows: &[AblationRow]) {
    let _ = writeln!(
        s,
        "\nAgainst {}, paired by seed (same demos, same rollout seeds): the difference's mean with its 95 % t \
         interval over seeds, \"differ\" when it excludes 0, \"undecided\" when not.\n",
        base.label
    );
    let heads: Vec<&str> = PAIRED.iter().map(|f| f.0).collect();
    let _ = writeln!(s, "| setting − {} | {} |", base.label, heads.join(" | "));
    let _ = writeln!(s, "|---|{}", "---|".repeat(PAIRED.len()));
    for row in rows {
        let cells: Vec<String> = PAIRED
            .iter()
            .map(|&(_, figure, places)| match paired(base, row, figure) {
                Some(e) => format!("{e:.places$} {}", verdict(e)),
                None => "– (a seed with no successful rollout)".into(),
            })
            .collect();
        let _ = writeln!(s, "| {} | {} |", row.label, cells.join(" | "));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn run(value: f64, seed: u64, success_pct: f32, passage_counts: Vec<usize>) -> AblationRun {
        AblationRun {
            value,
            seed,
            final_loss: 0.1,
            losses: vec![0.1],
            success_pct,
            passage_counts,
            gamma: 0.5,
            tv: 0.1,
        }
    }

    fn options(values: Vec<f64>, seeds: u64) -> AblateOptions {
        AblateOptions {
            knob: Knob::FmLambdaRec,
            values,
            demos: 10,
            epochs: Some(1),
            rollouts: 100,
            seeds,
            exec_horizon: 8,
            jobs: 1,
            resume: false,
        }
    }

    #[test]
    fn outer_share_is_the_first_and_last_passages_of_the_successes() {
        assert_eq!(outer_share(&[20, 24, 29, 27]), 0.47);
        assert!(outer_share(&[0, 0, 0, 0]).is_nan());
        assert!(outer_share(&[5]).is_nan());
    }

    #[test]
    fn a_steady_shift_to_the_centre_differs_and_one_seed_is_undecided() {
        let o = options(vec![0.0, 1.0], 5);
        let mut runs = Vec::new();
        for seed in 0..5 {
            let wobble = seed as usize;
            runs.push(run(0.0, seed, 90.0, vec![20 + wobble, 30, 30, 20]));
            runs.push(run(1.0, seed, 90.0 - seed as f32, vec![5, 40 + wobble, 45, 10]));
        }
        let rows: Vec<AblationRow> = o.values.iter().map(|&v| aggregate(&o, 1, v, &runs)).collect();
        let md = render(&rows, &o, Path::new("c.toml"), Path::new("l.toml"));
        let line = md.lines().find(|l| l.starts_with("| λ_rec 1 |") && l.contains("differ")).expect(&md);
        let cells: Vec<&str> = line.split(" | ").collect();
        assert!(cells[1].starts_with("-2.0 (") && cells[1].ends_with("differ"), "success: {line}");
        assert!(cells[2].starts_with("-0.") && cells[2].ends_with("differ"), "outer share: {line}");
        assert!(cells[3].ends_with("undecided"), "γ the same everywhere: {line}");

        let o = options(vec![0.0, 1.0], 1);
        let one: Vec<AblationRun> = runs.into_iter().filter(|r| r.seed == 0).collect();
        let rows: Vec<AblationRow> = o.values.iter().map(|&v| aggregate(&o, 1, v, &one)).collect();
        let md = render(&rows, &o, Path::new("c.toml"), Path::new("l.toml"));
        assert!(!md.contains(") differ"), "one seed decides nothing: {md}");
    }
}
