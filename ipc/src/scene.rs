//! The scene around the robot: the task's objects as a referee sees them, and the controller's requests to reset
//! them between episodes.
//!
//! On a real bench the referee is a motion-capture system or a person with a button; in the HIL demo it is the
//! simulated world (`mars-hil scene`), which also renders the camera. The controller never acts on these frames
//! (the policy sees only the robot's state and its cameras); it reads them to know when an episode succeeded and
//! which way it went, as an evaluator would.

use iceoryx2::prelude::ZeroCopySend;

/// What the scene is doing.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum ScenePhase {
    /// No episode asked for yet.
    Idle = 0,
    /// Set up for `episode`; the effector is lifted (touches nothing) until the controller says `Run`.
    Reset = 1,
    /// The episode runs: the objects move with the effector.
    Running = 2,
}

impl ScenePhase {
    pub fn from_u32(v: u32) -> Option<Self> {
        match v {
            0 => Some(Self::Idle),
            1 => Some(Self::Reset),
            2 => Some(Self::Running),
            _ => None,
        }
    }
}

/// The referee's view, published at its own rate.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("mars::SceneState")]
#[repr(C)]
pub struct SceneState {
    pub seq: u64,
    /// CLOCK_MONOTONIC when the scene was in this state (ns).
    pub timestamp_ns: u64,
    /// The episode the scene was last set up for (0: none).
    pub episode: u64,
    /// A [`ScenePhase`] as `u32`.
    pub phase: u32,
    /// 1 while the task's success condition holds.
    pub success: u32,
    /// The mode the episode has taken so far (e.g. a route's index); −1 while undecided.
    pub mode: i32,
    /// 1 once the scene stopped following the robot's state (no frame for longer than it allows).
    pub stale_robot: u32,
    /// The task object's pose in the table frame: x, y (m), θ (rad).
    pub object: [f64; 3],
    /// Where the scene has the effector (m, table frame).
    pub effector: [f64; 2],
    /// The object's distance (m) and angle (rad) to its goal.
    pub goal_error: [f64; 2],
}

impl Default for SceneState {
    fn default() -> Self {
        Self {
            seq: 0,
            timestamp_ns: 0,
            episode: 0,
            phase: ScenePhase::Idle as u32,
            success: 0,
            mode: -1,
            stale_robot: 0,
            object: [0.0; 3],
            effector: [0.0; 2],
            goal_error: [0.0; 2],
        }
    }
}

impl SceneState {
    pub fn phase(&self) -> Option<ScenePhase> {
        ScenePhase::from_u32(self.phase)
    }

    pub fn mode(&self) -> Option<usize> {
        usize::try_from(self.mode).ok()
    }
}

/// What the controller asks of the scene.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u32)]
pub enum SceneAction {
    /// Set the objects up for `episode` from `seed` and lift the effector.
    Reset = 1,
    /// Put the effector down where the robot has it and start the episode.
    Run = 2,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, ZeroCopySend)]
#[type_name("mars::SceneRequest")]
#[repr(C)]
pub struct SceneRequest {
    pub seq: u64,
    pub episode: u64,
    pub seed: u64,
    /// A [`SceneAction`] as `u32`.
    pub action: u32,
    pub _reserved: u32,
}

impl Default for SceneRequest {
    fn default() -> Self {
        Self { seq: 0, episode: 0, seed: 0, action: SceneAction::Reset as u32, _reserved: 0 }
    }
}

impl SceneRequest {
    pub fn action(&self) -> Option<SceneAction> {
        match self.action {
            1 => Some(SceneAction::Reset),
            2 => Some(SceneAction::Run),
            _ => None,
        }
    }
}
