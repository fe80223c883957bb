//! `mars diagnose-family DIR`: where a `mars family` run's checkpoints lose their demos' modes, judged over the
//! training seeds. For every layout, seed and policy: the first chunk's heading past the entry gate
//! ([`crate::diagnose::fork_choices`] on that seed's own demos) against the demos' recorded passages — the
//! distance *at the fork* — beside the rollouts' distance (the family's own figure for that seed). Their paired
//! difference says whether the modes are lost when the fork is chosen (≈ 0) or after it (> 0); MARS − FM at the
//! fork says whether MARS's first choice is further from the demos than FM's. Means over seeds with 95 % t
//! intervals; a claim is met, not met or undecided by its interval.

use crate::config::PolicyKind;
use crate::diagnose::fork_choices;
use crate::family::{LayoutResult, over_seeds};
use crate::inference::MarsPolicy;
use anyhow::Context;
use mars_tasks::nav2d::layout::Layout;
use mars_tasks::stats::{Estimate, Verdict, tv_distance};
use serde::Serialize;
use std::fmt::Write;
use std::path::Path;

/// How far MARS's first choice may be from the demos beyond FM's (the family's TV target, at the fork).
const FORK_TV_ABOVE_FM: f64 = 0.05;

/// One policy on one layout, seed by seed.
#[derive(Debug, Clone, Serialize)]
pub struct PolicyAtFork {
    pub kind: PolicyKind,
    /// Per seed: the first chunks' passage shares, their TV to the demos' recorded passages, the rollouts' TV.
    pub heading: Vec<Vec<f32>>,
    pub fork_tv: Vec<f64>,
    pub rollout_tv: Vec<f64>,
}

#[derive(Debug, Clone, Serialize)]
pub struct LayoutAtFork {
    pub layout: String,
    pub demo_proportions: Vec<f32>,
    pub policies: Vec<PolicyAtFork>,
    pub verdicts: Vec<(String, Verdict)>,
}

fn paired(a: &[f64], b: &[f64]) -> Estimate {
    over_seeds(&a.iter().zip(b).map(|(x, y)| x - y).collect::<Vec<_>>())
}

/// The fork of `kind` on every seed of `result`, its checkpoints under `dir/seed<s>/<kind>`.
fn policy_at_fork(
    dir: &Path,
    layout: &Layout,
    result: &LayoutResult,
    kind: PolicyKind,
    draws: usize,
) -> anyhow::Result<PolicyAtFork> {
    let stats = result.policies.iter().find(|p| p.kind == kind).context("policy not in family.json")?;
    let mut at = PolicyAtFork { kind, heading: Vec::new(), fork_tv: Vec::new(), rollout_tv: Vec::new() };
    for (seed, figures) in stats.per_seed.iter().enumerate() {
        let seed_dir = dir.join(format!("seed{seed}"));
        let demos = crate::demo_file::load_demos(&seed_dir.join("demos.json"))?.demos;
        let (mut policy, _) = MarsPolicy::load(&seed_dir.join(kind.name()), seed as u64)?;
        let fork = fork_choices(&mut policy, &demos, layout, draws, seed as u64)?;
        let f64s = |v: &[f32]| v.iter().map(|&x| f64::from(x)).collect::<Vec<_>>();
        at.fork_tv.push(tv_distance(&f64s(&fork.policy), &f64s(&fork.demos_recorded)));
        at.rollout_tv.push(figures.tv);
        at.heading.push(fork.policy);
    }
    Ok(at)
}

fn verdicts(policies: &[PolicyAtFork]) -> Vec<(String, Verdict)> {
    let mut v = Vec::new();
    for p in policies {
        let after = paired(&p.rollout_tv, &p.fork_tv);
        let claim =
            format!("{}'s rollouts further from the demos than its first chunks: rollouts − fork = {after:.3}", p.kind);
        v.push((claim, Verdict::at_least(after, 0.0)));
    }
    let get = |k: PolicyKind| policies.iter().find(|p| p.kind == k);
    if let (Some(m), Some(f)) = (get(PolicyKind::Mars), get(PolicyKind::Fm)) {
        let d = paired(&m.fork_tv, &f.fork_tv);
        let claim = format!(
            "MARS's first chunks at most {FORK_TV_ABOVE_FM:.2} further from the demos than FM's: MARS − FM = {d:.3}"
        );
        v.push((claim, Verdict::at_most(d, FORK_TV_ABOVE_FM)));
    }
    v
}

