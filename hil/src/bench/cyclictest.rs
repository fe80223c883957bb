//! cyclictest (rt-tests) at marsd's servo rate, priority and core, and its histogram's quantiles.

use super::*;
/// cyclictest's result: its wake-up latencies (ns) as a sparse histogram plus what did not fit.
pub(super) struct Cyclic {
    pub(super) cmdline: String,
    pub(super) version: String,
    pub(super) cycles: u64,
    /// (latency ns, count), ascending.
    pub(super) hist: Vec<(u64, u64)>,
    /// Wake-ups later than the histogram bound.
    pub(super) overflows: u64,
    pub(super) bound_ns: u64,
    pub(super) min_ns: u64,
    pub(super) max_ns: u64,
    pub(super) avg_ns: f64,
    /// Warnings cyclictest printed (a refused SCHED_FIFO or mlockall shows up here).
    pub(super) warnings: Vec<String>,
    pub(super) load: PhaseLoad,
}

impl Cyclic {
    /// The latency at quantile `q` the way HdrHistogram reports it (the smallest value with at least
    /// ceil(q·n) samples at or below it), in µs; `None` when it falls among the overflows.
    pub(super) fn quantile_us(&self, q: f64) -> Option<f64> {
        let rank = ((q * self.cycles as f64).ceil() as u64).max(1);
        let mut seen = 0;
        for &(v, n) in &self.hist {
            seen += n;
            if seen >= rank {
                return Some(v as f64 * 1e-3);
            }
        }
        None
    }

    /// Wake-ups at least one period late (the ones marsd counts as skipped periods instead).
    pub(super) fn at_least(&self, ns: u64) -> u64 {
        self.hist.iter().filter(|(v, _)| *v >= ns).map(|(_, n)| n).sum::<u64>() + self.overflows
    }
}

/// `cyclictest` at marsd's servo rate, priority and core, with mlockall, for `loops` wake-ups.
pub(super) fn run_cyclictest(
    args: &BenchArgs,
    loops: u64,
    period_us: u64,
    priority: i32,
    core: Option<usize>,
) -> anyhow::Result<Cyclic> {
    let json = std::fs::canonicalize(&args.out)?.join("cyclictest.json");
    let _ = std::fs::remove_file(&json);
    // One period: later wake-ups are what marsd counts as skipped periods; cyclictest counts them as histogram
    // overflows (keeping the exact max). Its histogram holds at most 10^6 buckets (ns with -N).
    let bound_ns = (period_us * 1000).min(1_000_000);
    let mut cmd = Command::new("cyclictest");
    cmd.args(["-m", "-p", &priority.to_string()]);
    if let Some(c) = core {
        cmd.args(["-a", &c.to_string()]);
    }
    cmd.args(["-t", "1", "-i", &period_us.to_string(), "-l", &loops.to_string(), "-q", "-N"]);
    cmd.args(["-h", &bound_ns.to_string(), "--histfile=/dev/null"]).arg(format!("--json={}", json.display()));
    if !args.cyclictest_pm_qos {
        cmd.arg("--default-system");
    }
    let cmdline = format!(
        "cyclictest {}",
        cmd.get_args().map(|a| a.to_string_lossy().into_owned()).collect::<Vec<_>>().join(" ")
    );
    eprintln!(
        "== bench: {cmdline}  ({loops} wake-ups ≈ {:.0} s, idle machine)",
        loops as f64 * period_us as f64 * 1e-6
    );
    let probe = LoadProbe::start();
    let output = match cmd.output() {
        Ok(o) => o,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {
            bail!("cyclictest is not installed (Debian/Ubuntu: `apt-get install rt-tests`)")
        }
        Err(e) => bail!("cannot start cyclictest: {e}"),
    };
    let load = probe.finish();
    let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
    let (stdout, stderr) = (text(&output.stdout), text(&output.stderr));
    let warnings: Vec<String> = stderr
        .lines()
        .chain(stdout.lines())
        .map(str::trim)
        .filter(|l| !l.is_empty() && !l.starts_with("T:") && !l.starts_with("# Histogram"))
        .map(str::to_string)
        .collect();
    if !output.status.success() {
        bail!("{cmdline} failed ({}): {}", output.status, warnings.join(" | "));
    }
    let v: Value = serde_json::from_str(
        &std::fs::read_to_string(&json)
            .with_context(|| format!("cyclictest wrote no {} (it needs rt-tests ≥ 2.0 for --json)", json.display()))?,
    )
    .with_context(|| format!("parsing {}", json.display()))?;
    let t = &v["thread"]["0"];
    let mut hist: Vec<(u64, u64)> = t["histogram"]
        .as_object()
        .context("cyclictest's JSON has no histogram for thread 0")?
        .iter()
        .filter_map(|(k, n)| Some((k.parse().ok()?, n.as_u64()?)))
        .collect();
    hist.sort_unstable();
    let cycles = t["cycles"].as_u64().unwrap_or(0);
    let counted: u64 = hist.iter().map(|(_, n)| n).sum();
    Ok(Cyclic {
        cmdline,
        version: v["rt_test_version:"].as_str().or(v["rt_test_version"].as_str()).unwrap_or("?").to_string(),
        cycles,
        hist,
        overflows: cycles.saturating_sub(counted),
        bound_ns,
        min_ns: t["min"].as_u64().unwrap_or(0),
        max_ns: t["max"].as_u64().unwrap_or(0),
        avg_ns: t["avg"].as_f64().unwrap_or(0.0),
        warnings,
        load,
    })
}
