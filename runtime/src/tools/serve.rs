//! `marsd serve`: this machine as the inference host of one or more robots (each robot's marsd with `[remote]`):
//! loads a checkpoint per robot, answers their queries earliest deadline first until SIGTERM/SIGINT or
//! `--duration-s`, then prints what it did per robot (and writes it as JSON with `--out`). Its session is a Zenoh
//! router: it forwards the robots' live frames to a `marsd top --connect` attached to it.

use std::fmt;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::Context;
use mars_engine::{Engine, EngineConfig};
use mars_remote::link::{LinkConfig, Role};
use mars_remote::server::{ServeReport, ServedRobot, serve};

#[derive(clap::Args, Debug, Clone)]
pub struct ServeArgs {
    /// A robot served, with its checkpoint: `NAME=DIR` (NAME is the robot's `robot` in its marsd config). Repeat
    /// for a fleet; each robot gets an engine of its own.
    #[arg(long = "robot", value_name = "NAME=DIR", required = true)]
    pub robots: Vec<String>,
    /// Key prefix shared with the robots' `[remote] prefix`.
    #[arg(long, default_value = "mars")]
    pub prefix: String,
    /// Zenoh locators to listen on, e.g. `tcp/0.0.0.0:7447`.
    #[arg(long)]
    pub listen: Vec<String>,
    /// Zenoh locators to connect to (a router, or robots that listen).
    #[arg(long)]
    pub connect: Vec<String>,
    /// Also find robots by UDP multicast scouting.
    #[arg(long)]
    pub multicast_scouting: bool,
    /// Seed of the engines' noise generators (each call is reseeded by the robot's request anyway).
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Stop after this many seconds (0: at SIGTERM/SIGINT).
    #[arg(long, default_value_t = 0.0)]
    pub duration_s: f64,
    /// Write the report here as JSON at exit.
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// What `marsd serve` prints at exit.
pub struct Served(pub ServeReport);

impl fmt::Display for Served {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "| robot | chunks | mean K | expired | late replies | refused | longest queue wait |")?;
        for (robot, c) in &self.0.robots {
            let mean_k = if c.chunks > 0 { c.k_sum as f64 / c.chunks as f64 } else { 0.0 };
            let queue_ms = c.max_queue_ns as f64 * 1e-6;
            let (chunks, expired, late, refused) = (c.chunks, c.expired, c.late_replies, c.refused);
            writeln!(f, "| {robot} | {chunks} | {mean_k:.2} | {expired} | {late} | {refused} | {queue_ms:.2} ms |")?;
        }
        writeln!(f, "queries for robots not served here: {}; undecodable: {}", self.0.unknown_robot, self.0.undecodable)
    }
}

pub fn run(a: &ServeArgs) -> anyhow::Result<Served> {
    anyhow::ensure!(
        a.duration_s.is_finite() && (0.0..=1e9).contains(&a.duration_s),
        "--duration-s must be a number of seconds ≥ 0, got {}",
        a.duration_s
    );
    let mut robots = Vec::new();
    for spec in &a.robots {
        let (robot, dir) = spec.split_once('=').with_context(|| format!("--robot {spec}: give NAME=CHECKPOINT_DIR"))?;
        let cfg = EngineConfig { seed: a.seed, ..EngineConfig::default() };
        let engine = Engine::load(dir.as_ref(), cfg).with_context(|| format!("--robot {robot}: checkpoint {dir}"))?;
        robots.push(ServedRobot { robot: robot.to_owned(), engine });
    }
    let link =
        LinkConfig { connect: a.connect.clone(), listen: a.listen.clone(), multicast_scouting: a.multicast_scouting };
    // A router, so that a `marsd top --connect` here sees the live frames of every robot connected here.
    let session = link.open_as(Role::Router)?;
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(sig, stop.clone())?;
    }
    if a.duration_s > 0.0 {
        let (s, d) = (stop.clone(), Duration::from_secs_f64(a.duration_s));
        std::thread::spawn(move || {
            std::thread::sleep(d);
            s.store(true, Ordering::Release);
        });
    }
    let report = serve(&session, &a.prefix, robots, &stop)?;
    if let Some(out) = &a.out {
        let json = serde_json::to_string_pretty(&report)?;
        std::fs::write(out, json).with_context(|| format!("writing {}", out.display()))?;
    }
    Ok(Served(report))
}
