//! A pick task in joint space, for any arm with a gripper: from a jittered `home`, a shared approach to a
//! pre-grasp pose, then one of several grasp configurations (the task's modes), the gripper closes, and a shared
//! retreat. The paper's real-world picks are its configurations: the FR3's Pick Cup (`configs/pick_cup.toml`: the
//! mug by its rim or by its handle) and the R1 Lite's Pick Vegetable (`configs/pick_vegetable.toml`: the carrot
//! or the daikon on either side of a mango). Read from TOML and checked against the arm's facts ([`Arm`], from
//! the robot profile) before anything moves. Its world is the arm itself: the HAL's mock plant in the HIL demo,
//! a simulator or the real robot, so the task is its poses, its observation and the [`EpisodeMonitor`] that
//! tells success and the mode from the measured state.

use std::path::Path;

use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use serde::Deserialize;

/// Every pose the task can command, jitter included, stays this far (rad) inside the profile's joint limits.
pub const LIMIT_MARGIN_RAD: f64 = 0.2;

/// What a joint-space task checks its poses against: the robot profile's facts (marsd and `mars-hil` build it
/// from the HAL's profile: `mars_runtime::task::arm`).
#[derive(Debug, Clone, PartialEq)]
pub struct Arm {
    pub name: String,
    pub joints: usize,
    /// The servo rate (Hz): a policy's rate must divide it.
    pub rate_hz: f64,
    /// The un-jittered start pose (rad).
    pub home: Vec<f64>,
    pub q_min: Vec<f64>,
    pub q_max: Vec<f64>,
    /// The gripper's opening range (m).
    pub gripper_min: f64,
    pub gripper_max: f64,
}

/// One way to grasp the object (or one object to grasp): a mode of the task.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Grasp {
    pub name: String,
    /// Joint configuration of the grasp (rad).
    pub q: Vec<f64>,
}

/// How the scripted expert moves between the task's poses (see `task::expert`).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExpertParams {
    /// Durations (s) of the minimum-jerk segments: start → pre-grasp → grasp, gripper closing, → retreat.
    pub approach_s: f64,
    pub grasp_s: f64,
    pub close_s: f64,
    pub retreat_s: f64,
    /// Holding still at the retreat pose at the end, so a policy learns to stop there.
    pub hold_s: f64,
    /// Each joint of the pre-grasp, grasp and retreat poses is shifted by U(±this) rad per demo.
    pub waypoint_jitter: f64,
}

/// The task as written in its TOML file.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PickConfig {
    pub name: String,
    pub policy_rate_hz: f64,
    pub start_jitter: f64,
    pub tolerance: f64,
    pub timeout_s: f64,
    pub gripper_open: f64,
    pub gripper_closed: f64,
    pub pregrasp: Vec<f64>,
    pub retreat: Vec<f64>,
    pub grasps: Vec<Grasp>,
    pub expert: ExpertParams,
}

/// The validated task, with the profile facts it depends on (start pose, servo ticks per action).
#[derive(Debug, Clone, PartialEq)]
pub struct Pick {
    pub cfg: PickConfig,
    /// The profile's `home`: the un-jittered start.
    pub home: Vec<f64>,
    /// Servo ticks per policy action (profile rate / policy rate).
    pub ticks_per_action: usize,
}

#[derive(Debug, thiserror::Error)]
pub enum TaskError {
    // The I/O and TOML errors are part of the message, not `source`s, so `{:#}` chains print them once.
    #[error("cannot read task {path}: {error}")]
    Read { path: String, error: std::io::Error },
    #[error("task {path} is not valid TOML for a pick task: {error}")]
    Parse { path: String, error: Box<toml::de::Error> },
    #[error("task {path}: `{field}` {problem}")]
    Invalid { path: String, field: String, problem: String },
}

