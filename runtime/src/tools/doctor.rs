//! `marsd doctor`: a preflight that measures this machine in a few seconds and says plainly what a run can
//! expect and how to improve it. It wakes a thread at the servo rate and priority (SCHED_FIFO, pinned to the
//! servo core, memory locked where allowed) on absolute deadlines, as the servo loop does, and records how late
//! each wake-up was; it samples the hypervisor's steal time over the same window; and it reads the settings that
//! decide real-time behaviour (RT limits and capabilities, PREEMPT_RT, CPU governor, isolated cores).
//!
//! The verdict is a pure function of those measurements ([`verdict`]), so its wording is tested on synthetic
//! machines; the measurement itself has no pass mark (it is what the machine did).

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use anyhow::Context;
use serde::Serialize;

use crate::rt::{self, Outcome, Ticker};

#[derive(clap::Args, Debug, Clone)]
pub struct DoctorArgs {
    /// Daemon configuration (TOML): the servo core, priority and the watchdog budget come from it.
    #[arg(long, default_value = "configs/marsd.toml")]
    pub config: PathBuf,
    /// How long to measure wake-ups (s).
    #[arg(long, default_value_t = 3.0)]
    pub seconds: f64,
    /// Where to write doctor.json (default: the config's `out`).
    #[arg(long)]
    pub out: Option<PathBuf>,
}

/// How late a thread at the servo's rate and priority woke, over a few seconds.
#[derive(Debug, Clone, Serialize)]
pub struct Wakeups {
    pub seconds: f64,
    pub period_us: f64,
    pub priority: i32,
    pub core: Option<usize>,
    pub pin_error: Option<String>,
    pub sched_fifo: Outcome,
    pub memory_locked: Outcome,
    pub wakeups: u64,
    /// Whole periods skipped because a wake-up came more than a period late.
    pub missed_periods: u64,
    /// Lateness past the deadline each wake-up was for, counting skipped periods (µs).
    pub late_p50_us: f64,
    pub late_p99_us: f64,
    pub late_max_us: f64,
    /// CPU time the hypervisor took during the measurement, all CPUs (ms); `None` without /proc/stat steal.
    pub steal_ms: Option<f64>,
}

/// The settings of this machine that decide real-time behaviour.
#[derive(Debug, Clone, Serialize)]
pub struct Machine {
    pub cpus: usize,
    /// Soft RLIMIT_RTPRIO ("unlimited" or a number).
    pub rlimit_rtprio: String,
    /// Soft RLIMIT_MEMLOCK in bytes ("unlimited" or a number).
    pub rlimit_memlock: String,
    /// CAP_SYS_NICE in the effective set (SCHED_FIFO whatever RLIMIT_RTPRIO says).
    pub cap_sys_nice: bool,
    /// CAP_IPC_LOCK in the effective set (mlockall whatever RLIMIT_MEMLOCK says).
    pub cap_ipc_lock: bool,
    /// `/sys/kernel/realtime` is 1, or `uname -v` says PREEMPT_RT.
    pub preempt_rt: bool,
    pub kernel_version: String,
    /// The scaling governor of each CPU; `None` where cpufreq is absent (usual on a VM).
    pub governors: Option<Vec<String>>,
    /// `/sys/devices/system/cpu/isolated` ("" when none).
    pub isolated: String,
}

/// What the daemon tolerates, from its config and the robot profile.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Budget {
    pub period_ms: f64,
    /// watchdog.max_state_gap_ms: marsd trips on a longer wait for a usable frame.
    pub max_state_gap_ms: f64,
    /// The HAL's command_timeout_ms: the HAL holds on a longer wait for a command.
    pub command_timeout_ms: f64,
    pub servo_core: Option<usize>,
}

