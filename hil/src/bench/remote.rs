//! `mars-hil bench-remote`: the HIL demo with its policy on `marsd serve` behind a shaped link
//! ([`crate::shaped_link`]), at each one-way delay, next to the same demo on its local engine. Each delay's chunks
//! are asked as many periods ahead as the round trip needs, continued guided and drop-late; printed as one table:
//! success (Wilson interval), whose chunks, the round trip, capture → first command, the link's bytes per second,
//! servo periods missed, late chunks, commands out of limits, and the policy's jerk across chunk handovers.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;
use serde_json::Value;

use crate::demo::DemoArgs;
use crate::shaped_link::ShapedLink;
use mars_runtime::cli::MarsdArgs;
use mars_runtime::config::DaemonConfig;
use mars_runtime::policy::remote::periods_ahead;

#[derive(clap::Args, Debug, Clone)]
pub struct RemoteBenchArgs {
    /// The daemon configuration every run starts from (its `[remote]`, if any, is replaced).
    #[arg(long, default_value = "configs/marsd.toml")]
    pub config: PathBuf,
    /// One-way delays of the link (ms).
    #[arg(long, value_delimiter = ',', default_value = "0,50,100,150,200")]
    pub one_way_ms: Vec<f64>,
    #[arg(long, default_value_t = 10)]
    pub episodes: usize,
    #[arg(long, default_value = "runs/bench_remote")]
    pub out: PathBuf,
}

struct Row {
    label: String,
    ahead: Option<usize>,
    continuity: &'static str,
    summary: Option<Value>,
    link_bytes_per_s: Option<f64>,
    error: Option<String>,
}

pub fn run(args: RemoteBenchArgs) -> anyhow::Result<()> {
    anyhow::ensure!(args.episodes > 0, "--episodes must be at least 1");
    let cfg = DaemonConfig::load(&args.config)?;
    let chunk = mars_engine::Engine::load(&cfg.checkpoint, mars_engine::EngineConfig::default())?.chunk_len();
    let _rig = mars_runtime::rt::rig_lock::rt_rig_lock().context("taking the real-time rig lock")?;
    std::fs::create_dir_all(&args.out).with_context(|| format!("creating {}", args.out.display()))?;
    let prefix = format!("mars-bench/{}", std::process::id());
    let (mut host, port) = spawn_host_of(&cfg.checkpoint, &prefix, &["bench".to_owned()], &[])?;
    let link = ShapedLink::start(([127, 0, 0, 1], port).into(), Duration::ZERO)?;
    let base = std::fs::read_to_string(&args.config)?;
    let base = base.split("\n[remote]").next().unwrap_or(&base).to_owned();
    let mut rows = vec![run_row(&args, &base, "local engine", None, None, None)];
    for &d in &args.one_way_ms {
        link.shape().set_delay(Duration::from_secs_f64(d / 1e3));
        // The generated `[remote]` leaves the local reserve at marsd's default.
        // The fewest periods ahead that leave the host the round trip and its answer (as `auto_ask_ahead` chooses).
        let ahead = periods_ahead(&cfg.policy, 2.0 * d, mars_runtime::config::DEFAULT_LOCAL_RESERVE_MS);
        let label = format!("{d:.0} ms");
        if 2 * ahead >= chunk {
            rows.push(Row {
                label,
                ahead: Some(ahead),
                continuity: "-",
                summary: None,
                link_bytes_per_s: None,
                error: Some(format!("needs {ahead} periods ahead; marsd asks at most {} ahead", (chunk - 1) / 2)),
            });
            continue;
        }
        let continuities: &[&'static str] = if ahead == 0 { &["guided"] } else { &["guided", "drop-late"] };
        for &c in continuities {
            rows.push(run_row(&args, &base, &label, Some((ahead, c)), Some(&link), Some(&prefix)));
        }
    }
    let _ = host.kill();
    let _ = host.wait();
    let table = table(&rows, args.episodes);
    std::fs::write(args.out.join("results.md"), &table)?;
    println!("{table}");
    Ok(())
}

/// `marsd serve` for `robots`, each with the checkpoint in `checkpoint`, on a free port (and `extra` arguments);
/// returns once it serves.
pub(super) fn spawn_host_of(
    checkpoint: &Path,
    prefix: &str,
    robots: &[String],
    extra: &[String],
) -> anyhow::Result<(Child, u16)> {
    let port = std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
    let mut cmd = Command::new(std::env::current_exe()?);
    cmd.args(["marsd", "serve"]);
    for r in robots {
        cmd.arg("--robot").arg(format!("{r}={}", checkpoint.display()));
    }
    cmd.args(["--prefix", prefix, "--listen", &format!("tcp/127.0.0.1:{port}")]).args(extra);
    let mut child = cmd.stdout(Stdio::null()).stderr(Stdio::piped()).spawn().context("starting marsd serve")?;
    let stderr = child.stderr.take().expect("piped");
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for line in BufReader::new(stderr).lines().map_while(Result::ok) {
            if line.contains("serving") {
                let _ = tx.send(());
            }
        }
    });
    rx.recv_timeout(Duration::from_secs(30)).context("marsd serve did not start serving within 30 s")?;
    Ok((child, port))
}

