//! The R1 Lite stand-in as `mars-hil demo --robot r1-lite --backend r1-lite-standin` runs it: the Cyclone DDS
//! peer (`tests/peers/r1_lite_standin.py`, another DDS implementation than the HAL's) publishing the R1 Lite's
//! feedback topics and tracking its target topics, on this host only, in a DDS domain no other run of this machine
//! holds. The HAL then drives it with its ros2 backend, as it would the robot.

use std::fs::File;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};

use anyhow::Context;
use mars_profile::Profile;

/// The stand-in's script and its environment (made by `.ci/dds-venv`), from the repository's root.
pub const SCRIPT: &str = "tests/peers/r1_lite_standin.py";
pub const VENV: &str = ".venv-dds";

/// A running stand-in; stopped (SIGTERM, then SIGKILL) when dropped.
pub struct StandIn {
    child: Child,
    pub domain: u16,
    pub log: PathBuf,
    /// Held while the stand-in runs: the domain's reservation (`mars_hal::ros2::domain`), as the tests hold theirs.
    _domain: File,
}

impl StandIn {
    /// Starts the stand-in for `profile`'s arm at its home pose, gripper open, at its rate, its joints lagging
    /// their target as the mock plant's do (`[sim] tracking_time_constant_s`, the plant the demos were recorded
    /// on); its JSON-lines log into `out`. Installs Cyclone DDS first if it is not.
    pub fn start(profile: &Profile, out: &Path) -> anyhow::Result<Self> {
        let python = Path::new(VENV).join("bin/python");
        if !python.exists() {
            eprintln!("installing Cyclone DDS into {VENV} (.ci/dds-venv)");
            let ok = Command::new(".ci/dds-venv").status().context("running .ci/dds-venv")?.success();
            anyhow::ensure!(ok, ".ci/dds-venv failed: the R1 Lite stand-in cannot run");
        }
        let (domain, lock) =
            mars_hal::ros2::domain::reserve_domain(std::process::id()).context("reserving a DDS domain")?;
        std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
        let log = out.join("standin.log");
        let home: Vec<String> = profile.home.iter().map(|q| q.to_string()).collect();
        let child = Command::new(&python)
            .arg(SCRIPT)
            .args(["--loopback", "--domain", &domain.to_string(), "--rate-hz", &profile.rate_hz.to_string()])
            .args(["--start", &home.join(","), "--start-gripper", &(profile.gripper_max * 1e3).to_string()])
            .args(["--time-constant-s", &profile.sim.tracking_time_constant_s.to_string()])
            .args(["--duration-s", "86400"])
            .arg("--log")
            .arg(&log)
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(File::create(out.join("standin.stderr")).context("creating the stand-in's stderr file")?)
            // Its own process group: a Ctrl-C aimed at the demo reaches it only through our Drop.
            .process_group(0)
            .spawn()
            .with_context(|| format!("starting {SCRIPT}"))?;
        Ok(Self { child, domain, log, _domain: lock })
    }
}

impl Drop for StandIn {
    fn drop(&mut self) {
        // SAFETY: plain kill(2) on our own child's pid.
        unsafe { libc::kill(self.child.id() as libc::pid_t, libc::SIGTERM) };
        for _ in 0..100 {
            if !matches!(self.child.try_wait(), Ok(None)) {
                return;
            }
            std::thread::sleep(std::time::Duration::from_millis(20));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}
