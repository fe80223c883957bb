//! Push-T: a T-shaped block on a table, pushed into a target pose by a round pusher (the FR3's end effector,
//! moving in the table plane), seen by a fixed top-down camera.
//!
//! Our setting of the paper's task: the block must be pushed 12 cm along its stem, by the back of its bar; the
//! pusher starts on the stem's side, so it must first go around the block — over the top or under the bottom,
//! the two modes a demonstrator takes equally often ([`expert`]). Units are metres
//! and radians in the table frame (x along the push, y across it).
//!
//! [`PushT::step`] takes one action — where the pusher should go — and runs the physics for one control period
//! (the pusher follows at a bounded speed; the block slides with table friction as damping).

pub mod episode;
pub mod expert;
pub mod render;

use rapier2d::prelude::*;
use serde::{Deserialize, Serialize};

/// The task's geometry and timing.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PushTConfig {
    /// The T's bar: length across the stem and thickness (m).
    pub bar: [f32; 2],
    /// The stem: thickness and length (m), from the bar's middle.
    pub stem: [f32; 2],
    pub pusher_radius: f32,
    /// Block start and goal: x, y, θ of the bar's centre (θ = 0: the stem points along +x from the bar).
    pub start: [f32; 3],
    pub goal: [f32; 3],
    pub pusher_start: [f32; 2],
    /// Random perturbation of the start pose per episode: ± position (m), ± angle (rad).
    pub start_noise: [f32; 2],
    /// Success: block within this distance (m) and angle (rad) of the goal.
    pub tolerance: [f32; 2],
    /// Fastest the pusher moves (m/s).
    pub pusher_speed: f32,
    /// One action per control period (s), simulated in `substeps` physics steps.
    pub control_period: f32,
    pub substeps: usize,
    pub max_steps: usize,
}

impl Default for PushTConfig {
    fn default() -> Self {
        Self {
            bar: [0.10, 0.025],
            stem: [0.025, 0.075],
            pusher_radius: 0.015,
            start: [0.30, 0.0, 0.0],
            goal: [0.42, 0.0, 0.0],
            pusher_start: [0.45, 0.0],
            start_noise: [0.01, 0.05],
            tolerance: [0.02, 0.2],
            pusher_speed: 0.15,
            control_period: 0.1,
            substeps: 10,
            max_steps: 150,
        }
    }
}

/// Everything an observer can know: the pusher and the block's pose.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PushTState {
    pub pusher: [f32; 2],
    /// x, y, θ.
    pub block: [f32; 3],
}

/// The world of one episode.
pub struct PushT {
    cfg: PushTConfig,
    world: PhysicsWorld,
    block: RigidBodyHandle,
    pusher: RigidBodyHandle,
    steps: usize,
    /// Physics substeps run by [`PushT::follow`].
    substeps: usize,
}

/// θ in (−π, π].
pub fn wrap(a: f32) -> f32 {
    let t = std::f32::consts::TAU;
    let r = (a + std::f32::consts::PI).rem_euclid(t) - std::f32::consts::PI;
    if r <= -std::f32::consts::PI { r + t } else { r }
}

