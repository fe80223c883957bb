//! One trial: a checker recording, marsd for one Pick Cup episode, a fault at the planned moment of its session,
//! the HAL's reaction waited for, and the checker's verdict on the recording.

use std::io::BufRead;
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;
use serde_json::Value;

use super::rig::{Rig, wait_child};
use super::watch::held_at_rest;
use mars_ipc::{HoldReason, status};

/// What is done to marsd.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Fault {
    /// Nothing (the run that measures how long an episode takes).
    None,
    /// SIGKILL.
    Kill,
    /// SIGSTOP, held this long, then SIGCONT.
    Stop(Duration),
}

impl Fault {
    pub fn kind(&self) -> &'static str {
        match self {
            Fault::None => "none",
            Fault::Kill => "SIGKILL",
            Fault::Stop(_) => "SIGSTOP",
        }
    }
}

#[derive(Debug, Clone, Copy)]
pub struct Plan {
    pub fault: Fault,
    /// After the session's first followed frame.
    pub at: Duration,
}

#[derive(Debug)]
pub struct Outcome {
    pub plan: Plan,
    /// Where its recording, logs and verdict are.
    pub dir: std::path::PathBuf,
    /// The fault was sent (false: marsd had ended before the moment came).
    pub delivered: bool,
    /// marsd's exit status (None: killed).
    pub marsd_exit: Option<i32>,
    /// Session start → marsd's exit.
    pub session_time: Duration,
    /// The checker's verdict (`mars-checker check --json`).
    pub verdict: Value,
    pub clean: bool,
}

/// How long marsd may take to start its session, and to end after the fault (an episode is ~6 s, its task's timeout
/// 12 s).
const SESSION_START: Duration = Duration::from_secs(60);
const MARSD_END: Duration = Duration::from_secs(60);
/// How long the HAL may take to hold the arm at rest once marsd is gone.
const AT_REST: Duration = Duration::from_secs(10);
/// Frames recorded after the arm came to rest, so the recording shows it held.
const TAIL: Duration = Duration::from_millis(100);
/// The checker reads at this SCHED_FIFO priority: below the HAL (85) and marsd's loops (80, 70), above everything
/// else, so a busy machine does not make it miss frames.
const WITNESS_PRIORITY: &str = "10";
/// Recoveries asked for after a reflex, 3 s apart.
const RECOVERY_TRIES: usize = 5;

pub fn run(rig: &mut Rig, checker: &Path, dir: &Path, plan: Plan) -> anyhow::Result<Outcome> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let recording = dir.join("stream.csv");
    let _ = std::fs::remove_file(&recording);
    let sim_log_from = rig.sim_log().len();
    let mut recorder = start_checker(checker, &rig.robot, &recording)?;
    rig.watch.drain();
    let last_session = rig.watch.last.map_or(0, |s| s.session);
    let mut marsd = rig.marsd(dir, 1)?;
    let started = rig.watch.wait(
        SESSION_START,
        |s| s.session != last_session && s.session != 0 && s.is(status::ACTIVE),
        || !matches!(marsd.try_wait(), Ok(None)),
    );
    let Some(first) = started else {
        stop_child(&mut marsd);
        stop_child(&mut recorder);
        anyhow::bail!("marsd started no session; its log:\n{}", tail(&dir.join("marsd.log")));
    };
    let session_start = Instant::now();
    let (delivered, fault_at_ns) = inject(&mut marsd, session_start, plan);
    let marsd_exit = wait_child(&mut marsd, MARSD_END);
    let session_time = session_start.elapsed();
    rig.watch.wait(AT_REST, |s| s.seq > first.seq && held_at_rest(s), || false);
    std::thread::sleep(TAIL);
    stop_child(&mut recorder);
    let robot_log = dir.join("robot.log");
    std::fs::write(&robot_log, rig.sim_log().get(sim_log_from..).unwrap_or_default())?;
    let verdict = check(checker, &recording, &rig.profile, delivered.then_some(fault_at_ns), &robot_log)?;
    let clean = verdict["clean"].as_bool() == Some(true);
    Ok(Outcome { plan, dir: dir.to_path_buf(), delivered, marsd_exit, session_time, verdict, clean })
}

