//! `mars-hil replay DATASET --episode N`: a recorded episode's commands through the mock HAL again — the demo's
//! rig (HAL process, marsd) with marsd running the recording's chunks instead of the policy's
//! ([`mars_runtime::policy::recorded_actions`]), from the same start pose, through the same servo smoothing and safety filter —
//! recorded in turn, and the two trajectories compared period by period. The plant is deterministic; what
//! differs is the live run's timing (which servo tick a chunk reached, the machine's stalls), so the answer is
//! how closely the plant's trajectory comes back, and whether the episode ends the same way.

use std::path::{Path, PathBuf};

use anyhow::Context;
use mars_lerobot::{Keys, LeRobotDataset};
use serde::Serialize;

use crate::demo::{DemoArgs, DemoRobot};
use mars_runtime::cli::MarsdArgs;
use mars_runtime::policy::recorded_actions::RunMeta;

#[derive(clap::Args, Debug, Clone)]
pub struct HilReplayArgs {
    /// A dataset recorded by `marsd --record` (or `mars-hil demo --record`).
    pub dataset: PathBuf,
    /// The dataset's episode (0-based, as LeRobot numbers them).
    #[arg(long)]
    pub episode: usize,
    /// Where the replay's report, logs and its own recording (`replayed/`) go; must not hold a replay yet.
    #[arg(long, default_value = "runs/hil-replay")]
    pub out: PathBuf,
    /// marsd's configuration (default: the one the recording names in meta/mars.json).
    #[arg(long)]
    pub config: Option<PathBuf>,
    /// The robot behind the HAL, as for the demo.
    #[arg(long, value_enum, default_value_t = DemoRobot::Mock)]
    pub backend: DemoRobot,
    /// The largest state difference (rad for joints, m for the gripper) still called reproduced.
    #[arg(long, default_value_t = DEFAULT_TOLERANCE)]
    pub tolerance: f64,
}

/// See README ("Replaying a run through the HAL") for what replays of the demo's runs came back within.
pub const DEFAULT_TOLERANCE: f64 = 0.05;

/// The replay's folder for its own recording, inside `--out`.
pub const REPLAYED: &str = "replayed";

/// Two recordings of one episode, period by period: each recorded state against the replay's at the same time
/// from the episode's start (the HAL's stamps, `mars.state_time_s`; the replay's states interpolated linearly
/// between its periods), as the loop's wake-up moves the instant a period's state is taken by a few ms, which at
/// 1 rad/s is as much as the plant's whole difference. Recordings without the stamps compare period by period.
#[derive(Debug, Clone, Serialize, PartialEq)]
pub struct TrajectoryComparison {
    pub recorded_frames: usize,
    pub replayed_frames: usize,
    /// Recorded periods compared (those within the replay's time span when aligned by time).
    pub compared: usize,
    /// Aligned by the HAL's stamps (else period by period).
    pub by_time: bool,
    /// Per state value its name and the largest |recorded − replayed|.
    pub max_abs_diff: Vec<(String, f64)>,
    /// The largest of them, and the period it came in.
    pub worst: f64,
    pub worst_frame: usize,
    /// The mean over periods of the largest difference in each.
    pub mean_of_max: f64,
}

impl TrajectoryComparison {
    /// `names`: the state values' names (one per value of a frame); `a`, `b`: frames × names values; `times`:
    /// each frame's time from the episode's start (s), for `a` and `b`, when both recordings have them.
    pub fn of(names: &[String], a: &[f32], b: &[f32], times: Option<(&[f32], &[f32])>) -> Self {
        let n = names.len().max(1);
        let (fa, fb) = (a.len() / n, b.len() / n);
        let mut c = TrajectoryComparison {
            recorded_frames: fa,
            replayed_frames: fb,
            compared: 0,
            by_time: times.is_some(),
            max_abs_diff: names.iter().map(|s| (s.clone(), 0.0)).collect(),
            worst: 0.0,
            worst_frame: 0,
            mean_of_max: 0.0,
        };
        let mut sum = 0.0;
        let mut other = vec![0.0f64; n];
        for t in 0..fa {
            // The replay's state at the recorded one's time, or at the same period.
            let found = match times {
                Some((ta, tb)) => interpolate(tb, b, n, f64::from(ta[t]), &mut other),
                None if t < fb => {
                    other.iter_mut().zip(&b[t * n..(t + 1) * n]).for_each(|(o, v)| *o = f64::from(*v));
                    true
                }
                None => false,
            };
            if !found {
                continue;
            }
            let mut frame_max = 0.0f64;
            for (j, m) in c.max_abs_diff.iter_mut().enumerate() {
                let d = (f64::from(a[t * n + j]) - other[j]).abs();
                m.1 = m.1.max(d);
                frame_max = frame_max.max(d);
            }
            if frame_max > c.worst {
                (c.worst, c.worst_frame) = (frame_max, t);
            }
            sum += frame_max;
            c.compared += 1;
        }
        c.mean_of_max = if c.compared > 0 { sum / c.compared as f64 } else { 0.0 };
        c
    }
}

