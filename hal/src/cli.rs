//! The `mars-hal` command line as a library, so another binary can run the very same HAL process.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::Context;

use crate::fci::{FciParams, LateCommands, Realtime};
use crate::ros2::Ros2Params;
use crate::runner::{Report, RunOptions, run};
use crate::sim::SimBackend;
use mars_profile::faults::FaultConfig;
use mars_profile::{BackendKind, Profile};

/// The `mars-hal` command line (also flattened into `mars-hil hal`, which runs the same HAL process).
#[derive(clap::Args)]
pub struct HalArgs {
    /// Robot profile (TOML), e.g. configs/fr3.toml.
    #[arg(long)]
    pub profile: PathBuf,
    /// Robot id of the iceoryx2 service namespace; defaults to the profile's name.
    #[arg(long)]
    pub robot: Option<String>,
    /// Stop after this many seconds (default: until SIGINT/SIGTERM).
    #[arg(long)]
    pub duration_s: Option<f64>,
    /// Pin the loop to this CPU core.
    #[arg(long)]
    pub core: Option<usize>,
    /// Run the loop at this SCHED_FIFO priority (1–99) when the process may.
    #[arg(long, value_parser = clap::value_parser!(i32).range(1..=99))]
    pub rt_priority: Option<i32>,
    /// Do not lock the process's memory (mlockall); by default it is locked when the process may.
    #[arg(long)]
    pub no_lock_memory: bool,
    /// The robot behind the HAL; overrides the profile's `backend`.
    #[arg(long, value_enum)]
    pub backend: Option<BackendKind>,
    /// fci: the robot's address (its Control's IP, e.g. 172.16.0.2, or host:port); overrides `[fci] robot_ip`.
    #[arg(long)]
    pub robot_ip: Option<String>,
    /// fci: require a PREEMPT_RT kernel (enforce) or not (ignore, e.g. for franka-sim); overrides `[fci] realtime`.
    #[arg(long, value_enum)]
    pub realtime: Option<Realtime>,
    /// fci: what the robot does with a command that missed its cycle (dropped: a real FR3; applied: franka-sim);
    /// overrides `[fci] late_commands`.
    #[arg(long, value_enum)]
    pub late_commands: Option<LateCommands>,
    /// fci: drive no Franka Hand (the gripper width reads 0); overrides `[fci] gripper`.
    #[arg(long)]
    pub no_gripper: bool,
    /// ros2: the DDS domain (ROS_DOMAIN_ID, 0–232); overrides `[ros2] domain_id`.
    #[arg(long, value_parser = clap::value_parser!(u16).range(0..=232))]
    pub ros_domain_id: Option<u16>,
    /// ros2: discover and talk over this host's loopback only (a robot simulated here); sets `[ros2]
    /// localhost_only`.
    #[arg(long)]
    pub ros_localhost_only: bool,
    /// Also write the exit report as JSON to this file (timing quantiles, counters, the robot's side).
    #[arg(long)]
    pub report_json: Option<PathBuf>,
    #[command(flatten)]
    pub faults: FaultArgs,
}

/// Fault injection; each flag overrides the profile's `[sim.faults]` entry of the same name. Ticks count from
/// 0 (the frame with `seq` 1).
#[derive(clap::Args)]
pub struct FaultArgs {
    /// Drop each state frame with this probability.
    #[arg(long)]
    drop_probability: Option<f64>,
    /// Drop every N-th state frame.
    #[arg(long)]
    drop_every: Option<u64>,
    /// Publish every N-th state frame late, by --late-ms.
    #[arg(long)]
    late_every: Option<u64>,
    #[arg(long)]
    late_ms: Option<f64>,
    /// The position sensor freezes at this tick.
    #[arg(long)]
    freeze_at_tick: Option<u64>,
    /// Joint --nan-joint measures NaN from --nan-at-tick on.
    #[arg(long)]
    nan_joint: Option<usize>,
    #[arg(long)]
    nan_at_tick: Option<u64>,
    /// The loop sleeps --stall-ms once at this tick.
    #[arg(long)]
    stall_at_tick: Option<u64>,
    #[arg(long)]
    stall_ms: Option<f64>,
    /// The process aborts at this tick.
    #[arg(long)]
    crash_at_tick: Option<u64>,
    /// The backend's read fails (a transient error) for --read-error-ticks ticks from this tick.
    #[arg(long)]
    read_error_at_tick: Option<u64>,
    #[arg(long)]
    read_error_ticks: Option<u64>,
    /// The backend's apply fails (a transient error) for --apply-error-ticks ticks from this tick.
    #[arg(long)]
    apply_error_at_tick: Option<u64>,
    #[arg(long)]
    apply_error_ticks: Option<u64>,
    /// The backend fails for good from this tick (a fatal error: mars-hal brakes to rest and exits 1).
    #[arg(long)]
    fatal_at_tick: Option<u64>,
    /// Seed of the random drops.
    #[arg(long)]
    fault_seed: Option<u64>,
}

