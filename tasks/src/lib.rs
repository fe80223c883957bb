//! The simulated tasks: for each, its world, its scripted expert, its success and mode, and what a camera sees.
//! One home for the policy's training and evaluation (crate `mars_policy` depends on this one) and for the HIL
//! scene (crate `mars_runtime`).
//!
//! - [`demo`]: what any task hands to training; [`rollout`]: what a task's evaluation needs of a policy;
//!   [`stats`]: the intervals and verdicts an evaluation's figures come with.
//! - [`nav2d`]: the benchmark task — a point agent through one of several passages between two gates.
//! - [`push_t`]: the paper's FR3 Push-T — a T block pushed across a table by the end effector, seen from above;
//!   the expert goes around the block by the upper or the lower route.
//! - [`pick`]: a pick in joint space with several grasps — the FR3 Pick Cup (a mug by its rim or its handle), the
//!   R1 Lite Pick Vegetable (the carrot or the daikon). Its world is the arm (the HAL's mock plant, a simulator or
//!   the robot), so its expert and rollouts live with the HAL's plant in `mars_runtime::task`; the task itself
//!   (poses, observation, success and mode) is here.
//!
//! Every task says what a policy and the runtime need to know of it through one small trait, [`Task`].

pub mod demo;
pub mod nav2d;
pub mod pick;
pub mod push_t;
pub mod rollout;
pub mod stats;

/// What every task tells the policy and the runtime about itself.
pub trait Task {
    fn name(&self) -> &str;
    /// Values per observation (state tasks; a camera's images come beside it).
    fn obs_dim(&self) -> usize;
    /// Values per action.
    fn action_dim(&self) -> usize;
    /// The modes' names, in the order the task numbers them.
    fn mode_names(&self) -> Vec<String>;
}
