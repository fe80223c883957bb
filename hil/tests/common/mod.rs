//! Shared rig of the multi-process HIL tests: the mock HAL (`mars-hil hal`) and `marsd` as real child processes,
//! killed when dropped; a recorder thread in the test process that reads the robot's state and command services;
//! and a limit checker of its own (independent of `mars_runtime::servo::limits` and of the HAL's safety filter).
//!
//! Every test uses its own robot id (pid + test name), so tests never meet each other's iceoryx2 services; and
//! every test that starts the HAL or marsd holds the machine-wide [`rt_rig_lock`] for its whole run (the spawners
//! check), so two real-time rigs never compete for the cores.

#![allow(dead_code)] // each test binary uses a different part of this module

pub mod rerun;
pub use rerun::*;

use std::fs::File;
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use mars_ipc::node::create_node;
use mars_ipc::{CommandReader, HoldReason, JointCommand, RobotNamespace, RobotState, StateReader, status};

#[allow(unused_imports)]
pub use mars_runtime::rt::rig_lock::{RtRigLock, rt_rig_lock_held, rt_rig_lock_path};

/// Takes the machine-wide real-time rig lock (see `mars_rt::rig_lock`) for the test's whole run, and starts the
/// stall witness (once per test binary) so that it watches the whole run.
pub fn rt_rig_lock() -> RtRigLock {
    start_witness();
    mars_runtime::rt::rig_lock::rt_rig_lock().expect("taking the real-time rig lock")
}

/// Starts this process's stall witness ([`rerun`]), saying once if it cannot witness (then no test reruns).
pub fn start_witness() {
    static SAID: std::sync::Once = std::sync::Once::new();
    let w = witness();
    SAID.call_once(|| {
        if let Some(why) = w.unable() {
            eprintln!("the stall witness cannot witness here, so no test will be rerun: {why}");
        }
        if let Some(why) = w.interrupt_trace_problem() {
            eprintln!("the kernel's interrupt trace records nothing here, so it excuses nothing: {why}");
        }
    });
}

fn assert_rig_locked(what: &str) {
    assert!(rt_rig_lock_held(), "{what} is a real-time process: hold rt_rig_lock() for the whole test");
}

/// The workspace root: the configs name their files relative to it, so every child runs there.
pub fn root() -> PathBuf {
    Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/..")).canonicalize().expect("workspace root")
}

/// A robot id no other test (or test run) uses: `t<pid>-<name>` (a valid iceoryx2 service-name part).
pub fn robot(name: &str) -> String {
    let id = format!("t{}-{name}", std::process::id());
    RobotNamespace::new(&id).unwrap_or_else(|e| panic!("bad robot id {id:?}: {e}"));
    id
}

pub fn monotonic_ns() -> u64 {
    mars_ipc::clock::monotonic_ns()
}

/// A scratch directory, removed when dropped unless the test failed (then its path is printed).
pub struct TempDir(pub PathBuf);

