//! The benchmark's `results.md`: the table, and each of the paper's nav2d claims checked against it.

use super::options::BenchmarkOptions;
use crate::config::PolicyKind;
use mars_tasks::nav2d::EvalIntervals;
use mars_tasks::nav2d::eval::EvalReport;
use mars_tasks::nav2d::layout::Layout;
use mars_tasks::stats::{Estimate, Verdict, mean_over_seeds};
use std::fmt::Write;
use std::path::Path;

#[derive(Clone)]
pub struct Row {
    pub kind: PolicyKind,
    pub epochs: usize,
    /// Training wall time; `None` for a checkpoint kept by `--resume` from a run that did not record it.
    pub train_s: Option<f32>,
    pub report: EvalReport,
    /// The report's figures with their 95 % bootstrap intervals over its rollouts.
    pub intervals: EvalIntervals,
    /// Mean ‖w‖∞ over demo samples in each named region.
    pub w_regions: Vec<(String, Option<f32>)>,
}

fn fmt_opt(v: Option<f32>) -> String {
    v.map_or("–".into(), |v| format!("{v:.2}"))
}

/// `files`: the config and layout files the run read, for its command line.
pub fn render(rows: &[Row], o: &BenchmarkOptions, files: (&Path, &Path), layout: &Layout) -> String {
    let mut s = String::new();
    let policies: Vec<&str> = o.policies.iter().map(|k| k.name()).collect();
    let _ = writeln!(s, "# nav2d benchmark\n");
    let _ = writeln!(
        s,
        "Command: `mars benchmark --config {} --layout {} --demos {} --rollouts {} --seed {} --exec-horizon {}{}{}{} --policies {} --jobs {}` \
         (layout `{}`, {} passages; {} CPU thread(s) per job; {}).\n",
        files.0.display(),
        files.1.display(),
        o.demos,
        o.rollouts,
        o.seed,
        o.exec_horizon,
        o.epochs.map_or(String::new(), |e| format!(" --epochs {e}")),
        if o.history_conditioning { " --history-conditioning" } else { "" },
        o.k_full_w.map_or(String::new(), |w| format!(" --k-full-w {w}")),
        policies.join(","),
        o.jobs,
        layout.name,
        layout.n_passages(),
        std::env::var("RAYON_NUM_THREADS").unwrap_or_else(|_| "?".into()),
        if o.side_by_side {
            "trained and evaluated beside other layouts or seeds of `mars family`, so the latencies are not alone"
        } else {
            "evaluation runs alone after training"
        },
    );
    let _ = writeln!(s, "{}", EvalReport::table_header());
    for r in rows {
        let _ = writeln!(s, "{}", r.report.to_table_row(r.kind.name()));
    }
    let _ = writeln!(
        s,
        "\n95 % intervals (percentile bootstrap over this run's rollouts; training seed {} only, so they do not \
         hold the spread between seeds):\n",
        o.seed
    );
    let _ = writeln!(s, "| policy | success % | passage shares % | γ | TV to the demos |\n|---|---|---|---|---|");
    for r in rows {
        let i = &r.intervals;
        let _ = writeln!(
            s,
            "| {} | {:.1} | {} | {} | {} |",
            r.kind,
            i.success.scaled(100.0),
            shares_pct(&i.shares),
            i.gamma,
            i.tv
        );
    }
    let _ = writeln!(s, "\n| policy | epochs | train s | mean ‖w‖∞ entry gate | junction | exit gate |");
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    for r in rows {
        let w: Vec<String> = r.w_regions.iter().map(|(_, v)| fmt_opt(*v)).collect();
        let train_s = r.train_s.map_or("–".into(), |t| format!("{t:.0}"));
        let _ = writeln!(s, "| {} | {} | {train_s} | {} |", r.kind, r.epochs, w.join(" | "));
    }
    let _ = writeln!(s, "\n## The paper's claims, measured\n");
    let _ = writeln!(
        s,
        "Each judged by its 95 % interval over this run's rollouts (met, not met, or undecided when the interval \
         straddles the bound): one training seed, so a verdict holds for this checkpoint; over seeds, `mars family` \
         judges.\n"
    );
    claims(&mut s, rows, o.seed);
    s
}

