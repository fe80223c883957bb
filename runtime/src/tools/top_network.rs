//! `marsd top --connect LOCATOR`: every robot of a fleet from any machine, a line each. It joins the Zenoh network
//! as a client of the inference host (`marsd serve`, a router) and subscribes to `<prefix>/*/live` (or one robot's
//! key with `--robot`), where each marsd with `[remote]` puts its live frames (`mars_remote::live`). Nothing is
//! asked of the daemons: a watcher costs them nothing more than the one on their own machine does.
//!
//! A frame's latencies and counters are its daemon's; "last frame" is how long ago this watcher received one,
//! on its own clock (the machines' clocks need not agree).

use std::collections::BTreeMap;
use std::fmt;
use std::io::IsTerminal;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::Context;
use mars_ipc::LiveStats;
use mars_remote::link::{LinkConfig, Role};
use mars_remote::live::{LiveError, LiveWatch};

use crate::report::latency::Channel;
use crate::shared::Phase;
use crate::tools::top::{TopArgs, TopEnd, show, trip_name};

/// A new table at most this often (frames come every `histograms.interval_s` from each robot).
const REFRESH: Duration = Duration::from_millis(500);

/// Watches the robots under `--prefix` through the hosts in `--connect` until `--count` tables, silence for
/// `timeout`, or a signal. An error if no frame came at all.
pub fn run(args: &TopArgs, timeout: Duration) -> anyhow::Result<TopEnd> {
    let link = LinkConfig { connect: args.connect.clone(), ..LinkConfig::default() };
    let session = link.open_as(Role::Client).with_context(|| format!("joining the network at {:?}", args.connect))?;
    let watch = LiveWatch::subscribe(&session, &args.prefix, args.robot.as_deref())?;
    let stop = Arc::new(AtomicBool::new(false));
    for sig in [signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT] {
        signal_hook::flag::register(sig, stop.clone())?;
    }
    let redraw = !args.plain && std::io::stdout().is_terminal();
    let mut fleet = Fleet::default();
    let (mut views, mut last_frame, mut last_view) = (0u64, Instant::now(), None::<Instant>);
    while !stop.load(Ordering::Acquire) {
        if let Some((robot, frame)) = watch.next(Duration::from_millis(50)) {
            fleet.receive(robot, frame, Instant::now());
            last_frame = Instant::now();
        } else if last_frame.elapsed() >= timeout {
            anyhow::ensure!(
                views > 0,
                "no live frame under {}/ within {:.1} s through {:?}: is a marsd with [remote] running there?",
                args.prefix,
                timeout.as_secs_f64(),
                args.connect
            );
            println!("no robot under {}/ published for {:.1} s", args.prefix, timeout.as_secs_f64());
            return Ok(TopEnd::DaemonGone { views });
        }
        let due = last_view.is_none_or(|t| t.elapsed() >= REFRESH);
        if !due || !fleet.changed {
            continue;
        }
        show(&FleetView { prefix: &args.prefix, fleet: &fleet, now: Instant::now() }.to_string(), redraw)?;
        fleet.changed = false;
        (views, last_view) = (views + 1, Some(Instant::now()));
        if args.count.is_some_and(|n| views >= n) {
            return Ok(TopEnd::Counted);
        }
    }
    Ok(TopEnd::Interrupted { views })
}

/// What this watcher has received, per robot.
#[derive(Default)]
pub struct Fleet {
    robots: BTreeMap<String, Seen>,
    /// A frame came since the last table.
    changed: bool,
}

/// One robot's newest frame and how its frames fared.
#[derive(Default)]
pub struct Seen {
    newest: Option<LiveStats>,
    at: Option<Instant>,
    frames: u64,
    /// Frames that could not be read (another version, a cut payload), and the last reason.
    refused: u64,
    last_refusal: Option<LiveError>,
}

