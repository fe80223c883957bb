//! `marsd top`: a running daemon's loops as they run, refreshed with every interval its latency collector
//! receives (`histograms.interval_s`, 0.25 s in the shipped config): latency percentiles, the servo's counters and
//! the HAL's safety counters, phase and trip. It attaches to `mars/<robot>/live` like any
//! subscriber: no server, no request to the daemon, nothing added to its real-time loops (see `live`). With
//! `--connect`, a fleet's robots through their inference host instead, from any machine (`top_network`).

use std::fmt;
use std::io::{IsTerminal, Write as _};
use std::time::{Duration, Instant};

use anyhow::Context;
use mars_ipc::clock::monotonic_ns;
use mars_ipc::node::create_node;
use mars_ipc::{LiveReader, LiveStats, RobotNamespace};

use crate::report::latency::Channel;
use crate::servo::watchdog::Trip;
use crate::shared::Phase;

#[derive(clap::Args, Debug, Clone)]
pub struct TopArgs {
    /// The robot whose daemon to watch (the service is mars/<robot>/live). Needed on the robot's machine; with
    /// `--connect`, only this robot of the fleet.
    #[arg(long)]
    pub robot: Option<String>,
    /// Watch every robot whose marsd has `[remote]` through the inference host at these Zenoh locators (e.g.
    /// `tcp/192.168.1.20:7447`, where `marsd serve` listens), from any machine: a line per robot.
    #[arg(long)]
    pub connect: Vec<String>,
    /// With `--connect`: the robots' `[remote] prefix`.
    #[arg(long, default_value = "mars")]
    pub prefix: String,
    /// Show this many views, then exit (default: until the daemon stops publishing, or Ctrl-C).
    #[arg(long)]
    pub count: Option<u64>,
    /// How long without a frame means the daemon is not (or no longer) running (s).
    #[arg(long, default_value_t = 5.0)]
    pub timeout_s: f64,
    /// Print each view below the last instead of redrawing the screen (the default when stdout is not a terminal).
    #[arg(long)]
    pub plain: bool,
}

/// How the watch ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TopEnd {
    /// `--count` views shown.
    Counted,
    /// Frames came, then stopped for the timeout: the daemon ended (or hung).
    DaemonGone { views: u64 },
    /// Ctrl-C or SIGTERM.
    Interrupted { views: u64 },
}

/// Watches until `--count` views, the daemon's silence, or a signal. An error if no frame came at all.
pub fn run(args: &TopArgs) -> anyhow::Result<TopEnd> {
    let timeout = Duration::try_from_secs_f64(args.timeout_s)
        .ok()
        .filter(|t| !t.is_zero() && t.as_secs() <= 86_400)
        .with_context(|| format!("--timeout-s must be a number of seconds in (0, 86400], got {}", args.timeout_s))?;
    if !args.connect.is_empty() {
        return crate::tools::top_network::run(args, timeout);
    }
    let robot =
        args.robot.as_deref().context("--robot NAME (this machine's daemon), or --connect LOCATOR (a fleet)")?;
    let ns = RobotNamespace::new(robot)?;
    let (node, _) = create_node(&format!("marsd-top-{robot}-{}", std::process::id()))?;
    let reader = LiveReader::new(&node, &ns).with_context(|| format!("subscribing to mars/{robot}/live"))?;
    let redraw = !args.plain && std::io::stdout().is_terminal();
    let (mut views, mut last_frame) = (0u64, Instant::now());
    loop {
        if node.wait(Duration::from_millis(50)).is_err() {
            return Ok(TopEnd::Interrupted { views });
        }
        // Only the newest frame matters; older ones queued while we slept are skipped.
        let mut newest = None;
        while let Some(frame) = reader.receive().with_context(|| format!("reading {}", reader.service()))? {
            newest = Some(frame);
        }
        let Some(frame) = newest else {
            if last_frame.elapsed() < timeout {
                continue;
            }
            if views == 0 {
                anyhow::bail!(
                    "no live frame on mars/{robot}/live within {:.1} s: is marsd running for robot {robot:?}?",
                    args.timeout_s,
                );
            }
            println!("marsd on {robot} stopped publishing ({:.1} s without a frame)", args.timeout_s);
            return Ok(TopEnd::DaemonGone { views });
        };
        last_frame = Instant::now();
        show(&View { robot, frame: &frame, now_ns: monotonic_ns() }.to_string(), redraw)?;
        views += 1;
        if args.count.is_some_and(|n| views >= n) {
            return Ok(TopEnd::Counted);
        }
    }
}

/// Prints one view: in place of the last (`redraw`, a terminal) or below it.
pub(crate) fn show(text: &str, redraw: bool) -> std::io::Result<()> {
    let mut out = std::io::stdout().lock();
    if redraw {
        // Home, clear: one screen that updates in place.
        write!(out, "\x1b[H\x1b[2J")?;
    }
    write!(out, "{text}")?;
    out.flush()
}