impl TempDir {
    pub fn new(name: &str) -> Self {
        let dir = std::env::temp_dir().join(format!("mars-hil-test-{}-{name}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        Self(dir)
    }

    pub fn path(&self) -> &Path {
        &self.0
    }

    pub fn join(&self, p: &str) -> PathBuf {
        self.0.join(p)
    }
}

impl Drop for TempDir {
    fn drop(&mut self) {
        if std::thread::panicking() {
            eprintln!("kept {} for inspection", self.0.display());
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// The shipped daemon config with `key = value` lines replaced (`edits`: (key, new value as TOML)); `extra` is
/// inserted before the first section. Each edited key must occur exactly once in the file.
pub fn config_text(edits: &[(&str, &str)], extra: &str) -> String {
    config_text_of("configs/marsd.toml", edits, extra)
}

/// [`config_text`] of another shipped daemon config (`file`, relative to the repository).
pub fn config_text_of(file: &str, edits: &[(&str, &str)], extra: &str) -> String {
    let text = std::fs::read_to_string(root().join(file)).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    for (key, value) in edits {
        let hits: Vec<usize> = (0..lines.len())
            .filter(|&i| {
                let l = lines[i].trim_start();
                l.strip_prefix(key).is_some_and(|rest| rest.trim_start().starts_with('='))
            })
            .collect();
        assert_eq!(hits.len(), 1, "key {key} must occur once in {file}");
        lines[hits[0]] = format!("{key} = {value}");
    }
    if !extra.is_empty() {
        let first_section = lines.iter().position(|l| l.starts_with('[')).unwrap();
        lines.insert(first_section, extra.to_owned());
    }
    lines.join("\n") + "\n"
}

/// Writes [`config_text`] into `dir` and returns its path.
pub fn write_config(dir: &TempDir, name: &str, edits: &[(&str, &str)], extra: &str) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, config_text(edits, extra)).unwrap();
    path
}

/// Scheduling of a child. The test runs niced (a shared 2-core CI machine); the processes under test are
/// real-time processes, so their niceness goes back to 0 (possible as root, ignored otherwise). Their real-time
/// settings are their own: marsd's from its config, the HAL's from its flags (see [`spawn_hal`]).
fn realtime_child(cmd: &mut Command) {
    // SAFETY: only async-signal-safe calls (setpriority) between fork and exec.
    unsafe {
        cmd.pre_exec(move || {
            libc::setpriority(libc::PRIO_PROCESS, 0, 0);
            Ok(())
        });
    }
}

/// The HAL's real-time priority, as `mars-hil demo` runs it: above marsd's servo (80) and policy (70) loops.
pub const HAL_PRIORITY: i32 = 85;

/// A child process, SIGKILLed when dropped; its stdout and stderr go to files (printed if the test fails).
pub struct Proc {
    pub child: Child,
    pub name: String,
    pub stdout: PathBuf,
    pub stderr: PathBuf,
    pub status: Option<ExitStatus>,
}

impl Proc {
    pub fn spawn(mut cmd: Command, name: &str, logs: &Path) -> Self {
        let stdout = logs.join(format!("{name}.stdout"));
        let stderr = logs.join(format!("{name}.stderr"));
        cmd.current_dir(root())
            // The test holds the real-time rig lock for its children (a demo or doctor child takes it too).
            .env(mars_runtime::rt::rig_lock::HELD_BY_PARENT, std::process::id().to_string())
            .env("RUST_LOG", "info")
            .env_remove("IOX2_LOG_LEVEL")
            .stdin(Stdio::null())
            .stdout(File::create(&stdout).unwrap())
            .stderr(File::create(&stderr).unwrap());
        let child = cmd.spawn().unwrap_or_else(|e| panic!("starting {name}: {e}"));
        Self { child, name: name.to_owned(), stdout, stderr, status: None }
    }

    pub fn pid(&self) -> libc::pid_t {
        self.child.id() as libc::pid_t
    }

    pub fn signal(&self, sig: libc::c_int) {
        assert!(self.status.is_none(), "{} already exited", self.name);
        // SAFETY: kill(2) on our own, not yet reaped child.
        let rc = unsafe { libc::kill(self.pid(), sig) };
        assert_eq!(rc, 0, "kill({}, {sig})", self.name);
    }

    /// The exit status, or `None` if it is still running after `timeout` (polled every 0.5 ms).
    pub fn wait_timeout(&mut self, timeout: Duration) -> Option<ExitStatus> {
        let end = Instant::now() + timeout;
        loop {
            if let Some(s) = self.status {
                return Some(s);
            }
            if let Some(s) = self.child.try_wait().unwrap() {
                self.status = Some(s);
                return Some(s);
            }
            if Instant::now() >= end {
                return None;
            }
            std::thread::sleep(Duration::from_micros(500));
        }
    }

    /// Waits up to `timeout` for it to be reaped after `signal` (e.g. "its SIGKILL"); panics with how the kernel
    /// sees its threads if it was not.
    pub fn expect_reaped(&mut self, timeout: Duration, signal: &str) {
        if self.wait_timeout(timeout).is_none() {
            panic!(
                "{} not reaped {timeout:?} after {signal}; as the kernel sees it: {}",
                self.name,
                self.kernel_view()
            );
        }
    }

    /// Each of its threads as the kernel sees them now (name, state, the kernel function it sleeps in): why a
    /// process that was sent SIGKILL has not been reaped yet.
    pub fn kernel_view(&self) -> String {
        let pid = self.child.id();
        let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
            return format!("/proc/{pid}/task cannot be read (reaped since?)");
        };
        let thread = |t: &Path| {
            let stat = std::fs::read_to_string(t.join("stat")).unwrap_or_default();
            let wchan = std::fs::read_to_string(t.join("wchan")).unwrap_or_default();
            // `pid (comm) S …`: the name may hold spaces and parentheses, the state follows the last ')'.
            let (name, rest) = stat.rsplit_once(')').unwrap_or(("?", ""));
            let name = name.split_once('(').map_or("?", |(_, n)| n);
            format!(
                "{name} {} in {}",
                rest.split_whitespace().next().unwrap_or("?"),
                if wchan.is_empty() { "-" } else { &wchan }
            )
        };
        let threads: Vec<String> = tasks.flatten().map(|t| thread(&t.path())).collect();
        format!("{} threads: {}", threads.len(), threads.join("; "))
    }

    /// The exit code; panics (with the logs) if it did not exit within `timeout` or died of a signal.
    pub fn exit_code(&mut self, timeout: Duration) -> i32 {
        match self.wait_timeout(timeout) {
            Some(s) => s.code().unwrap_or_else(|| panic!("{} died of a signal: {s:?}\n{}", self.name, self.logs())),
            None => panic!("{} still running after {timeout:?}\n{}", self.name, self.logs()),
        }
    }

    pub fn running(&mut self) -> bool {
        self.wait_timeout(Duration::ZERO).is_none()
    }

    pub fn stderr_text(&self) -> String {
        std::fs::read_to_string(&self.stderr).unwrap_or_default()
    }

    pub fn stdout_text(&self) -> String {
        std::fs::read_to_string(&self.stdout).unwrap_or_default()
    }

    pub fn logs(&self) -> String {
        let tail = |s: String| {
            let lines: Vec<&str> = s.lines().collect();
            lines[lines.len().saturating_sub(40)..].join("\n")
        };
        format!(
            "--- {} stderr ---\n{}\n--- {} stdout ---\n{}",
            self.name,
            tail(self.stderr_text()),
            self.name,
            tail(self.stdout_text())
        )
    }
}

impl Drop for Proc {
    fn drop(&mut self) {
        // SIGTERM first, as systemd stops a unit: a SIGKILLed process leaves its iceoryx2 node behind as dead,
        // and the next rig's liveness watch would spend its time cleaning that up. SIGKILL if it does not go.
        if self.status.is_none() && matches!(self.child.try_wait(), Ok(None)) {
            // SAFETY: kill(2) on our own, not yet reaped child.
            unsafe { libc::kill(self.pid(), libc::SIGTERM) };
            if self.wait_timeout(Duration::from_secs(2)).is_none() {
                let _ = self.child.kill();
            }
        }
        let _ = self.child.wait();
        if std::thread::panicking() {
            eprintln!("{}", self.logs());
        }
    }
}

/// The core of marsd's servo loop in the shipped config.
pub fn servo_core() -> usize {
    let cfg = mars_runtime::config::DaemonConfig::load(&shipped_config()).unwrap();
    cfg.servo.core.expect("configs/marsd.toml pins the servo loop")
}

/// The policy loop's core in the shipped config.
pub fn policy_core() -> usize {
    let cfg = mars_runtime::config::DaemonConfig::load(&shipped_config()).unwrap();
    cfg.policy.core.expect("configs/marsd.toml pins the policy loop")
}

/// `mars-hil hal --profile configs/fr3.toml --robot <robot> --core <servo core> --rt-priority 85 [extra]` (the
/// `mars-hal` process), as `mars-hil demo` runs it: a robot's own control loop is real-time, above the servo loop
/// it shares a core with (the HAL's ticks are short and phase-shifted from the servo's; the policy thread, which
/// may spin for tens of ms at SCHED_FIFO 70, has the other core).
pub fn spawn_hal(robot: &str, extra: &[&str], logs: &TempDir) -> Proc {
    spawn_hal_of("configs/fr3.toml", robot, extra, logs)
}

/// [`spawn_hal`] for the robot of another profile.
pub fn spawn_hal_of(profile: &str, robot: &str, extra: &[&str], logs: &TempDir) -> Proc {
    assert_rig_locked("the HAL");
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_mars-hil"));
    cmd.args(["hal", "--profile", profile, "--robot", robot])
        .args(["--core", &servo_core().to_string(), "--rt-priority", &HAL_PRIORITY.to_string()])
        .args(extra);
    realtime_child(&mut cmd);
    Proc::spawn(cmd, "mars-hal", logs.path())
}

/// Any command as a real-time child of the test (logs as [`Proc`]); the caller holds the rig lock.
pub fn spawn_named(mut cmd: Command, name: &str, logs: &TempDir) -> Proc {
    assert_rig_locked(name);
    realtime_child(&mut cmd);
    Proc::spawn(cmd, name, logs.path())
}

/// marsd as the demo starts it: `mars-hil marsd` runs the `marsd` binary's very command line (its daemon and
/// its tools), from the executable this package builds.
pub fn marsd_command() -> Command {
    let mut cmd = Command::new(env!("CARGO_BIN_EXE_mars-hil"));
    cmd.arg("marsd");
    cmd
}

/// `marsd --config <config> --robot <robot> --episodes <n> --out <logs>/out [extra]`.
pub fn spawn_marsd(robot: &str, config: &Path, episodes: usize, extra: &[&str], logs: &TempDir) -> Proc {
    spawn_marsd_named("marsd", robot, config, episodes, extra, logs)
}

pub fn spawn_marsd_named(
    name: &str,
    robot: &str,
    config: &Path,
    episodes: usize,
    extra: &[&str],
    logs: &TempDir,
) -> Proc {
    assert_rig_locked("marsd");
    let mut cmd = marsd_command();
    cmd.arg("--config")
        .arg(config)
        .args(["--robot", robot, "--episodes", &episodes.to_string()])
        .arg("--out")
        .arg(logs.join(&format!("{name}-out")))
        .args(extra);
    realtime_child(&mut cmd);
    Proc::spawn(cmd, name, logs.path())
}

pub fn shipped_config() -> PathBuf {
    root().join("configs/marsd.toml")
}

/// `summary.json` of a marsd run spawned by [`spawn_marsd_named`]. Every run's latency samples went to a
/// recorder that keeps their channel (a stray one is a loop recording what it should not).
pub fn summary(logs: &TempDir, name: &str) -> serde_json::Value {
    let path = logs.join(&format!("{name}-out/summary.json"));
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()));
    let s: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(s["latency"]["stray"], 0, "{name}: samples for channels their recorder does not own: {}", s["latency"]);
    s
}

