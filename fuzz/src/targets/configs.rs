//! The TOML files marsd and the HAL start from: marsd's configuration, its task files (checked against their
//! robot's profile), and the robot profiles. An accepted file is then used as the programs use it: every time
//! converted to a `Duration` or to nanoseconds, the safety filter, the sim plant and the HAL's control built on
//! it and run for a few ticks — what `config.rs` lets through must not panic after the threads start.

use std::time::Duration;

use mars_hal::backend::Backend;
use mars_hal::control::HalControl;
use mars_hal::fault::FaultInjector;
use mars_hal::profile::Profile;
use mars_hal::safety::SafetyFilter;
use mars_hal::sim::SimBackend;
use mars_runtime::config::DaemonConfig;
use mars_runtime::task::HilTask;
use rand::rngs::StdRng;

use super::{Seeds, bundle_seeds, generate_bundle, read, split_bundle};
use crate::runner::Target;

pub struct MarsdConfig {
    seeds: Seeds,
}

impl MarsdConfig {
    pub fn new() -> Self {
        let files = ["configs/marsd.toml", "configs/marsd_push_t.toml", "configs/marsd_r1_lite.toml"];
        Self { seeds: Seeds { files: files.iter().map(|f| read(f)).collect(), text: true } }
    }
}

impl Target for MarsdConfig {
    fn name(&self) -> &'static str {
        "marsd-config"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        self.seeds.pick(rng).1
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        self.seeds.files.clone()
    }

    fn run(&self, input: &[u8]) -> bool {
        let Ok(text) = std::str::from_utf8(input) else { return false };
        let Ok(cfg) = DaemonConfig::parse(text, "marsd.toml") else { return false };
        let _ = (cfg.handshake_timeout(), cfg.histogram_interval(), cfg.engine_step_delay(), cfg.record_writer_delay());
        let _ = (cfg.policy_period_ns(), mars_runtime::watchdog::ServoWatchdog::new(&cfg.watchdog));
        let _ = mars_runtime::traces::TraceRing::new(cfg.traces_kept);
        true
    }
}

/// A task file with the profile it is checked against (Pick Cup and Push-T on the FR3, Pick Vegetable on the R1 Lite).
pub struct MarsdTask {
    bundles: Vec<Vec<Vec<u8>>>,
    profiles: Vec<Profile>,
}

impl MarsdTask {
    pub fn new() -> Self {
        let pairs = [
            ("configs/pick_cup.toml", "configs/fr3.toml"),
            ("configs/push_t.toml", "configs/fr3.toml"),
            ("configs/pick_vegetable.toml", "configs/r1_lite.toml"),
        ];
        let profile = |p: &str| Profile::load(&super::repo(p)).expect("a shipped profile");
        Self {
            bundles: pairs.iter().map(|(t, _)| vec![read(t)]).collect(),
            profiles: pairs.iter().map(|(_, p)| profile(p)).collect(),
        }
    }
}

impl Target for MarsdTask {
    fn name(&self) -> &'static str {
        "marsd-task"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        generate_bundle(rng, &self.bundles, |_| true)
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        bundle_seeds(&self.bundles)
    }

    fn run(&self, input: &[u8]) -> bool {
        let Some((b, _, bytes)) = split_bundle(input, self.bundles.len()) else { return false };
        let Ok(text) = std::str::from_utf8(bytes) else { return false };
        let Ok(t) = HilTask::parse(text, "task.toml".into(), &self.profiles[b]) else { return false };
        let _ = (t.obs_dim(), t.action_dim(), t.mode_names(), t.policy_rate_hz(), t.plot_joints());
        true
    }
}

pub struct HalProfile {
    seeds: Seeds,
}

impl HalProfile {
    pub fn new() -> Self {
        Self { seeds: Seeds { files: vec![read("configs/fr3.toml"), read("configs/r1_lite.toml")], text: true } }
    }
}

impl Target for HalProfile {
    fn name(&self) -> &'static str {
        "hal-profile"
    }

    fn generate(&self, rng: &mut StdRng) -> Vec<u8> {
        self.seeds.pick(rng).1
    }

    fn seeds(&self) -> Vec<Vec<u8>> {
        self.seeds.files.clone()
    }

    fn run(&self, input: &[u8]) -> bool {
        let Ok(text) = std::str::from_utf8(input) else { return false };
        let Ok(p) = Profile::parse(text, "profile.toml") else { return false };
        let _ = (Duration::from_secs_f64(p.period_s()), p.timeout_ns(), p.gripper_interval_ticks());
        let _ = (p.position_limits(), p.planning_velocity_bounds(), p.ros2.feedback_timeout_ms(p.command_timeout_ms));
        // The filter's setpoints go to the robot: whatever the profile, they must be numbers.
        let mut filter = SafetyFilter::new(&p, &p.home);
        let mut target = [0.0; mars_ipc::MAX_JOINTS];
        for i in 0..p.joints {
            target[i] = p.q_max[i];
        }
        for t in [None, Some(&target), Some(&target), None] {
            let q = filter.step(t);
            assert!(q.iter().all(|x| x.is_finite()), "the safety filter's setpoint is not finite: {q:?}");
        }
        let mut faults = FaultInjector::new(p.sim.faults.clone());
        for tick in 0..4 {
            let _ = (faults.loop_faults(tick), faults.read_error(tick), faults.apply_error(tick));
        }
        let mut sim = SimBackend::new(&p);
        for _ in 0..3 {
            let _ = sim.read();
            let _ = sim.apply(&p.home);
        }
        let Ok(m) = sim.read() else { return false };
        let Ok(mut control) = HalControl::start(&p, &m) else { return false };
        control.begin_tick(1_000_000);
        let _ = control.state_frame(1_000_000);
        true
    }
}
