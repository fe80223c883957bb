//! `mars family`: the benchmark on every nav2d layout of a folder, over several training seeds, and the mode
//! targets checked on the means: does MARS keep each passage in the demos' proportion (as FM does) at a
//! fraction of FM's steps, on layouts the project was not tuned on?

use crate::cli::{BenchmarkOptions, benchmark};
use crate::config::PolicyKind;
use crate::report::Row;
use anyhow::Context;
use serde::Serialize;
use std::fmt::Write;
use std::path::{Path, PathBuf};

/// The mode targets of the family run (issue 11), checked for MARS against FM on each layout.
#[derive(Debug, Clone, Serialize)]
pub struct Targets {
    /// Largest allowed |MARS's share of a passage − the demos' share|, averaged over seeds.
    pub max_proportion_gap: f32,
    /// MARS's γ may be at most this much below FM's.
    pub gamma_below_fm: f32,
    /// MARS's success rate may be at most this many points below FM's.
    pub success_below_fm_pts: f32,
    /// Largest allowed mean K for MARS.
    pub max_mean_k: f32,
}

impl Default for Targets {
    fn default() -> Self {
        Self { max_proportion_gap: 0.10, gamma_below_fm: 0.10, success_below_fm_pts: 2.0, max_mean_k: 3.0 }
    }
}

pub struct FamilyOptions {
    pub bench: BenchmarkOptions,
    /// Training seeds 0..seeds (demos and rollouts use the same seed as the training).
    pub seeds: u64,
    pub targets: Targets,
}

#[derive(Debug, Clone, Copy, Serialize)]
pub struct MeanStd {
    pub mean: f32,
    /// Sample standard deviation (0 for a single seed).
    pub std: f32,
}

impl MeanStd {
    pub fn of(v: &[f32]) -> Self {
        let n = v.len().max(1) as f32;
        let mean = v.iter().sum::<f32>() / n;
        let var = if v.len() > 1 { v.iter().map(|x| (x - mean).powi(2)).sum::<f32>() / (n - 1.0) } else { 0.0 };
        Self { mean, std: var.sqrt() }
    }
}

impl std::fmt::Display for MeanStd {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let p = f.precision().unwrap_or(2);
        write!(f, "{:.p$} ± {:.p$}", self.mean, self.std)
    }
}

/// Successful rollouts per passage as shares of all successful rollouts that used a passage.
pub fn proportions(counts: &[usize]) -> Vec<f32> {
    let total: usize = counts.iter().sum();
    counts.iter().map(|&c| if total == 0 { 0.0 } else { c as f32 / total as f32 }).collect()
}

/// max_k |p_k − q_k|.
pub fn max_gap(p: &[f32], q: &[f32]) -> f32 {
    p.iter().zip(q).map(|(a, b)| (a - b).abs()).fold(0.0, f32::max)
}

#[derive(Debug, Clone, Serialize)]
pub struct PolicyStats {
    pub kind: PolicyKind,
    /// Success rate in percent.
    pub success_pct: MeanStd,
    pub gamma: MeanStd,
    pub mean_k: MeanStd,
    /// Mean over seeds of each passage's share.
    pub proportions: Vec<f32>,
    pub proportion_gap: MeanStd,
    /// Over the seeds whose training time was recorded (`--resume` keeps checkpoints of runs that did not).
    pub train_s: Option<MeanStd>,
    /// Per seed: passage counts, for the record.
    pub passage_counts: Vec<Vec<usize>>,
}

#[derive(Debug, Clone, Serialize)]
pub struct LayoutResult {
    pub layout: String,
    pub n_passages: usize,
    pub demo_proportions: Vec<f32>,
    pub demo_gamma: f32,
    pub policies: Vec<PolicyStats>,
    /// (claim, met) for MARS against FM.
    pub verdicts: Vec<(String, bool)>,
}

