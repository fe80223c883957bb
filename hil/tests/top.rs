//! `marsd top` against a running demo (mock HAL + marsd as processes) and against nothing.

mod common;

use std::time::Duration;

use common::*;

fn top(robot: &str, extra: &[&str], logs: &TempDir) -> Proc {
    let mut cmd = marsd_command();
    cmd.args(["top", "--robot", robot, "--plain"]).args(extra);
    // Not a real-time process: an ordinary child, as a user's terminal would run it.
    Proc::spawn(cmd, "top", logs.path())
}

/// The number in the column `col` (0 = the channel's name) of the row starting with `channel` (or
/// `channel[input]`, a frame age named by its input), in one view.
fn cell(view: &str, channel: &str, col: usize) -> Option<f64> {
    let named = |t: &str| t == channel || t.strip_prefix(channel).is_some_and(|r| r.starts_with('['));
    let row = view.lines().find(|l| l.split_whitespace().next().is_some_and(named))?;
    row.split_whitespace().nth(col)?.parse().ok()
}

/// The (count, p50, p99, max) of every `tag` interval in marsd's interval log, formatted as top formats a time
/// channel (µs, one decimal).
fn logged_intervals(hlog: &std::path::Path, tag: &str) -> Vec<[String; 4]> {
    use base64::Engine;
    use hdrhistogram::serialization::interval_log::{IntervalLogIterator, LogEntry};
    let bytes = std::fs::read(hlog).unwrap_or_else(|e| panic!("{}: {e}", hlog.display()));
    let mut deserializer = hdrhistogram::serialization::Deserializer::new();
    let us = |ns: u64| format!("{:.1}", ns as f64 / 1e3);
    let mut out = Vec::new();
    for entry in IntervalLogIterator::new(&bytes) {
        let LogEntry::Interval(i) = entry.expect("a parsable log") else { continue };
        if i.tag().is_some_and(|t| t.as_str() == tag) {
            let raw = base64::engine::general_purpose::STANDARD.decode(i.encoded_histogram()).unwrap();
            let h: hdrhistogram::Histogram<u64> = deserializer.deserialize(&mut &raw[..]).unwrap();
            let q = |p: f64| us(h.value_at_quantile(p));
            out.push([h.len().to_string(), q(0.5), q(0.99), us(h.max())]);
        }
    }
    out
}

/// The (count, p50, p99, max) cells of `channel`'s row in a view, as printed.
fn row_cells(view: &str, channel: &str) -> Option<[String; 4]> {
    let row = view.lines().find(|l| l.split_whitespace().next() == Some(channel))?;
    let cells: Vec<&str> = row.split_whitespace().collect();
    Some([cells.get(2)?, cells.get(3)?, cells.get(4)?, cells.get(5)?].map(|c| c.to_string()))
}

/// `servo ticks N` in a view's header.
fn ticks(view: &str) -> Option<u64> {
    let rest = view.split("servo ticks ").nth(1)?;
    rest.split(|c: char| !c.is_ascii_digit()).next()?.parse().ok()
}

/// The integer just before `label` in `text`.
fn number_before(text: &str, label: &str) -> Option<u64> {
    let head = &text[..text.find(label)?];
    head.rsplit(|c: char| !c.is_ascii_digit()).next()?.parse().ok()
}

#[test]
fn top_without_a_daemon_says_so_and_fails() {
    let logs = TempDir::new("top-nothing");
    let robot = robot("top-nothing");
    let mut t = top(&robot, &["--timeout-s", "0.5"], &logs);
    assert_eq!(t.exit_code(Duration::from_secs(30)), 1, "{}", t.logs());
    let err = t.stderr_text();
    assert!(err.contains(&format!("no live frame on mars/{robot}/live")) && err.contains("is marsd running"), "{err}");
}

