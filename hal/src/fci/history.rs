//! The robot's differencing history (its last applied setpoint, that setpoint's backward differences) and how
//! close to a reported setpoint ours must be to count as the same: what `setpoint_sync` models and `late_reads`
//! searches.

use super::JOINTS;

/// A reported setpoint this far (rad) from our last command means the robot applied another one: above float32
/// rounding (at most 2.4e-7 rad below 4.6 rad), below the jerk·dt³ (4.5e-6 rad at 4500 rad/s³) that matters.
pub const RESYNC_RAD: f64 = 5e-7;

/// The same for a reported velocity (rad/s): above float32 rounding (at most 2.4e-7 rad/s below 8 rad/s).
pub(super) const RESYNC_RAD_S: f64 = 5e-7;

/// The FCI cycle (s).
pub(super) const DT: f64 = 1e-3;

/// The robot's differencing history: its last applied setpoint and that setpoint's backward differences; after a
/// resync, the state the filter continues from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct History {
    pub q: [f64; JOINTS],
    pub v: [f64; JOINTS],
    pub a: [f64; JOINTS],
}

impl History {
    /// `c` applied, `cycles` after the last applied setpoint.
    pub(super) fn record(&mut self, c: &[f64; JOINTS], cycles: u64) {
        let step = cycles as f64 * DT;
        for (j, &c) in c.iter().enumerate() {
            let v = (c - self.q[j]) / step;
            self.a[j] = (v - self.v[j]) / step;
            self.v[j] = v;
            self.q[j] = c;
        }
    }

    /// One cycle extrapolated at constant acceleration (franka-sim's law, in its order of operations).
    fn extrapolate(&mut self) {
        for j in 0..JOINTS {
            self.q[j] += (self.v[j] + self.a[j] * DT) * DT;
            self.v[j] += self.a[j] * DT;
        }
    }

    pub(super) fn extrapolated(mut self, cycles: u64) -> Self {
        for _ in 0..cycles {
            self.extrapolate();
        }
        self
    }
}

/// The largest difference between two joint vectors.
pub(super) fn distance(a: &[f64; JOINTS], b: &[f64; JOINTS]) -> f64 {
    a.iter().zip(b).map(|(x, y)| (x - y).abs()).fold(0.0, f64::max)
}
