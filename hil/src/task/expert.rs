//! The scripted expert of a pick task (Pick Cup, Pick Vegetable): minimum-jerk moves between the task's poses, sampled
//! at the policy rate and executed on the HIL sim plant at the profile rate, so each demo is what the real servo path
//! would record. Modes alternate (balanced), everything is seeded, and every demo is checked before it is kept.

use anyhow::bail;
use mars_profile::Profile;
use mars_tasks::demo::Demo;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

use super::pick::{DoneReason, Pick, Progress};
use super::sim_arm::SimArm;

/// Minimum-jerk profile: 0 → 1 over τ ∈ [0, 1] with zero velocity and acceleration at both ends, so
/// consecutive segments join smoothly.
pub fn min_jerk(tau: f64) -> f64 {
    let t = tau.clamp(0.0, 1.0);
    t * t * t * (10.0 + t * (-15.0 + 6.0 * t))
}

/// One straight joint-space move with its gripper change.
struct Segment<'a> {
    from: &'a [f64],
    to: &'a [f64],
    gripper: (f64, f64),
    seconds: f64,
}

/// The expert's actions ([q target …, gripper target], one per policy step) for one episode from `start`
/// through grasp `mode`; pre-grasp, grasp and retreat poses are jittered per joint by the expert's
/// `waypoint_jitter`.
pub fn plan(task: &Pick, start: &[f64], mode: usize, rng: &mut impl Rng) -> Vec<Vec<f64>> {
    let c = &task.cfg;
    let e = &c.expert;
    let mut jitter = |pose: &[f64]| -> Vec<f64> {
        let j = e.waypoint_jitter;
        pose.iter().map(|&x| if j > 0.0 { x + rng.random_range(-j..=j) } else { x }).collect()
    };
    let pregrasp = jitter(&c.pregrasp);
    let grasp = jitter(&c.grasps[mode].q);
    let retreat = jitter(&c.retreat);
    let (open, closed) = (c.gripper_open, c.gripper_closed);
    let segments = [
        Segment { from: start, to: &pregrasp, gripper: (open, open), seconds: e.approach_s },
        Segment { from: &pregrasp, to: &grasp, gripper: (open, open), seconds: e.grasp_s },
        Segment { from: &grasp, to: &grasp, gripper: (open, closed), seconds: e.close_s },
        Segment { from: &grasp, to: &retreat, gripper: (closed, closed), seconds: e.retreat_s },
        Segment { from: &retreat, to: &retreat, gripper: (closed, closed), seconds: e.hold_s },
    ];
    let mut actions = Vec::new();
    for s in segments {
        let steps = (s.seconds * c.policy_rate_hz).round() as usize;
        for k in 1..=steps {
            // The action at step k is where the expert wants to be at the end of that step's slot.
            let m = min_jerk(k as f64 / steps as f64);
            let mut a: Vec<f64> = s.from.iter().zip(s.to).map(|(f, t)| f + m * (t - f)).collect();
            a.push(s.gripper.0 + m * (s.gripper.1 - s.gripper.0));
            actions.push(a);
        }
    }
    actions
}

/// Executes `actions` on a fresh sim plant (noise seeded by `sim_seed`) from `start`, recording the measured
/// observation before each action. Errors say why the demo is unusable: a limit left, or the wrong outcome.
pub fn record(
    task: &Pick,
    profile: &Profile,
    start: &[f64],
    actions: &[Vec<f64>],
    mode: usize,
    sim_seed: u64,
) -> anyhow::Result<Demo> {
    let mut arm = SimArm::new(profile, task, sim_seed);
    arm.move_to_start(start, task.cfg.gripper_open);
    let mut monitor = task.monitor();
    let mut progress = Progress::Running;
    let mut obs = vec![0.0f32; task.obs_dim()];
    let mut observations = Vec::with_capacity(actions.len());
    for (k, action) in actions.iter().enumerate() {
        task.observation(arm.q(), arm.gripper(), &mut obs);
        observations.push(obs.clone());
        let check = arm.execute(action, |q, g, t| {
            progress = monitor.update(q, g, t);
            false
        });
        if check.any() {
            bail!("step {k} leaves the {} limits ({check:?}): slow the expert down", profile.name);
        }
    }
    let want = Progress::Done { success: true, mode: Some(mode), reason: DoneReason::Retreated };
    if progress != want {
        bail!("ended {progress:?}, expected {want:?} (grasped {:?})", monitor.grasped());
    }
    Ok(Demo {
        observations,
        actions: actions.iter().map(|a| a.iter().map(|&x| x as f32).collect()).collect(),
        rest_action: task.rest_action(start),
        mode: Some(mode),
    })
}

/// `n` verified demos, demo i through grasp `i % n_modes` (balanced), deterministic for a given seed.
pub fn generate_demos(task: &Pick, profile: &Profile, n: usize, seed: u64) -> anyhow::Result<Vec<Demo>> {
    let mut rng = StdRng::seed_from_u64(seed);
    (0..n)
        .map(|i| {
            let mode = i % task.n_modes();
            let episode_seed: u64 = rng.random();
            let start = task.start_pose(episode_seed);
            let actions = plan(task, &start, mode, &mut rng);
            record(task, profile, &start, &actions, mode, episode_seed)
                .map_err(|e| e.context(format!("expert demo {i} (grasp `{}`) is invalid", task.cfg.grasps[mode].name)))
        })
        .collect()
}
