//! Push-T for the policy: what a policy observes, the expert's demos (half by each route), and closed-loop
//! episodes of a trained policy scored by success and by the route it took.

use std::time::{Duration, Instant};

use crate::demo::Demo;
use crate::rollout::ChunkPolicy;
use rand::{Rng, SeedableRng};

use super::expert::{Expert, Route, route_taken};
use super::render::Camera;
use super::{PushT, PushTConfig, PushTState};

/// What the policy sees each step.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Observe {
    /// The pusher and the block: x, y, x, y, cos θ, sin θ.
    State,
    /// The pusher's x, y (the robot's own position) and the top-down camera's `size` × `size` RGB image, values
    /// in [0, 1], channels last (a vision policy's observation: `mars_policy::vision`).
    Camera { size: u32 },
}

impl Observe {
    pub fn dim(self) -> usize {
        match self {
            Observe::State => 6,
            Observe::Camera { size } => 2 + (size * size * 3) as usize,
        }
    }
}

/// Builds observations; owns the camera (and its pixel buffer) when there is one.
pub struct Observer {
    kind: Observe,
    camera: Option<(Camera, Vec<u8>)>,
}

impl Observer {
    pub fn new(kind: Observe) -> Self {
        let camera = match kind {
            Observe::State => None,
            Observe::Camera { size } => Some((Camera::push_t(size), vec![0; (size * size * 3) as usize])),
        };
        Self { kind, camera }
    }

    pub fn kind(&self) -> Observe {
        self.kind
    }

    pub fn observe(&mut self, cfg: &PushTConfig, s: &PushTState) -> Vec<f32> {
        let [bx, by, a] = s.block;
        match &mut self.camera {
            None => vec![s.pusher[0], s.pusher[1], bx, by, a.cos(), a.sin()],
            Some((cam, rgb)) => {
                cam.render(cfg, s, rgb);
                let mut o = Vec::with_capacity(self.kind.dim());
                o.extend_from_slice(&s.pusher);
                o.extend(rgb.iter().map(|p| f32::from(*p) / 255.0));
                o
            }
        }
    }
}

/// `n` expert demos from seeds `seed`, `seed + 1`, …: each a random route (seeded), so half go each way on
/// average; `mode` = the route's index; each action is the pusher's position at the end of its period. Only
/// successful demos are kept (the expert fails rarely).
pub fn expert_demos(cfg: &PushTConfig, n: usize, seed: u64, observe: Observe) -> Vec<Demo> {
    let mut rng = rand::rngs::StdRng::seed_from_u64(seed ^ 0x5eed);
    let mut observer = Observer::new(observe);
    let mut demos = Vec::with_capacity(n);
    let mut episode_seed = seed;
    while demos.len() < n {
        let route = if rng.random_bool(0.5) { Route::Upper } else { Route::Lower };
        let mut world = PushT::new(cfg, episode_seed);
        episode_seed += 1;
        let mut expert = Expert::new(cfg, route);
        let start = world.state();
        let (mut observations, mut actions) = (Vec::new(), Vec::new());
        while !world.done() {
            let s = world.state();
            observations.push(observer.observe(cfg, &s));
            world.step(expert.act(&s));
            // The action a robot's log keeps: the setpoint the pusher reached in the period (the expert's target
            // is a waypoint it heads for at a bounded speed). Positions one period apart are what the HIL servo
            // interpolates and the arm follows, so a policy's action means the same in process and on the arm.
            actions.push(world.state().pusher.to_vec());
        }
        if world.success() {
            demos.push(Demo { observations, actions, rest_action: start.pusher.to_vec(), mode: Some(route.index()) });
        }
    }
    demos
}

/// One closed-loop episode of a policy.
#[derive(Debug, Clone)]
pub struct Episode {
    pub seed: u64,
    pub success: bool,
    pub steps: usize,
    pub route: Option<Route>,
    /// Per policy call: ODE steps, ‖w‖∞, latency.
    pub calls: Vec<(usize, f32, Duration)>,
    pub states: Vec<PushTState>,
}

/// Runs `policy` from the start of seed `seed`, executing `exec_horizon` actions of each chunk.
pub fn run_episode(
    cfg: &PushTConfig,
    policy: &mut dyn ChunkPolicy,
    observer: &mut Observer,
    seed: u64,
    exec_horizon: usize,
) -> anyhow::Result<Episode> {
    anyhow::ensure!(policy.action_dim() == 2, "Push-T actions are the pusher's target x, y");
    anyhow::ensure!((1..=policy.chunk_len()).contains(&exec_horizon), "exec_horizon must be in 1..=chunk_len");
    let mut world = PushT::new(cfg, seed);
    let start = world.state();
    let mut history: Vec<f32> = start.pusher.repeat(policy.history_len());
    let (mut calls, mut states) = (Vec::new(), vec![start]);
    'episode: while !world.done() {
        let obs = observer.observe(cfg, &world.state());
        let t = Instant::now();
        let p = policy.predict(&obs, &history)?;
        let w_inf = p.w.iter().fold(0.0f32, |m, w| m.max(w.abs()));
        calls.push((p.k, w_inf, t.elapsed()));
        for a in p.chunk.chunks_exact(2).take(exec_horizon) {
            let target = [a[0], a[1]];
            anyhow::ensure!(target.iter().all(|v| v.is_finite()), "the policy returned a non-finite action");
            world.step(target);
            history.drain(..2);
            history.extend_from_slice(&target);
            states.push(world.state());
            if world.done() {
                break 'episode;
            }
        }
    }
    let pusher: Vec<[f32; 2]> = states.iter().map(|s| s.pusher).collect();
    let block: Vec<[f32; 3]> = states.iter().map(|s| s.block).collect();
    Ok(Episode {
        seed,
        success: world.success(),
        steps: world.steps(),
        route: route_taken(&pusher, &block),
        calls,
        states,
    })
}

/// Success and route counts over episodes: successes by route [upper, lower], and γ (1 when both routes succeed
/// equally often, 0 when one is never taken).
#[derive(Debug, Clone, PartialEq)]
pub struct Score {
    pub episodes: usize,
    pub successes: usize,
    pub by_route: [usize; 2],
    pub gamma: f32,
    pub mean_k: f32,
}

pub fn score(episodes: &[Episode]) -> Score {
    let mut by_route = [0; 2];
    for e in episodes.iter().filter(|e| e.success) {
        if let Some(r) = e.route {
            by_route[r.index()] += 1;
        }
    }
    let calls: Vec<usize> = episodes.iter().flat_map(|e| e.calls.iter().map(|c| c.0)).collect();
    Score {
        episodes: episodes.len(),
        successes: episodes.iter().filter(|e| e.success).count(),
        by_route,
        gamma: crate::nav2d::eval::modal_balance(&by_route),
        mean_k: calls.iter().sum::<usize>() as f32 / calls.len().max(1) as f32,
    }
}
