//! What the three threads share, all lock-free and preallocated: the servo loop never waits on the others.
//!
//! - policy → servo: the newest chunk (a triple buffer) and [`Request`]s (an `rtrb` ring: the policy thread is
//!   its only producer, the servo thread its only consumer; wait-free on both ends, so the servo's pop never
//!   spins on a preempted policy thread);
//! - servo → policy: the newest usable state, [`Observed`] (a triple buffer);
//! - servo → everyone: [`Status`] atomics (phase, counters, the trip reason), which the daemon's notifier
//!   thread reads to decide whether systemd's watchdog gets its ping.

use std::sync::atomic::{AtomicBool, AtomicU8, AtomicU32, AtomicU64, Ordering};

use mars_ipc::MAX_JOINTS;

use crate::servo::watchdog::Trip;

/// What the policy thread (the episode coordinator) asks of the servo loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Request {
    /// End whatever runs, then move jerk-limited to `pose` (joints) with `gripper`, and report `Ready`.
    MoveTo { episode: u64, pose: [f64; MAX_JOINTS], gripper: f64 },
    /// All episodes done: come to rest, hand the HAL a hold command, and finish.
    Finish,
    /// A fault found outside the servo loop (late chunks, inference over budget, engine error).
    Trip(Trip),
}

/// The servo loop's view of the robot, for the policy thread.
#[derive(Debug, Clone, Copy, Default)]
pub struct Observed {
    /// Sequence number of the state frame (0: none yet).
    pub seq: u64,
    pub timestamp_ns: u64,
    pub position: [f64; MAX_JOINTS],
    pub gripper: f64,
    /// The frame's HAL status bits, fault bits and hold reason (`mars_ipc::status`, `mars_ipc::fault`,
    /// `HoldReason`), for the recording.
    pub status: u32,
    pub fault: u32,
    pub hold_reason: u32,
}

/// The servo loop's phase, as seen from outside.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[repr(u8)]
pub enum Phase {
    /// No usable state frame yet.
    WaitingForHal = 0,
    /// Holding where the robot is; waiting for a request.
    Idle = 1,
    /// Moving to an episode's start pose.
    Resetting = 2,
    /// At the start pose, holding; the policy may start.
    Ready = 3,
    /// Following the policy's chunks.
    Running = 4,
    /// Jerk-limited stop in progress (finish, signal or trip).
    Stopping = 5,
    /// At rest, hold command sent; the loop has ended.
    Finished = 6,
}

impl Phase {
    /// The phase a number (`Phase as u8`, as in a live frame) stands for; unknown numbers read as waiting.
    pub fn from_u8(v: u8) -> Self {
        match v {
            1 => Self::Idle,
            2 => Self::Resetting,
            3 => Self::Ready,
            4 => Self::Running,
            5 => Self::Stopping,
            6 => Self::Finished,
            _ => Self::WaitingForHal,
        }
    }
}

/// Counters and flags the servo publishes every tick (relaxed stores; readers want a recent value, not a
/// consistent snapshot).
#[derive(Default)]
pub struct Status {
    phase: AtomicU8,
    /// The episode the phase refers to.
    pub episode: AtomicU64,
    pub ticks: AtomicU64,
    /// Servo periods missed so far (the ticker's total), so the policy loop can say how many fell in an episode.
    pub missed_periods: AtomicU64,
    /// Bumped by the policy thread on every pass of its loops (also while it waits), so the daemon can tell
    /// a live policy thread from a stuck one.
    pub policy_beats: AtomicU64,
    /// [`Trip::code`] of the trip that stopped the loop; 0 = none.
    trip: AtomicU32,
    /// Set by the daemon on SIGTERM/SIGINT; the servo loop then stops safely.
    pub stop_requested: AtomicBool,
    /// The HAL handshake happened: a valid state frame of the right robot arrived.
    pub hal_ready: AtomicBool,
    /// When the daemon's main thread saw the trip (CLOCK_MONOTONIC ns; 0 = none), for the report.
    pub trip_seen_ns: AtomicU64,
}

impl Status {
    pub fn phase(&self) -> Phase {
        Phase::from_u8(self.phase.load(Ordering::Acquire))
    }

    pub fn set_phase(&self, p: Phase) {
        self.phase.store(p as u8, Ordering::Release);
    }

    pub fn trip(&self) -> Option<Trip> {
        Trip::from_code(self.trip.load(Ordering::Acquire))
    }

    /// Records the first trip only: the first fault is the cause, later ones are consequences — except a dead
    /// HAL, which replaces the stale state it caused.
    pub fn set_trip(&self, t: Trip) {
        if self.trip.compare_exchange(0, t.code(), Ordering::AcqRel, Ordering::Acquire).is_err() && t == Trip::HalDied {
            let _ = self.trip.compare_exchange(Trip::StaleState.code(), t.code(), Ordering::AcqRel, Ordering::Acquire);
        }
    }
}
