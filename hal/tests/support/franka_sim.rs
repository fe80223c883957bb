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
use std::io::Read;
use std::net::{SocketAddr, TcpStream};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicU32, Ordering};
use std::time::{Duration, Instant};

/// The simulator's robot (FCI command) port: libfranka's default, so `--robot-ip 127.0.0.1` reaches it.
pub const ROBOT_PORT: u16 = 1337;

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
    let root = repo_root();
    let _installing = lock("mars-franka-sim-install.lock");
    let script = root.join(".ci/franka-sim-venv");
    let status = Command::new(&script)
        .current_dir(&root)
        .status()
        .unwrap_or_else(|e| panic!("running {}: {e}", script.display()));
    assert!(status.success(), "{} failed ({status}): franka-sim is not installed", script.display());
    root.join(".venv-sim")
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

fn robot_port_accepts() -> bool {
    let addr = SocketAddr::from(([127, 0, 0, 1], ROBOT_PORT));
    TcpStream::connect_timeout(&addr, Duration::from_millis(200)).is_ok()
}

/// A running franka-sim on 127.0.0.1:1337; killed (its whole process group) when dropped.
pub struct FrankaSim {
    child: Child,
    log: PathBuf,
    /// Held while the simulator runs; released after it was killed (fields drop after `Drop::drop`).
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
        // Under our lock nothing of ours listens there: anything that does is a simulator or robot some other
        // program started, which our server could not bind past (and which we would otherwise test instead).
        assert!(
            !robot_port_accepts(),
            "something already listens on 127.0.0.1:{ROBOT_PORT} (a franka-sim started by hand?): stop it first"
        );
        static N: AtomicU32 = AtomicU32::new(0);
        let log = std::env::temp_dir().join(format!(
            "mars-franka-sim-{}-{}.log",
            std::process::id(),
            N.fetch_add(1, Ordering::Relaxed)
        ));
        let out = File::create(&log).unwrap_or_else(|e| panic!("{}: {e}", log.display()));
        let child = Command::new(venv.join("bin/run-franka-sim-server"))
            .args(args)
            .env("FR3_MJCF", venv.join("fr3.xml"))
            .stdin(Stdio::null())
            .stdout(out.try_clone().unwrap())
            .stderr(out)
            // Its own process group, so Drop can signal everything it started, and a Ctrl-C aimed at the test run
            // reaches it only through our Drop.
            .process_group(0)
            .spawn()
            .unwrap_or_else(|e| panic!("starting run-franka-sim-server: {e}"));
        // From here a panic drops `sim`, which kills the server.
        let mut sim = FrankaSim { child, log, _lock: lock };
        let start = Instant::now();
        loop {
            if let Some(status) = sim.child.try_wait().unwrap() {
                panic!("franka-sim exited ({status}) before listening; its log:\n{}", sim.log_text());
            }
            if robot_port_accepts() {
                eprintln!(
                    "franka-sim listening after {:.1} s (log {})",
                    start.elapsed().as_secs_f64(),
                    sim.log.display()
                );
                return sim;
            }
            assert!(
                start.elapsed() < START_TIMEOUT,
                "franka-sim did not listen on {ROBOT_PORT} within {START_TIMEOUT:?}; its log:\n{}",
                sim.log_text()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// Everything the server wrote so far.
    pub fn log_text(&self) -> String {
        let mut s = String::new();
        let _ = File::open(&self.log).and_then(|mut f| f.read_to_string(&mut s));
        s
    }
}

impl FrankaSim {
    /// Kills the server at once (SIGKILL to its group), like a robot losing power or its network.
    pub fn kill_now(&mut self) {
        // SAFETY: kill(2) with a negative pid signals that process group; no memory is involved.
        unsafe { libc::kill(-(self.child.id() as i32), libc::SIGKILL) };
        let _ = self.child.wait();
    }
}

impl Drop for FrankaSim {
    fn drop(&mut self) {
        let group = -(self.child.id() as i32);
        // SIGTERM first (the server shuts down cleanly and frees its ports), SIGKILL if it has not within 5 s; then
        // SIGKILL whatever else is left in its group.
        // SAFETY: kill(2) with a negative pid signals that process group; no memory is involved.
        unsafe { libc::kill(group, libc::SIGTERM) };
        let end = Instant::now() + Duration::from_secs(5);
        while Instant::now() < end && matches!(self.child.try_wait(), Ok(None)) {
            std::thread::sleep(Duration::from_millis(20));
        }
        // SAFETY: as above; ESRCH (nothing left) is fine.
        unsafe { libc::kill(group, libc::SIGKILL) };
        let _ = self.child.wait();
        // A failing test keeps the simulator's log for the reader (it says why a reflex fired).
        if std::thread::panicking() {
            eprintln!("franka-sim's log kept: {}", self.log.display());
        } else {
            let _ = std::fs::remove_file(&self.log);
        }
    }
}