impl FaultArgs {
    fn apply(&self, f: &mut FaultConfig) {
        macro_rules! set {
            ($($field:ident),*) => { $(if let Some(v) = self.$field { f.$field = v; })* };
        }
        macro_rules! set_opt {
            ($($field:ident),*) => { $(if self.$field.is_some() { f.$field = self.$field; })* };
        }
        set!(drop_probability, drop_every, late_every, late_ms, stall_ms, read_error_ticks, apply_error_ticks);
        set_opt!(
            freeze_at_tick,
            nan_joint,
            nan_at_tick,
            stall_at_tick,
            crash_at_tick,
            read_error_at_tick,
            apply_error_at_tick,
            fatal_at_tick
        );
        if let Some(seed) = self.fault_seed {
            f.seed = seed;
        }
    }
}

/// `mars-hal fci-status`: reach an FCI robot and print one state; commands nothing.
#[derive(clap::Args)]
pub struct FciStatusArgs {
    /// The robot's address: its Control's IP (e.g. 172.16.0.2), or host:port (FCI's port is 1337).
    #[arg(long)]
    pub robot_ip: String,
    /// Give up after this many seconds (connecting and reading together).
    #[arg(long, default_value_t = 5.0)]
    pub timeout_s: f64,
}

/// Runs `mars-hal fci-status`, prints the robot's state (stdout) or why it could not be read (stderr), and returns
/// the exit status: 0 the state was read (whatever mode the robot is in: the output says), 1 the robot could not
/// be reached or read, 2 a bad argument (nothing was sent).
pub fn fci_status(args: FciStatusArgs) -> i32 {
    fci_command("fci-status", args.timeout_s, |timeout| {
        print!("{}", crate::fci::status::probe(&args.robot_ip, timeout)?);
        Ok(0)
    })
}

/// The shape both robot commands share: `--timeout-s` checked (2 when bad, nothing sent), then `run`'s exit
/// status, or its error on stderr with 2 for a bad address (nothing sent) and 1 for anything else.
fn fci_command(name: &str, timeout_s: f64, run: impl FnOnce(Duration) -> Result<i32, crate::fci::FciError>) -> i32 {
    if !(timeout_s.is_finite() && timeout_s > 0.0 && timeout_s <= 3600.0) {
        eprintln!("mars-hal {name}: --timeout-s must be a number of seconds in (0, 3600], got {timeout_s}");
        return 2;
    }
    match run(Duration::from_secs_f64(timeout_s)) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("mars-hal {name}: {e}");
            if matches!(e, crate::fci::FciError::BadAddress { .. }) { 2 } else { 1 }
        }
    }
}

/// `mars-hal recover`: clear a reflex on a robot no HAL is driving.
#[derive(clap::Args)]
pub struct RecoverArgs {
    /// The robot's address: its Control's IP (e.g. 172.16.0.2), or host:port.
    #[arg(long)]
    pub robot_ip: String,
    /// Give up on each step (connect, read, recover) after this many seconds.
    #[arg(long, default_value_t = 10.0)]
    pub timeout_s: f64,
}

/// Runs `mars-hal recover`: exit 0 when the robot is ready afterwards (printed), 1 when it could not be reached
/// or is still not ready, 2 for a bad argument.
pub fn recover(args: RecoverArgs) -> i32 {
    fci_command("recover", args.timeout_s, |timeout| {
        let (needed, status) = crate::fci::recover::recover(&args.robot_ip, timeout)?;
        println!("{}", if needed { "error recovery ran" } else { "no error to recover from" });
        print!("{status}");
        let ready = status.status.current_errors.is_empty()
            && !matches!(status.status.mode, franka::RobotMode::Reflex | franka::RobotMode::UserStopped);
        Ok(if ready { 0 } else { 1 })
    })
}

