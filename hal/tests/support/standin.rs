//! The R1 Lite stand-in for tests (`tests/peers/r1_lite_standin.py`): Cyclone DDS's Python binding speaking ROS
//! 2's wire, started as a process of its own, in a DDS domain of its own, on loopback only.
//!
//! - It is installed into `.venv-dds/` by `.ci/dds-venv` (idempotent), run under a machine-wide lock so two test
//!   binaries never install at the same time.
//! - Each stand-in gets a DDS domain no other test of this machine uses at the same time ([`unique_domain`]), so
//!   tests in parallel never see each other's topics.
//! - It runs in its own process group, killed when the handle is dropped; its JSON-lines log (every target it
//!   received, when it went silent) is what the tests read, and is kept when a test fails.

use std::fs::File;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

use serde_json::Value;

use super::franka_sim::{install_venv, repo_root};

/// The stand-in's virtual environment, installed first if it is missing.
pub fn venv() -> PathBuf {
    install_venv(".ci/dds-venv", ".venv-dds", "mars-dds-install.lock")
}

/// A DDS domain (1–101) for one stand-in and its HAL. Each domain is held by an flock for as long as the
/// returned guard lives, so no two tests of this machine (threads or processes) share one; the search starts
/// from this process's id, so concurrent binaries rarely even try the same one.
pub fn unique_domain() -> (u16, File) {
    static N: AtomicU32 = AtomicU32::new(0);
    let start = std::process::id().wrapping_add(N.fetch_add(1, Ordering::Relaxed) * 37);
    mars_hal::ros2::domain::reserve_domain(start).unwrap_or_else(|e| panic!("{e}"))
}

/// How the stand-in starts.
pub struct StandInOptions {
    pub start: Vec<f64>,
    /// Gripper stroke (mm) at start.
    pub start_gripper: f64,
    pub rate_hz: f64,
    pub time_constant_s: f64,
    /// Arm feedback with the gripper as a 7th position.
    pub gripper_as_joint: bool,
    /// Publish the head and wrist cameras (JPEG test cards), truncating every `camera_bad_every`-th frame (0:
    /// none).
    pub cameras: bool,
    pub camera_bad_every: u32,
}

/// A running stand-in; killed (its process group) when dropped.
pub struct StandIn {
    child: Child,
    log: PathBuf,
    pub domain: u16,
    _domain_lock: File,
}