impl Pick {
    pub fn load(path: &Path, profile: &Arm) -> Result<Self, TaskError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|error| TaskError::Read { path: origin.clone(), error })?;
        Self::parse(&text, &origin, profile)
    }

    /// Parse and validate against `profile`; `origin` names the source in errors.
    pub fn parse(text: &str, origin: &str, profile: &Arm) -> Result<Self, TaskError> {
        let cfg: PickConfig =
            toml::from_str(text).map_err(|e| TaskError::Parse { path: origin.to_owned(), error: Box::new(e) })?;
        let ticks = profile.rate_hz / cfg.policy_rate_hz;
        let task = Self { home: profile.home.clone(), ticks_per_action: ticks.round().max(1.0) as usize, cfg };
        task.validate(profile).map_err(|(field, problem)| TaskError::Invalid {
            path: origin.to_owned(),
            field,
            problem,
        })?;
        Ok(task)
    }

    fn validate(&self, p: &Arm) -> Result<(), (String, String)> {
        let at_most = |max: f64| if max < f64::MAX { format!(" and at most {max}") } else { String::new() };
        let c = &self.cfg;
        let err = |field: &str, problem: String| Err((field.to_owned(), problem));
        // The upper bounds keep what is sized by these (the expert's steps, an episode's ticks) a size a machine
        // has: an hour of demo segment, a day of episode.
        for (field, v, max) in [
            ("policy_rate_hz", c.policy_rate_hz, 10_000.0),
            ("tolerance", c.tolerance, f64::MAX),
            ("timeout_s", c.timeout_s, 86_400.0),
            ("expert.approach_s", c.expert.approach_s, 3600.0),
            ("expert.grasp_s", c.expert.grasp_s, 3600.0),
            ("expert.close_s", c.expert.close_s, 3600.0),
            ("expert.retreat_s", c.expert.retreat_s, 3600.0),
        ] {
            if !(v.is_finite() && v > 0.0 && v <= max) {
                return err(field, format!("is {v:?}, must be a finite number > 0{}", at_most(max)));
            }
        }
        for (field, v, max) in [
            ("start_jitter", c.start_jitter, f64::MAX),
            ("expert.hold_s", c.expert.hold_s, 3600.0),
            ("expert.waypoint_jitter", c.expert.waypoint_jitter, f64::MAX),
        ] {
            if !(v.is_finite() && v >= 0.0 && v <= max) {
                return err(field, format!("is {v:?}, must be a finite number ≥ 0{}", at_most(max)));
            }
        }
        let ticks = p.rate_hz / c.policy_rate_hz;
        if (ticks - ticks.round()).abs() > 1e-9 || ticks < 1.0 {
            return err(
                "policy_rate_hz",
                format!(
                    "{} must divide the profile's rate_hz {} (servo ticks per action: {ticks})",
                    c.policy_rate_hz, p.rate_hz
                ),
            );
        }
        if c.grasps.len() < 2 {
            return err("grasps", format!("has {} entries; a multimodal task needs at least 2", c.grasps.len()));
        }
        // A grasp pose counts as reached within `tolerance` even after the expert's jitter moved it.
        if c.expert.waypoint_jitter >= c.tolerance / 2.0 {
            return err(
                "expert.waypoint_jitter",
                format!(
                    "{} must be below tolerance / 2 = {} so jittered grasps still count",
                    c.expert.waypoint_jitter,
                    c.tolerance / 2.0
                ),
            );
        }
        let in_range = |g: f64| (p.gripper_min..=p.gripper_max).contains(&g);
        if !in_range(c.gripper_open) || !in_range(c.gripper_closed) || c.gripper_closed >= c.gripper_open {
            return err(
                "gripper_closed",
                format!(
                    "{} and gripper_open {} must satisfy {} ≤ closed < open ≤ {} (the profile's gripper range)",
                    c.gripper_closed, c.gripper_open, p.gripper_min, p.gripper_max
                ),
            );
        }
        let j = c.expert.waypoint_jitter;
        let mut poses = vec![("home (the profile's)".to_owned(), &self.home, c.start_jitter)];
        poses.push(("pregrasp".to_owned(), &c.pregrasp, j));
        poses.push(("retreat".to_owned(), &c.retreat, j));
        poses.extend(c.grasps.iter().enumerate().map(|(i, g)| (format!("grasps[{i}] ({})", g.name), &g.q, j)));
        for (field, q, jitter) in poses {
            if q.len() != p.joints {
                return err(&field, format!("has {} values but the {} has {} joints", q.len(), p.name, p.joints));
            }
            for (i, &x) in q.iter().enumerate() {
                let (lo, hi) = (p.q_min[i] + LIMIT_MARGIN_RAD, p.q_max[i] - LIMIT_MARGIN_RAD);
                if !(x.is_finite() && x - jitter >= lo && x + jitter <= hi) {
                    let limits = format!("the {} limits less a {LIMIT_MARGIN_RAD} rad margin", p.name);
                    return err(
                        &field,
                        format!("joint {i} = {x} (± jitter {jitter}) leaves [{lo:.4}, {hi:.4}]: {limits}"),
                    );
                }
            }
        }
        // The modes must be told apart by the monitor: no pose within reach of two grasps, nor of the pre-grasp.
        for (a, ga) in c.grasps.iter().enumerate() {
            if max_abs_diff(&ga.q, &c.pregrasp) <= 2.0 * c.tolerance {
                return err(
                    &format!("grasps[{a}]"),
                    format!("({}) lies within 2·tolerance of the pregrasp pose", ga.name),
                );
            }
            for gb in &c.grasps[a + 1..] {
                if max_abs_diff(&ga.q, &gb.q) <= 2.0 * c.tolerance {
                    return err(
                        &format!("grasps[{a}]"),
                        format!(
                            "({}) and {} differ by at most 2·tolerance: the modes would be ambiguous",
                            ga.name, gb.name
                        ),
                    );
                }
            }
        }
        Ok(())
    }

    pub fn joints(&self) -> usize {
        self.home.len()
    }

    /// Observation = [q (rad) …, gripper width (m)].
    pub fn obs_dim(&self) -> usize {
        self.joints() + 1
    }

    /// Action = [q target (rad) …, gripper target (m)].
    pub fn action_dim(&self) -> usize {
        self.joints() + 1
    }

    /// The two joints in which the grasps differ most, in joint order: the plane where the modes show as two
    /// branches (Pick Cup: joints 0 and 6).
    pub fn most_distinct_joints(&self) -> [usize; 2] {
        let spread = |j: usize| {
            let q = self.cfg.grasps.iter().map(|g| g.q[j]);
            q.clone().fold(f64::NEG_INFINITY, f64::max) - q.fold(f64::INFINITY, f64::min)
        };
        let mut joints: Vec<usize> = (0..self.joints()).collect();
        joints.sort_by(|&a, &b| spread(b).total_cmp(&spread(a)).then(a.cmp(&b)));
        let (a, b) = (joints[0], joints.get(1).copied().unwrap_or(joints[0]));
        [a.min(b), a.max(b)]
    }

    pub fn n_modes(&self) -> usize {
        self.cfg.grasps.len()
    }

    /// The seconds one policy action lasts.
    pub fn action_period_s(&self) -> f64 {
        1.0 / self.cfg.policy_rate_hz
    }

    /// The episode's start: `home` with each joint shifted by U(±start_jitter), from `seed` alone.
    pub fn start_pose(&self, seed: u64) -> Vec<f64> {
        let mut rng = StdRng::seed_from_u64(seed);
        let j = self.cfg.start_jitter;
        self.home.iter().map(|&h| if j > 0.0 { h + rng.random_range(-j..=j) } else { h }).collect()
    }

    /// Writes the observation for measured joints `q` and gripper width into `out` (obs_dim values).
    pub fn observation(&self, q: &[f64], gripper: f64, out: &mut [f32]) {
        let n = self.joints();
        for (o, &x) in out[..n].iter_mut().zip(&q[..n]) {
            *o = x as f32;
        }
        out[n] = gripper as f32;
    }

    /// "Stay at the start with the gripper open": pads the action history before the first action, in the demos
    /// and at run time alike.
    pub fn rest_action(&self, start: &[f64]) -> Vec<f32> {
        let mut a: Vec<f32> = start.iter().map(|&x| x as f32).collect();
        a.push(self.cfg.gripper_open as f32);
        a
    }

    pub fn monitor(&self) -> EpisodeMonitor {
        EpisodeMonitor::new(self)
    }
}