/// `x` (frames × `n` values at times `t`, increasing) at time `at`, linearly between the frames around it, into
/// `out`; false outside the frames' span.
fn interpolate(t: &[f32], x: &[f32], n: usize, at: f64, out: &mut [f64]) -> bool {
    let Some(i) = t.windows(2).position(|w| f64::from(w[0]) <= at && at <= f64::from(w[1])) else { return false };
    let (t0, t1) = (f64::from(t[i]), f64::from(t[i + 1]));
    let s = if t1 > t0 { (at - t0) / (t1 - t0) } else { 0.0 };
    for (j, o) in out.iter_mut().enumerate() {
        let (x0, x1) = (f64::from(x[i * n + j]), f64::from(x[(i + 1) * n + j]));
        *o = x0 + s * (x1 - x0);
    }
    true
}

/// What the replay found.
#[derive(Debug, Clone, Serialize)]
pub struct HilReplayReport {
    pub dataset: PathBuf,
    pub episode: usize,
    pub trajectory: TrajectoryComparison,
    /// (success, mode) of the recorded episode and of the replay.
    pub recorded_outcome: (bool, Option<usize>),
    pub replayed_outcome: (bool, Option<usize>),
    pub tolerance: f64,
    /// Same outcome, and every state within the tolerance over the periods both have.
    pub reproduced: bool,
}

impl std::fmt::Display for HilReplayReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let t = &self.trajectory;
        writeln!(
            f,
            "replay of {} episode {}: {} periods recorded, {} replayed, {} compared {}",
            self.dataset.display(),
            self.episode,
            t.recorded_frames,
            t.replayed_frames,
            t.compared,
            if t.by_time { "at the recorded states' times" } else { "period by period" }
        )?;
        let outcome = |(s, m): (bool, Option<usize>)| {
            format!("{}{}", if s { "success" } else { "failure" }, m.map(|m| format!(", mode {m}")).unwrap_or_default())
        };
        writeln!(
            f,
            "  outcome: recorded {}, replayed {}",
            outcome(self.recorded_outcome),
            outcome(self.replayed_outcome)
        )?;
        let per: Vec<String> = t.max_abs_diff.iter().map(|(n, d)| format!("{n} {d:.4}")).collect();
        writeln!(f, "  largest |recorded − replayed| per state value: {}", per.join(", "))?;
        writeln!(
            f,
            "  worst {:.4} at period {}; mean over periods of each period's largest {:.4}",
            t.worst, t.worst_frame, t.mean_of_max
        )?;
        writeln!(
            f,
            "  {} (tolerance {})",
            if self.reproduced { "REPRODUCED" } else { "NOT REPRODUCED" },
            self.tolerance
        )
    }
}

