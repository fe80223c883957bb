//! What marsd reports: the latency histograms the loops record without allocating ([`latency`]), the live view
//! for `marsd top` ([`live`]), the evidence of a machine stall ([`stall`]), the episode traces ([`traces`]) and the
//! PNG plots ([`plots`]); below, the exit report itself.
//!
//! What `marsd` reports at exit: success, modes and γ, K statistics, deadline misses, limit violations, frame
//! refusals and the latency percentile table — printed, and written as `summary.json` with the plots.

pub mod latency;
pub mod live;
pub mod plots;
pub mod stall;
pub mod traces;

use std::path::{Path, PathBuf};

use anyhow::Context;
use serde::Serialize;

use crate::config::DaemonConfig;
use crate::policy::remote::Side;
use crate::policy::{EpisodeResult, PolicyReport};
use crate::report::latency::{Channel, Totals};
use crate::rt::RtStatus;
use crate::servo::StopCause;
use crate::servo::frame::FrameCounts;
use crate::servo::servo_loop::ServoReport;
use mars_ipc::HeartbeatReport;

#[derive(Debug, Clone, Serialize)]
pub struct KStats {
    pub calls: u64,
    pub requested_mean: f64,
    pub used_mean: f64,
    pub used_max: f64,
    /// Calls whose K the deadline cut.
    pub capped: u64,
}

#[derive(Debug, Clone, Serialize)]
pub struct DeadlineMisses {
    /// Servo periods skipped because a tick ran a whole period late.
    pub servo_missed_periods: u64,
    /// Policy periods skipped because the policy loop woke a whole period late (its thread or the machine
    /// stalled): each chunk's deadline still comes from the clock.
    pub policy_missed_periods: u64,
    pub late_chunks: u64,
    /// The first late chunks' inference windows (all of them when `late_chunks` is at most
    /// [`crate::policy::LATE_CHUNKS_KEPT`]).
    pub late_chunk_times: Vec<crate::policy::LateChunk>,
    pub over_budget: u64,
    /// Actions of late chunks that were already due, dropped.
    pub actions_dropped: u64,
    /// Servo ticks with the chunk used up and no newer one.
    pub starved_ticks: u64,
    /// Commands that reached the HAL after its next tick, as marsd saw it in the following frame (the HAL's
    /// `last_command_seq` fell short of the command answering the previous frame).
    pub late_commands: u64,
    /// The same, as the HAL counted it (a command whose `state_seq` was not its newest frame), since the
    /// handshake.
    pub hal_late_commands: u64,
    /// Second commands answering one HAL frame, which the HAL did not follow: as the HAL counted them (0 from a
    /// servo that answers each frame once).
    pub hal_duplicate_commands: u64,
    /// Servo ticks that found no new state frame (it woke twice in one HAL period, or the robot's clock runs
    /// slower than marsd's) and so sent no command: one command per frame.
    pub frameless_ticks: u64,
}

/// Out-of-limit commands, wherever they were caught. Late commands are timing, not content: they are in
/// [`DeadlineMisses`].
#[derive(Debug, Clone, Serialize)]
pub struct LimitViolations {
    /// Commands that failed marsd's own final check (never sent).
    pub final_check: u64,
    /// Out-of-limit commands the HAL refused (under `limit_policy = "reject"`), from its state frames.
    pub hal_rejected: u64,
    /// Out-of-limit commands the HAL clamped into its limits (under `limit_policy = "clamp"`).
    pub hal_clamped: u64,
    /// Re-synchronisations to the HAL's applied setpoint after a late command (see `ServoCounters::resyncs`).
    pub resyncs: u64,
}

impl LimitViolations {
    /// Commands that exceeded a limit: refused by marsd's final check, refused by the HAL or clamped by it.
    pub fn total(&self) -> u64 {
        self.final_check + self.hal_rejected + self.hal_clamped
    }
}

/// The HAL's last resorts since the handshake (from its state frames): each should stay 0.
#[derive(Debug, Clone, Serialize)]
pub struct HalLastResorts {
    /// Ticks its position guard stopped a joint at a limit, breaking the acceleration/jerk limits on purpose.
    pub position_guard_hits: u64,
    /// Ticks no setpoint satisfied every limit and its filter took the middle of the empty interval.
    pub infeasible_steps: u64,
    /// Errors of its backend or ports (each brakes the arm to rest).
    pub backend_errors: u64,
}