impl Fleet {
    pub fn receive(&mut self, robot: String, frame: Result<LiveStats, LiveError>, at: Instant) {
        let seen = self.robots.entry(robot).or_default();
        match frame {
            Ok(f) => {
                (seen.newest, seen.at) = (Some(f), Some(at));
                seen.frames += 1;
            }
            Err(e) => {
                seen.last_refusal = Some(e);
                seen.refused += 1;
            }
        }
        self.changed = true;
    }
}

/// One table of `marsd top --connect`.
pub struct FleetView<'a> {
    pub prefix: &'a str,
    pub fleet: &'a Fleet,
    pub now: Instant,
}

impl fmt::Display for FleetView<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "marsd top: {} robot(s) under {}/ (latencies of each daemon's last interval)",
            self.fleet.robots.len(),
            self.prefix
        )?;
        writeln!(
            f,
            "| robot | phase | episode | servo ticks | trip | wake late p99 µs | inference p99 ms (budget) | starved \
             ticks | limit stops | HAL clamped / rejected | frames (refused) | last frame s ago |"
        )?;
        for (robot, seen) in &self.fleet.robots {
            let age = seen.at.map_or("–".to_string(), |t| format!("{:.1}", self.now.duration_since(t).as_secs_f64()));
            let (frames, refused) = (seen.frames, seen.refused);
            let Some(fr) = &seen.newest else {
                let why = seen.last_refusal.as_ref().map_or(String::new(), ToString::to_string);
                writeln!(f, "| {robot} | no frame read: {why} | | | | | | | | | {frames} ({refused}) | {age} |")?;
                continue;
            };
            let wake = &fr.channels[Channel::WakeJitter.index()];
            let inference = &fr.channels[Channel::Inference.index()];
            let inference = match inference.count {
                0 => format!("– ({:.1})", fr.inference_budget_ns as f64 / 1e6),
                _ => format!("{:.1} ({:.1})", inference.p99 as f64 / 1e6, fr.inference_budget_ns as f64 / 1e6),
            };
            writeln!(
                f,
                "| {robot} | {} | {} | {} | {} | {:.1} | {inference} | {} | {} | {} / {} | {frames} ({refused}) | {age} |",
                phase(fr.phase),
                fr.episode,
                fr.ticks,
                trip_name(fr.trip),
                wake.p99 as f64 / 1e3,
                fr.servo.starved_ticks,
                fr.servo.limit_violations,
                fr.hal.clamped,
                fr.hal.rejected,
            )?;
        }
        writeln!(f)
    }
}

/// A frame's phase by name; a number this build does not know (a newer daemon) as the number.
fn phase(code: u32) -> String {
    match u8::try_from(code) {
        Ok(v @ 0..=6) => format!("{:?}", Phase::from_u8(v)),
        _ => format!("phase {code}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each robot a line, sorted by name; a robot whose frames could not be read says why, not a zero row.
    #[test]
    fn the_table_has_a_line_per_robot_and_names_a_refused_frame() {
        let now = Instant::now();
        let mut fleet = Fleet::default();
        let mut frame = LiveStats { episode: 3, ticks: 4321, inference_budget_ns: 8_000_000, ..Default::default() };
        frame.channels[Channel::WakeJitter.index()].p99 = 53_000;
        frame.channels[Channel::Inference.index()] =
            mars_ipc::LiveChannel { count: 5, p99: 2_100_000, ..Default::default() };
        frame.phase = Phase::Running as u32;
        fleet.receive("b-arm".into(), Ok(frame), now);
        fleet.receive("a-arm".into(), Err(LiveError::Version(9)), now);
        let text = FleetView { prefix: "mars", fleet: &fleet, now }.to_string();
        let lines: Vec<&str> = text.lines().collect();
        assert!(lines[0].contains("2 robot(s) under mars/"), "{text}");
        assert!(lines[2].starts_with("| a-arm | no frame read: live frame: version 9"), "{text}");
        assert!(
            lines[3]
                .starts_with("| b-arm | Running | 3 | 4321 | none | 53.0 | 2.1 (8.0) | 0 | 0 | 0 / 0 | 1 (0) | 0.0 |"),
            "{text}"
        );
        assert_eq!(phase(300), "phase 300");
    }
}
