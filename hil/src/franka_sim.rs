//! franka-sim as a process of its own: a MuJoCo FR3 behind the real Franka Control Interface (TCP 1337 for the
//! robot, 1338 for the hand), so the fci backend talks to it exactly as to a robot. Used by
//! `mars-hil demo --backend franka-sim` and by the tests.
//!
//! It is installed into a virtual environment by `.ci/franka-sim-venv` (which also writes the fixed FR3 model
//! `fr3.xml` there), runs headless with `FR3_MJCF` pointing at that model (without it franka-sim would try to
//! clone a model repository from GitHub), in its own process group, which is killed when the handle is dropped.

use std::fs::File;
use std::net::{SocketAddr, TcpStream};
use std::os::unix::process::CommandExt;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;

/// The simulator's robot (FCI command) port: libfranka's default, so `--robot-ip 127.0.0.1` reaches it.
pub const ROBOT_PORT: u16 = 1337;

/// Whether something accepts connections on 127.0.0.1:1337.
pub fn robot_port_accepts() -> bool {
    let addr = SocketAddr::from(([127, 0, 0, 1], ROBOT_PORT));
    TcpStream::connect_timeout(&addr, Duration::from_millis(200)).is_ok()
}

/// A running franka-sim on 127.0.0.1:1337; killed (its whole process group) when dropped.
pub struct FrankaSim {
    child: Child,
    log: PathBuf,
}

impl FrankaSim {
    /// Starts `run-franka-sim-server args…` from the environment `venv`, its output into `log`, and waits (at
    /// most `timeout`) until port 1337 accepts. Refuses when something else listens there already (a simulator
    /// or robot some other program started, which this one could not bind past).
    ///
    /// `core`: the one core the simulator (all its threads) may run on; give it the HAL's. A real FR3 is a
    /// machine of its own, whose clock does not stop when ours does; on one virtual machine the host can take a
    /// core away for ~10 ms (steal), and a robot running on the other core would then count the frozen HAL's
    /// cycles as lost commands. Sharing the HAL's core, the simulator stops with it. It runs as an ordinary
    /// process below the HAL's real-time loop, so a HAL that overruns its cycle still delays its answer past
    /// the simulator's next state — but only when the HAL yields the core to it: see README, "franka-sim".
    pub fn start(
        venv: &Path,
        args: &[&str],
        log: &Path,
        timeout: Duration,
        core: Option<usize>,
    ) -> anyhow::Result<Self> {
        let server = venv.join("bin/run-franka-sim-server");
        anyhow::ensure!(
            server.exists() && venv.join("fr3.xml").exists(),
            "franka-sim is not installed in {} (run .ci/franka-sim-venv)",
            venv.display()
        );
        anyhow::ensure!(
            !robot_port_accepts(),
            "something already listens on 127.0.0.1:{ROBOT_PORT} (another franka-sim?): stop it first"
        );
        let out = File::create(log).with_context(|| format!("creating {}", log.display()))?;
        let mut command = Command::new(&server);
        if let Some(core) = core {
            // SAFETY: runs in the forked child before exec; sched_setaffinity(2) is async-signal-safe and the
            // closure touches only its own stack.
            unsafe { command.pre_exec(move || only_on_core(core)) };
        }
        let child = command
            .args(args)
            .env("FR3_MJCF", venv.join("fr3.xml"))
            // Its log's times in UTC, like ours, so a line of its lines up with ours (its overload warnings are
            // the evidence a test may rerun on: `stall_witness::peer`).
            .env("TZ", "UTC")
            .stdin(Stdio::null())
            .stdout(out.try_clone()?)
            .stderr(out)
            // Its own process group, so Drop can signal everything it started, and a Ctrl-C aimed at us reaches
            // it only through our Drop.
            .process_group(0)
            .spawn()
            .with_context(|| format!("starting {}", server.display()))?;
        // From here an early return drops `sim`, which kills the server.
        let mut sim = FrankaSim { child, log: log.to_path_buf() };
        let start = Instant::now();
        loop {
            if let Some(status) = sim.child.try_wait()? {
                anyhow::bail!("franka-sim exited ({status}) before listening; its log:\n{}", sim.log_text());
            }
            if robot_port_accepts() {
                return Ok(sim);
            }
            anyhow::ensure!(
                start.elapsed() < timeout,
                "franka-sim did not listen on {ROBOT_PORT} within {timeout:?}; its log:\n{}",
                sim.log_text()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    pub fn log_path(&self) -> &Path {
        &self.log
    }

    /// Everything the server wrote so far.
    pub fn log_text(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    /// Kills the server at once (SIGKILL to its group), like a robot losing power or its network.
    pub fn kill_now(&mut self) {
        // SAFETY: kill(2) with a negative pid signals that process group; no memory is involved.
        unsafe { libc::kill(-(self.child.id() as i32), libc::SIGKILL) };
        let _ = self.child.wait();
    }
}

/// Restricts the calling process (and the threads it will start) to `core`.
fn only_on_core(core: usize) -> std::io::Result<()> {
    // SAFETY: a zeroed cpu_set_t is the empty set; CPU_SET writes within it (core is checked against its size).
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    if core >= 8 * std::mem::size_of::<libc::cpu_set_t>() {
        return Err(std::io::Error::from_raw_os_error(libc::EINVAL));
    }
    unsafe { libc::CPU_SET(core, &mut set) };
    // SAFETY: pid 0 is this process; the set is a valid cpu_set_t of the size passed.
    match unsafe { libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &set) } {
        0 => Ok(()),
        _ => Err(std::io::Error::last_os_error()),
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
    }
}