/// marsd's side of the wire.
#[derive(Debug, Clone, Serialize)]
pub struct WireErrors {
    /// State frames refused for a wrong schema version.
    pub schema_refusals: u64,
    /// Receive calls iceoryx2 itself failed.
    pub receive_port_errors: u64,
    /// Command sends that failed (`watchdog.max_consecutive_send_errors` in a row trip).
    pub send_errors: u64,
    /// The liveness heartbeat (a non-RT thread that beats while the servo's tick counter advances).
    pub heartbeat: HeartbeatReport,
}

/// Facts about the run gathered outside the two loops' reports.
pub struct RunFacts {
    /// The real-time setup of each loop thread, as applied.
    pub realtime: Vec<RtStatus>,
    pub heartbeat: HeartbeatReport,
}

#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub robot: String,
    pub checkpoint: PathBuf,
    /// "finished", "signal" or "trip".
    pub stop: &'static str,
    pub trip: Option<String>,
    pub episodes: usize,
    pub successes: usize,
    pub success_rate: f64,
    pub modes: Vec<(String, usize)>,
    /// k · min_i n_i / Σ n_i over the k modes: 1 when successes split evenly, 0 if a mode is never used.
    pub gamma: f64,
    pub k: KStats,
    pub deadline_misses: DeadlineMisses,
    pub limit_violations: LimitViolations,
    pub hal_last_resorts: HalLastResorts,
    pub frames: FrameCounts,
    pub wire: WireErrors,
    pub commands_sent: u64,
    /// Heap allocations on the servo thread after warm-up, over `servo_ticks_counted` ticks (None: not
    /// measured). `system` must be 0; `pooled` must equal `servo_samples_sent` (iceoryx2's one block per sample).
    pub servo_allocations: Option<crate::alloc_count::Counts>,
    pub servo_ticks_counted: u64,
    /// Command samples sent over the same ticks.
    pub servo_samples_sent: u64,
    /// Whether SCHED_FIFO, the core pinning and mlockall were applied, per loop thread.
    pub realtime: Vec<RtStatus>,
    pub latency: Totals,
    /// A camera task's adopted chunks, timed (the first [`crate::servo::servo_loop::CAPTURE_SPANS_KEPT`]).
    pub capture_to_command: Vec<crate::servo::servo_loop::CaptureSpan>,
    /// The last `traces_kept` episodes' results (the counts above cover every episode).
    pub episode_results: Vec<EpisodeResult>,
    /// Episode traces dropped from the plot (only the last `traces_kept` are kept).
    pub traces_dropped: u64,
    /// A camera task: its frames as the policy judged them.
    pub camera: Option<crate::policy::CameraReport>,
    /// `[remote]`: the inference host's chunks, the local engine's takeovers and why.
    pub remote: Option<crate::policy::remote::RemoteReport>,
    /// The policy's actions across chunk handovers (before the servo's smoothing).
    pub handover_jerk: crate::policy::handover::HandoverJerk,
    /// A task acting on the table: references the servo's IK clamped or could not reach.
    pub effector: Option<crate::servo::effector::EffectorCounts>,
    /// `--record`: what the dataset got.
    pub record: Option<crate::record::RecordReport>,
    /// When marsd's main thread saw the trip (CLOCK_MONOTONIC ns): the moment a stall's evidence is sought around.
    pub trip_seen_ns: Option<u64>,
}

