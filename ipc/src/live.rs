//! What `marsd top` shows of a running daemon: the newest latency interval of each of its loops and the servo
//! loop's status, published a few times a second by the daemon's latency collector.
//!
//! The collector is an ordinary thread that already receives every interval's histograms from the real-time
//! loops (through wait-free rings) to write the interval log; publishing a summary of them adds nothing to the
//! loops themselves. Anyone can subscribe (`marsd top`, a test, a dashboard) without the daemon knowing.

use iceoryx2::prelude::ZeroCopySend;

/// Latency channels a frame has room for, in the order of the daemon's channel list
/// (`mars_runtime::report::latency::Channel::ALL`, which checks at compile time that it fits).
pub const LIVE_CHANNELS: usize = 12;

/// One channel over its newest interval: time channels in ns, the K channels in ODE steps. `count` 0: no sample
/// in that interval (the other fields are then 0).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("mars::LiveChannel")]
#[repr(C)]
pub struct LiveChannel {
    pub count: u64,
    pub p50: u64,
    pub p99: u64,
    pub max: u64,
    /// Samples at or above the servo period (time channels): wake-ups a whole period late, ticks or answers
    /// that took a period or more.
    pub over_period: u64,
    /// CLOCK_MONOTONIC start and end of the interval (ns).
    pub start_ns: u64,
    pub end_ns: u64,
}

/// A daemon's live view, sent after each interval the collector receives.
#[derive(Debug, Clone, Copy, PartialEq, ZeroCopySend)]
#[type_name("mars::LiveStats")]
#[repr(C)]
pub struct LiveStats {
    pub seq: u64,
    /// CLOCK_MONOTONIC when sent (ns).
    pub timestamp_ns: u64,
    /// The servo loop's period (ns).
    pub period_ns: u64,
    /// The policy's time budget per call (ns): the lead of a chunk over the servo's need of it.
    pub inference_budget_ns: u64,
    pub channels: [LiveChannel; LIVE_CHANNELS],
    /// The servo loop's phase (`mars_runtime::shared::Phase` as a number), its episode and ticks so far.
    pub phase: u32,
    /// The trip that stopped the loop (`mars_runtime::servo::watchdog::Trip` code); 0: none.
    pub trip: u32,
    pub episode: u64,
    pub ticks: u64,
    /// Passes of the policy thread's loops (a stuck policy thread stops counting).
    pub policy_beats: u64,
    /// Interval sets the loops kept filling because the collector had not returned one (a slow collector).
    pub starved: u64,
    /// The servo loop's counters since the handshake, as of its newest interval (as in marsd's report).
    pub servo: ServoLive,
    /// The HAL's counters from its newest frame the servo read, since this controller's handshake.
    pub hal: HalLive,
    /// The camera whose frames the `camera_age` channel times (UTF-8, zero-padded; empty: no camera).
    pub camera: [u8; CAMERA_NAME_LEN],
}

/// Bytes of a camera's name in a live frame.
pub const CAMERA_NAME_LEN: usize = 32;

impl LiveStats {
    /// The camera's name (see [`LiveStats::camera`]).
    pub fn camera_name(&self) -> &str {
        let end = self.camera.iter().position(|b| *b == 0).unwrap_or(CAMERA_NAME_LEN);
        std::str::from_utf8(&self.camera[..end]).unwrap_or("?")
    }

    /// Sets the camera's name, cut at [`CAMERA_NAME_LEN`] bytes (on a character boundary).
    pub fn set_camera_name(&mut self, name: &str) {
        let mut end = name.len().min(CAMERA_NAME_LEN);
        while !name.is_char_boundary(end) {
            end -= 1;
        }
        self.camera = [0; CAMERA_NAME_LEN];
        self.camera[..end].copy_from_slice(&name.as_bytes()[..end]);
    }
}

/// The servo loop's counters (see marsd's report for each).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("mars::ServoLive")]
#[repr(C)]
pub struct ServoLive {
    pub commands_sent: u64,
    /// Commands that reached the HAL after its next tick.
    pub late_commands: u64,
    /// Times the trajectory continued from the HAL's applied setpoint.
    pub resyncs: u64,
    /// Ticks with no new state frame (nothing sent).
    pub frameless_ticks: u64,
    /// Actions whose chunk came after they were due.
    pub actions_dropped: u64,
    /// Running ticks with the chunk used up.
    pub starved_ticks: u64,
    /// Commands the final limit check stopped (never sent; must be 0).
    pub limit_violations: u64,
}

/// The HAL's safety counters.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, ZeroCopySend)]
#[type_name("mars::HalLive")]
#[repr(C)]
pub struct HalLive {
    pub rejected: u64,
    pub clamped: u64,
    pub late: u64,
    pub position_guard_hits: u64,
    pub infeasible_steps: u64,
    pub backend_errors: u64,
}

impl Default for LiveStats {
    fn default() -> Self {
        Self {
            seq: 0,
            timestamp_ns: 0,
            period_ns: 0,
            inference_budget_ns: 0,
            channels: [LiveChannel::default(); LIVE_CHANNELS],
            phase: 0,
            trip: 0,
            episode: 0,
            ticks: 0,
            policy_beats: 0,
            starved: 0,
            servo: ServoLive::default(),
            hal: HalLive::default(),
            camera: [0; CAMERA_NAME_LEN],
        }
    }
}