/// Runs the HAL process loop with the profile's backend (or `--backend`) until the duration ends, SIGINT/SIGTERM,
/// a fatal backend error or a lost robot; returns its report.
pub fn run_hal(args: HalArgs) -> anyhow::Result<Report> {
    let mut profile = Profile::load(&args.profile)?;
    args.faults.apply(&mut profile.sim.faults);
    if let Some(b) = args.backend {
        profile.backend = b;
    }
    profile.validate()?;
    // Each driver reads its own table of the profile; the options override it, and it is checked before anything
    // moves (only the backend that runs: a sim profile may carry an unused table).
    let mut fci = FciParams::of(&profile)?;
    if let Some(ip) = &args.robot_ip {
        fci.robot_ip = Some(ip.clone());
    }
    if let Some(rt) = args.realtime {
        fci.realtime = rt;
    }
    if args.no_gripper {
        fci.gripper = false;
    }
    if let Some(l) = args.late_commands {
        fci.late_commands = l;
    }
    let mut ros2 = Ros2Params::of(&profile)?;
    if let Some(d) = args.ros_domain_id {
        ros2.domain_id = d;
    }
    if args.ros_localhost_only {
        ros2.localhost_only = true;
    }
    match profile.backend {
        BackendKind::Sim => {}
        BackendKind::Fci => fci.check(&profile)?,
        BackendKind::Ros2 => ros2.check(&profile)?,
    }
    if profile.sim.faults.any() {
        tracing::warn!(faults = ?profile.sim.faults, "fault injection is on");
    }
    let duration = match args.duration_s {
        Some(d) => Some(Duration::try_from_secs_f64(d).ok().filter(|t| !t.is_zero()).with_context(|| {
            format!("--duration-s must be a positive number of seconds (that fits a Duration), got {d}")
        })?),
        None => None,
    };
    let opts = RunOptions {
        robot: args.robot.unwrap_or_else(|| profile.name.clone()),
        duration,
        core: args.core,
        rt_priority: args.rt_priority,
        lock_memory: !args.no_lock_memory,
        stop: None,
        // A real robot is released only at rest; the sim ends at once (its tests count on it).
        brake_before_exit: profile.backend != BackendKind::Sim,
    };
    let report = match profile.backend {
        BackendKind::Sim => run(&profile, &mut SimBackend::new(&profile), &opts)?,
        BackendKind::Fci => {
            anyhow::ensure!(!profile.sim.faults.any(), "fault injection is a sim backend feature; not with fci");
            let Some(addr) = fci.robot_ip.clone() else {
                anyhow::bail!("backend fci needs the robot's address: --robot-ip or [fci] robot_ip in the profile");
            };
            crate::fci::drive::run(&profile, &fci, &addr, &opts)?
        }
        BackendKind::Ros2 => {
            anyhow::ensure!(!profile.sim.faults.any(), "fault injection is a sim backend feature; not with ros2");
            crate::ros2::drive::run(&profile, &ros2, &opts)?
        }
    };
    // The run is over and the arm at rest: a file that cannot be written costs only the file.
    if let Some(path) = &args.report_json
        && let Err(e) = crate::report_json::write(&report, path)
    {
        tracing::warn!("could not write the JSON report: {e:#}");
    }
    Ok(report)
}

/// Prints the outcome of [`run_hal`] and returns the process's exit status: 0 after a duration or a termination
/// request, 1 after a fatal backend error (at rest) or any other failure, 2 when it refused to start (nothing
/// was commanded).
pub fn report_and_exit_code(outcome: anyhow::Result<Report>) -> i32 {
    match outcome {
        Ok(report) => {
            println!("{report}");
            use crate::runner::Ended;
            if matches!(report.ended, Ended::BackendFailed(_) | Ended::ConnectionLost | Ended::NotTakenOver(_)) {
                1
            } else {
                0
            }
        }
        Err(e) => {
            eprintln!("mars-hal: {e:#}");
            let refused = e.downcast_ref::<crate::control::StartError>().is_some()
                || e.downcast_ref::<crate::fci::drive::FciStartRefusal>().is_some();
            if refused { 2 } else { 1 }
        }
    }
}
