//! The last few robot cycles as the HAL saw them, kept in place (no allocation in the loop) and logged after a
//! reflex: what the robot reported it applied next to what we sent, so a discontinuity can be traced to its cycle.

use super::state::JOINTS;

/// One cycle: the robot's period (ms), its reported setpoint and derivatives, and the command we sent back.
#[derive(Debug, Clone, Copy, Default)]
pub struct CycleRecord {
    pub period_ms: u64,
    pub q_d: [f64; JOINTS],
    pub dq_d: [f64; JOINTS],
    pub ddq_d: [f64; JOINTS],
    pub sent: [f64; JOINTS],
    pub resynced: bool,
}

/// A ring of the last `N` cycles.
#[derive(Debug)]
pub struct RecentCycles<const N: usize> {
    ring: [CycleRecord; N],
    next: usize,
    len: usize,
}

impl<const N: usize> Default for RecentCycles<N> {
    fn default() -> Self {
        Self { ring: [CycleRecord::default(); N], next: 0, len: 0 }
    }
}

impl<const N: usize> RecentCycles<N> {
    pub fn push(&mut self, c: CycleRecord) {
        self.ring[self.next] = c;
        self.next = (self.next + 1) % N;
        self.len = (self.len + 1).min(N);
    }

    /// Oldest first.
    pub fn iter(&self) -> impl Iterator<Item = &CycleRecord> {
        (0..self.len).map(move |i| &self.ring[(self.next + N - self.len + i) % N])
    }

    /// One line per cycle for `joint`: period, q_d, dq_d, ddq_d, what we sent, and the velocity and acceleration
    /// our command implies against the robot's reported setpoint (what the robot's differencing judges).
    pub fn describe(&self, joint: usize) -> String {
        let mut out = String::new();
        for c in self.iter() {
            let v = (c.sent[joint] - c.q_d[joint]) / 1e-3;
            let a = (v - c.dq_d[joint]) / 1e-3;
            out += &format!(
                "\n    period {} ms{}: q_d {:.7} dq_d {:.5} ddq_d {:.3} | sent {:.7} → v {:.5} a {:.3}",
                c.period_ms,
                if c.resynced { " (resync)" } else { "" },
                c.q_d[joint],
                c.dq_d[joint],
                c.ddq_d[joint],
                c.sent[joint],
                v,
                a
            );
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keeps_the_last_n_oldest_first() {
        let mut r = RecentCycles::<3>::default();
        for p in 1..=5 {
            r.push(CycleRecord { period_ms: p, ..Default::default() });
        }
        assert_eq!(r.iter().map(|c| c.period_ms).collect::<Vec<_>>(), vec![3, 4, 5]);
        assert_eq!(r.describe(0).lines().count(), 4);
    }
}