pub fn u64_at(v: &serde_json::Value, pointer: &str) -> u64 {
    v.pointer(pointer).and_then(serde_json::Value::as_u64).unwrap_or_else(|| panic!("{pointer} in {v:#}"))
}

pub fn f64_at(v: &serde_json::Value, pointer: &str) -> f64 {
    v.pointer(pointer).and_then(serde_json::Value::as_f64).unwrap_or_else(|| panic!("{pointer} in {v:#}"))
}

/// A percentile of a latency channel of the summary (µs for time channels), e.g. ("wake_jitter", "p99").
pub fn latency(v: &serde_json::Value, channel: &str, field: &str) -> f64 {
    let channels = v.pointer("/latency/channels").and_then(|c| c.as_array()).expect("latency channels");
    let c = channels.iter().find(|c| c["channel"] == channel).unwrap_or_else(|| panic!("no channel {channel}"));
    c[field].as_f64().unwrap_or_else(|| panic!("{channel}.{field}"))
}

/// Everything the test process read from the robot's services, with its receive time (CLOCK_MONOTONIC ns).
#[derive(Default)]
pub struct Recorded {
    pub states: Vec<(RobotState, u64)>,
    pub commands: Vec<(JointCommand, u64)>,
    pub errors: u64,
}

impl Recorded {
    /// The HAL's period as its frames show it (ms): the median step between consecutive frames' stamps (1 ms for
    /// the FR3's mock HAL, 5 for the R1 Lite's), 1 ms before two consecutive frames are recorded.
    pub fn period_ms(&self) -> f64 {
        let mut steps: Vec<u64> = self
            .states
            .windows(2)
            .filter(|w| w[1].0.seq == w[0].0.seq + 1)
            .map(|w| w[1].0.timestamp_ns.saturating_sub(w[0].0.timestamp_ns))
            .collect();
        if steps.is_empty() {
            return 1.0;
        }
        let mid = steps.len() / 2;
        *steps.select_nth_unstable(mid).1 as f64 * 1e-6
    }
}