/// The largest difference between two poses, joint by joint (rad).
pub fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).fold(0.0, |m, (x, y)| m.max((x - y).abs()))
}

/// Why an episode ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum DoneReason {
    /// Grasped, then reached the retreat pose with the gripper closed.
    Retreated,
    Timeout,
    /// A measured joint or the gripper was NaN or infinite.
    InvalidState,
    /// Push-T: the scene's referee saw the block home.
    GoalReached,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    Running,
    /// `success`: a grasp configuration was reached; `mode`: the first one reached.
    Done {
        success: bool,
        mode: Option<usize>,
        reason: DoneReason,
    },
}

/// Watches one episode's measured state. Owns copies of the poses (allocated once, in `new`), so `update`
/// allocates nothing and the monitor can run on the servo thread.
#[derive(Debug, Clone)]
pub struct EpisodeMonitor {
    grasps: Vec<Vec<f64>>,
    retreat: Vec<f64>,
    tolerance: f64,
    timeout_s: f64,
    /// Below this width the gripper counts as closed (holding the object): halfway between closed and open.
    gripper_holding_below: f64,
    grasped: Option<usize>,
    done: Option<Progress>,
}

impl EpisodeMonitor {
    pub fn new(task: &Pick) -> Self {
        let c = &task.cfg;
        Self {
            grasps: c.grasps.iter().map(|g| g.q.clone()).collect(),
            retreat: c.retreat.clone(),
            tolerance: c.tolerance,
            timeout_s: c.timeout_s,
            gripper_holding_below: 0.5 * (c.gripper_open + c.gripper_closed),
            grasped: None,
            done: None,
        }
    }

