//! The HIL sim plant (`mars_hal::sim::SimBackend`) behind the servo the task uses between policy actions: each
//! 10 Hz action is reached by moving the 1 kHz setpoint linearly across its slot. Shared by the expert (which
//! must produce demos the plant can follow) and the in-process evaluation (which must run policies the same way).

use mars_hal::backend::{Backend, Measurement};
use mars_hal::gripper::GripperMove;
use mars_hal::sim::SimBackend;
use mars_ipc::MAX_JOINTS;
use mars_profile::Profile;

use super::pick::Pick;

/// Reset motion from the profile's `home` to an episode's start (not part of the episode): slow enough that
/// the largest start jitter moves at a small fraction of any velocity limit.
const RESET_RAMP_S: f64 = 1.0;
/// Holding still after the reset ramp so the first-order plant settles before the episode clock starts.
const RESET_SETTLE_S: f64 = 0.1;

/// What the setpoints of one action did against the profile's limits.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LimitCheck {
    /// The target lay outside [q_min, q_max] (it was clamped, as the HAL's `clamp` policy would).
    pub position: bool,
    /// The interpolated setpoint moved faster than dq_max.
    pub velocity: bool,
    /// The gripper target lay outside the profile's range (clamped).
    pub gripper: bool,
}

impl LimitCheck {
    pub fn any(&self) -> bool {
        self.position || self.velocity || self.gripper
    }
}

pub struct SimArm {
    sim: SimBackend,
    joints: usize,
    dt: f64,
    ticks_per_action: usize,
    profile: Profile,
    /// The setpoint applied last: where the next action's interpolation starts.
    setpoint: [f64; MAX_JOINTS],
    gripper_setpoint: f64,
    measured: Measurement,
    /// Seconds since the episode started (since the reset motion ended).
    t_s: f64,
}

impl SimArm {
    /// The profile's plant with its noise seeded by `sim_seed` (so each episode sees its own noise).
    pub fn new(profile: &Profile, task: &Pick, sim_seed: u64) -> Self {
        let mut profile = profile.clone();
        profile.sim.seed = sim_seed;
        let sim = SimBackend::new(&profile);
        let mut setpoint = [0.0; MAX_JOINTS];
        setpoint[..profile.joints].copy_from_slice(&profile.home);
        let gripper = profile.sim.start_gripper.unwrap_or(profile.gripper_max);
        let measured = Measurement { position: setpoint, gripper, ..Default::default() };
        Self {
            sim,
            joints: profile.joints,
            dt: profile.period_s(),
            ticks_per_action: task.ticks_per_action,
            gripper_setpoint: gripper,
            profile,
            setpoint,
            measured,
            t_s: 0.0,
        }
    }

    /// Moves from wherever the plant is to `start` with the gripper at `gripper`, then restarts the episode
    /// clock at 0.
    pub fn move_to_start(&mut self, start: &[f64], gripper: f64) {
        let mut target = [0.0; MAX_JOINTS + 1];
        target[..self.joints].copy_from_slice(start);
        target[self.joints] = gripper;
        self.ramp(&target[..=self.joints], (RESET_RAMP_S / self.dt).round() as usize, |_, _, _| false);
        self.ramp(&target[..=self.joints], (RESET_SETTLE_S / self.dt).round() as usize, |_, _, _| false);
        self.t_s = 0.0;
    }

    pub fn q(&self) -> &[f64] {
        &self.measured.position[..self.joints]
    }

    pub fn gripper(&self) -> f64 {
        self.measured.gripper
    }

    pub fn t_s(&self) -> f64 {
        self.t_s
    }

    /// One policy action `[q target …, gripper target]`: the setpoint moves linearly from the previous action to
    /// this one over the action's slot, one plant tick per servo tick. After each tick `on_tick(q, gripper, t_s)`
    /// sees the measurement; returning true stops the slot early. Returns how the action met the limits.
    pub fn execute(&mut self, action: &[f64], on_tick: impl FnMut(&[f64], f64, f64) -> bool) -> LimitCheck {
        let n = self.joints;
        let p = &self.profile;
        let mut target = [0.0; MAX_JOINTS + 1];
        let mut check = LimitCheck::default();
        let slot_s = self.ticks_per_action as f64 * self.dt;
        for i in 0..n {
            target[i] = action[i].clamp(p.q_min[i], p.q_max[i]);
            check.position |= target[i] != action[i];
            check.velocity |= (target[i] - self.setpoint[i]).abs() / slot_s > p.dq_max[i];
        }
        target[n] = action[n].clamp(p.gripper_min, p.gripper_max);
        check.gripper = target[n] != action[n];
        self.ramp(&target[..=n], self.ticks_per_action, on_tick);
        check
    }

    /// `ticks` servo ticks moving the setpoint linearly from the current one to `target`.
    fn ramp(&mut self, target: &[f64], ticks: usize, mut on_tick: impl FnMut(&[f64], f64, f64) -> bool) {
        let n = self.joints;
        let (from, g_from) = (self.setpoint, self.gripper_setpoint);
        for tick in 1..=ticks.max(1) {
            let s = tick as f64 / ticks.max(1) as f64;
            for i in 0..n {
                self.setpoint[i] = from[i] + s * (target[i] - from[i]);
            }
            self.gripper_setpoint = g_from + s * (target[n] - g_from);
            // The sim neither fails nor refuses; an error here would be a bug in it. The gripper gets the ramp's
            // width each tick and moves toward it at its top speed, as the HAL passes targets on.
            self.sim.apply(&self.setpoint[..n]).expect("sim backend apply");
            let width = GripperMove { width: self.gripper_setpoint, speed: self.profile.gripper_speed_max };
            self.sim.move_gripper(width).expect("sim backend gripper");
            self.measured = self.sim.read().expect("sim backend read");
            self.t_s += self.dt;
            if on_tick(&self.measured.position[..n], self.measured.gripper, self.t_s) {
                return;
            }
        }
    }
}