impl PushT {
    /// A new episode; `seed` draws the start pose's perturbation.
    pub fn new(cfg: &PushTConfig, seed: u64) -> Self {
        use rand::{Rng, SeedableRng};
        let mut rng = rand::rngs::StdRng::seed_from_u64(seed);
        let [dp, da] = cfg.start_noise;
        let mut u = |s: f32| if s > 0.0 { rng.random_range(-s..=s) } else { 0.0 };
        let start = [cfg.start[0] + u(dp), cfg.start[1] + u(dp), cfg.start[2] + u(da)];

        // A top-down table: no gravity in its plane.
        let mut world = PhysicsWorld { gravity: Vector::ZERO, ..Default::default() };
        world.integration_parameters.dt = cfg.control_period / cfg.substeps as f32;
        // rapier scales its tolerances (prediction distance, contact reuse, allowed penetration) by the size of
        // the scene's objects; at its default of 1 m, contacts are kept and pushed on from 5 cm away.
        world.integration_parameters.length_unit = cfg.bar[0];
        // Table friction, as damping of the sliding block (a top-down world has no normal force to rub on).
        let body = RigidBodyBuilder::dynamic()
            .translation(Vector::new(start[0], start[1]))
            .rotation(start[2])
            .linear_damping(8.0)
            .angular_damping(8.0)
            // Both bodies stay awake: a sleeping pusher ignores its next kinematic pose, a sleeping block a push.
            .can_sleep(false);
        let [bar_len, bar_t] = cfg.bar;
        let [stem_t, stem_len] = cfg.stem;
        // Local frame: the bar along y at x = 0, the stem along +x from it.
        let bar = ColliderBuilder::cuboid(bar_t / 2.0, bar_len / 2.0).density(100.0).friction(0.5);
        let (block, _) = world.insert(body, bar);
        let stem = ColliderBuilder::cuboid(stem_len / 2.0, stem_t / 2.0)
            .translation(Vector::new((bar_t + stem_len) / 2.0, 0.0))
            .density(100.0)
            .friction(0.5);
        world.colliders.insert_with_parent(stem, block, &mut world.bodies);
        let pusher_body = RigidBodyBuilder::kinematic_position_based()
            .translation(Vector::new(cfg.pusher_start[0], cfg.pusher_start[1]))
            .can_sleep(false);
        let (pusher, _) = world.insert(pusher_body, ColliderBuilder::ball(cfg.pusher_radius).friction(0.5));
        Self { cfg: cfg.clone(), world, block, pusher, steps: 0, substeps: 0 }
    }

    pub fn config(&self) -> &PushTConfig {
        &self.cfg
    }

    pub fn state(&self) -> PushTState {
        let p = self.world.bodies[self.pusher].translation();
        let b = &self.world.bodies[self.block];
        let t = b.translation();
        PushTState { pusher: [p.x, p.y], block: [t.x, t.y, b.rotation().angle()] }
    }

    /// One control period with the pusher sent toward `target` (x, y) at most at its speed.
    pub fn step(&mut self, target: [f32; 2]) {
        let dt = self.world.integration_parameters.dt;
        let reach = self.cfg.pusher_speed * dt;
        for _ in 0..self.cfg.substeps {
            let p = self.world.bodies[self.pusher].translation();
            let d = Vector::new(target[0] - p.x, target[1] - p.y);
            let len = d.length();
            let next = if len <= reach { Vector::new(target[0], target[1]) } else { p + d * (reach / len) };
            self.world.bodies[self.pusher].set_next_kinematic_translation(next);
            self.world.step();
        }
        self.steps += 1;
    }

    /// One physics substep (`control_period / substeps`) with the pusher carried to `pusher` (x, y): the HIL
    /// scene, where the pusher is wherever the arm's flange is, not a point moving at the task's speed.
    /// Counts a control period every `substeps` calls.
    pub fn follow(&mut self, pusher: [f32; 2]) {
        self.world.bodies[self.pusher].set_next_kinematic_translation(Vector::new(pusher[0], pusher[1]));
        self.world.step();
        self.substeps += 1;
        if self.substeps.is_multiple_of(self.cfg.substeps) {
            self.steps += 1;
        }
    }

    /// Puts the pusher at `pusher` at once, touching nothing on the way (a pusher lifted off the table and set
    /// down again, as between two episodes of the HIL scene).
    pub fn place_pusher(&mut self, pusher: [f32; 2]) {
        let body = &mut self.world.bodies[self.pusher];
        body.set_translation(Vector::new(pusher[0], pusher[1]), true);
        body.set_next_kinematic_translation(Vector::new(pusher[0], pusher[1]));
    }

    /// The physics substep (s).
    pub fn substep_s(&self) -> f32 {
        self.world.integration_parameters.dt
    }

    pub fn steps(&self) -> usize {
        self.steps
    }

    /// Distance (m) and |angle| (rad) from the block to the goal.
    pub fn goal_error(&self) -> (f32, f32) {
        let [x, y, a] = self.state().block;
        let [gx, gy, ga] = self.cfg.goal;
        (((x - gx).powi(2) + (y - gy).powi(2)).sqrt(), wrap(a - ga).abs())
    }

    pub fn success(&self) -> bool {
        let (d, a) = self.goal_error();
        d <= self.cfg.tolerance[0] && a <= self.cfg.tolerance[1]
    }

    pub fn done(&self) -> bool {
        self.success() || self.steps >= self.cfg.max_steps
    }
}
