//! `mars-hil bench-fleet`: one `marsd serve` (this executable, another process) serving N robots, each a client
//! thread that asks for a chunk every policy period, phase-shifted by 1/N of a period from the next, with the time a
//! robot gives the host (marsd's lead less its handoff margin and local reserve, as at `ask_ahead_periods = 0`): per
//! robot, the chunks back in time, the misses, the round trip; per robot on the host, the longest queue wait. The
//! robots here are the wire's clients without a servo (this 2-core VM cannot run N HAL + servo pairs beside the
//! host): the measurement is the host's scheduling of N robots' deadlines.

use std::path::PathBuf;
use std::sync::{Arc, Barrier};
use std::time::{Duration, Instant};

use anyhow::Context;
use hdrhistogram::Histogram;
use mars_engine::{Engine, EngineConfig};
use mars_remote::client::RemotePolicy;
use mars_remote::link::LinkConfig;
use mars_remote::wire::Request;
use mars_rt::Ticker;

#[derive(clap::Args, Debug, Clone)]
pub struct FleetBenchArgs {
    #[arg(long, default_value = "assets/checkpoints/fr3_pick_cup/mars")]
    pub checkpoint: PathBuf,
    /// Robots served by the one host.
    #[arg(long, default_value_t = 4)]
    pub robots: usize,
    /// Each robot's chunk rate (Hz).
    #[arg(long, default_value_t = 10.0)]
    pub rate_hz: f64,
    /// The time each robot gives the host for a chunk (ms): the shipped config's 80 ms lead less 2 ms handoff margin
    /// and 10 ms local reserve.
    #[arg(long, default_value_t = 68.0)]
    pub wait_ms: f64,
    #[arg(long, default_value_t = 30.0)]
    pub seconds: f64,
    #[arg(long, default_value = "runs/bench_fleet")]
    pub out: PathBuf,
}

/// One robot's account.
#[derive(Debug, Default)]
struct RobotRun {
    asked: u64,
    chunks: u64,
    misses: u64,
    first_miss: Option<String>,
    round_trip_us: Option<Histogram<u64>>,
}

pub fn run(a: FleetBenchArgs) -> anyhow::Result<()> {
    anyhow::ensure!((1..=64).contains(&a.robots), "--robots must be 1..=64");
    anyhow::ensure!(a.rate_hz > 0.0 && a.rate_hz <= 1000.0, "--rate-hz must be in (0, 1000], got {}", a.rate_hz);
    anyhow::ensure!(a.wait_ms > 0.0 && a.wait_ms.is_finite(), "--wait-ms must be positive, got {}", a.wait_ms);
    anyhow::ensure!(a.seconds > 0.0 && a.seconds <= 86_400.0, "--seconds must be in (0, 86400], got {}", a.seconds);
    std::fs::create_dir_all(&a.out).with_context(|| format!("creating {}", a.out.display()))?;
    let engine = Engine::load(&a.checkpoint, EngineConfig::default())?;
    let m = engine.meta();
    let (obs, hist) = (m.normalizer.obs.mean.clone(), m.normalizer.action.mean.repeat(engine.chunk_len()));
    let names: Vec<String> = (0..a.robots).map(|i| format!("robot{i}")).collect();
    let prefix = format!("mars-fleet/{}", std::process::id());
    let report = a.out.join("host.json");
    let extra = vec!["--out".to_owned(), report.display().to_string()];
    let (mut host, port) = super::remote::spawn_host_of(&a.checkpoint, &prefix, &names, &extra)?;
    let locator = format!("tcp/127.0.0.1:{port}");
    let period = Duration::from_secs_f64(1.0 / a.rate_hz);
    let calls = (a.seconds * a.rate_hz).ceil() as u64;
    let ready = Arc::new(Barrier::new(a.robots));
    let threads: Vec<_> = names
        .iter()
        .enumerate()
        .map(|(i, name)| {
            let (name, prefix, locator, ready) = (name.clone(), prefix.clone(), locator.clone(), ready.clone());
            let (obs, hist, wait) = (obs.clone(), hist.clone(), Duration::from_secs_f64(a.wait_ms / 1e3));
            let phase = period.mul_f64(i as f64 / a.robots as f64);
            std::thread::spawn(move || {
                robot(&locator, &prefix, &name, (obs, hist), (period, phase, wait), calls, &ready)
            })
        })
        .collect();
    let runs: Vec<anyhow::Result<RobotRun>> =
        threads.into_iter().map(|t| t.join().unwrap_or_else(|_| Err(anyhow::anyhow!("a robot panicked")))).collect();
    // SAFETY: kill(2) on our own child, not yet reaped.
    unsafe { libc::kill(host.id() as libc::pid_t, libc::SIGTERM) };
    let _ = host.wait();
    let host_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&report).context("the host's report")?)?;
    let table = table(&a, &names, &runs, &host_json);
    std::fs::write(a.out.join("results.md"), &table)?;
    println!("{table}");
    Ok(())
}