impl Budget {
    /// The shortest stall a run trips on.
    pub fn stall_ms(&self) -> f64 {
        self.max_state_gap_ms.min(self.command_timeout_ms)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
pub enum Level {
    Good,
    MissedPeriods,
    OccasionalTrips,
    Trips,
}

#[derive(Debug, Clone, Serialize)]
pub struct Verdict {
    pub level: Level,
    /// What a run can expect, one sentence.
    pub expect: String,
    /// How to improve it, one line each.
    pub advice: Vec<String>,
}

/// Everything `doctor` found (doctor.json).
#[derive(Debug, Clone, Serialize)]
pub struct Report {
    pub wakeups: Wakeups,
    pub machine: Machine,
    pub budget: Budget,
    pub verdict: Verdict,
}

/// The verdict on a machine: what to expect from the worst wake-up against the stall budget, and advice for
/// each setting that is not as a robot PC should have it.
pub fn verdict(w: &Wakeups, m: &Machine, b: &Budget) -> Verdict {
    let worst = w.late_max_us * 1e-3;
    let budget = b.stall_ms();
    let over = format!(
        "the worst wake-up in {:.0} s was {worst:.1} ms ({:.0} % of the {budget:.0} ms stall budget: \
         watchdog.max_state_gap_ms / the HAL's command_timeout_ms), p99 {:.0} µs",
        w.seconds,
        100.0 * worst / budget,
        w.late_p99_us
    );
    let (level, expect) = if worst >= budget {
        (Level::Trips, format!("expect watchdog trips: {over}"))
    } else if worst >= budget / 4.0 {
        (Level::OccasionalTrips, format!("expect occasional watchdog trips (longer runs meet longer stalls): {over}"))
    } else if w.missed_periods > 0 || worst >= b.period_ms {
        (Level::MissedPeriods, format!("expect missed servo periods but no watchdog trips: {over}"))
    } else {
        (Level::Good, format!("good: {over}"))
    };
    let mut advice = Vec::new();
    if let Some(s) = w.steal_ms.filter(|s| *s > 0.0) {
        advice.push(format!(
            "the hypervisor took {s:.0} ms of CPU during the measurement ({:.1} % of {} CPUs): this VM shares its \
             cores; a VM with dedicated cores, or a bare-metal PC, removes these stalls",
            100.0 * s / (w.seconds * 1e3 * m.cpus.max(1) as f64),
            m.cpus
        ));
    }
    if matches!(w.sched_fifo, Outcome::Denied { .. } | Outcome::Failed { .. }) {
        advice.push(format!(
            "SCHED_FIFO {} was refused (RLIMIT_RTPRIO {}, CAP_SYS_NICE {}): `LimitRTPRIO=95` in the systemd unit, \
             `setcap cap_sys_nice+ep` on the binaries, or `--ulimit rtprio=95` for a container",
            w.priority,
            m.rlimit_rtprio,
            yes_no(m.cap_sys_nice)
        ));
    }
    if matches!(w.memory_locked, Outcome::Denied { .. } | Outcome::Failed { .. }) {
        advice.push(format!(
            "mlockall was refused (RLIMIT_MEMLOCK {}, CAP_IPC_LOCK {}): a page fault can stall a loop; \
             `LimitMEMLOCK=infinity` in the unit or `--ulimit memlock=-1` for a container",
            m.rlimit_memlock,
            yes_no(m.cap_ipc_lock)
        ));
    }
    if let Some(e) = &w.pin_error {
        advice.push(format!("the servo core could not be pinned ({e}): check servo.core against `nproc`"));
    }
    if !m.preempt_rt {
        advice.push(format!(
            "the kernel is not PREEMPT_RT ({}): a PREEMPT_RT kernel (e.g. Ubuntu's linux-realtime) bounds wake-ups \
             to tens of µs on a tuned PC",
            m.kernel_version
        ));
    }
    match &m.governors {
        None => advice.push(
            "no CPU frequency scaling here (/sys/devices/system/cpu/cpu*/cpufreq absent): usual on a VM, where the \
             host sets the clock"
                .into(),
        ),
        Some(g) if g.iter().any(|g| g != "performance") => advice.push(format!(
            "CPU governor {}: set `performance` (`cpupower frequency-set -g performance`) so a core never wakes slow",
            g.join(",")
        )),
        Some(_) => {}
    }
    let core = b.servo_core.map_or("<servo core>".to_string(), |c| c.to_string());
    if m.isolated.trim().is_empty() {
        advice.push(format!(
            "no isolated cores: boot with `isolcpus={core} nohz_full={core} rcu_nocbs={core}` so only the servo \
             loop and the HAL run on the servo core"
        ));
    }
    if m.cpus < 3 {
        advice.push(format!(
            "{} CPUs: the HAL, the servo loop and the policy share them; a robot PC should give each a core",
            m.cpus
        ));
    }
    Verdict { level, expect, advice }
}

fn yes_no(b: bool) -> &'static str {
    if b { "yes" } else { "no" }
}

/// Wakes a thread every `period` for `seconds` on absolute deadlines at SCHED_FIFO `priority`, pinned to
/// `core`, with memory locked if `lock_memory` (unlocked again afterwards: the caller may be a tool process
/// with a small RLIMIT_MEMLOCK). Returns the lateness statistics and the steal over the same window.
pub fn measure_wakeups(
    seconds: f64,
    period: Duration,
    core: Option<usize>,
    priority: i32,
    lock_memory: bool,
) -> anyhow::Result<Wakeups> {
    anyhow::ensure!(seconds.is_finite() && seconds > 0.0 && seconds <= 600.0, "--seconds must be in (0, 600]");
    let n = (seconds / period.as_secs_f64()).ceil() as usize;
    std::thread::Builder::new()
        .name("doctor".into())
        .spawn(move || {
            let status = rt::setup_realtime("doctor", core, Some(priority), lock_memory);
            // Preallocated: the loop below records without allocating, as a servo tick must.
            let mut late_us = Vec::with_capacity(n);
            let steal0 = crate::report::stall::steal_ms();
            let mut ticker = Ticker::new(period);
            let mut missed = 0;
            while late_us.len() + (missed as usize) < n {
                let w = ticker.wait();
                missed += w.missed;
                late_us.push((w.late_ns + w.missed * ticker.period_ns()) as f64 * 1e-3);
            }
            let steal = steal0.zip(crate::report::stall::steal_ms()).map(|(a, b)| b - a);
            if status.memory_locked == Outcome::Applied {
                // SAFETY: munlockall has no preconditions; it undoes this process's mlockall.
                unsafe { libc::munlockall() };
            }
            late_us.sort_by(f64::total_cmp);
            let pct = |p: f64| late_us[((late_us.len() - 1) as f64 * p).round() as usize];
            Wakeups {
                seconds,
                period_us: period.as_secs_f64() * 1e6,
                priority,
                core: status.core,
                pin_error: status.pin_error,
                sched_fifo: status.sched_fifo,
                memory_locked: status.memory_locked,
                wakeups: late_us.len() as u64,
                missed_periods: missed,
                late_p50_us: pct(0.5),
                late_p99_us: pct(0.99),
                late_max_us: pct(1.0),
                steal_ms: steal,
            }
        })
        .context("starting the measuring thread")?
        .join()
        .map_err(|_| anyhow::anyhow!("the measuring thread panicked"))
}

/// Reads this machine's real-time settings.
pub fn inspect_machine() -> Machine {
    let read = |p: &str| std::fs::read_to_string(p).map(|s| s.trim().to_string());
    let cap_eff = read("/proc/self/status").ok().and_then(|s| {
        let hex = s.lines().find_map(|l| l.strip_prefix("CapEff:"))?.trim().to_string();
        u64::from_str_radix(&hex, 16).ok()
    });
    let has_cap = |bit: u32| cap_eff.is_some_and(|c| c & (1 << bit) != 0);
    let kernel_version = uname_version();
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    let mut governors = Vec::new();
    for cpu in 0.. {
        match read(&format!("/sys/devices/system/cpu/cpu{cpu}/cpufreq/scaling_governor")) {
            Ok(g) => governors.push(g),
            Err(_) if std::path::Path::new(&format!("/sys/devices/system/cpu/cpu{cpu}")).exists() => {}
            Err(_) => break,
        }
    }
    Machine {
        cpus,
        rlimit_rtprio: rlimit_text(libc::RLIMIT_RTPRIO),
        rlimit_memlock: rlimit_text(libc::RLIMIT_MEMLOCK),
        // CAP_SYS_NICE is capability 23, CAP_IPC_LOCK 14 (linux/capability.h).
        cap_sys_nice: has_cap(23),
        cap_ipc_lock: has_cap(14),
        preempt_rt: read("/sys/kernel/realtime").is_ok_and(|s| s == "1") || kernel_version.contains("PREEMPT_RT"),
        kernel_version,
        governors: (!governors.is_empty()).then_some(governors),
        isolated: read("/sys/devices/system/cpu/isolated").unwrap_or_default(),
    }
}

fn uname_version() -> String {
    // SAFETY: uname fills the zeroed struct; its fields are NUL-terminated C strings.
    unsafe {
        let mut u: libc::utsname = std::mem::zeroed();
        if libc::uname(&mut u) != 0 {
            return "unknown".into();
        }
        std::ffi::CStr::from_ptr(u.version.as_ptr()).to_string_lossy().into_owned()
    }
}

fn rlimit_text(resource: libc::__rlimit_resource_t) -> String {
    let mut lim = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: getrlimit fills the struct.
    if unsafe { libc::getrlimit(resource, &mut lim) } != 0 {
        return "unknown".into();
    }
    if lim.rlim_cur == libc::RLIM_INFINITY { "unlimited".into() } else { lim.rlim_cur.to_string() }
}

/// Measures for `seconds` at the servo's settings of `config`, judges, and writes `doctor.json` into `out`.
pub fn run(config: &Path, seconds: f64, out: Option<&Path>) -> anyhow::Result<Report> {
    let cfg = crate::config::DaemonConfig::load(config)?;
    let profile = mars_profile::Profile::load(&cfg.profile)
        .with_context(|| format!("loading the profile {}", cfg.profile.display()))?;
    let budget = Budget {
        period_ms: profile.period_s() * 1e3,
        max_state_gap_ms: cfg.watchdog.max_state_gap_ms,
        command_timeout_ms: profile.command_timeout_ms,
        servo_core: cfg.servo.core,
    };
    // Its wake-up measurement is a real-time thread on the servo core: not beside another real-time rig.
    let _rig = crate::rt::rig_lock::rt_rig_lock().context("taking the real-time rig lock")?;
    let period = Duration::from_secs_f64(profile.period_s());
    let wakeups = measure_wakeups(seconds, period, cfg.servo.core, cfg.servo.priority, cfg.servo.lock_memory)?;
    let machine = inspect_machine();
    let verdict = verdict(&wakeups, &machine, &budget);
    let report = Report { wakeups, machine, budget, verdict };
    let dir = out.unwrap_or(&cfg.out);
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let json = dir.join("doctor.json");
    std::fs::write(&json, serde_json::to_string_pretty(&report)?)
        .with_context(|| format!("writing {}", json.display()))?;
    Ok(report)
}

impl fmt::Display for Report {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let w = &self.wakeups;
        let m = &self.machine;
        writeln!(
            f,
            "doctor: {} wake-ups at {:.0} µs, SCHED_FIFO {} ({:?}), core {:?}, mlockall {:?}: late p50 {:.0} µs, \
             p99 {:.0} µs, max {:.0} µs, {} periods missed; steal {}",
            w.wakeups,
            w.period_us,
            w.priority,
            w.sched_fifo,
            w.core,
            w.memory_locked,
            w.late_p50_us,
            w.late_p99_us,
            w.late_max_us,
            w.missed_periods,
            w.steal_ms.map_or("unknown".into(), |s| format!("{s:.0} ms")),
        )?;
        writeln!(
            f,
            "doctor: {} CPUs, isolated [{}], PREEMPT_RT {}, governor {}, RLIMIT_RTPRIO {}, RLIMIT_MEMLOCK {}",
            m.cpus,
            m.isolated,
            yes_no(m.preempt_rt),
            m.governors.as_ref().map_or("absent".into(), |g| g.join(",")),
            m.rlimit_rtprio,
            m.rlimit_memlock
        )?;
        writeln!(f, "doctor: {}", self.verdict.expect)?;
        for a in &self.verdict.advice {
            writeln!(f, "doctor:   - {a}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn wakeups(max_ms: f64, missed: u64, steal_ms: Option<f64>) -> Wakeups {
        Wakeups {
            seconds: 3.0,
            period_us: 1000.0,
            priority: 80,
            core: Some(1),
            pin_error: None,
            sched_fifo: Outcome::Applied,
            memory_locked: Outcome::Applied,
            wakeups: 3000,
            missed_periods: missed,
            late_p50_us: 20.0,
            late_p99_us: 80.0,
            late_max_us: max_ms * 1e3,
            steal_ms,
        }
    }

    fn robot_pc() -> Machine {
        Machine {
            cpus: 8,
            rlimit_rtprio: "95".into(),
            rlimit_memlock: "unlimited".into(),
            cap_sys_nice: false,
            cap_ipc_lock: false,
            preempt_rt: true,
            kernel_version: "#1 SMP PREEMPT_RT".into(),
            governors: Some(vec!["performance".into(); 8]),
            isolated: "1".into(),
        }
    }

    const BUDGET: Budget =
        Budget { period_ms: 1.0, max_state_gap_ms: 20.0, command_timeout_ms: 20.0, servo_core: Some(1) };

    #[test]
    fn a_tuned_robot_pc_is_good_with_no_advice() {
        let v = verdict(&wakeups(0.08, 0, Some(0.0)), &robot_pc(), &BUDGET);
        assert_eq!(v.level, Level::Good);
        assert!(v.expect.starts_with("good: the worst wake-up in 3 s was 0.1 ms"), "{}", v.expect);
        assert!(v.advice.is_empty(), "{:?}", v.advice);
    }

    #[test]
    fn the_level_follows_the_worst_wake_up_against_the_stall_budget() {
        let level = |max_ms, missed| verdict(&wakeups(max_ms, missed, None), &robot_pc(), &BUDGET).level;
        assert_eq!(level(0.9, 0), Level::Good);
        assert_eq!(level(0.9, 1), Level::MissedPeriods);
        assert_eq!(level(2.0, 1), Level::MissedPeriods);
        assert_eq!(level(5.0, 4), Level::OccasionalTrips);
        assert_eq!(level(19.9, 19), Level::OccasionalTrips);
        assert_eq!(level(20.0, 20), Level::Trips);
        // The budget is the shorter of the two timeouts.
        let tight = Budget { command_timeout_ms: 8.0, ..BUDGET };
        assert_eq!(verdict(&wakeups(9.0, 8, None), &robot_pc(), &tight).level, Level::Trips);
        let v = verdict(&wakeups(12.3, 12, None), &robot_pc(), &BUDGET);
        assert!(
            v.expect.starts_with("expect occasional watchdog trips")
                && v.expect.contains("the worst wake-up in 3 s was 12.3 ms (62 % of the 20 ms stall budget"),
            "{}",
            v.expect
        );
    }

    #[test]
    fn a_noisy_untuned_vm_gets_advice_for_every_setting() {
        let vm = Machine {
            cpus: 2,
            rlimit_rtprio: "0".into(),
            rlimit_memlock: "8388608".into(),
            preempt_rt: false,
            kernel_version: "#1 SMP PREEMPT_DYNAMIC".into(),
            governors: None,
            isolated: String::new(),
            ..robot_pc()
        };
        let w = Wakeups {
            sched_fifo: Outcome::Denied { errno: libc::EPERM },
            memory_locked: Outcome::Denied { errno: libc::ENOMEM },
            ..wakeups(30.0, 29, Some(270.0))
        };
        let v = verdict(&w, &vm, &BUDGET);
        assert_eq!(v.level, Level::Trips);
        let all = v.advice.join("\n");
        for needle in [
            "the hypervisor took 270 ms of CPU during the measurement (4.5 % of 2 CPUs)",
            "LimitRTPRIO=95",
            "RLIMIT_RTPRIO 0",
            "LimitMEMLOCK=infinity",
            "not PREEMPT_RT (#1 SMP PREEMPT_DYNAMIC)",
            "cpufreq absent): usual on a VM",
            "isolcpus=1 nohz_full=1 rcu_nocbs=1",
            "2 CPUs",
        ] {
            assert!(all.contains(needle), "no {needle:?} in:\n{all}");
        }
        let slow = Machine { governors: Some(vec!["performance".into(), "powersave".into()]), ..robot_pc() };
        let v = verdict(&wakeups(0.1, 0, None), &slow, &BUDGET);
        assert_eq!(v.advice.len(), 1);
        assert!(v.advice[0].contains("governor performance,powersave: set `performance`"), "{:?}", v.advice);
    }
}
