//! `mars family`: the benchmark on every nav2d layout of a folder, over several training seeds (each with its own
//! demos), and the method's targets judged by their 95 % intervals over the seeds: met, not met or undecided.
//! MARS and FM trained on one seed's demos are compared seed by seed (paired differences); A2A and Noise-A2A are
//! judged on whether they keep one passage only (the paper's Table 1).

use crate::benchmark::{BenchmarkOptions, Row, benchmark};
use crate::config::PolicyKind;
use crate::stats::proportions;
use anyhow::Context;
use mars_tasks::stats::{Estimate, Verdict, mean_over_seeds};
use serde::{Deserialize, Serialize};
use std::fmt::Write;
use std::path::{Path, PathBuf};

/// The method's targets (issue 34), checked for MARS against FM on each layout.
#[derive(Debug, Clone, Serialize)]
pub struct Targets {
    /// MARS's total-variation distance to the demos' passage shares may exceed FM's by at most this.
    pub tv_above_fm: f64,
    /// MARS's success rate may be at most this many points below FM's.
    pub success_below_fm_pts: f64,
    /// Largest allowed mean K for MARS.
    pub max_mean_k: f64,
    /// FM's own total-variation distance to its demos' shares.
    pub fm_max_tv: f64,
}

impl Default for Targets {
    fn default() -> Self {
        Self { tv_above_fm: 0.05, success_below_fm_pts: 2.0, max_mean_k: 3.0, fm_max_tv: 0.10 }
    }
}

pub struct FamilyOptions {
    pub bench: BenchmarkOptions,
    /// Training seeds 0..seeds (demos and rollouts use the same seed as the training).
    pub seeds: u64,
    pub targets: Targets,
}

/// One seed's figures of one policy.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SeedFigures {
    pub success_pct: f64,
    pub tv: f64,
    pub gamma: f64,
    pub mean_k: f64,
    pub passage_counts: Vec<usize>,
}

impl SeedFigures {
    fn of(row: &Row) -> Self {
        Self {
            success_pct: 100.0 * row.intervals.success.value,
            tv: row.intervals.tv.value,
            gamma: row.intervals.gamma.value,
            mean_k: f64::from(row.report.mean_k),
            passage_counts: row.report.passage_counts.clone(),
        }
    }
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PolicyStats {
    pub kind: PolicyKind,
    /// Means over seeds with their 95 % t intervals.
    pub success_pct: Estimate,
    pub tv: Estimate,
    pub gamma: Estimate,
    pub mean_k: Estimate,
    /// Mean over seeds of each passage's share.
    pub proportions: Vec<f32>,
    /// Over the seeds whose training time was recorded (`--resume` keeps checkpoints of runs that did not).
    pub train_s: Option<Estimate>,
    pub per_seed: Vec<SeedFigures>,
}

#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LayoutResult {
    pub layout: String,
    pub n_passages: usize,
    pub demo_proportions: Vec<f32>,
    pub demo_gamma: f32,
    pub seeds: usize,
    pub policies: Vec<PolicyStats>,
    /// (claim with its interval, verdict) for MARS against FM.
    pub verdicts: Vec<(String, Verdict)>,
}

/// The mean over seeds with its interval; no value (no seed, or a non-finite figure) gives NaN throughout,
/// which every [`Verdict`] reads as undecided (NaN compares false both ways) and the tables print as NaN.
pub(crate) fn over_seeds(values: &[f64]) -> Estimate {
    mean_over_seeds(values).unwrap_or(Estimate::new(f64::NAN, f64::NAN, f64::NAN))
}

/// Aggregates one layout's benchmark rows over seeds (`runs[seed]` = that seed's rows).
pub fn aggregate(layout: &str, demo_counts: &[usize], runs: &[Vec<Row>], targets: &Targets) -> LayoutResult {
    let kinds: Vec<PolicyKind> = runs.first().map(|r| r.iter().map(|row| row.kind).collect()).unwrap_or_default();
    let policies: Vec<PolicyStats> =
        kinds.into_iter().map(|kind| policy_stats(kind, demo_counts.len(), runs)).collect();
    LayoutResult {
        layout: layout.into(),
        n_passages: demo_counts.len(),
        demo_gamma: mars_tasks::nav2d::eval::modal_balance(demo_counts),
        demo_proportions: proportions(demo_counts),
        seeds: runs.len(),
        verdicts: verdicts(&policies, targets),
        policies,
    }
}