/// One robot: joins, waits for the host's clock, then asks every period (all robots start together, each `phase`
/// after the first).
fn robot(
    locator: &str,
    prefix: &str,
    name: &str,
    (observation, history): (Vec<f32>, Vec<f32>),
    (period, phase, wait): (Duration, Duration, Duration),
    calls: u64,
    ready: &Barrier,
) -> anyhow::Result<RobotRun> {
    let mut client = RemotePolicy::connect(&LinkConfig::connecting(locator), prefix, name)?;
    let t0 = Instant::now();
    let clock = loop {
        match client.probe_clock(5, Duration::from_secs(1)) {
            Ok(c) => break c,
            Err(_) if t0.elapsed() < Duration::from_secs(20) => std::thread::sleep(Duration::from_millis(50)),
            Err(e) => return Err(e).context("the host never answered its clock"),
        }
    };
    ready.wait();
    let mut ticker = Ticker::new(period + phase);
    let mut run = RobotRun { round_trip_us: Some(Histogram::new_with_bounds(1, 60_000_000, 3)?), ..Default::default() };
    let mut request = Request {
        budget_ns: (wait.as_nanos() as u64).saturating_sub(clock.rtt_min_ns),
        observation,
        history,
        ..Default::default()
    };
    for k in 0..calls {
        ticker.wait();
        (request.seq, request.period, request.seed) = (k + 1, k, k);
        request.sent_ns = mars_ipc::clock::monotonic_ns();
        run.asked += 1;
        let sent = Instant::now();
        match client.infer(&request, wait) {
            Ok(_) => {
                run.chunks += 1;
                let us = sent.elapsed().as_micros() as u64;
                run.round_trip_us.as_mut().expect("made above").record(us.max(1))?;
            }
            Err(e) => {
                run.misses += 1;
                run.first_miss.get_or_insert_with(|| e.to_string());
            }
        }
    }
    Ok(run)
}

fn table(a: &FleetBenchArgs, names: &[String], runs: &[anyhow::Result<RobotRun>], host: &serde_json::Value) -> String {
    let mut out = format!(
        "{} robots on one `marsd serve`, {} Hz each, {:.0} ms given per chunk, {:.0} s; {}\n\n\
         | robot | asked | chunks in time | misses | round trip p50 / p99 / max ms | host: expired / late replies | host: longest queue wait ms |\n\
         |---|---|---|---|---|---|---|\n",
        a.robots,
        a.rate_hz,
        a.wait_ms,
        a.seconds,
        a.checkpoint.display()
    );
    for (name, r) in names.iter().zip(runs) {
        let h = &host["robots"][name];
        let host_cols = format!(
            "{} / {} | {:.2}",
            h["expired"].as_u64().unwrap_or(0),
            h["late_replies"].as_u64().unwrap_or(0),
            h["max_queue_ns"].as_u64().unwrap_or(0) as f64 * 1e-6
        );
        match r {
            Ok(r) => {
                let rtt = r.round_trip_us.as_ref().filter(|h| !h.is_empty()).map_or("-".into(), |h| {
                    let ms = |q: f64| h.value_at_quantile(q) as f64 * 1e-3;
                    format!("{:.2} / {:.2} / {:.2}", ms(0.5), ms(0.99), h.max() as f64 * 1e-3)
                });
                let misses = match &r.first_miss {
                    Some(e) => format!("{} (first: {e})", r.misses),
                    None => r.misses.to_string(),
                };
                out += &format!("| {name} | {} | {} | {misses} | {rtt} | {host_cols} |\n", r.asked, r.chunks);
            }
            Err(e) => out += &format!("| {name} | failed: {e:#} |||||||\n"),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args() -> FleetBenchArgs {
        FleetBenchArgs {
            checkpoint: "assets/checkpoints/fr3_pick_cup/mars".into(),
            robots: 4,
            rate_hz: 10.0,
            wait_ms: 68.0,
            seconds: 1.0,
            out: std::env::temp_dir().join(format!("mars-fleet-args-{}", std::process::id())),
        }
    }

    /// Bad arguments are refused before a host is started.
    #[test]
    fn bad_arguments_are_refused_with_the_reason() {
        for (bad, want) in [
            (FleetBenchArgs { robots: 0, ..args() }, "--robots"),
            (FleetBenchArgs { rate_hz: f64::NAN, ..args() }, "--rate-hz"),
            (FleetBenchArgs { wait_ms: -1.0, ..args() }, "--wait-ms"),
        ] {
            let err = run(bad).unwrap_err().to_string();
            assert!(err.contains(want), "{err}");
        }
    }
}
