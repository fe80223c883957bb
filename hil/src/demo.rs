//! `mars-hil demo`: the HAL and marsd as two processes of this executable (and franka-sim or the R1 Lite
//! stand-in where the backend needs one), started, watched and stopped as systemd would, their trip explained.

use std::io::BufRead;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use anyhow::Context;

use mars_runtime::cli::{DEFAULT_CONFIG, MarsdArgs};
use mars_runtime::daemon::exit;

#[derive(clap::Args, Debug, Clone)]
pub struct DemoArgs {
    #[command(flatten)]
    pub marsd: MarsdArgs,
    /// CPU core of the HAL's loop. The servo loop's core by default: its ticks are short and phase-shifted
    /// from the HAL's, while the policy thread (which may spin for tens of ms at SCHED_FIFO) gets the other.
    #[arg(long, default_value_t = 1)]
    pub hal_core: usize,
    /// Fault injection, passed to the HAL: its loop sleeps --hal-stall-ms once at this tick (a machine stall as
    /// the demo would meet one).
    #[arg(long, requires = "hal_stall_ms")]
    pub hal_stall_at_tick: Option<u64>,
    #[arg(long, requires = "hal_stall_at_tick")]
    pub hal_stall_ms: Option<f64>,
    /// The robot behind the HAL: the mock plant in the HAL process; franka-sim (a MuJoCo FR3 speaking the
    /// Franka Control Interface, started here; the HAL drives it with its fci backend, as it would a real FR3);
    /// or, with `--robot r1-lite`, the R1 Lite stand-in (a Cyclone DDS peer on the R1 Lite's ROS 2 topics,
    /// started here; the HAL drives it with its ros2 backend, as it would the robot).
    #[arg(long, value_enum, default_value_t = DemoRobot::Mock)]
    pub backend: DemoRobot,
    /// franka-sim's virtual environment (made by `.ci/franka-sim-venv`, which the demo runs first).
    #[arg(long, default_value = FRANKA_SIM_VENV)]
    pub franka_sim_venv: PathBuf,
    /// The task: the robot's pick (the FR3's Pick Cup, configs/marsd.toml; the R1 Lite's Pick Vegetable) or
    /// Push-T with its camera and scene (configs/marsd_push_t.toml); an explicit --config decides instead.
    #[arg(long, value_enum, default_value_t = DemoTask::Pick)]
    pub task: DemoTask,
}

impl DemoArgs {
    /// The demo of `marsd` with the command line's defaults: the mock robot, Pick, the HAL on core 1, no stall.
    pub fn new(marsd: MarsdArgs) -> Self {
        Self {
            marsd,
            hal_core: 1,
            hal_stall_at_tick: None,
            hal_stall_ms: None,
            backend: DemoRobot::Mock,
            franka_sim_venv: FRANKA_SIM_VENV.into(),
            task: DemoTask::Pick,
        }
    }
}

#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum DemoTask {
    #[value(alias = "pick-cup", alias = "pick-vegetable")]
    Pick,
    PushT,
}

/// franka-sim's virtual environment, where `.ci/franka-sim-venv` makes it.
pub const FRANKA_SIM_VENV: &str = ".venv-sim";

/// The same for `--task push-t`.
pub const PUSH_T_CONFIG: &str = "configs/marsd_push_t.toml";
/// The demo's configuration for each robot `mars-hil demo --robot` can name.
pub const ROBOT_CONFIGS: [(&str, &str); 2] = [("fr3", DEFAULT_CONFIG), ("r1-lite", "configs/marsd_r1_lite.toml")];

#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq)]
pub enum DemoRobot {
    Mock,
    FrankaSim,
    R1LiteStandin,
}

/// marsd's allowed gap between usable frames when the robot is franka-sim (ms).
pub(crate) const FRANKA_SIM_STATE_GAP_MS: f64 = 100.0;

/// Kills a child on drop, so a failing demo never leaves a HAL running.
struct Reaped(Child);

impl Drop for Reaped {
    fn drop(&mut self) {
        if matches!(self.0.try_wait(), Ok(None)) {
            let _ = self.0.kill();
            let _ = self.0.wait();
        }
    }
}

