//! The fault runs' table: per backend and fault, the trials, what the checker found, and how the HAL reacted.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use serde_json::Value;

use super::rig::HalEnd;
use super::trial::Outcome;
use super::{FaultArgs, backend_name};
use crate::demo::DemoRobot;

pub struct BackendResult {
    pub backend: DemoRobot,
    pub outcomes: Vec<Outcome>,
    pub errors: Vec<String>,
    /// One per rig (a rig is restarted after a reflex the HAL could not recover from).
    pub hal: Vec<HalEnd>,
}

/// A JSON number of milliseconds as text ("–" when absent).
pub fn ms(v: &Value) -> String {
    v.as_f64().map_or("–".into(), |x| format!("{x:.1}"))
}

const HEADER: &str = "| backend | fault | trials | faults sent | violations | reflexes | frames lost | HAL reaction | \
                      HAL's hold reason: n (fault → hold, median / max ms) | fault → at rest, median / max ms | marsd exit |\n\
                      |---|---|---:|---:|---:|---:|---:|---|---|---|---|\n";

pub fn render(rows: &[BackendResult], args: &FaultArgs) -> String {
    let mut s = format!(
        "\nmars-hil faults --trials {} --seed {} --stop-min-ms {} --stop-max-ms {} (the verdicts: mars-checker check)\n\n",
        args.trials, args.seed, args.stop_min_ms, args.stop_max_ms
    );
    s.push_str(HEADER);
    for r in rows {
        for kind in ["none", "SIGKILL", "SIGSTOP"] {
            let of_kind: Vec<&Outcome> = r.outcomes.iter().filter(|o| o.plan.fault.kind() == kind).collect();
            if !of_kind.is_empty() {
                let _ = writeln!(s, "| {} | {} | {} |", backend_name(r.backend), label(kind), row(&of_kind));
            }
        }
    }
    for r in rows {
        for (n, hal) in r.hal.iter().enumerate() {
            // The HAL report's line of the robot's own side (fci): "robot <address>: … N reflexes, …".
            let robot = hal.report.lines().map(str::trim).find(|l| l.starts_with("robot ") && l.contains(" reflexes"));
            let _ = writeln!(
                s,
                "\n{} (rig {}): HAL exit {}{}",
                backend_name(r.backend),
                n + 1,
                hal.code.map_or("– (killed)".into(), |c| c.to_string()),
                robot.map_or(String::new(), |l| format!("; {l}"))
            );
        }
        for e in &r.errors {
            let _ = writeln!(s, "  NOT RUN: {}", e.lines().next().unwrap_or(""));
        }
    }
    let dirty: Vec<String> =
        rows.iter().flat_map(|r| r.outcomes.iter().filter(|o| !o.clean)).map(describe_dirty).collect();
    let _ = writeln!(s, "\nnot clean: {}", if dirty.is_empty() { "none".into() } else { dirty.join("\n  ") });
    s
}

/// A trial that was not clean: where, what was planned, the checker's counts and its first violation.
fn describe_dirty(o: &Outcome) -> String {
    let v = &o.verdict;
    let first = &v["first_violations"][0];
    let first = if first.is_object() {
        format!(
            "; first: seq {} joint {} {} {} (limit {})",
            first["seq"], first["joint"], first["what"], first["value"], first["limit"]
        )
    } else {
        String::new()
    };
    format!(
        "{} ({:?}, {}): {} violations, {} reflexes, ends at rest: {}, the HAL's longest pause {} ms{first}",
        o.dir.display(),
        o.plan,
        if o.delivered { "sent" } else { "not sent: marsd had ended" },
        v["violations"],
        super::trial::reflexes(v),
        v["ends_at_rest"],
        ms(&v["largest_gap_ms"])
    )
}

fn label(kind: &str) -> &str {
    if kind == "none" { "none (baseline episode)" } else { kind }
}

/// The cells after `backend | fault |` for a group of trials.
fn row(of: &[&Outcome]) -> String {
    let sum = |key: &str| of.iter().map(|o| o.verdict[key].as_u64().unwrap_or(0)).sum::<u64>();
    let reflexes: u64 = of.iter().map(|o| super::trial::reflexes(&o.verdict)).sum();
    let sent = of.iter().filter(|o| o.delivered).count();
    let mut reactions: BTreeMap<&str, usize> = BTreeMap::new();
    let mut reasons: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut rest = Vec::new();
    for o in of.iter().filter(|o| o.delivered) {
        let r = &o.verdict["reaction"];
        let reason = r["hold_reason"].as_str().unwrap_or("none");
        // A hold marsd asked for (its episode's end, or its own watchdog's stop after SIGCONT) is marsd's reaction,
        // not the HAL's.
        let by_hal = r["held"] == true && reason != "controller requested";
        let what = match (by_hal, r["moving"] == true) {
            (true, true) => "braked",
            (true, false) => "held at rest",
            (false, _) => "left to marsd",
        };
        *reactions.entry(what).or_default() += 1;
        if by_hal {
            reasons.entry(reason.to_owned()).or_default().extend(r["hold_ms"].as_f64());
            rest.extend(r["rest_ms"].as_f64());
        }
    }
    let count_list = |m: &BTreeMap<&str, usize>| m.iter().map(|(k, n)| format!("{k} {n}")).collect::<Vec<_>>();
    let reason_list: Vec<String> =
        reasons.iter().map(|(k, t)| format!("{k}: {} ({})", t.len(), median_max(t))).collect();
    let mut exits: BTreeMap<String, usize> = BTreeMap::new();
    for o in of {
        *exits.entry(o.marsd_exit.map_or("killed".into(), |c| c.to_string())).or_default() += 1;
    }
    let exits: Vec<String> = exits.iter().map(|(k, n)| format!("{k}: {n}")).collect();
    format!(
        "{} | {sent} | {} | {reflexes} | {} | {} | {} | {} | {}",
        of.len(),
        sum("violations"),
        sum("lost_frames"),
        or_dash(count_list(&reactions)),
        or_dash(reason_list),
        median_max(&rest),
        exits.join(", ")
    )
}

fn or_dash(items: Vec<String>) -> String {
    if items.is_empty() { "–".into() } else { items.join(", ") }
}

fn median_max(values: &[f64]) -> String {
    if values.is_empty() {
        return "–".into();
    }
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    format!("{:.1} / {:.1}", v[v.len() / 2], v[v.len() - 1])
}