impl Summary {
    pub fn new(
        cfg: &DaemonConfig,
        mode_names: &[String],
        s: &ServoReport,
        p: &PolicyReport,
        latency: Totals,
        run: RunFacts,
    ) -> Self {
        let t = &p.episodes;
        let counts = t.mode_successes.iter().map(|&c| c as usize);
        let mean = |c: Channel| latency.stats(c).map_or(0.0, |s| s.mean);
        let (stop, trip) = match s.cause {
            Some(StopCause::Trip(t)) => ("trip", Some(t.to_string())),
            Some(StopCause::Signal) => ("signal", None),
            _ => ("finished", None),
        };
        Self {
            robot: cfg.robot.clone(),
            checkpoint: cfg.checkpoint.clone(),
            stop,
            trip,
            episodes: t.episodes as usize,
            successes: t.successes as usize,
            success_rate: t.success_rate(),
            modes: mode_names.iter().cloned().zip(counts).collect(),
            gamma: t.gamma(),
            k: KStats {
                calls: p.inferences,
                requested_mean: mean(Channel::KRequested),
                used_mean: mean(Channel::KUsed),
                used_max: latency.stats(Channel::KUsed).map_or(0.0, |s| s.max),
                capped: p.capped,
            },
            deadline_misses: DeadlineMisses {
                servo_missed_periods: s.missed_periods,
                policy_missed_periods: p.policy_missed_periods,
                late_chunks: p.late_chunks,
                late_chunk_times: p.late_chunk_times.clone(),
                over_budget: p.over_budget,
                actions_dropped: s.counters.actions_dropped,
                starved_ticks: s.counters.starved_ticks,
                late_commands: s.counters.late_commands,
                hal_late_commands: s.hal.late,
                hal_duplicate_commands: s.hal.duplicate,
                frameless_ticks: s.counters.frameless_ticks,
            },
            limit_violations: LimitViolations {
                final_check: s.counters.limit_violations,
                hal_rejected: s.hal.rejected,
                hal_clamped: s.hal.clamped,
                resyncs: s.counters.resyncs,
            },
            hal_last_resorts: HalLastResorts {
                position_guard_hits: s.hal.position_guard_hits,
                infeasible_steps: s.hal.infeasible_steps,
                backend_errors: s.hal.backend_errors,
            },
            frames: s.frames,
            wire: WireErrors {
                schema_refusals: s.schema_refusals,
                receive_port_errors: s.receive_port_errors,
                send_errors: s.send_errors,
                heartbeat: run.heartbeat,
            },
            commands_sent: s.counters.commands_sent,
            servo_allocations: s.allocations_after_warmup,
            servo_ticks_counted: s.ticks_counted,
            servo_samples_sent: s.samples_sent_after_warmup,
            realtime: run.realtime,
            latency,
            capture_to_command: s.capture_spans.clone(),
            episode_results: t.recent.iter().cloned().collect(),
            traces_dropped: p.traces_dropped,
            camera: p.camera.clone(),
            remote: p.remote.clone(),
            handover_jerk: p.handover_jerk,
            effector: s.effector,
            record: None,
            trip_seen_ns: None,
        }
    }

    /// Writes `summary.json`, `latency.txt` and the PNG plots into `dir`; returns the paths written.
    pub fn write(&self, dir: &Path, p: &PolicyReport, task: &crate::task::HilTask) -> anyhow::Result<Vec<PathBuf>> {
        let mut written = Vec::new();
        let mode_names: Vec<String> = self.modes.iter().map(|(name, _)| name.clone()).collect();
        let [jx, jy] = task.plot_joints();
        let json = dir.join("summary.json");
        std::fs::write(&json, serde_json::to_string_pretty(self)?)
            .with_context(|| format!("writing {}", json.display()))?;
        written.push(json);
        let table = dir.join("latency.txt");
        std::fs::write(&table, self.latency.to_string()).with_context(|| format!("writing {}", table.display()))?;
        written.push(table);
        written.push(self.latency.log.clone());
        type Draw<'a> = Box<dyn Fn(&Path) -> anyhow::Result<()> + 'a>;
        let plots: [(&str, Draw); 3] = [
            ("latency.png", Box::new(|path| crate::report::plots::plot_latency(&self.latency, path))),
            ("k.png", Box::new(|path| crate::report::plots::plot_k(&self.latency, path))),
            // The two joints in which the task's modes differ most.
            (
                "episodes.png",
                Box::new(|path| crate::report::plots::plot_episodes(&p.traces, &mode_names, jx, jy, path)),
            ),
        ];
        let mut plots = Vec::from(plots);
        if let crate::task::HilTask::PushT(t) = task {
            // The camera's view with the flange's path: the two routes show as two ways around the block.
            let size = t.cfg.camera.size;
            let (effector, camera) = (t.effector(), mars_tasks::push_t::render::Camera::push_t(size));
            let mode_names = mode_names.clone();
            let draw: Draw = Box::new(move |path| {
                let xy = |q: &[f64; mars_ipc::MAX_JOINTS]| effector.xy(&q[..7]);
                let pixel = |p: [f64; 2]| camera.pixel(p[0] as f32, p[1] as f32);
                crate::report::plots::plot_camera_strip(&p.traces, &mode_names, size, xy, pixel, path, 6)
            });
            plots.push(("camera_strip.png", draw));
        }
        for (name, draw) in plots {
            let path = dir.join(name);
            match draw(&path) {
                Ok(()) => written.push(path),
                Err(e) => tracing::warn!("could not draw {}: {e:#}", path.display()),
            }
        }
        Ok(written)
    }
}