#[test]
fn top_follows_a_running_demo() {
    let _rt = rt_rig_lock();
    let logs = TempDir::new("top-demo");
    let robot = robot("top-demo");
    let (_hal, _rec) = hal_with_recorder(&robot, &[], &logs);
    let mut marsd = spawn_marsd(&robot, &shipped_config(), 3, &[], &logs);
    // 12 views: at the shipped 0.25 s intervals (servo and policy each hand one over), a few seconds of the run.
    let mut t = top(&robot, &["--count", "12", "--timeout-s", "20"], &logs);
    let code = t.exit_code(Duration::from_secs(60));
    let out = t.stdout_text();
    let _ = marsd.exit_code(Duration::from_secs(120));
    assert_eq!(code, 0, "top failed\n{}\nmarsd:\n{}", t.logs(), marsd.logs());
    let views: Vec<&str> = out.split("marsd on ").skip(1).collect();
    assert_eq!(views.len(), 12, "{out}");
    eprintln!("the last view:\nmarsd on {}", views[11]);
    assert!(views.iter().all(|v| v.starts_with(&robot)), "{out}");
    // The servo's channels are in every view once its first interval is in, with the samples of a whole interval.
    let servo_views: Vec<&&str> = views.iter().filter(|v| cell(v, "wake_jitter", 2).is_some()).collect();
    assert!(servo_views.len() >= 10, "{out}");
    for v in &servo_views {
        let samples = cell(v, "tick_compute", 2).unwrap();
        assert!(samples >= 50.0, "an interval of 0.25 s at 1 kHz has ~250 ticks\n{v}");
        assert!(cell(v, "state_age", 2).unwrap() > 0.0, "{v}");
        assert!(v.contains("state_age[robot]"), "the robot's frame age is named\n{v}");
        let (p50, p99, max) = (
            cell(v, "tick_compute", 3).unwrap(),
            cell(v, "tick_compute", 4).unwrap(),
            cell(v, "tick_compute", 5).unwrap(),
        );
        assert!(0.0 < p50 && p50 <= p99 && p99 <= max, "{v}");
    }
    // The policy ran and was shown with its budget; the servo's ticks only go forward.
    assert!(views.iter().any(|v| cell(v, "inference", 2).is_some_and(|n| n > 0.0)), "{out}");
    // MARS's ‖w‖∞ of those calls, in [0, 1] (the scheduler's output).
    let w = views.iter().find_map(|v| cell(v, "w_inf", 2).filter(|n| *n > 0.0).and(cell(v, "w_inf", 5)));
    assert!(w.is_some_and(|w| (0.0..=1.0).contains(&w)), "{out}");
    assert!(out.contains("inference p99") && out.contains("budget"), "{out}");
    assert!(out.contains("Running") || out.contains("Resetting"), "{out}");
    // The servo's and the HAL's counters: commands flow, none stopped by the final check, none refused by the HAL.
    let last = views[11];
    let sent = number_before(last, " commands sent").expect(last);
    assert!(sent > 100, "{last}");
    assert_eq!(number_before(last, " stopped by the final limit check"), Some(0), "{last}");
    assert_eq!(number_before(last, " commands rejected"), Some(0), "{last}");
    let ticks: Vec<u64> = views.iter().filter_map(|v| ticks(v)).collect();
    assert!(ticks.windows(2).all(|w| w[0] <= w[1]) && ticks.last() > ticks.first(), "{ticks:?}");
    // What top shows is what marsd measured: each view's tick_compute interval is one of those marsd logged
    // (latency.hlog, written by marsd's collector from the same intervals), count and percentiles alike.
    let logged = logged_intervals(&logs.join("marsd-out/latency.hlog"), "tick_compute");
    for v in &servo_views {
        let shown = row_cells(v, "tick_compute").unwrap();
        assert!(logged.contains(&shown), "top showed {shown:?}, no interval marsd logged:\n{v}\nlogged: {logged:?}");
    }
    // And its counters reach marsd's final ones: never more than marsd sent in all.
    let total = u64_at(&summary(&logs, "marsd"), "/commands_sent");
    assert!(sent <= total, "top showed {sent} commands sent, marsd's report {total}");
}