/// Runs the replay; returns the report and the exit status: marsd's if the run failed, else 0 when reproduced
/// and 2 when not.
pub fn run(args: &HilReplayArgs) -> anyhow::Result<(Option<HilReplayReport>, u8)> {
    let meta = RunMeta::load(&args.dataset)?;
    let em = meta.episode(args.episode)?.clone();
    let config = match (&args.config, &meta.config) {
        (Some(c), _) => c.clone(),
        (None, Some(c)) => c.clone(),
        (None, None) => anyhow::bail!(
            "{}: the recording does not name marsd's configuration; give --config",
            args.dataset.display()
        ),
    };
    let replayed = args.out.join(REPLAYED);
    anyhow::ensure!(
        !replayed.exists(),
        "{} holds a replay already; give another --out (nothing is overwritten)",
        replayed.display()
    );
    let marsd = MarsdArgs {
        episodes: Some(1),
        out: Some(args.out.clone()),
        checkpoint: Some(meta.checkpoint.clone()),
        record: Some(replayed.clone()),
        replay_actions: Some(args.dataset.clone()),
        replay_episode: Some(args.episode),
        ..MarsdArgs::new(config)
    };
    let demo = DemoArgs { backend: args.backend, ..DemoArgs::new(marsd) };
    let code = crate::demo::demo(demo)?;
    if code != 0 {
        return Ok((None, code));
    }
    let replay_meta = RunMeta::load(&replayed)?;
    let re = replay_meta.episode(0).context("the replay recorded no episode")?;
    let trajectory = compare(&args.dataset, args.episode, &replayed, 0)?;
    let same_outcome = (em.success, em.mode) == (re.success, re.mode);
    let report = HilReplayReport {
        dataset: args.dataset.clone(),
        episode: args.episode,
        reproduced: same_outcome && trajectory.worst <= args.tolerance,
        trajectory,
        recorded_outcome: (em.success, em.mode),
        replayed_outcome: (re.success, re.mode),
        tolerance: args.tolerance,
    };
    let path = args.out.join("replay.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)? + "\n")
        .with_context(|| format!("writing {}", path.display()))?;
    let code = if report.reproduced { 0 } else { 2 };
    Ok((Some(report), code))
}

/// Episode `a_ep` of dataset `a` against episode `b_ep` of `b`, by `observation.state` (at the same times where
/// both have `mars.state_time_s`).
pub fn compare(a: &Path, a_ep: usize, b: &Path, b_ep: usize) -> anyhow::Result<TrajectoryComparison> {
    // (state names, states, state times if recorded)
    type Read = (Vec<String>, Vec<f32>, Option<Vec<f32>>);
    let read = |p: &Path, ep: usize| -> anyhow::Result<Read> {
        let ds = LeRobotDataset::open(p)?;
        let timed = ds.vector_len(TIME_KEY).is_ok();
        let time_key = if timed { TIME_KEY } else { "action" };
        let keys = Keys { state: "observation.state".into(), action: time_key.into(), images: vec![] };
        // LeRobot's names: a list of strings (as we write them) or other shapes, which are not used here.
        let names: Vec<String> = ds
            .info
            .features
            .get("observation.state")
            .and_then(|f| f.names.as_ref()?.as_array().cloned())
            .map(|a| a.iter().filter_map(|v| v.as_str().map(str::to_owned)).collect())
            .unwrap_or_default();
        let (mut episodes, _) = ds.read(&keys, (0, 0))?;
        anyhow::ensure!(ep < episodes.len(), "{}: no episode {ep}", p.display());
        let e = episodes.swap_remove(ep);
        let dim = e.state.len() / e.len.max(1);
        let names = if names.len() == dim { names } else { (0..dim).map(|j| format!("state[{j}]")).collect() };
        Ok((names, e.state, timed.then_some(e.action)))
    };
    let (names, sa, ta) = read(a, a_ep)?;
    let (names_b, sb, tb) = read(b, b_ep)?;
    anyhow::ensure!(names.len() == names_b.len(), "the two recordings' states differ in size");
    let times = ta.as_deref().zip(tb.as_deref());
    Ok(TrajectoryComparison::of(&names, &sa, &sb, times))
}

/// Our column with each period's state time (see [`mars_runtime::record::RecordFrame::state_time_s`]).
const TIME_KEY: &str = "mars.state_time_s";

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_comparison_finds_the_largest_difference_per_value_and_where() {
        let names = vec!["q".to_owned(), "g".to_owned()];
        let a = [0.0, 0.08, 0.1, 0.08, 0.2, 0.03];
        let b = [0.0, 0.08, 0.1, 0.07, 0.5, 0.03, 0.6, 0.03];
        let c = TrajectoryComparison::of(&names, &a, &b, None);
        assert_eq!((c.recorded_frames, c.replayed_frames, c.compared), (3, 4, 3));
        assert!((c.max_abs_diff[0].1 - 0.3).abs() < 1e-6 && (c.max_abs_diff[1].1 - 0.01).abs() < 1e-6, "{c:?}");
        assert_eq!(c.worst_frame, 2);
        assert!((c.mean_of_max - (0.0 + 0.01 + 0.3) / 3.0).abs() < 1e-6);
    }

    /// The same ramp q = t sampled at other instants: equal at the recorded times once aligned, off by the
    /// sampling offset period by period; a recorded time outside the replay's span is not compared.
    #[test]
    fn aligned_by_time_a_ramp_sampled_late_is_the_same_ramp() {
        let names = vec!["q".to_owned()];
        let (ta, tb) = ([0.1f32, 0.2, 0.3, 0.9], [0.0f32, 0.11, 0.23, 0.32]);
        let c = TrajectoryComparison::of(&names, &ta, &tb, Some((&ta, &tb)));
        assert_eq!(c.compared, 3);
        assert!(c.worst < 1e-6, "{c:?}");
        let by_period = TrajectoryComparison::of(&names, &ta, &tb, None);
        assert!((by_period.worst - 0.58).abs() < 1e-6, "{by_period:?}");
    }
}