/// Aggregates one layout's benchmark rows over seeds (`runs[seed]` = that seed's rows).
pub fn aggregate(layout: &str, demo_counts: &[usize], runs: &[Vec<Row>], targets: &Targets) -> LayoutResult {
    let demo_proportions = proportions(demo_counts);
    let mut policies = Vec::new();
    let kinds: Vec<PolicyKind> = runs.first().map(|r| r.iter().map(|row| row.kind).collect()).unwrap_or_default();
    for kind in kinds {
        let rows: Vec<&Row> = runs.iter().filter_map(|r| r.iter().find(|row| row.kind == kind)).collect();
        let per_seed = |f: &dyn Fn(&Row) -> f32| MeanStd::of(&rows.iter().map(|r| f(r)).collect::<Vec<_>>());
        let props: Vec<Vec<f32>> = rows.iter().map(|r| proportions(&r.report.passage_counts)).collect();
        let mean_props = (0..demo_counts.len())
            .map(|k| props.iter().map(|p| p[k]).sum::<f32>() / props.len().max(1) as f32)
            .collect();
        policies.push(PolicyStats {
            kind,
            success_pct: per_seed(&|r| 100.0 * r.report.success_rate()),
            gamma: per_seed(&|r| r.report.modal_balance),
            mean_k: per_seed(&|r| r.report.mean_k),
            proportions: mean_props,
            proportion_gap: MeanStd::of(&props.iter().map(|p| max_gap(p, &demo_proportions)).collect::<Vec<_>>()),
            train_s: {
                let t: Vec<f32> = rows.iter().filter_map(|r| r.train_s).collect();
                (!t.is_empty()).then(|| MeanStd::of(&t))
            },
            passage_counts: rows.iter().map(|r| r.report.passage_counts.clone()).collect(),
        });
    }
    let verdicts = verdicts(&policies, targets);
    LayoutResult {
        layout: layout.into(),
        n_passages: demo_counts.len(),
        demo_gamma: mars_tasks::nav2d::eval::modal_balance(demo_counts),
        demo_proportions,
        policies,
        verdicts,
    }
}

fn verdicts(policies: &[PolicyStats], t: &Targets) -> Vec<(String, bool)> {
    let get = |k: PolicyKind| policies.iter().find(|p| p.kind == k);
    let mut v = Vec::new();
    let Some(m) = get(PolicyKind::Mars) else { return v };
    v.push((
        format!(
            "MARS passage shares within {:.2} of the demos' (max |p − p_demo|): {:.3}",
            t.max_proportion_gap, m.proportion_gap
        ),
        m.proportion_gap.mean <= t.max_proportion_gap,
    ));
    if let Some(f) = get(PolicyKind::Fm) {
        v.push((
            format!("MARS γ at most {:.2} below FM's: {:.2} vs {:.2}", t.gamma_below_fm, m.gamma, f.gamma),
            m.gamma.mean >= f.gamma.mean - t.gamma_below_fm,
        ));
        v.push((
            format!(
                "MARS success at most {:.0} points below FM's: {:.1} % vs {:.1} %",
                t.success_below_fm_pts, m.success_pct, f.success_pct
            ),
            m.success_pct.mean >= f.success_pct.mean - t.success_below_fm_pts,
        ));
    }
    v.push((format!("MARS mean K ≤ {:.0}: {:.2}", t.max_mean_k, m.mean_k), m.mean_k.mean <= t.max_mean_k));
    v
}

/// The layouts of a folder: every `*.toml`, by file name.
pub fn layout_files(dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
    let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
        .with_context(|| format!("cannot read the layout folder {}", dir.display()))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    files.sort();
    anyhow::ensure!(!files.is_empty(), "no *.toml layout in {}", dir.display());
    Ok(files)
}

/// Runs the benchmark for every layout × seed under `out/<layout>/seed<s>`, then writes `out/family.md` and
/// `out/family.json` and prints the tables.
pub fn run(out: &Path, config: &Path, layouts_dir: &Path, o: &FamilyOptions) -> anyhow::Result<Vec<LayoutResult>> {
    anyhow::ensure!(o.seeds >= 1, "--seeds must be at least 1");
    let files = layout_files(layouts_dir)?;
    let mut results = Vec::new();
    for file in &files {
        let layout = mars_tasks::nav2d::layout::Layout::load(file)?;
        let mut runs = Vec::new();
        let mut demo_counts = vec![0usize; layout.n_passages()];
        for seed in 0..o.seeds {
            let dir = out.join(&layout.name).join(format!("seed{seed}"));
            println!("\n=== {} (seed {seed}) → {}", layout.name, dir.display());
            let bench = BenchmarkOptions { seed, ..o.bench.clone() };
            runs.push(benchmark(&dir, config, file, &bench)?);
            if seed == 0 {
                let set = crate::cli::load_demos(&dir.join("demos.json"))?;
                for m in set.demos.iter().filter_map(|d| d.mode) {
                    if let Some(c) = demo_counts.get_mut(m) {
                        *c += 1;
                    }
                }
            }
        }
        results.push(aggregate(&layout.name, &demo_counts, &runs, &o.targets));
    }
    let md = render(&results, o, layouts_dir);
    std::fs::write(out.join("family.md"), &md).with_context(|| format!("cannot write {}", out.display()))?;
    std::fs::write(out.join("family.json"), serde_json::to_string_pretty(&results)?)
        .with_context(|| format!("cannot write {}", out.display()))?;
    println!("\n{md}");
    Ok(results)
}