impl StandIn {
    pub fn start(o: &StandInOptions) -> Self {
        let python = venv().join("bin/python");
        let (domain, domain_lock) = unique_domain();
        static N: AtomicU32 = AtomicU32::new(0);
        let log = std::env::temp_dir().join(format!(
            "mars-r1-standin-{}-{}.jsonl",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let _ = std::fs::remove_file(&log);
        let start: Vec<String> = o.start.iter().map(|q| format!("{q:?}")).collect();
        let mut cmd = Command::new(&python);
        cmd.arg(repo_root().join("tests/peers/r1_lite_standin.py"))
            .args(["--domain", &domain.to_string(), "--loopback", "--duration-s", "120"])
            .args(["--rate-hz", &o.rate_hz.to_string(), "--start", &start.join(",")])
            .args(["--start-gripper", &o.start_gripper.to_string()])
            .args(["--time-constant-s", &o.time_constant_s.to_string()])
            .arg("--log")
            .arg(&log)
            .stdout(Stdio::null())
            .stderr(Stdio::inherit())
            .process_group(0);
        if o.gripper_as_joint {
            cmd.arg("--feedback-gripper-as-joint");
        }
        if o.cameras {
            cmd.args(["--cameras", "--camera-bad-every", &o.camera_bad_every.to_string()]);
        }
        let child = cmd.spawn().unwrap_or_else(|e| panic!("starting {}: {e}", python.display()));
        let mut s = StandIn { child, log, domain, _domain_lock: domain_lock };
        s.wait_for_event("ready", Duration::from_secs(30));
        s
    }

    pub fn log_path(&self) -> &Path {
        &self.log
    }

    /// Every event logged so far, in order.
    pub fn events(&self) -> Vec<Value> {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        // The last line may be half written.
        text.lines().filter_map(|l| serde_json::from_str(l).ok()).collect()
    }

    /// Events named `ev`.
    pub fn named(&self, ev: &str) -> Vec<Value> {
        self.events().into_iter().filter(|e| e["ev"] == ev).collect()
    }

    /// Waits (at most `timeout`) for the first event named `ev`.
    pub fn wait_for_event(&mut self, ev: &str, timeout: Duration) -> Value {
        let end = Instant::now() + timeout;
        loop {
            if let Some(e) = self.named(ev).into_iter().next() {
                return e;
            }
            if let Ok(Some(status)) = self.child.try_wait() {
                panic!("the stand-in exited ({status}) before it logged {ev:?} ({})", self.log.display());
            }
            assert!(Instant::now() < end, "the stand-in logged no {ev:?} within {timeout:?} ({})", self.log.display());
            std::thread::sleep(Duration::from_millis(10));
        }
    }

    /// The arm targets received: (CLOCK_MONOTONIC ns, positions), the positions exactly as sent.
    pub fn arm_targets(&self) -> Vec<(u64, Vec<f64>)> {
        self.exact("arm_target")
    }

    /// The gripper targets received: (ns, stroke).
    pub fn gripper_targets(&self) -> Vec<(u64, f64)> {
        self.exact("gripper_target").into_iter().map(|(t, p)| (t, p[0])).collect()
    }

    /// (t_ns, pos) of the events named `ev`, `pos` read from the line's text with `str::parse` (exact: Python
    /// writes each float's shortest round-trip form, and serde_json's own float parsing may be an ulp off).
    fn exact(&self, ev: &str) -> Vec<(u64, Vec<f64>)> {
        let text = std::fs::read_to_string(&self.log).unwrap_or_default();
        let tag = format!("{{\"ev\": \"{ev}\"");
        text.lines()
            .filter(|l| l.starts_with(&tag) && l.ends_with('}'))
            .map(|l| {
                let e: Value = serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}"));
                let list = l.split("\"pos\": [").nth(1).and_then(|r| r.split(']').next()).unwrap_or("");
                let pos = list.split(", ").filter(|x| !x.is_empty()).map(|x| x.parse().unwrap()).collect();
                (ns(&e["t_ns"]), pos)
            })
            .collect()
    }

    fn signal(&self, sig: i32) {
        // SAFETY: kill(2) on our own child's pid; no memory is involved.
        assert_eq!(unsafe { libc::kill(self.child.id() as i32, sig) }, 0);
    }

    /// Stops publishing feedback (SIGUSR1); it keeps receiving and logging.
    pub fn go_silent(&self) {
        self.signal(libc::SIGUSR1);
    }

    /// Publishes feedback again (SIGUSR2).
    pub fn speak_again(&self) {
        self.signal(libc::SIGUSR2);
    }
}

pub fn ns(v: &Value) -> u64 {
    v.as_u64().unwrap_or_else(|| panic!("not a time in ns: {v}"))
}

pub fn floats(v: &Value) -> Vec<f64> {
    v.as_array().unwrap_or_else(|| panic!("not an array: {v}")).iter().map(|x| x.as_f64().unwrap()).collect()
}

impl Drop for StandIn {
    fn drop(&mut self) {
        // SAFETY: kill(2) on our child's process group (it is its leader); no memory is involved.
        unsafe { libc::kill(-(self.child.id() as i32), libc::SIGKILL) };
        let _ = self.child.wait();
        if std::thread::panicking() {
            eprintln!("the stand-in's log kept: {}", self.log.display());
        } else {
            let _ = std::fs::remove_file(&self.log);
        }
    }
}