impl std::fmt::Display for Summary {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        self.write_outcome(f)?;
        self.write_counts(f)?;
        self.write_threads_and_inputs(f)?;
        write!(f, "{}", self.latency)
    }
}

/// The report's sections, in the order `Display` writes them.
impl Summary {
    /// Episodes, successes and modes; why the run stopped; what was recorded.
    fn write_outcome(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let modes: Vec<String> = self.modes.iter().map(|(m, n)| format!("{m} {n}")).collect();
        writeln!(
            f,
            "marsd on {}: {} episodes, {} succeeded ({:.0} %), modes: {}, γ = {:.2}",
            self.robot,
            self.episodes,
            self.successes,
            100.0 * self.success_rate,
            modes.join(", "),
            self.gamma
        )?;
        match &self.trip {
            Some(t) => writeln!(f, "  STOPPED BY THE WATCHDOG: {t}")?,
            None => writeln!(f, "  stopped: {}", self.stop)?,
        }
        if let Some(r) = &self.record {
            writeln!(
                f,
                "  recorded {} episodes ({} frames) to {}; left out {} incomplete episodes, {} frames dropped{}",
                r.episodes_written,
                r.frames_written,
                r.path.display(),
                r.episodes_incomplete,
                r.frames_dropped,
                r.error.as_ref().map_or(String::new(), |e| format!("; {e}"))
            )?;
        }
        Ok(())
    }

    /// K, deadline misses, limits, the HAL's last resorts and the wire's errors.
    fn write_counts(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let k = &self.k;
        writeln!(
            f,
            "  K: {} calls, mean requested {:.2}, mean used {:.2}, max used {}, capped by the deadline {}",
            k.calls, k.requested_mean, k.used_mean, k.used_max, k.capped
        )?;
        let d = &self.deadline_misses;
        writeln!(
            f,
            "  deadline misses: servo periods missed {}, policy periods missed {}, late chunks {}, over budget {} (actions dropped {}, starved ticks {})",
            d.servo_missed_periods,
            d.policy_missed_periods,
            d.late_chunks,
            d.over_budget,
            d.actions_dropped,
            d.starved_ticks
        )?;
        let l = &self.limit_violations;
        writeln!(
            f,
            "  of {} commands: {} out of limits (final check {}, HAL rejected {}, HAL clamped {}); {} late for the HAL's tick (HAL's count {}), {} second answers to one frame, {} ticks with no new frame (nothing sent); re-synchronised {}",
            self.commands_sent,
            l.total(),
            l.final_check,
            l.hal_rejected,
            l.hal_clamped,
            d.late_commands,
            d.hal_late_commands,
            d.hal_duplicate_commands,
            d.frameless_ticks,
            l.resyncs
        )?;
        let h = &self.hal_last_resorts;
        writeln!(
            f,
            "  HAL last resorts: position guard hits {}, infeasible steps {}, backend errors {}",
            h.position_guard_hits, h.infeasible_steps, h.backend_errors
        )?;
        let w = &self.wire;
        writeln!(
            f,
            "  wire: schema refusals {}, receive port errors {}, send errors {}; heartbeats {} ({} errors, {} withheld while the servo did not advance)",
            w.schema_refusals,
            w.receive_port_errors,
            w.send_errors,
            w.heartbeat.beats,
            w.heartbeat.errors,
            w.heartbeat.withheld
        )?;
        Ok(())
    }

