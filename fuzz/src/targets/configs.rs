//! The TOML files marsd and the HAL start from: marsd's configuration, its task files (checked against their
//! robot's profile), and the robot profiles. An accepted file is then used as the programs use it: every time
//! converted to a `Duration` or to nanoseconds, the safety filter, the sim plant and the HAL's control built on
//! it and run for a few ticks — what `config.rs` lets through must not panic after the threads start.

use std::sync::Arc;
use std::time::Duration;

use mars_hal::backend::Backend;
use mars_hal::control::HalControl;
use mars_hal::fault::FaultInjector;
use mars_hal::fci::FciParams;
use mars_hal::ros2::Ros2Params;
use mars_hal::safety::SafetyFilter;
use mars_hal::sim::SimBackend;
use mars_profile::Profile;
use mars_runtime::config::DaemonConfig;
use mars_runtime::task::HilTask;

use super::{Bundles, read, repo, text};
use crate::runner::Target;

pub fn marsd_config() -> Arc<dyn Target> {
    let files =
        ["configs/marsd.toml", "configs/marsd_push_t.toml", "configs/marsd_r1_lite.toml", "configs/marsd_remote.toml"];
    Bundles::of_files("marsd-config", files.iter().map(|f| read(f)).collect(), true, |_, bytes| {
        let Some(Ok(cfg)) = text(bytes).map(|t| DaemonConfig::parse(t, "marsd.toml")) else { return false };
        let _ = (cfg.handshake_timeout(), cfg.histogram_interval(), cfg.engine_step_delay(), cfg.record_writer_delay());
        let _ = (cfg.policy_period_ns(), mars_runtime::servo::watchdog::ServoWatchdog::new(&cfg.watchdog));
        let _ = mars_runtime::report::traces::TraceRing::new(cfg.traces_kept);
        true
    })
}

/// A task file with the profile it is checked against (Pick Cup and Push-T on the FR3, Pick Vegetable on the R1 Lite).
pub fn marsd_task() -> Arc<dyn Target> {
    let pairs = [
        ("configs/pick_cup.toml", "configs/fr3.toml"),
        ("configs/push_t.toml", "configs/fr3.toml"),
        ("configs/pick_vegetable.toml", "configs/r1_lite.toml"),
    ];
    let profiles: Vec<Profile> =
        pairs.iter().map(|(_, p)| Profile::load(&repo(p)).expect("a shipped profile")).collect();
    Bundles::of_files("marsd-task", pairs.iter().map(|(t, _)| read(t)).collect(), true, move |b, bytes| {
        let Some(Ok(t)) = text(bytes).map(|x| HilTask::parse(x, "task.toml".into(), &profiles[b])) else {
            return false;
        };
        let _ = (t.obs_dim(), t.action_dim(), t.mode_names(), t.policy_rate_hz(), t.plot_joints());
        true
    })
}

pub fn hal_profile() -> Arc<dyn Target> {
    let files = vec![read("configs/fr3.toml"), read("configs/r1_lite.toml")];
    Bundles::of_files("hal-profile", files, true, |_, bytes| {
        let Some(Ok(p)) = text(bytes).map(|t| Profile::parse(t, "profile.toml")) else { return false };
        let _ = (Duration::from_secs_f64(p.period_s()), p.timeout_ns(), p.gripper_interval_ticks());
        let _ = (p.position_limits(), p.planning_velocity_bounds());
        // Each driver's table as that driver reads and checks it (the HAL does so before anything moves).
        if let Ok(r) = Ros2Params::of(&p) {
            let _ = (r.check(&p), r.feedback_timeout_ms(p.command_timeout_ms));
        }
        if let Ok(f) = FciParams::of(&p) {
            let _ = f.check(&p);
        }
        run_filter(&p);
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
    })
}

/// The safety filter at home, braking, then sent to the upper limits: its setpoints go to the robot, so whatever
/// the profile, they must be numbers.
fn run_filter(p: &Profile) {
    let mut filter = SafetyFilter::new(p, &p.home);
    let mut target = [0.0; mars_ipc::MAX_JOINTS];
    target[..p.joints].copy_from_slice(&p.q_max);
    for t in [None, Some(&target), Some(&target), None] {
        let q = filter.step(t);
        assert!(q.iter().all(|x| x.is_finite()), "the safety filter's setpoint is not finite: {q:?}");
    }
}