/// Sends the planned fault at its moment; (sent, when: CLOCK_MONOTONIC ns).
fn inject(marsd: &mut Child, session_start: Instant, plan: Plan) -> (bool, u64) {
    let pid = marsd.id() as libc::pid_t;
    if let Some(wait) = (session_start + plan.at).checked_duration_since(Instant::now()) {
        std::thread::sleep(wait);
    }
    if plan.fault == Fault::None || !matches!(marsd.try_wait(), Ok(None)) {
        return (false, mars_ipc::clock::monotonic_ns());
    }
    let at = mars_ipc::clock::monotonic_ns();
    // SAFETY: kill(2) on our own child's pid, which has not been reaped (try_wait said it runs).
    match plan.fault {
        Fault::Kill => unsafe {
            libc::kill(pid, libc::SIGKILL);
        },
        Fault::Stop(held) => unsafe {
            libc::kill(pid, libc::SIGSTOP);
            std::thread::sleep(held);
            libc::kill(pid, libc::SIGCONT);
        },
        Fault::None => {}
    }
    (true, at)
}

/// `mars-checker record` for `robot` into `out`, once it said it is subscribed.
fn start_checker(checker: &Path, robot: &str, out: &Path) -> anyhow::Result<Child> {
    let mut child = Command::new(checker)
        .args(["record", "--robot", robot, "--rt-priority", WITNESS_PRIORITY, "--out"])
        .arg(out)
        .stdout(Stdio::piped())
        .stderr(std::fs::File::create(out.with_extension("log"))?)
        .spawn()
        .with_context(|| format!("starting {}", checker.display()))?;
    let stdout = child.stdout.take().context("the checker's stdout")?;
    let mut line = String::new();
    // It prints "ready" once subscribed, or exits (end of file) when it cannot.
    std::io::BufReader::new(stdout).read_line(&mut line)?;
    if line.trim() != "ready" {
        stop_child(&mut child);
        anyhow::bail!("the checker did not start: {}", tail(&out.with_extension("log")));
    }
    Ok(child)
}

/// The checker's verdict on `recording`.
fn check(checker: &Path, recording: &Path, profile: &Path, fault_at: Option<u64>, log: &Path) -> anyhow::Result<Value> {
    let mut cmd = Command::new(checker);
    cmd.arg("check").arg(recording).arg("--profile").arg(profile).arg("--robot-log").arg(log).arg("--json");
    if let Some(t) = fault_at {
        cmd.args(["--fault-at-ns", &t.to_string()]);
    }
    let out = cmd.output().with_context(|| format!("running {} check", checker.display()))?;
    anyhow::ensure!(
        matches!(out.status.code(), Some(0 | 1)),
        "the checker could not judge {}: {}",
        recording.display(),
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).context("reading the checker's verdict")
}

/// The reflexes a verdict counts: the same reflex shows in the recorded frames and in the robot's own log, so the
/// larger of the two counts.
pub fn reflexes(v: &Value) -> u64 {
    v["reflexes"].as_u64().unwrap_or(0).max(v["robot_log_reflexes"].as_u64().unwrap_or(0))
}

/// After a reflex: the HAL recovers the robot on SIGUSR1 (as a person would have it), so the next trials can run. The
/// HAL takes over only an arm at rest, and franka-sim's arm may still settle after its recovery: asked again until
/// the HAL no longer holds for the robot's fault. False when it still does.
pub fn recover(rig: &mut Rig) -> bool {
    let recovered = |s: &mars_ipc::RobotState| s.fault == 0 && s.hold_reason != HoldReason::RobotFault as u32;
    for _ in 0..RECOVERY_TRIES {
        // SAFETY: kill(2) on our own child's pid.
        unsafe { libc::kill(rig.hal_pid(), libc::SIGUSR1) };
        if rig.watch.wait(Duration::from_secs(3), recovered, || false).is_some() {
            return true;
        }
    }
    false
}

/// SIGTERM, then SIGKILL after 5 s.
fn stop_child(child: &mut Child) {
    // SAFETY: kill(2) on our own child's pid.
    unsafe { libc::kill(child.id() as libc::pid_t, libc::SIGTERM) };
    wait_child(child, Duration::from_secs(5));
}

/// The last lines of a log, for an error message.
fn tail(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = text.lines().collect();
    lines[lines.len().saturating_sub(20)..].join("\n")
}