/// Diagnoses every layout of the family run in `dir` (its family.json, demos and checkpoints) whose layout file
/// is in `layouts_dir`; MARS and FM, `draws` chunks per demo state.
pub fn diagnose(dir: &Path, layouts_dir: &Path, draws: usize) -> anyhow::Result<Vec<LayoutAtFork>> {
    let results = crate::family_diff::load(&dir.join("family.json"))?;
    let files = crate::family::layout_files(layouts_dir)?;
    let layouts = files.iter().map(|f| Layout::load(f)).collect::<Result<Vec<_>, _>>()?;
    let mut out = Vec::new();
    for result in &results {
        let layout = layouts.iter().find(|l| l.name == result.layout).with_context(|| {
            format!("layout {} of {} has no file in {}", result.layout, dir.display(), layouts_dir.display())
        })?;
        let kinds =
            [PolicyKind::Mars, PolicyKind::Fm].into_iter().filter(|k| result.policies.iter().any(|p| p.kind == *k));
        let policies = kinds
            .map(|k| policy_at_fork(&dir.join(&result.layout), layout, result, k, draws))
            .collect::<anyhow::Result<Vec<_>>>()
            .with_context(|| format!("layout {}", result.layout))?;
        let verdicts = verdicts(&policies);
        out.push(LayoutAtFork {
            layout: result.layout.clone(),
            demo_proportions: result.demo_proportions.clone(),
            policies,
            verdicts,
        });
    }
    Ok(out)
}

fn shares(p: &[f32]) -> String {
    p.iter().map(|x| format!("{:.0}", 100.0 * x)).collect::<Vec<_>>().join("/")
}

/// The tables and verdicts, markdown.
pub fn render(layouts: &[LayoutAtFork], draws: usize) -> String {
    let mut s = String::from("# Where the modes are lost: the fork's first chunk against the rollouts\n\n");
    let _ = writeln!(
        s,
        "First chunk past the entry gate from each demo's own state and history ({draws} draws each, K(w) as \
         deployed), classified by the passage it heads for; TV to the demos' recorded passages. Means over the \
         training seeds with 95 % t intervals.\n"
    );
    let _ = writeln!(
        s,
        "| layout (demo shares %) | policy | first chunks head for % | TV at the fork | TV of the rollouts \
         | rollouts − fork |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    for l in layouts {
        for (i, p) in l.policies.iter().enumerate() {
            let n = l.demo_proportions.len();
            let mean: Vec<f32> =
                (0..n).map(|k| p.heading.iter().map(|h| h[k]).sum::<f32>() / p.heading.len().max(1) as f32).collect();
            let name = if i == 0 { format!("{} ({})", l.layout, shares(&l.demo_proportions)) } else { String::new() };
            let _ = writeln!(
                s,
                "| {name} | {} | {} | {:.3} | {:.3} | {:.3} |",
                p.kind,
                shares(&mean),
                over_seeds(&p.fork_tv),
                over_seeds(&p.rollout_tv),
                paired(&p.rollout_tv, &p.fork_tv)
            );
        }
    }
    for l in layouts {
        let _ = writeln!(s, "\n**{}**", l.layout);
        for (claim, verdict) in &l.verdicts {
            let _ = writeln!(s, "- {claim}: **{verdict}**");
        }
    }
    s
}

/// `mars diagnose-family`: prints the tables and writes `diagnose_family.md` and `.json` beside family.json.
pub fn run(dir: &Path, layouts_dir: &Path, draws: usize) -> anyhow::Result<()> {
    anyhow::ensure!(draws >= 1, "--draws must be at least 1");
    let layouts = diagnose(dir, layouts_dir, draws)?;
    let md = render(&layouts, draws);
    println!("{md}");
    std::fs::write(dir.join("diagnose_family.md"), &md)
        .with_context(|| format!("cannot write in {}", dir.display()))?;
    std::fs::write(dir.join("diagnose_family.json"), serde_json::to_string_pretty(&layouts)?)
        .with_context(|| format!("cannot write in {}", dir.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn at(kind: PolicyKind, fork_tv: &[f64], rollout_tv: &[f64]) -> PolicyAtFork {
        PolicyAtFork { kind, heading: vec![], fork_tv: fork_tv.to_vec(), rollout_tv: rollout_tv.to_vec() }
    }

    /// MARS choosing at the fork as far from the demos as its rollouts end, and further than FM, on every seed:
    /// lost at the fork (the "after" claim not met) and the fork target not met; FM drifting after its fork: met.
    #[test]
    fn a_collapse_at_the_fork_and_a_drift_after_it_are_told_apart() {
        let mars = at(PolicyKind::Mars, &[0.40, 0.42, 0.38, 0.41, 0.39], &[0.30, 0.33, 0.29, 0.31, 0.32]);
        let fm = at(PolicyKind::Fm, &[0.05, 0.08, 0.06, 0.07, 0.04], &[0.20, 0.25, 0.22, 0.18, 0.24]);
        let v = verdicts(&[mars, fm]);
        let got: Vec<Verdict> = v.iter().map(|(_, v)| *v).collect();
        assert_eq!(got, [Verdict::NotMet, Verdict::Met, Verdict::NotMet], "{v:?}");
    }

    /// Two seeds that disagree decide nothing.
    #[test]
    fn seeds_that_disagree_leave_it_undecided() {
        let mars = at(PolicyKind::Mars, &[0.1, 0.5], &[0.5, 0.1]);
        let fm = at(PolicyKind::Fm, &[0.3, 0.2], &[0.2, 0.3]);
        assert!(verdicts(&[mars, fm]).iter().all(|(_, v)| *v == Verdict::Undecided));
    }
}