    /// Forget the episode: ready for the next one.
    pub fn reset(&mut self) {
        self.grasped = None;
        self.done = None;
    }

    /// The grasp reached so far, if any.
    pub fn grasped(&self) -> Option<usize> {
        self.grasped
    }

    /// Feed the measured joints, gripper width and time since the episode started. Once `Done`, stays `Done`.
    pub fn update(&mut self, q: &[f64], gripper: f64, t_s: f64) -> Progress {
        if let Some(done) = self.done {
            return done;
        }
        let n = self.retreat.len();
        let q = &q[..n];
        let reason = if q.iter().any(|x| !x.is_finite()) || !gripper.is_finite() {
            Some(DoneReason::InvalidState)
        } else {
            if self.grasped.is_none() {
                self.grasped = self.grasps.iter().position(|g| max_abs_diff(q, g) <= self.tolerance);
            }
            let holding = gripper < self.gripper_holding_below;
            if self.grasped.is_some() && holding && max_abs_diff(q, &self.retreat) <= self.tolerance {
                Some(DoneReason::Retreated)
            } else if t_s >= self.timeout_s {
                Some(DoneReason::Timeout)
            } else {
                None
            }
        };
        let Some(reason) = reason else { return Progress::Running };
        let done = Progress::Done { success: self.grasped.is_some(), mode: self.grasped, reason };
        self.done = Some(done);
        done
    }
}

impl crate::Task for Pick {
    fn name(&self) -> &str {
        &self.cfg.name
    }

    fn obs_dim(&self) -> usize {
        Pick::obs_dim(self)
    }

    fn action_dim(&self) -> usize {
        Pick::action_dim(self)
    }

    fn mode_names(&self) -> Vec<String> {
        self.cfg.grasps.iter().map(|g| g.name.clone()).collect()
    }
}