    /// The real-time threads, the servo's allocations, the camera, the end effector and the state frames.
    fn write_threads_and_inputs(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for rt in &self.realtime {
            writeln!(
                f,
                "  {} thread: core {:?}, SCHED_FIFO {:?}, mlockall {:?}{}",
                rt.thread,
                rt.core,
                rt.sched_fifo,
                rt.memory_locked,
                rt.pin_error.as_deref().map(|e| format!(", pinning failed: {e}")).unwrap_or_default()
            )?;
        }
        match self.servo_allocations {
            Some(n) => writeln!(
                f,
                "  servo thread after warm-up ({} ticks): {} system-allocator calls; {} blocks from the RT pool for {} samples sent (iceoryx2's per-sample bookkeeping, only inside send)",
                self.servo_ticks_counted, n.system, n.pooled, self.servo_samples_sent
            )?,
            None => writeln!(
                f,
                "  servo thread heap allocations: not measured (counting allocator not installed, or the loop ended \
                 within its warm-up after the handshake)"
            )?,
        }
        if let Some(c) = &self.camera {
            let n = &c.counts;
            writeln!(
                f,
                "  camera {}: {} frames used, {} superseded, {} refused (size {}, encoding {}, stale {}, other {}), {} inferences with no usable frame{}",
                c.service,
                n.used,
                n.superseded,
                n.refused(),
                n.size,
                n.encoding,
                n.stale,
                n.refused() - n.size - n.encoding - n.stale,
                c.no_frame,
                c.first_refusal.as_deref().map(|r| format!("; first refusal: {r}")).unwrap_or_default()
            )?;
        }
        let h = &self.handover_jerk;
        writeln!(
            f,
            "  chunk handovers: {}, the policy's jerk across them (action units/s³, before smoothing) mean {:.1} max {:.1}",
            h.handovers, h.mean_rad_s3, h.max_rad_s3
        )?;
        if let Some(r) = &self.remote {
            write_remote(f, r)?;
        }
        if let Some(e) = &self.effector {
            writeln!(
                f,
                "  end-effector references: {} outside the workspace (clamped), {} not reached by IK (closest used), {} not finite",
                e.outside_workspace, e.unreachable, e.not_finite
            )?;
        }
        let fr = &self.frames;
        writeln!(
            f,
            "  state frames: {} used, {} refused (wrong DOF {}, non-finite {}, sensor fault {}, stale {}, out of order {})",
            fr.used,
            fr.refused(),
            fr.wrong_dof,
            fr.non_finite,
            fr.sensor_fault,
            fr.stale,
            fr.out_of_order
        )?;
        Ok(())
    }
}

/// `[remote]`'s lines: whose chunks, why the host's were missed, the round trip and the host's clock.
fn write_remote(f: &mut std::fmt::Formatter<'_>, r: &crate::policy::remote::RemoteReport) -> std::fmt::Result {
    // `on_miss = "rest"`: the calls that got no chunk, the arm resting.
    let rested = if r.rested > 0 { format!(", {} with none (the arm at rest)", r.rested) } else { String::new() };
    writeln!(
        f,
        "  inference host {}: {} chunks from the host, {} from the local engine{rested} (timeout {}, no host {}, \
         expired {}, error {}, no time {}); round trip p50 {:.2} ms, p99 {:.2} ms, max {:.2} ms",
        r.key,
        r.host_chunks,
        r.local_chunks,
        r.timeouts,
        r.no_host,
        r.expired,
        r.errors,
        r.no_time,
        r.round_trip_ms_p50,
        r.round_trip_ms_p99,
        r.round_trip_ms_max
    )?;
    match &r.clock {
        Some(c) => writeln!(
            f,
            "  host clock − robot clock at start: {:.3} ms (± {:.3} ms; round trip min {:.3}, median {:.3} ms)",
            c.offset_ns as f64 * 1e-6,
            c.rtt_min_ns as f64 * 0.5e-6,
            c.rtt_min_ns as f64 * 1e-6,
            c.rtt_median_ns as f64 * 1e-6
        )?,
        None => writeln!(f, "  host clock: no host answered at start")?,
    }
    if let Some(a) = &r.auto_ask_ahead {
        let why = match (a.round_trip_ms, a.needed) {
            (None, _) => "no host answered at start".to_string(),
            (Some(rtt), Some(n)) if n > a.periods => {
                format!("the round trip of {rtt:.1} ms at start needs {n}, more than the chunk allows")
            }
            (Some(rtt), _) => format!("for the round trip of {rtt:.1} ms at start"),
        };
        writeln!(f, "  ask ahead (auto_ask_ahead): {} periods, {why}", a.periods)?;
    }
    for s in &r.switches {
        // A switch away from the host always has its reason; one back to the host has none.
        let why = s.miss.map_or_else(String::new, |m| format!(" ({m:?})"));
        let to = match s.to {
            Side::Host => "chunks from the host",
            Side::Local => "chunks from the local engine",
            Side::Rest => "no chunks, the arm at rest",
        };
        writeln!(f, "    episode {} period {}: {to}{why}", s.episode, s.period)?;
    }
    Ok(())
}