fn policy_stats(kind: PolicyKind, n_passages: usize, runs: &[Vec<Row>]) -> PolicyStats {
    let rows: Vec<&Row> = runs.iter().filter_map(|r| r.iter().find(|row| row.kind == kind)).collect();
    let per_seed: Vec<SeedFigures> = rows.iter().map(|r| SeedFigures::of(r)).collect();
    let of = |f: fn(&SeedFigures) -> f64| over_seeds(&per_seed.iter().map(f).collect::<Vec<_>>());
    let props: Vec<Vec<f32>> = rows.iter().map(|r| proportions(&r.report.passage_counts)).collect();
    let train_s: Vec<f64> = rows.iter().filter_map(|r| r.train_s).map(f64::from).collect();
    PolicyStats {
        kind,
        success_pct: of(|s| s.success_pct),
        tv: of(|s| s.tv),
        gamma: of(|s| s.gamma),
        mean_k: of(|s| s.mean_k),
        proportions: (0..n_passages)
            .map(|k| props.iter().map(|p| p[k]).sum::<f32>() / props.len().max(1) as f32)
            .collect(),
        train_s: (!train_s.is_empty()).then(|| over_seeds(&train_s)),
        per_seed,
    }
}

/// MARS − FM, seed by seed (both trained on that seed's demos), as a mean over seeds with its interval.
fn paired(m: &PolicyStats, f: &PolicyStats, figure: fn(&SeedFigures) -> f64) -> Estimate {
    let d: Vec<f64> = m.per_seed.iter().zip(&f.per_seed).map(|(a, b)| figure(a) - figure(b)).collect();
    over_seeds(&d)
}

/// The largest passage's share of one seed's successful rollouts (NaN with none).
fn largest_share(s: &SeedFigures) -> f64 {
    let total: usize = s.passage_counts.iter().sum();
    s.passage_counts.iter().max().map_or(f64::NAN, |&m| m as f64 / total as f64)
}

fn verdicts(policies: &[PolicyStats], t: &Targets) -> Vec<(String, Verdict)> {
    let get = |k: PolicyKind| policies.iter().find(|p| p.kind == k);
    let mut v = Vec::new();
    // The paper's Table 1: the history-sourced baselines keep one mode.
    for a2a in [PolicyKind::A2a, PolicyKind::NoiseA2a].into_iter().filter_map(get) {
        let top = over_seeds(&a2a.per_seed.iter().map(largest_share).collect::<Vec<_>>()).scaled(100.0);
        let claim = format!("{} collapses onto one passage (its largest share ≥ 90 %): {top:.1} %", a2a.kind);
        v.push((claim, Verdict::at_least(top, 90.0)));
    }
    let Some(m) = get(PolicyKind::Mars) else { return v };
    if let Some(f) = get(PolicyKind::Fm) {
        let tv = paired(m, f, |s| s.tv);
        let claim = format!("MARS's TV to the demos at most {:.2} above FM's: MARS − FM = {tv:.3}", t.tv_above_fm);
        v.push((claim, Verdict::at_most(tv, t.tv_above_fm)));
        let success = paired(m, f, |s| s.success_pct);
        let claim = format!(
            "MARS success at most {:.0} points below FM's: MARS − FM = {success:.1} points",
            t.success_below_fm_pts
        );
        v.push((claim, Verdict::at_least(success, -t.success_below_fm_pts)));
        let claim = format!("FM's TV to its demos ≤ {:.2}: {:.3}", t.fm_max_tv, f.tv);
        v.push((claim, Verdict::at_most(f.tv, t.fm_max_tv)));
    }
    v.push((format!("MARS mean K ≤ {:.0}: {:.2}", t.max_mean_k, m.mean_k), Verdict::at_most(m.mean_k, t.max_mean_k)));
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
    let layouts = files.iter().map(|f| mars_tasks::nav2d::layout::Layout::load(f)).collect::<Result<Vec<_>, _>>()?;
    // Every layout × seed is one benchmark, its policies trained one after the other; the benchmarks run `jobs`
    // at a time, so no core idles while a long MARS training finishes beside a short FM one.
    let items: Vec<(usize, u64)> = (0..files.len()).flat_map(|l| (0..o.seeds).map(move |s| (l, s))).collect();
    let runs = crate::jobs::parallel(&items, o.bench.jobs, &|&(l, seed)| {
        let dir = out.join(&layouts[l].name).join(format!("seed{seed}"));
        println!("\n=== {} (seed {seed}) → {}", layouts[l].name, dir.display());
        let bench = BenchmarkOptions { seed, jobs: 1, side_by_side: o.bench.jobs > 1, ..o.bench.clone() };
        benchmark(&dir, config, &files[l], &bench)
    })?;
    let mut runs = runs.into_iter();
    let mut results = Vec::new();
    for layout in &layouts {
        let runs: Vec<_> = runs.by_ref().take(o.seeds as usize).collect();
        let set = crate::demo_file::load_demos(&out.join(&layout.name).join("seed0").join("demos.json"))?;
        let mut demo_counts = vec![0usize; layout.n_passages()];
        for m in set.demos.iter().filter_map(|d| d.mode) {
            if let Some(c) = demo_counts.get_mut(m) {
                *c += 1;
            }
        }
        results.push(aggregate(&layout.name, &demo_counts, &runs, &o.targets));
    }
    let md = render(&results, o, config, layouts_dir);
    std::fs::write(out.join("family.md"), &md).with_context(|| format!("cannot write {}", out.display()))?;
    std::fs::write(out.join("family.json"), serde_json::to_string_pretty(&results)?)
        .with_context(|| format!("cannot write {}", out.display()))?;
    println!("\n{md}");
    Ok(results)
}

