//! The processes a fault run keeps for all its trials: franka-sim (on that backend), the HAL as the demo starts it,
//! and a watch on the HAL's state frames. Each trial starts its own marsd (and checker) against them.

use std::fs::File;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use crate::franka_sim::FrankaSim;
use anyhow::Context;

use super::watch::StateWatch;
use crate::demo::{DemoRobot, FRANKA_SIM_STATE_GAP_MS, hal_command, start_franka_sim};

pub struct Rig {
    pub robot: String,
    pub backend: DemoRobot,
    pub profile: PathBuf,
    pub dir: PathBuf,
    pub watch: StateWatch,
    exe: PathBuf,
    config: PathBuf,
    hal: Child,
    /// Dropped after the HAL (which brakes and releases the robot first).
    sim: Option<FrankaSim>,
    _rig: mars_rt::rig_lock::RtRigLock,
}

/// The HAL at the end of a backend's trials: its exit status and its report.
pub struct HalEnd {
    pub code: Option<i32>,
    pub report: String,
}

/// How long the HAL may take to publish its first frame (franka-sim connects first).
const HAL_START: Duration = Duration::from_secs(60);

impl Rig {
    /// Starts the rig in `dir`: franka-sim (from `venv`) when `backend` is franka-sim, then the HAL on `config`'s
    /// profile, and waits for its first frame. Takes the machine's real-time rig lock for its whole life.
    pub fn start(exe: &Path, config: &Path, backend: DemoRobot, venv: &Path, dir: &Path) -> anyhow::Result<Self> {
        let cfg = mars_runtime::config::DaemonConfig::load(config)?;
        std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
        let lock = mars_rt::rig_lock::rt_rig_lock().context("taking the real-time rig lock")?;
        let robot =
            format!("faults-{}-{}", std::process::id(), if backend == DemoRobot::Mock { "mock" } else { "sim" });
        let core = crate::bench::demo_hal_core();
        let sim = match backend {
            DemoRobot::FrankaSim => Some(start_franka_sim(venv, dir, core)?),
            DemoRobot::Mock => None,
            DemoRobot::R1LiteStandin => anyhow::bail!("the fault runs are on the FR3: --backend mock or franka-sim"),
        };
        let mut hal = hal_command(exe, &cfg.profile, &robot, core, backend, &dir.join("hal.json"));
        hal.stdout(log_file(dir, "hal.out")?).stderr(log_file(dir, "hal.log")?);
        let hal = hal.spawn().context("starting the HAL")?;
        let watch = StateWatch::open(&robot)?;
        let mut rig = Self {
            robot,
            backend,
            profile: cfg.profile,
            dir: dir.to_path_buf(),
            watch,
            exe: exe.to_path_buf(),
            config: config.to_path_buf(),
            hal,
            sim,
            _rig: lock,
        };
        let first = {
            let Rig { watch, hal, .. } = &mut rig;
            watch.wait(HAL_START, |_| true, || !matches!(hal.try_wait(), Ok(None)))
        };
        anyhow::ensure!(
            first.is_some(),
            "the HAL published no state within {HAL_START:?}; its log:\n{}",
            rig.hal_log()
        );
        Ok(rig)
    }

    /// marsd for `episodes` episodes into `out`, as the demo runs it, its log into `out/marsd.log`.
    pub fn marsd(&self, out: &Path, episodes: usize) -> anyhow::Result<Child> {
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let mut marsd = Command::new(&self.exe);
        marsd.arg("marsd").arg("--config").arg(&self.config).args(["--robot", &self.robot]);
        marsd.args(["--episodes", &episodes.to_string()]).arg("--out").arg(out);
        if self.backend == DemoRobot::FrankaSim {
            marsd.args(["--max-state-gap-ms", &FRANKA_SIM_STATE_GAP_MS.to_string()]);
        }
        marsd.stdout(Stdio::null()).stderr(log_file(out, "marsd.log")?);
        marsd.spawn().context("starting marsd")
    }

    pub fn hal_pid(&self) -> libc::pid_t {
        self.hal.id() as libc::pid_t
    }

    /// franka-sim's log so far (empty on the mock).
    pub fn sim_log(&self) -> Vec<u8> {
        self.sim.as_ref().and_then(|s| std::fs::read(s.log_path()).ok()).unwrap_or_default()
    }

    pub fn hal_log(&self) -> String {
        std::fs::read_to_string(self.dir.join("hal.log")).unwrap_or_default()
    }

    /// Stops the HAL as systemd would (SIGTERM: it brakes to rest and releases the robot), then the simulator;
    /// returns the HAL's exit status and its report (stdout).
    pub fn stop(mut self) -> HalEnd {
        // SAFETY: kill(2) on our own child's pid.
        unsafe { libc::kill(self.hal_pid(), libc::SIGTERM) };
        let code = wait_child(&mut self.hal, Duration::from_secs(15));
        let report = std::fs::read_to_string(self.dir.join("hal.out")).unwrap_or_default();
        HalEnd { code, report }
    }
}

impl Drop for Rig {
    fn drop(&mut self) {
        if matches!(self.hal.try_wait(), Ok(None)) {
            let _ = self.hal.kill();
            let _ = self.hal.wait();
        }
    }
}

fn log_file(dir: &Path, name: &str) -> anyhow::Result<File> {
    let path = dir.join(name);
    File::create(&path).with_context(|| format!("creating {}", path.display()))
}

/// The child's exit status within `timeout`, else SIGKILL and `None`.
pub fn wait_child(child: &mut Child, timeout: Duration) -> Option<i32> {
    let end = std::time::Instant::now() + timeout;
    while std::time::Instant::now() < end {
        if let Ok(Some(status)) = child.try_wait() {
            return status.code();
        }
        std::thread::sleep(Duration::from_millis(5));
    }
    let _ = child.kill();
    let _ = child.wait();
    None
}