/// The paper's nav2d claims, each with the interval it is judged by.
fn claims(s: &mut String, rows: &[Row], seed: u64) {
    let get = |k: PolicyKind| rows.iter().find(|r| r.kind == k);
    if let Some(fm) = get(PolicyKind::Fm) {
        let shares = &fm.intervals.shares;
        let spread = if shares.iter().all(|e| e.lo > 0.0) {
            Verdict::Met
        } else if shares.iter().any(|e| e.hi <= 0.0) {
            Verdict::NotMet
        } else {
            Verdict::Undecided
        };
        let _ = writeln!(
            s,
            "- FM uses every passage (paper 20/24/29/24; each share's interval above 0): {} % — {spread}",
            shares_pct(shares)
        );
    }
    if let Some(a2a) = get(PolicyKind::A2a) {
        let largest = a2a.intervals.shares.iter().copied().max_by(|a, b| a.value.total_cmp(&b.value));
        if let Some(top) = largest {
            let _ = writeln!(
                s,
                "- A2A collapses onto one passage (its largest share ≥ 90 %): {:.0} % — {}",
                top.scaled(100.0),
                Verdict::at_least(top, 0.9)
            );
        }
    }
    if let (Some(m), Some(fm)) = (get(PolicyKind::Mars), get(PolicyKind::Fm)) {
        if let Some(d) = m.report.difference(&fm.report, seed) {
            let _ = writeln!(
                s,
                "- MARS γ within 0.15 of FM's (MARS − FM ≥ −0.15): {} — {}",
                d.gamma,
                Verdict::at_least(d.gamma, -0.15)
            );
            let _ = writeln!(
                s,
                "- MARS success ≥ FM's − 2 points: MARS − FM {:.1} points — {}",
                d.success.scaled(100.0),
                Verdict::at_least(d.success, -0.02)
            );
        }
        if let Some(k) = episodes_mean_k(&m.report) {
            let _ = writeln!(
                s,
                "- MARS mean K far below K_max = 10 (≤ 5; over episodes): {k:.2} — {}",
                Verdict::at_most(k, 5.0)
            );
        }
        if let (Some(lm), Some(lf)) = (m.report.latency_p50_ms, fm.report.latency_p50_ms) {
            let _ = writeln!(
                s,
                "- MARS p50 inference latency against FM's (paper −83.2 %): {lm:.2} ms vs {lf:.2} ms = {:.0} % — no \
                 verdict: a few timed rollouts, not a measurement with an interval (`cargo bench -p mars-engine` times \
                 inference)",
                100.0 * lm / lf
            );
        }
    }
    if let Some(m) = get(PolicyKind::Mars) {
        let w = |name: &str| m.w_regions.iter().find(|(n, _)| n == name).and_then(|(_, v)| *v);
        if let (Some(j), Some(e)) = (w("junction"), w("exit_gate")) {
            let _ = writeln!(
                s,
                "- MARS ‖w‖∞ higher at the junction than in the exit gate (this checkpoint on every demo state of the \
                 two regions, no sampling): {j:.2} vs {e:.2} — {}",
                if j > e { Verdict::Met } else { Verdict::NotMet }
            );
        }
    }
}

/// `12 (10–14) / 26 (23–29) / …`, percent.
fn shares_pct(shares: &[Estimate]) -> String {
    shares.iter().map(|e| format!("{:.0}", e.scaled(100.0))).collect::<Vec<_>>().join(" / ")
}

/// The mean over episodes of each episode's mean K, with its 95 % t interval over the episodes (the t interval of
/// a mean that `mean_over_seeds` computes, here over episodes).
fn episodes_mean_k(r: &EvalReport) -> Option<Estimate> {
    let per_episode: Vec<f64> = r
        .episodes
        .iter()
        .filter(|e| !e.calls.is_empty())
        .map(|e| e.calls.iter().map(|c| c.k as f64).sum::<f64>() / e.calls.len() as f64)
        .collect();
    mean_over_seeds(&per_episode)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mars_tasks::nav2d::eval::CallRecord;
    use mars_tasks::nav2d::{Episode, Termination};
    use std::time::Duration;

    /// An evaluation: `failed` rollouts fail, `split[i]` succeed through passage i; every call with `k` steps.
    fn row(kind: PolicyKind, failed: usize, split: [usize; 4], k: usize) -> Row {
        let call = CallRecord { latency: Duration::ZERO, k, w_inf: 0.0 };
        let episode = |termination, mode| Episode {
            seed: 0,
            start: [0.0; 2],
            steps: vec![],
            calls: vec![call.clone(); 3],
            termination,
            mode,
        };
        let mut e: Vec<Episode> = (0..failed).map(|_| episode(Termination::Timeout, None)).collect();
        for (p, n) in split.into_iter().enumerate() {
            e.extend((0..n).map(|_| episode(Termination::Success, Some(p))));
        }
        let report = EvalReport::from_episodes(4, e);
        let intervals = report.intervals(&[0.25; 4], 1);
        Row { kind, epochs: 1, train_s: None, report, intervals, w_regions: vec![] }
    }

    fn claims_of(rows: &[Row]) -> String {
        let mut s = String::new();
        claims(&mut s, rows, 7);
        s
    }

    #[test]
    fn claims_are_judged_by_their_intervals() {
        let fm = row(PolicyKind::Fm, 40, [90, 90, 90, 90], 10);
        // Far better: met; as good: undecided against "≥ FM − 2 points"; far worse: not met.
        let better = claims_of(&[row(PolicyKind::Mars, 0, [100, 100, 100, 100], 2), fm.clone()]);
        assert!(
            better.contains("success ≥ FM's − 2 points: MARS − FM 10.0 (") && better.contains("points — met"),
            "{better}"
        );
        assert!(better.contains("γ within 0.15 of FM's") && better.contains("— met\n"), "{better}");
        assert!(
            better.contains("mean K far below K_max = 10 (≤ 5; over episodes): 2.00 (2.00–2.00) — met"),
            "{better}"
        );
        assert!(better.contains("FM uses every passage") && better.contains("% — met"), "{better}");
        let same = claims_of(&[row(PolicyKind::Mars, 40, [90, 90, 90, 90], 2), fm.clone()]);
        assert!(same.contains("MARS − FM 0.0 (") && same.contains("points — undecided"), "{same}");
        let worse = claims_of(&[row(PolicyKind::Mars, 200, [200, 0, 0, 0], 2), fm]);
        assert!(worse.contains("points — not met") && worse.contains("γ within 0.15 of FM's"), "{worse}");
        assert!(worse.lines().any(|l| l.contains("γ within") && l.ends_with("— not met")), "{worse}");
        let collapsed =
            claims_of(&[row(PolicyKind::A2a, 0, [0, 400, 0, 0], 1), row(PolicyKind::Fm, 0, [0, 400, 0, 0], 10)]);
        assert!(
            collapsed.contains("A2A collapses onto one passage (its largest share ≥ 90 %): 100 (100–100) % — met"),
            "{collapsed}"
        );
        assert!(collapsed.contains("FM uses every passage") && collapsed.contains("% — not met"), "{collapsed}");
    }
}