/// Which configuration the demo runs when no `--config` is given: the robot `--robot` names (its namespace then
/// made per run, as without `--robot`), and for it the task `--task` names.
fn choose_demo_config(args: &mut DemoArgs) -> anyhow::Result<()> {
    if args.marsd.config != Path::new(DEFAULT_CONFIG) {
        return Ok(());
    }
    let named = args.marsd.robot.as_deref().and_then(|r| ROBOT_CONFIGS.iter().find(|(name, _)| *name == r));
    if let Some((name, config)) = named {
        anyhow::ensure!(
            args.task == DemoTask::Pick || *name == "fr3",
            "--task push-t runs on the FR3 (its table, camera and kinematics are the FR3's), not on --robot {name}"
        );
        let (backend, simulates) = match args.backend {
            DemoRobot::Mock => ("mock", *name),
            DemoRobot::FrankaSim => ("franka-sim", "fr3"),
            DemoRobot::R1LiteStandin => ("r1-lite-standin", "r1-lite"),
        };
        anyhow::ensure!(*name == simulates, "--backend {backend} stands in for --robot {simulates}, not {name}");
        args.marsd.config = (*config).into();
        args.marsd.robot = None;
    }
    if args.task == DemoTask::PushT {
        args.marsd.config = PUSH_T_CONFIG.into();
    }
    Ok(())
}

/// The HIL demo: the mock FR3 HAL and `marsd` as two processes (both from this executable), N episodes, the
/// report. Returns marsd's exit status.
pub fn demo(mut args: DemoArgs) -> anyhow::Result<u8> {
    let exe = std::env::current_exe().context("locating this executable")?;
    choose_demo_config(&mut args)?;
    let cfg = mars_runtime::config::DaemonConfig::load(&args.marsd.config)?;
    // A camera task has a scene (the world, the camera, the referee) as a process of its own.
    let profile = mars_profile::Profile::load(&cfg.profile)?;
    let task = mars_runtime::task::HilTask::load(&cfg.task, &profile)
        .with_context(|| format!("task {}", cfg.task.display()))?;
    // One real-time rig at a time on this machine (a second demo, the benchmark or the HIL tests would take this
    // rig's cores): wait for the one running, if any.
    let _rig = mars_runtime::rt::rig_lock::rt_rig_lock().context("taking the real-time rig lock")?;
    // A namespace of its own, so a demo never meets another run's HAL or controller.
    let robot = args.marsd.robot.clone().unwrap_or_else(|| format!("{}-demo-{}", cfg.robot, std::process::id()));
    let out = args.marsd.out.clone().unwrap_or_else(|| cfg.out.clone());
    // The preflight: what this machine can do, before anything runs on it (it never stops the demo).
    match mars_runtime::tools::doctor::run(&args.marsd.config, 2.0, Some(&out)) {
        Ok(report) => print!("{report}"),
        Err(e) => eprintln!("doctor: could not measure this machine: {e:#}"),
    }
    // franka-sim first: the HAL reads the robot before anything else.
    let _sim = match args.backend {
        DemoRobot::Mock | DemoRobot::R1LiteStandin => None,
        DemoRobot::FrankaSim => Some(start_franka_sim(&args.franka_sim_venv, &out, args.hal_core)?),
    };
    let standin = match args.backend {
        DemoRobot::R1LiteStandin => {
            anyhow::ensure!(profile.joints == 6, "the R1 Lite stand-in needs the R1 Lite's profile (--robot r1-lite)");
            let s = crate::standin::StandIn::start(&profile, &out)?;
            eprintln!("R1 Lite stand-in on DDS domain {} (log {})", s.domain, s.log.display());
            Some(s)
        }
        _ => None,
    };
    // The HAL's exit report as JSON next to marsd's summary (the backend benchmark reads it).
    std::fs::create_dir_all(&out).with_context(|| format!("creating {}", out.display()))?;
    let mut hal = hal_command(&exe, &cfg.profile, &robot, args.hal_core, args.backend, &out.join("hal.json"));
    if let (Some(tick), Some(ms)) = (args.hal_stall_at_tick, args.hal_stall_ms) {
        anyhow::ensure!(args.backend == DemoRobot::Mock, "--hal-stall-at-tick injects into the mock HAL only");
        hal.args(["--stall-at-tick", &tick.to_string(), "--stall-ms", &ms.to_string()]);
    }
    if let Some(s) = &standin {
        hal.args(["--backend", "ros2", "--ros-domain-id", &s.domain.to_string(), "--ros-localhost-only"]);
    }
    let mut hal = Reaped(hal.spawn().context("starting the HAL process")?);
    let mut scene = match &task {
        mars_runtime::task::HilTask::PushT(_) => {
            let mut scene = Command::new(&exe);
            scene.args(["scene", "--task"]).arg(&cfg.task).arg("--profile").arg(&cfg.profile).args(["--robot", &robot]);
            Some(Reaped(scene.spawn().context("starting the scene process")?))
        }
        mars_runtime::task::HilTask::Pick(_) => None,
    };
    let watch = crate::stall_watch::StallWatch::start(&robot, profile.period_s() * 1e3)?;
    let marsd = marsd_command(&exe, &args.marsd, &robot, args.backend);
    let (status, trip_line) = run_marsd(marsd)?;
    let watched = watch.finish();
    if status.code() == Some(i32::from(exit::TRIPPED)) {
        explain_trip(&out, trip_line.as_deref(), &watched, profile.period_s() * 1e3);
    }
    stop_like_systemd(&mut scene.iter_mut().chain([&mut hal]).collect::<Vec<_>>());
    drop(scene);
    drop(hal);
    Ok(status.code().map_or(exit::FAILURE, |c| c as u8))
}