fn shares(p: &[f32]) -> String {
    p.iter().map(|x| format!("{:.0}", 100.0 * x)).collect::<Vec<_>>().join("/")
}

pub fn render(results: &[LayoutResult], o: &FamilyOptions, config: &Path, layouts_dir: &Path) -> String {
    let b = &o.bench;
    let policies: Vec<&str> = b.policies.iter().map(|k| k.name()).collect();
    let mut s = String::from("# nav2d layout family\n\n");
    let _ = writeln!(
        s,
        "Command: `mars family --config {} --layouts {} --seeds {} --demos {} --rollouts {}{}{}{} --policies {} --jobs {}`; \
         mean over training seeds 0..{} (each seed its own demos and rollouts) with its 95 % t interval; a \
         target is met or not met when the whole interval says so, undecided otherwise.\n",
        config.display(),
        layouts_dir.display(),
        o.seeds,
        b.demos,
        b.rollouts,
        b.epochs.map_or(String::new(), |e| format!(" --epochs {e}")),
        if b.history_conditioning { " --history-conditioning" } else { "" },
        b.k_full_w.map_or(String::new(), |w| format!(" --k-full-w {w}")),
        policies.join(","),
        b.jobs,
        o.seeds,
    );
    for r in results {
        let _ = writeln!(
            s,
            "## {} ({} passages; demo shares {} %, demos' own γ {:.2}; {} seeds)\n",
            r.layout,
            r.n_passages,
            shares(&r.demo_proportions),
            r.demo_gamma,
            r.seeds
        );
        let _ =
            writeln!(s, "| policy | success % | passage shares % (mean) | TV to the demos | γ | mean K | train s |");
        let _ = writeln!(s, "|---|---|---|---|---|---|---|");
        for p in &r.policies {
            let _ = writeln!(
                s,
                "| {} | {:.1} | {} | {:.3} | {:.2} | {:.2} | {} |",
                p.kind,
                p.success_pct,
                shares(&p.proportions),
                p.tv,
                p.gamma,
                p.mean_k,
                p.train_s.map_or("–".into(), |t| format!("{t:.0}"))
            );
        }
        let _ = writeln!(s);
        for (claim, verdict) in &r.verdicts {
            let _ = writeln!(s, "- {claim} — {verdict}");
        }
        let _ = writeln!(s);
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;
    use mars_tasks::nav2d::eval::EvalReport;

    /// A row of `n` rollouts: `counts[i]` successes through passage i, the rest collisions.
    fn row(kind: PolicyKind, counts: Vec<usize>, n: usize, k: f32) -> Row {
        use mars_tasks::nav2d::{Episode, Termination};
        let episode =
            |termination, mode| Episode { seed: 0, start: [0.0; 2], steps: vec![], calls: vec![], termination, mode };
        let mut episodes: Vec<Episode> =
            (0..n - counts.iter().sum::<usize>()).map(|_| episode(Termination::Collision, None)).collect();
        for (passage, &c) in counts.iter().enumerate() {
            episodes.extend((0..c).map(|_| episode(Termination::Success, Some(passage))));
        }
        let mut report = EvalReport::from_episodes(counts.len(), episodes);
        report.mean_k = k;
        let demo_shares = [0.25, 0.45, 0.30];
        let shares: &[f64] = if counts.len() == 3 { &demo_shares } else { &[0.5, 0.5] };
        let intervals = report.intervals(shares, 0);
        Row { kind, epochs: 1, train_s: Some(1.0), report, intervals, w_regions: Vec::new() }
    }

    fn runs(fm: &[Vec<usize>], mars: &[Vec<usize>], mars_k: f32) -> Vec<Vec<Row>> {
        fm.iter()
            .zip(mars)
            .map(|(f, m)| {
                vec![row(PolicyKind::Mars, m.clone(), 100, mars_k), row(PolicyKind::Fm, f.clone(), 100, 10.0)]
            })
            .collect()
    }

    #[test]
    fn a_collapsed_mars_is_judged_not_met_and_a_faithful_one_met_by_their_intervals() {
        let demos = [25, 45, 30];
        let fm = [vec![24, 46, 30], vec![26, 44, 30], vec![25, 45, 29], vec![23, 47, 30], vec![25, 44, 31]];
        let collapsed = [vec![4, 60, 24], vec![5, 62, 25], vec![3, 58, 27], vec![6, 61, 24], vec![4, 63, 23]];
        let r = aggregate("three", &demos, &runs(&fm, &collapsed, 1.7), &Targets::default());
        let got: Vec<Verdict> = r.verdicts.iter().map(|v| v.1).collect();
        // TV 0.2 above FM's, success 10 points below, FM faithful, K low.
        assert_eq!(got, [Verdict::NotMet, Verdict::NotMet, Verdict::Met, Verdict::Met], "{:?}", r.verdicts);
        assert!((r.demo_gamma - 0.75).abs() < 1e-6);
        assert_eq!(r.seeds, 5);

        let faithful = [vec![25, 45, 30], vec![26, 44, 30], vec![24, 46, 30], vec![25, 46, 29], vec![24, 45, 31]];
        let r = aggregate("three", &demos, &runs(&fm, &faithful, 2.5), &Targets::default());
        assert!(r.verdicts.iter().all(|v| v.1 == Verdict::Met), "{:?}", r.verdicts);
    }

    #[test]
    fn a2a_on_one_passage_is_judged_collapsed_and_one_on_two_is_not() {
        let demos = [25, 45, 30];
        let one = [vec![0, 95, 0], vec![0, 90, 2], vec![1, 93, 0], vec![0, 96, 0], vec![0, 92, 1]];
        let two = [vec![40, 50, 0], vec![45, 45, 0], vec![30, 60, 0], vec![50, 40, 0], vec![41, 49, 0]];
        let a2a_runs = |counts: &[Vec<usize>; 5]| -> Vec<Vec<Row>> {
            counts.iter().map(|c| vec![row(PolicyKind::A2a, c.clone(), 100, 1.0)]).collect()
        };
        let r = aggregate("three", &demos, &a2a_runs(&one), &Targets::default());
        assert_eq!(r.verdicts.len(), 1, "no MARS, so no MARS target: {:?}", r.verdicts);
        assert!(r.verdicts[0].0.starts_with("a2a collapses onto one passage"), "{:?}", r.verdicts);
        assert_eq!(r.verdicts[0].1, Verdict::Met, "{:?}", r.verdicts);
        let r = aggregate("three", &demos, &a2a_runs(&two), &Targets::default());
        assert_eq!(r.verdicts[0].1, Verdict::NotMet, "{:?}", r.verdicts);
    }

    #[test]
    fn two_seeds_that_disagree_leave_the_targets_undecided() {
        let demos = [50, 50];
        let fm = [vec![50, 50], vec![50, 50]];
        let mars = [vec![50, 50], vec![90, 10]];
        let r = aggregate("two", &demos, &runs(&fm, &mars, 2.0), &Targets::default());
        assert_eq!(r.verdicts[0].1, Verdict::Undecided, "{:?}", r.verdicts);
        // One seed says nothing of the spread between seeds: its interval is unbounded.
        let r = aggregate("two", &demos, &runs(&fm[..1], &mars[..1], 2.0), &Targets::default());
        assert!(r.verdicts.iter().all(|v| v.1 == Verdict::Undecided), "{:?}", r.verdicts);
    }
}