fn shares(p: &[f32]) -> String {
    p.iter().map(|x| format!("{:.0}", 100.0 * x)).collect::<Vec<_>>().join("/")
}

pub fn render(results: &[LayoutResult], o: &FamilyOptions, layouts_dir: &Path) -> String {
    let b = &o.bench;
    let policies: Vec<&str> = b.policies.iter().map(|k| k.name()).collect();
    let mut s = String::from("# nav2d layout family\n\n");
    let _ = writeln!(
        s,
        "Command: `mars family --layouts {} --seeds {} --demos {} --rollouts {}{} --policies {} --jobs {}`; \
         mean ± std over training seeds 0..{} (demos and rollouts seeded alike).\n",
        layouts_dir.display(),
        o.seeds,
        b.demos,
        b.rollouts,
        b.epochs.map_or(String::new(), |e| format!(" --epochs {e}")),
        policies.join(","),
        b.jobs,
        o.seeds,
    );
    for r in results {
        let _ = writeln!(
            s,
            "## {} ({} passages; demo shares {} %, demos' own γ {:.2})\n",
            r.layout,
            r.n_passages,
            shares(&r.demo_proportions),
            r.demo_gamma
        );
        let _ = writeln!(s, "| policy | success % | passage shares % | max \\|p − p_demo\\| | γ | mean K | train s |");
        let _ = writeln!(s, "|---|---:|---|---:|---:|---:|---:|");
        for p in &r.policies {
            let _ = writeln!(
                s,
                "| {} | {:.1} | {} | {:.3} | {:.2} | {:.2} | {} |",
                p.kind,
                p.success_pct,
                shares(&p.proportions),
                p.proportion_gap,
                p.gamma,
                p.mean_k,
                p.train_s.map_or("–".into(), |t| format!("{t:.0}"))
            );
        }
        let _ = writeln!(s);
        for (claim, ok) in &r.verdicts {
            let _ = writeln!(s, "- {claim} — {}", if *ok { "met" } else { "NOT met" });
        }
        let _ = writeln!(s);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use mars_tasks::nav2d::eval::EvalReport;

    fn row(kind: PolicyKind, counts: Vec<usize>, n: usize, k: f32) -> Row {
        let mut report = EvalReport::from_episodes(counts.len(), Vec::new());
        report.successes = counts.iter().sum();
        report.n = n;
        report.modal_balance = mars_tasks::nav2d::eval::modal_balance(&counts);
        report.passage_counts = counts;
        report.mean_k = k;
        Row { kind, epochs: 1, train_s: Some(1.0), report, w_regions: Vec::new() }
    }

    #[test]
    fn mean_std_is_the_sample_deviation() {
        let m = MeanStd::of(&[1.0, 2.0, 3.0]);
        assert_eq!(m.mean, 2.0);
        assert!((m.std - 1.0).abs() < 1e-6);
        assert_eq!(MeanStd::of(&[5.0]).std, 0.0);
    }

    #[test]
    fn a_collapsed_mars_fails_the_share_and_gamma_targets_and_a_faithful_one_meets_them() {
        let demos = [25, 45, 30];
        let fm =
            vec![row(PolicyKind::Fm, vec![24, 46, 30], 100, 10.0), row(PolicyKind::Fm, vec![26, 44, 30], 100, 10.0)];
        let collapsed =
            vec![row(PolicyKind::Mars, vec![4, 68, 24], 100, 1.7), row(PolicyKind::Mars, vec![5, 70, 25], 100, 1.7)];
        let runs: Vec<Vec<Row>> = fm.into_iter().zip(collapsed).map(|(f, m)| vec![m, f]).collect();
        let r = aggregate("three", &demos, &runs, &Targets::default());
        let met: Vec<bool> = r.verdicts.iter().map(|v| v.1).collect();
        assert_eq!(met, [false, false, true, true], "{:?}", r.verdicts);
        assert!((r.demo_gamma - 0.75).abs() < 1e-6);

        let fm = vec![row(PolicyKind::Fm, vec![24, 46, 30], 100, 10.0)];
        let faithful = vec![row(PolicyKind::Mars, vec![27, 41, 31], 99, 2.5)];
        let runs: Vec<Vec<Row>> = fm.into_iter().zip(faithful).map(|(f, m)| vec![m, f]).collect();
        let r = aggregate("three", &demos, &runs, &Targets::default());
        assert!(r.verdicts.iter().all(|v| v.1), "{:?}", r.verdicts);
    }

    #[test]
    fn no_success_gives_zero_shares_and_the_full_gap() {
        assert_eq!(proportions(&[0, 0]), vec![0.0, 0.0]);
        assert_eq!(max_gap(&[0.0, 0.0], &[0.3, 0.7]), 0.7);
    }
}