/// A thread of the test process that subscribes to the robot's state and command services and records every
/// frame (iceoryx2 ports belong to the thread that opened them, so the thread opens its own).
pub struct Recorder {
    stop: Arc<AtomicBool>,
    pub data: Arc<Mutex<Recorded>>,
    handle: Option<JoinHandle<()>>,
}

impl Recorder {
    pub fn start(robot: &str) -> Self {
        let stop = Arc::new(AtomicBool::new(false));
        let data = Arc::new(Mutex::new(Recorded::default()));
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let (robot, stop2, data2) = (robot.to_owned(), stop.clone(), data.clone());
        let handle = std::thread::Builder::new()
            .name(format!("rec-{robot}"))
            .spawn(move || {
                // Back to niceness 0 for this thread (the test runs niced): it must keep up with 1 kHz frames
                // (iceoryx2 keeps 16 per subscriber).
                // SAFETY: setpriority on this thread's own tid.
                unsafe { libc::setpriority(libc::PRIO_PROCESS, libc::gettid() as libc::id_t, 0) };
                let ns = RobotNamespace::new(&robot).unwrap();
                let (node, _) = create_node(&format!("test-rec-{robot}")).unwrap();
                let states = StateReader::new(&node, &ns).unwrap();
                let commands = CommandReader::new(&node, &ns).unwrap();
                ready_tx.send(()).unwrap();
                let mut s_buf = Vec::with_capacity(64);
                let mut c_buf = Vec::with_capacity(64);
                let mut errors = 0;
                while !stop2.load(Ordering::Acquire) {
                    loop {
                        match states.receive() {
                            Ok(Some(s)) => s_buf.push((s, monotonic_ns())),
                            Ok(None) => break,
                            Err(_) => errors += 1,
                        }
                    }
                    loop {
                        match commands.receive() {
                            Ok(Some(c)) => c_buf.push((c, monotonic_ns())),
                            Ok(None) => break,
                            Err(_) => errors += 1,
                        }
                    }
                    if !s_buf.is_empty() || !c_buf.is_empty() || errors > 0 {
                        let mut d = data2.lock().unwrap();
                        d.states.append(&mut s_buf);
                        d.commands.append(&mut c_buf);
                        d.errors += errors;
                        errors = 0;
                    }
                    std::thread::sleep(Duration::from_micros(200));
                }
            })
            .unwrap();
        ready_rx.recv_timeout(Duration::from_secs(30)).expect("the recorder did not open its ports");
        Self { stop, data, handle: Some(handle) }
    }

