//! franka-sim for tests: a MuJoCo FR3 behind the real Franka Control Interface protocol, started as a process of
//! its own so franka-rs talks to it exactly as to a robot.
//!
//! - It is installed into `.venv-sim/` by `.ci/franka-sim-venv` (idempotent: it returns at once when installed),
//!   run under a machine-wide lock so two test binaries never install at the same time.
//! - The simulator serves one client on fixed ports (TCP 1337 for the robot, 1338 for the gripper), so every test
//!   that starts one holds a second machine-wide lock for as long as it runs: an flock, like
//!   `mars_rt::rig_lock`, which the kernel releases if the test process dies. Threads of one test binary
//!   serialise on it too (each takes it through its own open file).
//! - It runs headless (no viewer unless `-v`), with `FR3_MJCF` pointing at the fixed model the script writes
//!   (without it franka-sim would try to clone a model repository from GitHub), in its own process group, which
//!   is killed when the handle is dropped, so a failing test leaves no simulator behind.

use std::fs::{File, OpenOptions, TryLockError};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

// The simulator's process handle is the HIL rig's (`mars_hil::franka_sim`, which the demo starts it with); the HAL
// does not depend on the rig, so its tests take the file itself.
#[path = "../../../hil/src/franka_sim.rs"]
mod process;
use process::FrankaSim as Sim;

/// How long the simulator may take to listen (MuJoCo compiles the model and settles it first: ~1 s idle, several
/// seconds on a loaded 2-core machine).
const START_TIMEOUT: Duration = Duration::from_secs(60);

pub fn repo_root() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").canonicalize().expect("the repository root")
}

/// Takes the machine-wide lock `name` (in the temp dir), waiting and saying so while another process holds it.
fn lock(name: &str) -> File {
    let path = std::env::temp_dir().join(name);
    let file = OpenOptions::new()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&path)
        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    match file.try_lock() {
        Ok(()) => {}
        Err(TryLockError::WouldBlock) => {
            let waited = Instant::now();
            eprintln!("waiting for {}: another test is using it", path.display());
            file.lock().unwrap_or_else(|e| panic!("{}: {e}", path.display()));
            eprintln!("waited {:.1} s for {}", waited.elapsed().as_secs_f64(), path.display());
        }
        Err(TryLockError::Error(e)) => panic!("{}: {e}", path.display()),
    }
    file
}

/// The simulator's virtual environment, installed first if it is missing.
pub fn venv() -> PathBuf {
    install_venv(".ci/franka-sim-venv", ".venv-sim", "mars-franka-sim-install.lock")
}

/// Runs the idempotent installer `script` (from the repository's root) under the machine-wide lock `lock`, so
/// two test binaries never install at once; returns the environment `dir` it makes.
pub fn install_venv(script: &str, dir: &str, lock_name: &str) -> PathBuf {
    let root = repo_root();
    let _installing = lock(lock_name);
    let script = root.join(script);
    let status = Command::new(&script)
        .current_dir(&root)
        .status()
        .unwrap_or_else(|e| panic!("running {}: {e}", script.display()));
    assert!(status.success(), "{} failed ({status}): {dir} is not installed", script.display());
    root.join(dir)
}

/// What the simulator starts as, from its own installed source (not from numbers copied here): the arm's initial
/// joint positions (`franka_sim.mujoco_franka_sim.ARM_INITIAL_Q`, which it writes into the model before settling;
/// the MJCF's "home" keyframe is not used and differs in joint 7) and the robot mode of a fresh robot state
/// (`franka_sim.robot_state.RobotState`), without the `k` of libfranka's enum names.
pub fn start_pose_and_rest_mode() -> ([f64; 7], String) {
    let python = venv().join("bin/python");
    let out = Command::new(&python)
        .args([
            "-c",
            "from franka_sim.mujoco_franka_sim import ARM_INITIAL_Q\n\
             from franka_sim.robot_state import RobotState\n\
             from franka_sim.franka_protocol import RobotMode\n\
             print(' '.join(repr(float(q)) for q in ARM_INITIAL_Q))\n\
             print(RobotMode(RobotState().state['robot_mode']).name)",
        ])
        .stderr(Stdio::inherit())
        .output()
        .unwrap_or_else(|e| panic!("running {}: {e}", python.display()));
    assert!(out.status.success(), "asking franka-sim for its start pose failed ({})", out.status);
    let text = String::from_utf8(out.stdout).unwrap();
    let mut lines = text.lines();
    let q: Vec<f64> = lines.next().unwrap_or("").split_whitespace().map(|v| v.parse().unwrap()).collect();
    let mode = lines.next().expect("a robot mode").trim();
    let q: [f64; 7] = q.try_into().unwrap_or_else(|q| panic!("franka-sim's start pose has not 7 joints: {q:?}"));
    (q, mode.strip_prefix('k').unwrap_or(mode).to_string())
}

/// A running franka-sim on 127.0.0.1:1337 (see [`mars_hal::fci::franka_sim`]), under the machine-wide simulator
/// lock; killed when dropped.
pub struct FrankaSim {
    sim: Option<Sim>,
    /// Held while the simulator runs; released after it was killed (fields drop in order).
    _lock: File,
}

impl FrankaSim {
    /// Installs it if needed, waits for the simulator lock, starts the server and waits until port 1337 accepts.
    pub fn start() -> Self {
        Self::start_with(&[])
    }

    /// As the robot would be: the 20-lost-cycles communication reflex and the motion-limit reflexes on.
    pub fn start_strict() -> Self {
        Self::start_with(&["--enforce-comm-constraints", "--enforce-motion-limits"])
    }

    /// [`Self::start`] with extra server arguments.
    pub fn start_with(args: &[&str]) -> Self {
        let venv = venv();
        let lock = lock("mars-franka-sim.lock");
        static N: AtomicU32 = AtomicU32::new(0);
        let log = std::env::temp_dir().join(format!(
            "mars-franka-sim-{}-{}.log",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let start = Instant::now();
        // On no core of its own: these tests leave the HAL unpinned too (`Sim::start` says when to pin both).
        let sim = Sim::start(&venv, args, &log, START_TIMEOUT, None).unwrap_or_else(|e| panic!("{e:#}"));
        eprintln!("franka-sim listening after {:.1} s (log {})", start.elapsed().as_secs_f64(), log.display());
        FrankaSim { sim: Some(sim), _lock: lock }
    }

    /// Everything the server wrote so far.
    pub fn log_text(&self) -> String {
        self.sim.as_ref().map(Sim::log_text).unwrap_or_default()
    }

    /// Kills the server at once (SIGKILL to its group), like a robot losing power or its network.
    pub fn kill_now(&mut self) {
        if let Some(sim) = self.sim.as_mut() {
            sim.kill_now();
        }
    }
}

impl Drop for FrankaSim {
    fn drop(&mut self) {
        let Some(sim) = self.sim.take() else { return };
        let log = sim.log_path().to_path_buf();
        drop(sim);
        // A failing test keeps the simulator's log for the reader (it says why a reflex fired).
        if std::thread::panicking() {
            eprintln!("franka-sim's log kept: {}", log.display());
        } else {
            let _ = std::fs::remove_file(&log);
        }
    }
}
