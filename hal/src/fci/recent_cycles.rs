//! The last few robot cycles as the HAL saw them, kept in place (no allocation in the loop) and logged after a
//! reflex: what the robot reported it applied next to what we sent, so a discontinuity can be traced to its cycle,
//! and how regularly its states came before it (a robot that skipped or bunched states leaves the HAL to guess what
//! it applied meanwhile).

use super::JOINTS;

/// One cycle: the robot's period (ms), its reported setpoint and derivatives, and the command we sent back.
#[derive(Debug, Clone, Copy, Default)]
pub struct CycleRecord {
    pub period_ms: u64,
    pub q_d: [f64; JOINTS],
    pub dq_d: [f64; JOINTS],
    pub ddq_d: [f64; JOINTS],
    pub sent: [f64; JOINTS],
    pub resynced: bool,
    /// The state came less than half a period after the one before.
    pub bunched: bool,
    /// The robot's control command success rate in the state (its last 100 cycles).
    pub success_rate: f64,
}

/// The longest stretch of unseen states counted as short.
pub const SHORT_STRETCH: u64 = 3;

/// How regularly the robot's states came over the cycles kept.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Regularity {
    pub cycles: usize,
    /// States the robot sent that the HAL never saw.
    pub unseen: u64,
    /// The most unseen at once (one stretch).
    pub longest_unseen: u64,
    /// Unseen states in stretches of at most [`SHORT_STRETCH`]: a machine's hiccups, not a stall of seconds' worth.
    pub short_unseen: u64,
    /// States that came bunched behind the one before.
    pub bunched: u64,
    /// Cycles whose state showed the robot's success rate lower than the state before: a command of ours reached
    /// it too late for its cycle (at least one; a loss leaving its 100-cycle window as one enters hides it).
    pub rate_falls: u64,
}

impl std::fmt::Display for Regularity {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "in the {} cycles before it: {} unseen states (at most {} at once; {} in stretches of 1-{SHORT_STRETCH}), {} \
             bunched, the robot's success rate fell {} times",
            self.cycles, self.unseen, self.longest_unseen, self.short_unseen, self.bunched, self.rate_falls
        )
    }
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

    /// Unseen and bunched states over the cycles kept.
    pub fn regularity(&self) -> Regularity {
        let mut r = Regularity { cycles: self.len, ..Default::default() };
        let mut rate: Option<f64> = None;
        for c in self.iter() {
            r.rate_falls += u64::from(rate.replace(c.success_rate).is_some_and(|before| c.success_rate < before));
            let unseen = c.period_ms.saturating_sub(1);
            r.unseen += unseen;
            r.longest_unseen = r.longest_unseen.max(unseen);
            if unseen <= SHORT_STRETCH {
                r.short_unseen += unseen;
            }
            r.bunched += u64::from(c.bunched);
        }
        r
    }

    /// What our command of cycle `c` implies for `joint` against the robot's reported setpoint and derivatives
    /// (what the robot's differencing judges, up to the report's float32 rounding): velocity, acceleration, jerk.
    fn implied(c: &CycleRecord, joint: usize) -> (f64, f64, f64) {
        let v = (c.sent[joint] - c.q_d[joint]) / 1e-3;
        let a = (v - c.dq_d[joint]) / 1e-3;
        (v, a, (a - c.ddq_d[joint]) / 1e-3)
    }

    /// The joint whose commands in the last `last` cycles implied the largest jerk: where a discontinuity is.
    pub fn roughest_joint(&self, last: usize) -> usize {
        let worst = |j: usize| {
            self.iter().skip(self.len.saturating_sub(last)).map(|c| Self::implied(c, j).2.abs()).fold(0.0, f64::max)
        };
        (0..JOINTS).max_by(|&a, &b| worst(a).total_cmp(&worst(b))).unwrap_or(0)
    }

    /// One line per cycle for `joint`, the last `last` cycles: period, q_d, dq_d, ddq_d, what we sent, and the
    /// velocity, acceleration and jerk it implies.
    pub fn describe(&self, joint: usize, last: usize) -> String {
        let mut out = String::new();
        for c in self.iter().skip(self.len.saturating_sub(last)) {
            let (v, a, j) = Self::implied(c, joint);
            out += &format!(
                "\n    period {} ms{}{}: q_d {:.7} dq_d {:.5} ddq_d {:.3} | sent {:.7} → v {:.5} a {:.3} j {:.0}",
                c.period_ms,
                if c.resynced { " (resync)" } else { "" },
                if c.bunched { " (bunched)" } else { "" },
                c.q_d[joint],
                c.dq_d[joint],
                c.ddq_d[joint],
                c.sent[joint],
                v,
                a,
                j
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
        assert_eq!(r.describe(0, 8).lines().count(), 4);
        assert_eq!(r.describe(0, 2).lines().count(), 3);
        // Joint 3's last command steps 1e-6 rad off a setpoint at rest: 1000 rad/s³ implied there, nowhere else.
        let mut c = CycleRecord { period_ms: 1, ..Default::default() };
        c.sent[3] = 1e-6;
        let mut rough = RecentCycles::<4>::default();
        rough.push(c);
        assert_eq!(rough.roughest_joint(8), 3);
        assert!(rough.describe(3, 8).ends_with("j 1000"), "{}", rough.describe(3, 8));
        // Periods 3, 4, 5 ms: 2 + 3 + 4 unseen, at most 4 at once, 2 + 3 of them in short stretches.
        let want = Regularity { cycles: 3, unseen: 9, longest_unseen: 4, short_unseen: 5, bunched: 0, rate_falls: 0 };
        assert_eq!(r.regularity(), want);
        // A bunched state, and the success rate falling (1.0 in the cycles before): once.
        r.push(CycleRecord { period_ms: 1, bunched: true, success_rate: 0.99, ..Default::default() });
        let want = Regularity { cycles: 3, unseen: 7, longest_unseen: 4, short_unseen: 3, bunched: 1, rate_falls: 0 };
        assert_eq!(r.regularity(), want, "the rate of the cycles before was 0: it rose");
        r.push(CycleRecord { period_ms: 1, success_rate: 0.98, ..Default::default() });
        // Periods 5, 1, 1 ms kept.
        let want = Regularity { cycles: 3, unseen: 4, longest_unseen: 4, short_unseen: 0, bunched: 1, rate_falls: 1 };
        assert_eq!(r.regularity(), want);
        assert_eq!(
            want.to_string(),
            "in the 3 cycles before it: 4 unseen states (at most 4 at once; 0 in stretches of 1-3), 1 bunched, the \
             robot's success rate fell 1 times"
        );
    }
}