    pub fn states_len(&self) -> usize {
        self.data.lock().unwrap().states.len()
    }

    pub fn commands_len(&self) -> usize {
        self.data.lock().unwrap().commands.len()
    }

    /// The first state frame at index ≥ `from` for which `pred` holds, with its index; `None` after `timeout`.
    pub fn wait_state(
        &self,
        from: usize,
        timeout: Duration,
        pred: impl FnMut(&RobotState) -> bool,
    ) -> Option<(usize, RobotState)> {
        self.wait_state_while(from, timeout, || true, pred)
    }

    /// [`Self::wait_state`] that also gives up as soon as `go_on` returns false (polled every millisecond).
    pub fn wait_state_while(
        &self,
        from: usize,
        timeout: Duration,
        mut go_on: impl FnMut() -> bool,
        mut pred: impl FnMut(&RobotState) -> bool,
    ) -> Option<(usize, RobotState)> {
        let end = Instant::now() + timeout;
        let mut i = from;
        loop {
            {
                let d = self.data.lock().unwrap();
                while i < d.states.len() {
                    if pred(&d.states[i].0) {
                        return Some((i, d.states[i].0));
                    }
                    i += 1;
                }
            }
            if Instant::now() >= end || !go_on() {
                return None;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
    }

    /// Like [`Self::wait_state`], panicking with `what` on timeout.
    pub fn expect_state(
        &self,
        what: &str,
        from: usize,
        timeout: Duration,
        pred: impl FnMut(&RobotState) -> bool,
    ) -> (usize, RobotState) {
        self.wait_state(from, timeout, pred).unwrap_or_else(|| panic!("timed out after {timeout:?} waiting for {what}"))
    }

    /// Waits until the robot is being moved in an episode: a session active for at least 2.5 s (past the first
    /// reset to the start pose) and some joint's applied setpoint faster than 0.1 rad/s. Returns that frame, or
    /// `None` after `timeout` or as soon as `go_on` returns false.
    pub fn wait_moving(&self, timeout: Duration, go_on: impl FnMut() -> bool) -> Option<(usize, RobotState)> {
        let mut active_since: Option<u64> = None;
        self.wait_state_while(0, timeout, go_on, |s| {
            if s.session == 0 || !s.is(status::ACTIVE) {
                return false;
            }
            let t0 = *active_since.get_or_insert(s.timestamp_ns);
            s.timestamp_ns - t0 > 2_500_000_000 && s.applied_velocity[..7].iter().any(|v| v.abs() > 0.1)
        })
    }

    /// Stops the thread (after a last read of the services) and returns everything it recorded.
    pub fn finish(mut self) -> Recorded {
        std::thread::sleep(Duration::from_millis(20));
        self.stop.store(true, Ordering::Release);
        if let Some(h) = self.handle.take() {
            h.join().unwrap();
        }
        std::mem::take(&mut *self.data.lock().unwrap())
    }
}

impl Drop for Recorder {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Release);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

/// The FR3's limits, read from configs/fr3.toml by the test itself.
#[derive(Debug, Clone)]
pub struct Limits {
    pub n: usize,
    pub dt: f64,
    pub q_min: Vec<f64>,
    pub q_max: Vec<f64>,
    pub dq: Vec<f64>,
    pub ddq: Vec<f64>,
    pub jerk: Vec<f64>,
    pub home: Vec<f64>,
}

/// Relative tolerance of every limit check.
pub const REL_TOL: f64 = 1e-6;

impl Limits {
    pub fn fr3() -> Self {
        let l = Self::of("configs/fr3.toml");
        assert_eq!(l.dt, 1e-3, "the checks assume the 1 kHz FR3 profile");
        l
    }

    /// The limits of the profile at `path` (from the repository's root).
    pub fn of(path: &str) -> Self {
        let text = std::fs::read_to_string(root().join(path)).unwrap();
        let t: toml::Table = toml::from_str(&text).unwrap();
        let v = |k: &str| -> Vec<f64> {
            t[k].as_array().unwrap_or_else(|| panic!("{k}")).iter().map(|x| x.as_float().unwrap()).collect()
        };
        let n = t["joints"].as_integer().unwrap() as usize;
        let rate = t["rate_hz"].as_float().unwrap();
        let l = Self {
            n,
            dt: 1.0 / rate,
            q_min: v("q_min"),
            q_max: v("q_max"),
            dq: v("dq_max"),
            ddq: v("ddq_max"),
            jerk: v("jerk_max"),
            home: v("home"),
        };
        assert!([&l.q_min, &l.q_max, &l.dq, &l.ddq, &l.jerk].iter().all(|x| x.len() == n));
        l
    }

    fn within(value: f64, limit: f64) -> bool {
        value.abs() <= limit * (1.0 + REL_TOL)
    }

    fn in_range(&self, j: usize, q: f64) -> bool {
        let (lo, hi) = (self.q_min[j], self.q_max[j]);
        q >= lo - REL_TOL * lo.abs().max(1.0) && q <= hi + REL_TOL * hi.abs().max(1.0)
    }
}

/// What [`check_applied`] looked at, and the largest |value| / limit seen per quantity.
#[derive(Debug, Default, Clone, Copy)]
pub struct AppliedStats {
    pub frames: usize,
    pub velocity_samples: usize,
    pub acceleration_samples: usize,
    pub jerk_samples: usize,
    pub max_ratio: [f64; 3],
}

/// Checks the applied setpoint stream (`applied_position` of each frame for which `include` holds) against
/// the position limits, and by finite differences over runs of consecutive `seq`s (dt = one period) against the
/// velocity, acceleration and jerk limits. Returns the first violation as an error.
pub fn check_applied(
    frames: &[(RobotState, u64)],
    lim: &Limits,
    include: impl Fn(&RobotState) -> bool,
) -> Result<AppliedStats, String> {
    let n = lim.n;
    let mut st = AppliedStats::default();
    // The run of consecutive included frames so far (last four positions suffice), newest last.
    let mut run: Vec<&RobotState> = Vec::with_capacity(4);
    for (s, _) in frames {
        if !include(s) {
            run.clear();
            continue;
        }
        if run.last().is_some_and(|p| s.seq != p.seq + 1) {
            run.clear();
        }
        // A robot-paced HAL after states it never saw: the setpoint moved over that many robot cycles. The step is
        // judged over them (velocity); the differences start anew from this frame.
        if s.robot_cycles > 1 {
            if let Some(p) = run.last() {
                let dt = lim.dt * f64::from(s.robot_cycles);
                for j in 0..n {
                    let v = (s.applied_position[j] - p.applied_position[j]) / dt;
                    if !Limits::within(v, lim.dq[j]) {
                        return Err(format!(
                            "seq {}: joint {j} applied velocity {v} over {} robot cycles exceeds {}",
                            s.seq, s.robot_cycles, lim.dq[j]
                        ));
                    }
                }
            }
            run.clear();
        }
        if run.len() == 4 {
            run.remove(0);
        }
        run.push(s);
        st.frames += 1;
        for j in 0..n {
            let q = s.applied_position[j];
            if !q.is_finite() || !lim.in_range(j, q) {
                return Err(format!(
                    "seq {}: joint {j} applied position {q} outside [{}, {}]",
                    s.seq, lim.q_min[j], lim.q_max[j]
                ));
            }
        }
        let dt = lim.dt;
        let q = |k: usize, j: usize| run[run.len() - 1 - k].applied_position[j];
        let k = run.len();
        for j in 0..n {
            let checks: [(usize, &str, f64, f64); 3] = [
                (2, "velocity", if k >= 2 { (q(0, j) - q(1, j)) / dt } else { 0.0 }, lim.dq[j]),
                (
                    3,
                    "acceleration",
                    if k >= 3 { (q(0, j) - 2.0 * q(1, j) + q(2, j)) / (dt * dt) } else { 0.0 },
                    lim.ddq[j],
                ),
                (
                    4,
                    "jerk",
                    if k >= 4 { (q(0, j) - 3.0 * q(1, j) + 3.0 * q(2, j) - q(3, j)) / (dt * dt * dt) } else { 0.0 },
                    lim.jerk[j],
                ),
            ];
            for (i, (need, what, value, limit)) in checks.into_iter().enumerate() {
                if k < need {
                    continue;
                }
                st.max_ratio[i] = st.max_ratio[i].max(value.abs() / limit);
                if !Limits::within(value, limit) {
                    return Err(format!(
                        "seq {}: joint {j} applied {what} {value} exceeds {limit} (session {}, status {:#b}, hold {})",
                        s.seq, s.session, s.status, s.hold_reason
                    ));
                }
            }
        }
        if k >= 2 {
            st.velocity_samples += 1;
        }
        if k >= 3 {
            st.acceleration_samples += 1;
        }
        if k >= 4 {
            st.jerk_samples += 1;
        }
    }
    Ok(st)
}

/// The frames of a controller session: non-zero session, followed (ACTIVE) or braked/held (HOLDING).
pub fn in_session(s: &RobotState) -> bool {
    s.session != 0 && (s.is(status::ACTIVE) || s.is(status::HOLDING))
}

/// Checks every command: the right joint count, finite, positions within the position limits, the velocity and
/// acceleration fields within dq_max / ddq_max. Returns the number checked.
pub fn check_commands(commands: &[(JointCommand, u64)], lim: &Limits) -> Result<usize, String> {
    for (c, _) in commands {
        if c.num_joints as usize != lim.n {
            return Err(format!("command {}: {} joints", c.seq, c.num_joints));
        }
        if !c.gripper.is_finite() {
            return Err(format!("command {}: gripper {}", c.seq, c.gripper));
        }
        for j in 0..lim.n {
            let (q, v, a) = (c.position[j], c.velocity[j], c.acceleration[j]);
            if !(q.is_finite() && v.is_finite() && a.is_finite()) {
                return Err(format!("command {}: joint {j} not finite: q {q} v {v} a {a}", c.seq));
            }
            if !lim.in_range(j, q) {
                return Err(format!(
                    "command {}: joint {j} position {q} outside [{}, {}]",
                    c.seq, lim.q_min[j], lim.q_max[j]
                ));
            }
            if !Limits::within(v, lim.dq[j]) {
                return Err(format!("command {}: joint {j} velocity {v} exceeds {}", c.seq, lim.dq[j]));
            }
            if !Limits::within(a, lim.ddq[j]) {
                return Err(format!("command {}: joint {j} acceleration {a} exceeds {}", c.seq, lim.ddq[j]));
            }
        }
    }
    Ok(commands.len())
}

/// The first line of `text` containing every one of `needles`.
pub fn find_line<'a>(text: &'a str, needles: &[&str]) -> Option<&'a str> {
    text.lines().find(|l| needles.iter().all(|n| l.contains(n)))
}

