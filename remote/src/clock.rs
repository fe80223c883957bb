//! The host's clock against the robot's, by ping-pong: the robot asks the host's time `n` times; the sample with
//! the shortest round trip bounds the offset best (its reply left the host within that round trip), as NTP does.

use std::time::Duration;

use serde::Serialize;

/// What the ping-pong measured.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ClockEstimate {
    /// host clock − robot clock (ns), from the sample with the shortest round trip.
    pub offset_ns: i64,
    /// That sample's round trip: the offset is right within ± half of it.
    pub rtt_min_ns: u64,
    /// The median round trip over the samples.
    pub rtt_median_ns: u64,
    pub samples: usize,
}

/// One ping: the robot's clock when it asked and when the answer came, and the host's clock in the answer.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ping {
    pub asked_ns: u64,
    pub host_ns: u64,
    pub answered_ns: u64,
}

impl ClockEstimate {
    /// The estimate from the pings that came back (None: none did).
    pub fn from_pings(pings: &[Ping]) -> Option<Self> {
        let best = pings.iter().min_by_key(|p| p.answered_ns.saturating_sub(p.asked_ns))?;
        let mid = best.asked_ns / 2 + best.answered_ns / 2;
        let mut rtts: Vec<u64> = pings.iter().map(|p| p.answered_ns.saturating_sub(p.asked_ns)).collect();
        rtts.sort_unstable();
        Some(Self {
            offset_ns: best.host_ns as i64 - mid as i64,
            rtt_min_ns: rtts[0],
            rtt_median_ns: rtts[rtts.len() / 2],
            samples: pings.len(),
        })
    }

    /// A time on the host's clock, on the robot's.
    pub fn to_robot(&self, host_ns: u64) -> u64 {
        host_ns.saturating_add_signed(-self.offset_ns)
    }

    pub fn rtt_min(&self) -> Duration {
        Duration::from_nanos(self.rtt_min_ns)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shortest_round_trip_sets_the_offset() {
        // Host 1 s ahead; the first ping's answer was held up on its way back (asymmetric), the second was not.
        let pings = [
            Ping { asked_ns: 1_000, host_ns: 1_000_001_500, answered_ns: 9_000 },
            Ping { asked_ns: 20_000, host_ns: 1_000_020_500, answered_ns: 21_000 },
        ];
        let c = ClockEstimate::from_pings(&pings).unwrap();
        assert_eq!(c.offset_ns, 1_000_000_000);
        assert_eq!((c.rtt_min_ns, c.rtt_median_ns, c.samples), (1_000, 8_000, 2));
        assert_eq!(c.to_robot(1_000_020_500), 20_500);
        assert_eq!(ClockEstimate::from_pings(&[]), None);
    }
}