fn run_row(
    args: &RemoteBenchArgs,
    base: &str,
    label: &str,
    remote: Option<(usize, &'static str)>,
    link: Option<&ShapedLink>,
    prefix: Option<&str>,
) -> Row {
    let slug = label.replace(' ', "_");
    let dir = args.out.join(format!("{slug}-{}", remote.map_or("local", |r| r.1)));
    let mut text = base.to_owned();
    if let (Some((ahead, continuity)), Some(link), Some(prefix)) = (remote, link, prefix) {
        let policy = format!("handoff_margin_ms = 2.0\nask_ahead_periods = {ahead}\ncontinuity = \"{continuity}\"");
        text = text.replacen("handoff_margin_ms = 2.0", &policy, 1);
        text += &format!("\n[remote]\nprefix = \"{prefix}\"\nname = \"bench\"\nconnect = [\"tcp/{}\"]\n", link.local);
    }
    let config = args.out.join(format!("{slug}-{}.toml", remote.map_or("local", |r| r.1)));
    let mut row = Row {
        label: label.to_owned(),
        ahead: remote.map(|r| r.0),
        continuity: remote.map_or("-", |r| r.1),
        summary: None,
        link_bytes_per_s: None,
        error: None,
    };
    if let Err(e) = std::fs::write(&config, text) {
        row.error = Some(e.to_string());
        return row;
    }
    let _ = std::fs::remove_file(dir.join("summary.json"));
    let marsd = MarsdArgs {
        robot: Some(format!("bench-remote-{}-{slug}-{}", std::process::id(), row.continuity)),
        episodes: Some(args.episodes),
        out: Some(dir.clone()),
        ..MarsdArgs::new(config)
    };
    eprintln!("== bench-remote: {label} ({}), {} episodes → {}", row.continuity, args.episodes, dir.display());
    let bytes0 = link.map(|l| l.shape().bytes());
    let t0 = Instant::now();
    if let Err(e) = crate::demo::demo(DemoArgs { hal_core: super::demo_hal_core(), ..DemoArgs::new(marsd) }) {
        row.error = Some(format!("{e:#}"));
    }
    let secs = t0.elapsed().as_secs_f64();
    row.link_bytes_per_s = link.zip(bytes0).map(|(l, b0)| (l.shape().bytes() - b0) as f64 / secs);
    row.summary = std::fs::read_to_string(dir.join("summary.json")).ok().and_then(|t| serde_json::from_str(&t).ok());
    row
}

fn u(s: &Value, p: &str) -> u64 {
    s.pointer(p).and_then(Value::as_u64).unwrap_or(0)
}

fn f(s: &Value, p: &str) -> f64 {
    s.pointer(p).and_then(Value::as_f64).unwrap_or(f64::NAN)
}

/// A histogram channel's percentile (µs) from the summary's latency table.
fn channel(s: &Value, name: &str, key: &str) -> f64 {
    let channels = s.pointer("/latency/channels").and_then(Value::as_array);
    channels.and_then(|c| c.iter().find(|c| c["channel"] == name)).map_or(f64::NAN, |c| f(c, &format!("/{key}")))
}

/// The handovers' mean jerk with a normal-approximation 95 % interval (handovers: tens per run).
fn handover(s: &Value) -> String {
    let (n, mean, std) =
        (u(s, "/handover_jerk/handovers"), f(s, "/handover_jerk/mean_rad_s3"), f(s, "/handover_jerk/std_rad_s3"));
    if n < 2 {
        return "-".into();
    }
    let half = 1.96 * std / (n as f64).sqrt();
    format!("{mean:.0} ({:.0}–{:.0})", mean - half, mean + half)
}

fn table(rows: &[Row], episodes: usize) -> String {
    let mut out = format!(
        "{episodes} episodes per row; delays are one way, through a user-space TCP delay line (this kernel has no netem)\n\n\
         | one-way delay | ask ahead | continuity | success % | host / local chunks | round trip p50 / p99 ms | capture → command p50 / p99 ms | link kB/s | servo periods missed | late chunks | out of limits | handover jerk (95 % interval of the mean) / max |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|\n"
    );
    for r in rows {
        let ahead = r.ahead.map_or("-".into(), |a| a.to_string());
        let Some(s) = &r.summary else {
            let why = r.error.as_deref().unwrap_or("no summary");
            out += &format!("| {} | {ahead} | {} | {why} |||||||||\n", r.label, r.continuity);
            continue;
        };
        let n = u(s, "/episodes") as usize;
        let success = mars_tasks::stats::wilson(u(s, "/successes") as usize, n)
            .map_or("-".into(), |e| format!("{:.0}", e.scaled(100.0)));
        let chunks = match s.get("remote").filter(|r| !r.is_null()) {
            Some(rm) => format!("{} / {}", u(rm, "/host_chunks"), u(rm, "/local_chunks")),
            None => format!("0 / {}", u(s, "/k/calls")),
        };
        let rtt = match s.get("remote").filter(|r| !r.is_null()) {
            Some(rm) => format!("{:.1} / {:.1}", f(rm, "/round_trip_ms_p50"), f(rm, "/round_trip_ms_p99")),
            None => "-".into(),
        };
        let capture = format!(
            "{:.1} / {:.1}",
            channel(s, "capture_to_command", "p50") * 1e-3,
            channel(s, "capture_to_command", "p99") * 1e-3
        );
        let limits: u64 = ["final_check", "hal_rejected", "hal_clamped"]
            .iter()
            .map(|k| u(s, &format!("/limit_violations/{k}")))
            .sum();
        out += &format!(
            "| {} | {ahead} | {} | {success} | {chunks} | {rtt} | {capture} | {} | {} | {} | {limits} | {} / {:.0} |\n",
            r.label,
            r.continuity,
            r.link_bytes_per_s.map_or("-".into(), |b| format!("{:.1}", b / 1e3)),
            u(s, "/deadline_misses/servo_missed_periods"),
            u(s, "/deadline_misses/late_chunks"),
            handover(s),
            f(s, "/handover_jerk/max_rad_s3"),
        );
    }
    out
}
