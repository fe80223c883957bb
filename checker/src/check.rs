//! `mars-checker check`: the verdict on one recording, printed for a person or as JSON for a program.

use std::path::PathBuf;

use anyhow::Context;
use serde::Serialize;

use crate::judge::{Verdict, judge};
use crate::limits::Limits;
use crate::stream;

#[derive(clap::Args, Debug)]
pub struct CheckArgs {
    /// The recording `mars-checker record` wrote.
    pub recording: PathBuf,
    /// The robot's profile, whose limits judge the stream (e.g. configs/fr3.toml).
    #[arg(long)]
    pub profile: PathBuf,
    /// When a fault was injected (CLOCK_MONOTONIC ns, the recorder's clock): the verdict adds how the HAL reacted.
    #[arg(long)]
    pub fault_at_ns: Option<u64>,
    /// The robot's own log over the recording (franka-sim's): each motion it aborted counts as a reflex.
    #[arg(long)]
    pub robot_log: Option<PathBuf>,
    /// Print the verdict as one JSON object instead of text.
    #[arg(long)]
    pub json: bool,
}

/// What franka-sim logs when its safety checks abort a motion (its reflex), once per abort.
pub const ROBOT_LOG_ABORT: &str = "aborting the motion";

#[derive(Debug, Serialize)]
pub struct Report {
    #[serde(flatten)]
    pub verdict: Verdict,
    /// Motions the robot's own log says it aborted (None: no log given).
    pub robot_log_reflexes: Option<u64>,
    pub clean: bool,
}

/// The report on `args.recording`; an error for input that cannot be judged (unreadable, not a recording, a bad
/// profile).
pub fn report(args: &CheckArgs) -> anyhow::Result<Report> {
    let limits = Limits::load(&args.profile)?;
    let text =
        std::fs::read_to_string(&args.recording).with_context(|| format!("reading {}", args.recording.display()))?;
    let frames = stream::parse(&text).with_context(|| format!("{}", args.recording.display()))?;
    let verdict = judge(&frames, &limits, args.fault_at_ns);
    let robot_log_reflexes = match &args.robot_log {
        None => None,
        Some(p) => {
            let log = std::fs::read(p).with_context(|| format!("reading {}", p.display()))?;
            Some(String::from_utf8_lossy(&log).matches(ROBOT_LOG_ABORT).count() as u64)
        }
    };
    let clean = verdict.clean() && robot_log_reflexes.unwrap_or(0) == 0;
    Ok(Report { verdict, robot_log_reflexes, clean })
}

impl std::fmt::Display for Report {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let v = &self.verdict;
        writeln!(
            f,
            "{} frames ({} lost by the recording, {} after robot cycles the HAL never saw, the longest pause of the \
             HAL's stamps {:.1} ms); steps judged: {} velocity, {} acceleration, {} jerk",
            v.frames,
            v.lost_frames,
            v.robot_gaps,
            v.largest_gap_ms,
            v.velocity_steps,
            v.acceleration_steps,
            v.jerk_steps
        )?;
        writeln!(
            f,
            "largest |v|/dq_max {:.3}, |a|/ddq_max {:.3}, |j|/jerk_max {:.3}; least room to the velocity bound at its \
             position {:.4} rad/s",
            v.max_ratio.velocity, v.max_ratio.acceleration, v.max_ratio.jerk, v.least_velocity_room
        )?;
        for x in &v.first_violations {
            writeln!(f, "VIOLATION seq {} joint {}: {} {} (limit {})", x.seq, x.joint, x.what, x.value, x.limit)?;
        }
        let log = self.robot_log_reflexes.map_or(String::new(), |n| format!(", {n} in the robot's log"));
        writeln!(f, "{} violations, {} reflexes{log}", v.violations, v.reflexes)?;
        if let Some(r) = &v.reaction {
            let ms = |x: Option<f64>| x.map_or("–".into(), |x| format!("{x:.1} ms"));
            writeln!(
                f,
                "after the fault (arm {}): HAL holding: {} ({}), after {}; at rest after {}",
                if r.moving { "moving" } else { "at rest" },
                r.held,
                r.hold_reason,
                ms(r.hold_ms),
                ms(r.rest_ms)
            )?;
        }
        write!(f, "{}", if self.clean { "CLEAN" } else { "NOT CLEAN" })?;
        if !v.ends_at_rest {
            write!(f, " (the recording does not end with the arm held at rest)")?;
        }
        writeln!(f)
    }
}
