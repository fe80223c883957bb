//! The hardware-in-the-loop tasks marsd runs, behind one [`HilTask`]: a pick in joint space (the FR3's Pick Cup,
//! the R1 Lite's Pick Vegetable) and Push-T on the table (around the block by the upper or the lower route).
//!
//! The pick task itself (TOML, start poses, observations, the [`pick::EpisodeMonitor`]) lives with the other tasks
//! in `mars_tasks::pick`, checked against the profile's facts ([`arm`]). Its expert demos and in-process evaluation
//! on the sim plant are the HIL rig's (`mars_hil::task`). [`push_t`] is Push-T as marsd sees it (the world is the
//! scene process, `mars_hil::scene`).

pub mod push_t;

use std::path::Path;

use mars_profile::Profile;
pub use mars_tasks::Task;
pub use mars_tasks::pick;

pub use pick::{Arm, DoneReason, EpisodeMonitor, Pick, Progress, TaskError};
pub use push_t::PushTHil;

/// The profile's facts a joint-space task is checked against.
pub fn arm(p: &Profile) -> Arm {
    Arm {
        name: p.name.clone(),
        joints: p.joints,
        rate_hz: p.rate_hz,
        home: p.home.clone(),
        q_min: p.q_min.clone(),
        q_max: p.q_max.clone(),
        gripper_min: p.gripper_min,
        gripper_max: p.gripper_max,
    }
}

/// A task marsd can run, chosen by the task file's `kind` (none: a pick task).
#[derive(Debug, Clone)]
// One per marsd run, built at start: the variants' sizes do not matter.
#[allow(clippy::large_enum_variant)]
pub enum HilTask {
    Pick(Pick),
    PushT(PushTHil),
}

impl HilTask {
    /// Reads the task file and validates it against `profile`; its `kind` key says which task it is.
    pub fn load(path: &Path, profile: &Profile) -> Result<Self, TaskError> {
        let origin = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|error| TaskError::Read { path: origin.clone(), error })?;
        Self::parse(&text, origin, profile)
    }

    /// [`HilTask::load`] of a task file's text (`origin` names it in errors).
    pub fn parse(text: &str, origin: String, profile: &Profile) -> Result<Self, TaskError> {
        let kind = text
            .parse::<toml::Table>()
            .map_err(|e| TaskError::Parse { path: origin.clone(), error: Box::new(e) })?
            .get("kind")
            .map(|k| k.as_str().map(str::to_owned));
        match kind {
            None => Pick::parse(text, &origin, &arm(profile)).map(Self::Pick),
            Some(Some(k)) if k == "push_t" => PushTHil::parse(text, &origin, profile).map(Self::PushT),
            Some(k) => Err(TaskError::Invalid {
                path: origin,
                field: "kind".into(),
                problem: format!("is {k:?}: \"push_t\", or no `kind` for a pick task"),
            }),
        }
    }

    /// The task behind the trait every task shares.
    pub fn task(&self) -> &dyn Task {
        match self {
            Self::Pick(t) => t,
            Self::PushT(t) => t,
        }
    }

    pub fn name(&self) -> &str {
        self.task().name()
    }

    pub fn obs_dim(&self) -> usize {
        self.task().obs_dim()
    }

    pub fn action_dim(&self) -> usize {
        self.task().action_dim()
    }

    pub fn policy_rate_hz(&self) -> f64 {
        match self {
            Self::Pick(t) => t.cfg.policy_rate_hz,
            Self::PushT(t) => t.cfg.policy_rate_hz,
        }
    }

    /// The two joints the episodes plot shows: where a pick's grasps differ most; Push-T's 0 and 6 (the FR3's
    /// base and wrist, which swing the flange between the two routes).
    pub fn plot_joints(&self) -> [usize; 2] {
        match self {
            Self::Pick(t) => t.most_distinct_joints(),
            Self::PushT(_) => [0, 6],
        }
    }

    /// The modes' names, in the order the task numbers them.
    pub fn mode_names(&self) -> Vec<String> {
        self.task().mode_names()
    }
}

/// A path in the repository (tests run from the crate's directory).
#[cfg(test)]
pub(crate) fn repo_path(rel: &str) -> std::path::PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(rel)
}
