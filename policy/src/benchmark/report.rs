//! The benchmark's `results.md`: the table, and each of the paper's nav2d claims checked against it.

use super::options::BenchmarkOptions;
use crate::config::PolicyKind;
use mars_tasks::nav2d::EvalIntervals;
use mars_tasks::nav2d::eval::EvalReport;
use mars_tasks::nav2d::layout::Layout;
use std::fmt::Write;
use std::path::Path;

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

fn verdict(ok: bool) -> &'static str {
    if ok { "reproduced" } else { "NOT reproduced" }
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
        let shares: Vec<String> = i.shares.iter().map(|e| format!("{:.0}", e.scaled(100.0))).collect();
        let _ = writeln!(
            s,
            "| {} | {:.1} | {} | {} | {} |",
            r.kind,
            i.success.scaled(100.0),
            shares.join(" / "),
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
    let get = |k: PolicyKind| rows.iter().find(|r| r.kind == k);
    let _ = writeln!(s, "\n## The paper's claims, measured\n");
    if let Some(fm) = get(PolicyKind::Fm) {
        let c = &fm.report.passage_counts;
        let _ = writeln!(
            s,
            "- FM spreads over all passages (paper 20/24/29/24): {c:?} — {}",
            verdict(c.iter().all(|&n| n > 0))
        );
    }
    if let Some(a2a) = get(PolicyKind::A2a) {
        let used = a2a.report.passage_counts.iter().filter(|&&n| n > 0).count();
        let failed = a2a.report.n - a2a.report.successes;
        let _ = writeln!(
            s,
            "- A2A collapses to one passage or collides: {used} passage(s) used, {failed}/{} rollouts failed — {}",
            a2a.report.n,
            verdict(used <= 1 || failed > 0)
        );
    }
    if let (Some(m), Some(fm)) = (get(PolicyKind::Mars), get(PolicyKind::Fm)) {
        let (gm, gf) = (m.report.modal_balance, fm.report.modal_balance);
        let _ = writeln!(s, "- MARS γ close to FM's (within 0.15): {gm:.2} vs {gf:.2} — {}", verdict(gm >= gf - 0.15));
        let (sm, sf) = (m.report.success_rate(), fm.report.success_rate());
        let _ =
            writeln!(s, "- MARS success ≥ FM's: {:.0} % vs {:.0} % — {}", sm * 100.0, sf * 100.0, verdict(sm >= sf));
        let _ = writeln!(
            s,
            "- MARS mean K far below K_max = 10 (≤ 5): {:.2} — {}",
            m.report.mean_k,
            verdict(m.report.mean_k <= 5.0)
        );
        if let (Some(lm), Some(lf)) = (m.report.latency_p50_ms, fm.report.latency_p50_ms) {
            let ratio = lm / lf;
            let _ = writeln!(
                s,
                "- MARS p50 inference latency ≤ 20 % of FM's (paper −83.2 %): {lm:.2} ms vs {lf:.2} ms = {:.0} % — {}",
                ratio * 100.0,
                verdict(ratio <= 0.2)
            );
        }
    }
    if let Some(m) = get(PolicyKind::Mars) {
        let w = |name: &str| m.w_regions.iter().find(|(n, _)| n == name).and_then(|(_, v)| *v);
        if let (Some(j), Some(e)) = (w("junction"), w("exit_gate")) {
            let _ = writeln!(
                s,
                "- MARS ‖w‖∞ higher at the junction than in the exit gate: {j:.2} vs {e:.2} — {}",
                verdict(j > e)
            );
        }
    }
    s
}