/// Major page faults of a process so far (/proc/<pid>/stat field 12).
pub fn major_faults(pid: libc::pid_t) -> Option<u64> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    stat.rsplit_once(')')?.1.split_whitespace().nth(9)?.parse().ok()
}

/// Generous: the first start may include iceoryx2 setup and the checkpoint's warm-up on a loaded machine.
pub const START: Duration = Duration::from_secs(30);

pub fn hold_reason(s: &RobotState) -> Option<HoldReason> {
    HoldReason::from_u32(s.hold_reason)
}

/// Starts the HAL and waits for its first frame (so marsd never races the HAL's service creation).
pub fn hal_with_recorder(robot: &str, extra: &[&str], logs: &TempDir) -> (Proc, Recorder) {
    hal_of_with_recorder("configs/fr3.toml", robot, extra, logs)
}

/// [`hal_with_recorder`] for the robot of another profile.
pub fn hal_of_with_recorder(profile: &str, robot: &str, extra: &[&str], logs: &TempDir) -> (Proc, Recorder) {
    let rec = Recorder::start(robot);
    let hal = spawn_hal_of(profile, robot, extra, logs);
    rec.expect_state("the HAL's first state frame", 0, START, |_| true);
    (hal, rec)
}

/// The applied stream (session frames) and the command stream within `lim`, by the tests' own checker.
pub fn assert_limits(r: &Recorded, lim: &Limits, what: &str) -> AppliedStats {
    let st = check_applied(&r.states, lim, in_session).unwrap_or_else(|e| panic!("{what}: applied stream: {e}"));
    let checked = check_commands(&r.commands, lim).unwrap_or_else(|e| panic!("{what}: command stream: {e}"));
    eprintln!(
        "{what}: {} session frames ({} jerk samples; max |v|/v_max {:.3}, |a|/a_max {:.3}, |j|/j_max {:.3}), \
         {checked} commands checked, all within limits",
        st.frames, st.jerk_samples, st.max_ratio[0], st.max_ratio[1], st.max_ratio[2]
    );
    st
}