/// `<exe> marsd` with the demo's overrides passed on, in the demo's namespace `robot`.
fn marsd_command(exe: &Path, args: &MarsdArgs, robot: &str, backend: DemoRobot) -> Command {
    let mut marsd = Command::new(exe);
    marsd.arg("marsd").arg("--config").arg(&args.config).args(["--robot", robot]);
    if let Some(n) = args.episodes {
        marsd.args(["--episodes", &n.to_string()]);
    }
    if let Some(o) = &args.out {
        marsd.arg("--out").arg(o);
    }
    if let Some(c) = &args.checkpoint {
        marsd.arg("--checkpoint").arg(c);
    }
    if let Some(d) = args.engine_step_delay_ms {
        marsd.args(["--engine-step-delay-ms", &d.to_string()]);
    }
    if let Some(r) = &args.record {
        marsd.arg("--record").arg(r);
    }
    if let Some(d) = args.record_writer_delay_ms {
        marsd.args(["--record-writer-delay-ms", &d.to_string()]);
    }
    if let (Some(dataset), Some(n)) = (&args.replay_actions, args.replay_episode) {
        marsd.arg("--replay-actions").arg(dataset).args(["--replay-episode", &n.to_string()]);
    }
    // franka-sim is a Python MuJoCo loop that pauses now and then on a loaded machine (it runs at 0.6–0.9× real
    // time); its states then come late all together, counted in its own cycles, with no command lost. A real FR3
    // never pauses, so on a robot marsd keeps its 20 ms.
    let gap = args.max_state_gap_ms.or((backend == DemoRobot::FrankaSim).then_some(FRANKA_SIM_STATE_GAP_MS));
    if let Some(g) = gap {
        marsd.args(["--max-state-gap-ms", &g.to_string()]);
    }
    marsd
}

/// Runs marsd to its end, its log passed through to the terminal (the first watchdog-trip line kept) and a
/// termination request to the demo passed on to it. Its exit status, and the trip line if any.
fn run_marsd(mut marsd: Command) -> anyhow::Result<(std::process::ExitStatus, Option<String>)> {
    // marsd's log passes through this process on its way to the terminal, so the trip line can be found.
    let mut marsd = Reaped(marsd.stderr(Stdio::piped()).spawn().context("starting marsd")?);
    let log = marsd.0.stderr.take().context("marsd's stderr")?;
    // A termination request to the demo (Ctrl-C reaches marsd too; `kill` or `timeout` only us) is passed on to
    // marsd, which ends its episodes; the demo then stops the HAL and the simulator as after a normal run.
    let marsd_pid = marsd.0.id() as libc::pid_t;
    let mut signals = signal_hook::iterator::Signals::new([signal_hook::consts::SIGTERM, signal_hook::consts::SIGINT])
        .context("registering the demo's termination handler")?;
    let signals_handle = signals.handle();
    let forwarder = std::thread::spawn(move || {
        for _ in signals.forever() {
            // SAFETY: plain kill(2) on our own child's pid (at worst already reaped: ESRCH).
            unsafe { libc::kill(marsd_pid, libc::SIGTERM) };
        }
    });
    let forward = std::thread::spawn(move || {
        let mut trip_line = None;
        for line in std::io::BufReader::new(log).lines().map_while(Result::ok) {
            eprintln!("{line}");
            if trip_line.is_none() && line.contains("watchdog trip") {
                trip_line = Some(line);
            }
        }
        trip_line
    });
    let status = marsd.0.wait().context("running marsd")?;
    signals_handle.close();
    let _ = forwarder.join();
    let trip_line = forward.join().unwrap_or(None);
    Ok((status, trip_line))
}

