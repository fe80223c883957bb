//! `mars family-diff A B`: two `mars family` runs (their family.json) of the same layouts, seeds and demos under two
//! configurations — e.g. the velocity field conditioned on the history or not — compared seed by seed. For each
//! layout and policy: B − A of success, TV to the demos, γ and mean K, as the mean over seeds with its 95 % t
//! interval; "differ" when the interval excludes 0, "undecided" when it does not.

use crate::family::{LayoutResult, PolicyStats, SeedFigures};
use anyhow::Context;
use mars_tasks::stats::{Estimate, mean_over_seeds};
use std::fmt::Write;
use std::path::Path;

/// A family.json as `mars family` wrote it.
pub fn load(path: &Path) -> anyhow::Result<Vec<LayoutResult>> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{} is not a family.json of `mars family`", path.display()))
}

/// B − A of one figure, seed by seed (both trained on that seed's demos).
fn paired(a: &PolicyStats, b: &PolicyStats, figure: fn(&SeedFigures) -> f64) -> Estimate {
    let d: Vec<f64> = a.per_seed.iter().zip(&b.per_seed).map(|(x, y)| figure(y) - figure(x)).collect();
    mean_over_seeds(&d).unwrap_or(Estimate::new(f64::NAN, f64::NAN, f64::NAN))
}

/// "differ" when a difference's 95 % interval excludes 0, "undecided" when it does not (one seed never decides).
pub(crate) fn verdict(e: Estimate) -> &'static str {
    if e.lo > 0.0 || e.hi < 0.0 { "differ" } else { "undecided" }
}

/// A compared figure: its heading, how it is read from a seed's figures, and the decimal places it is printed with.
type Figure = (&'static str, fn(&SeedFigures) -> f64, usize);

/// The figures compared.
const FIGURES: [Figure; 4] = [
    ("success (points)", |s| s.success_pct, 1),
    ("TV to the demos", |s| s.tv, 3),
    ("γ", |s| s.gamma, 2),
    ("mean K", |s| s.mean_k, 2),
];

/// The comparison table of the layouts and policies the two runs share; an error where a shared layout was run on
/// other seeds or demos (its differences would not pair).
pub fn render(a: &[LayoutResult], b: &[LayoutResult], names: (&str, &str)) -> anyhow::Result<String> {
    let mut s = format!("# {} − {}, seed by seed\n\n", names.1, names.0);
    let _ = writeln!(
        s,
        "Each cell: B − A as the mean over training seeds with its 95 % t interval, then whether the interval \
         excludes 0 (differ) or not (undecided). A = {}, B = {}.\n",
        names.0, names.1
    );
    let heads: Vec<&str> = FIGURES.iter().map(|f| f.0).collect();
    let _ = writeln!(s, "| layout | policy | seeds | {} |", heads.join(" | "));
    let _ = writeln!(s, "|---|---|---:|{}", "---|".repeat(FIGURES.len()));
    let mut rows = 0;
    for la in a {
        let Some(lb) = b.iter().find(|l| l.layout == la.layout) else { continue };
        anyhow::ensure!(
            la.seeds == lb.seeds && la.demo_proportions == lb.demo_proportions,
            "layout {}: the runs were not on the same seeds and demos ({} seeds, demo shares {:?}; {} seeds, {:?})",
            la.layout,
            la.seeds,
            la.demo_proportions,
            lb.seeds,
            lb.demo_proportions
        );
        for pa in &la.policies {
            let Some(pb) = lb.policies.iter().find(|p| p.kind == pa.kind) else { continue };
            let cells: Vec<String> = FIGURES
                .iter()
                .map(|&(_, figure, places)| {
                    let e = paired(pa, pb, figure);
                    format!("{e:.places$} {}", verdict(e))
                })
                .collect();
            let _ = writeln!(s, "| {} | {} | {} | {} |", la.layout, pa.kind, la.seeds, cells.join(" | "));
            rows += 1;
        }
    }
    anyhow::ensure!(rows > 0, "the two runs share no layout and policy");
    Ok(s)
}

/// Loads both runs, prints the table and writes it to `out` if given.
pub fn run(a: &Path, b: &Path, out: Option<&Path>) -> anyhow::Result<()> {
    let names = (a.display().to_string(), b.display().to_string());
    let md = render(&load(a)?, &load(b)?, (&names.0, &names.1))?;
    if let Some(out) = out {
        std::fs::write(out, &md).with_context(|| format!("cannot write {}", out.display()))?;
    }
    println!("{md}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::config::PolicyKind;

    fn stats(kind: PolicyKind, success: &[f64]) -> PolicyStats {
        let e = Estimate::new(0.0, 0.0, 0.0);
        let seed = |&s: &f64| SeedFigures { success_pct: s, tv: 0.1, gamma: 0.5, mean_k: 2.0, passage_counts: vec![] };
        PolicyStats {
            kind,
            success_pct: e,
            tv: e,
            gamma: e,
            mean_k: e,
            proportions: vec![],
            train_s: None,
            per_seed: success.iter().map(seed).collect(),
        }
    }

    fn layout(seeds: usize, policies: Vec<PolicyStats>) -> LayoutResult {
        let demo_proportions = vec![0.25; 4];
        LayoutResult {
            layout: "four".into(),
            n_passages: 4,
            demo_proportions,
            demo_gamma: 1.0,
            seeds,
            policies,
            verdicts: vec![],
        }
    }

    #[test]
    fn a_steady_gain_differs_and_a_noisy_one_is_undecided() {
        let mars_a = stats(PolicyKind::Mars, &[80.0, 82.0, 78.0, 85.0, 81.0]);
        let fm_a = stats(PolicyKind::Fm, &[70.0, 75.0, 72.0, 71.0, 74.0]);
        let mars_b = stats(PolicyKind::Mars, &[90.0, 91.0, 88.0, 94.0, 90.0]);
        let fm_b = stats(PolicyKind::Fm, &[80.0, 65.0, 79.0, 62.0, 84.0]);
        let md = render(&[layout(5, vec![mars_a, fm_a])], &[layout(5, vec![mars_b, fm_b])], ("A", "B")).unwrap();
        let row = |kind: &str| md.lines().find(|l| l.starts_with(&format!("| four | {kind} |"))).unwrap().to_string();
        let cells = |kind: &str| row(kind).split(" | ").map(str::to_string).collect::<Vec<_>>();
        // MARS gains 10, 9, 10, 9, 9 points; FM 10, −10, 7, −9, 10.
        assert!(cells("mars")[3].starts_with("9.4 (") && cells("mars")[3].ends_with("differ"), "{md}");
        assert!(cells("fm")[3].starts_with("1.6 (") && cells("fm")[3].ends_with("undecided"), "{md}");
        // The same TV everywhere: no difference, undecided.
        assert!(cells("mars")[4].ends_with("undecided"), "{md}");
    }

    #[test]
    fn runs_on_other_seeds_do_not_pair() {
        let a = [layout(5, vec![stats(PolicyKind::Mars, &[80.0; 5])])];
        let b = [layout(3, vec![stats(PolicyKind::Mars, &[80.0; 3])])];
        let e = render(&a, &b, ("A", "B")).unwrap_err().to_string();
        assert!(e.contains("not on the same seeds and demos"), "{e}");
        let other = [LayoutResult { layout: "two".into(), ..layout(5, vec![]) }];
        assert!(render(&a, &other, ("A", "B")).is_err());
    }
}