/// A trip code as a frame carries it, by name ("none" for 0; a code this build does not know as the number).
pub(crate) fn trip_name(code: u32) -> String {
    match code {
        0 => "none".to_string(),
        c => Trip::from_code(c).map_or(format!("code {c}"), |t| t.to_string()),
    }
}

/// One screen of `marsd top`.
pub struct View<'a> {
    pub robot: &'a str,
    pub frame: &'a LiveStats,
    pub now_ns: u64,
}

impl fmt::Display for View<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let fr = self.frame;
        let trip = trip_name(fr.trip);
        writeln!(
            f,
            "marsd on {} — {:?}, episode {}, servo ticks {}, trip: {trip}",
            self.robot,
            Phase::from_u8(fr.phase as u8),
            fr.episode,
            fr.ticks
        )?;
        writeln!(
            f,
            "servo period {:.0} µs; policy budget per call {:.1} ms; live frame {}; intervals extended (collector slow) {}",
            fr.period_ns as f64 / 1e3,
            fr.inference_budget_ns as f64 / 1e6,
            fr.seq,
            fr.starved
        )?;
        writeln!(
            f,
            "{:<23} {:>5} {:>7} {:>9} {:>9} {:>9} {:>9} {:>8}",
            "channel (last interval)", "unit", "count", "p50", "p99", "max", "≥ period", "age s"
        )?;
        for c in Channel::ALL {
            let ch = &fr.channels[c.index()];
            if ch.end_ns == 0 {
                continue; // this daemon does not record it (e.g. camera channels on a state-only task)
            }
            let value = |v: u64| match c {
                Channel::WInf => format!("{:.3}", v as f64 / 1e3),
                _ if c.is_time() => format!("{:.1}", v as f64 / 1e3),
                _ => v.to_string(),
            };
            let over = if c.is_time() { ch.over_period.to_string() } else { "–".to_string() };
            // The inputs' frame ages say whose frames they are: the robot's, and the camera's by name.
            let label = match c {
                Channel::StateAge => format!("{}[robot]", c.tag()),
                Channel::CameraAge if !fr.camera_name().is_empty() => format!("{}[{}]", c.tag(), fr.camera_name()),
                _ => c.tag().to_owned(),
            };
            writeln!(
                f,
                "{:<23} {:>5} {:>7} {:>9} {:>9} {:>9} {:>9} {:>8.1}",
                label,
                c.unit(),
                ch.count,
                value(ch.p50),
                value(ch.p99),
                value(ch.max),
                over,
                self.now_ns.saturating_sub(ch.end_ns) as f64 / 1e9
            )?;
        }
        let (sv, h) = (&fr.servo, &fr.hal);
        writeln!(
            f,
            "servo: {} commands sent, {} late for the HAL, {} resyncs, {} ticks with no new frame, {} actions dropped, \
             {} starved ticks, {} stopped by the final limit check",
            sv.commands_sent,
            sv.late_commands,
            sv.resyncs,
            sv.frameless_ticks,
            sv.actions_dropped,
            sv.starved_ticks,
            sv.limit_violations
        )?;
        writeln!(
            f,
            "HAL: {} commands rejected, {} clamped, {} late; position guard {}, infeasible steps {}, backend errors {}",
            h.rejected, h.clamped, h.late, h.position_guard_hits, h.infeasible_steps, h.backend_errors
        )?;
        let inference = &fr.channels[Channel::Inference.index()];
        if inference.count > 0 && fr.inference_budget_ns > 0 {
            writeln!(
                f,
                "inference p99 {:.1} ms of its {:.1} ms budget ({:.0} %)",
                inference.p99 as f64 / 1e6,
                fr.inference_budget_ns as f64 / 1e6,
                100.0 * inference.p99 as f64 / fr.inference_budget_ns as f64
            )?;
        }
        writeln!(f)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The inputs' frame ages are named: the robot's, and the camera's by the name the daemon sent (a long name cut
    /// at a character boundary); a state-only daemon shows no camera row.
    #[test]
    fn frame_ages_are_named_by_their_input() {
        let mut frame = LiveStats::default();
        for c in [Channel::StateAge, Channel::CameraAge] {
            frame.channels[c.index()].end_ns = 1;
        }
        frame.set_camera_name("top");
        let text = View { robot: "r", frame: &frame, now_ns: 2 }.to_string();
        assert!(text.contains("state_age[robot]") && text.contains("camera_age[top]"), "{text}");
        frame.set_camera_name(&"é".repeat(20));
        assert_eq!(frame.camera_name(), "é".repeat(16));
        frame.channels[Channel::CameraAge.index()].end_ns = 0;
        frame.set_camera_name("");
        let text = View { robot: "r", frame: &frame, now_ns: 2 }.to_string();
        assert!(!text.contains("camera_age"), "{text}");
    }
}