/// Stops the demo's helper processes the way systemd would: SIGTERM to each, then up to 5 s for them to end.
fn stop_like_systemd(children: &mut [&mut Reaped]) {
    for child in children.iter() {
        // SAFETY: plain kill(2) on our own child's pid.
        unsafe { libc::kill(child.0.id() as libc::pid_t, libc::SIGTERM) };
    }
    let deadline = Instant::now() + Duration::from_secs(5);
    for child in children.iter_mut() {
        while Instant::now() < deadline && matches!(child.0.try_wait(), Ok(None)) {
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// The HAL process as the demo starts it (`<exe> hal`, the same code as `mars-hal`): the robot's own control loop,
/// real-time above the servo loop it shares `core` with; its exit report as JSON to `report_json`; on franka-sim
/// with the fci backend.
pub fn hal_command(
    exe: &Path,
    profile: &Path,
    robot: &str,
    core: usize,
    backend: DemoRobot,
    report_json: &Path,
) -> Command {
    let mut hal = Command::new(exe);
    hal.args(["hal", "--profile"]).arg(profile).args(["--robot", robot, "--core", &core.to_string()]);
    hal.args(["--rt-priority", "85", "--report-json"]).arg(report_json);
    if backend == DemoRobot::FrankaSim {
        // franka-sim runs on an ordinary kernel (a real FR3 wants PREEMPT_RT: see README, "On a real FR3").
        hal.args(["--backend", "fci", "--robot-ip", "127.0.0.1", "--realtime", "ignore", "--late-commands", "applied"]);
    }
    hal
}

/// franka-sim for the demo, with the robot's reflexes on (20 lost cycles, motion limits) and a 3 cm object
/// between the hand's fingers (the task's mug, as far as the gripper can tell), installed first if it is not; on
/// the HAL's core (`FrankaSim::start` says why).
pub(crate) fn start_franka_sim(
    venv: &Path,
    out: &Path,
    hal_core: usize,
) -> anyhow::Result<crate::franka_sim::FrankaSim> {
    let installer = Path::new(".ci/franka-sim-venv");
    if !venv.join("bin/run-franka-sim-server").exists() && installer.exists() {
        eprintln!("installing franka-sim into {} ({})", venv.display(), installer.display());
        let ok = Command::new(installer).status().context("running .ci/franka-sim-venv")?.success();
        anyhow::ensure!(ok, ".ci/franka-sim-venv failed: franka-sim is not installed");
    }
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    let log = out.join("franka-sim.log");
    let args = ["--enforce-comm-constraints", "--enforce-motion-limits", "--gripper-object-width", "0.03"];
    let sim = crate::franka_sim::FrankaSim::start(venv, &args, &log, Duration::from_secs(60), Some(hal_core))?;
    eprintln!("franka-sim listening on 127.0.0.1:{} (log {})", crate::franka_sim::ROBOT_PORT, log.display());
    Ok(sim)
}

/// After a trip: if marsd stopped on a timing check, says whether this machine stalled around it, with the
/// evidence (the HAL's frame gap and the steal at that moment), rather than leaving only the watchdog's reason;
/// and writes the same to `trip.json` in `out`, for tools (the tests' rerun rule) rather than people.
fn explain_trip(out: &Path, trip_line: Option<&str>, watched: &crate::stall_watch::Watched, period_ms: f64) {
    let summary = std::fs::read_to_string(out.join("summary.json"))
        .ok()
        .and_then(|t| serde_json::from_str::<serde_json::Value>(&t).ok());
    let Some(trip) = summary.as_ref().and_then(|s| s["trip"].as_str().map(str::to_owned)) else { return };
    let Some(line) = trip_line else { return };
    let Some(trip_ns) = mars_runtime::report::stall::trip_time_from_log(line) else { return };
    let gaps: Vec<_> = watched.gaps.iter().copied().collect();
    let steal: Vec<_> = watched.steal.iter().copied().collect();
    let evidence = mars_runtime::report::stall::around_trip(trip_ns, &gaps, period_ms, &steal);
    let clock = line.get(11..23).unwrap_or("the trip");
    if let Some(m) = mars_runtime::report::stall::demo_message(&trip, clock, &evidence) {
        eprintln!("{m}");
    }
    let record = serde_json::json!({
        "trip": trip,
        "logged_at": clock,
        "timing_check": mars_runtime::report::stall::is_timing_trip(&trip),
        "machine_stalled": evidence.is_stall(),
        "evidence": evidence,
        "said": evidence.to_string(),
    });
    let path = out.join("trip.json");
    if let Err(e) = std::fs::write(&path, format!("{record:#}\n")) {
        eprintln!("could not write {}: {e}", path.display());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::Parser;

    #[derive(Parser)]
    struct Demo {
        #[command(flatten)]
        demo: DemoArgs,
    }

    /// The rigs' `DemoArgs::new(MarsdArgs::new(…))` is the demo a user gets with no options.
    #[test]
    fn the_constructors_are_the_command_lines_defaults() {
        let parsed = Demo::parse_from(["mars-hil"]).demo;
        let built = DemoArgs::new(MarsdArgs::new(DEFAULT_CONFIG.into()));
        assert_eq!(format!("{parsed:?}"), format!("{built:?}"));
    }
}
