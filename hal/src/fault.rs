//! Fault injection for the sim backend: what can go wrong between a robot and its controller, switched on
//! from the profile's `[sim.faults]` table or the `mars-hal` command line, deterministic for a given seed.
//!
//! Sensor faults change what the backend *measures* (the plant itself keeps moving): a frozen sensor repeats
//! the positions of tick T with zero velocity, a NaN sensor reports NaN for one joint from tick T. Both set
//! their [`mars_ipc::fault`] bit in every state frame they touch, so a controller can reject those frames.
//! Loop faults change the HAL loop itself: dropped state frames (never published; the frame `seq` still
//! advances, so the controller sees a gap), late state frames (published after an extra delay; the frame
//! timestamp stays the measurement time), a stalled loop (one sleep of S ms at tick T), and a crash
//! (`abort()` at tick T: no goodbye, no clean-up, like a segfault). Backend errors make the backend itself fail,
//! as a robot's driver can: its `read` or `apply` returns a transient error for N ticks from tick T, or a fatal one
//! from tick T on (the robot is gone for good).
//!
//! Ticks count from 0 (the first state frame, `seq` 1, is tick 0).

use std::time::Duration;

pub use mars_profile::faults::FaultConfig;

/// What the HAL loop must do to the frame of one tick.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct LoopFaults {
    /// Do not publish this tick's state frame.
    pub drop_frame: bool,
    /// Publish it only after this extra delay.
    pub late: Duration,
    /// Sleep this long after the tick (a stalled loop).
    pub stall: Duration,
    /// Abort the process now.
    pub crash: bool,
}

/// Decides, tick by tick, which faults fire. Deterministic: the same config gives the same faults.
#[derive(Debug, Clone)]
pub struct FaultInjector {
    cfg: FaultConfig,
    rng: u64,
}

impl FaultInjector {
    pub fn new(cfg: FaultConfig) -> Self {
        let rng = cfg.seed.wrapping_mul(0xD1B54A32D192ED03).wrapping_add(0x9E3779B97F4A7C15) | 1;
        Self { cfg, rng }
    }

    pub fn config(&self) -> &FaultConfig {
        &self.cfg
    }

    fn unit(&mut self) -> f64 {
        // splitmix64 step: well mixed even for small seeds.
        self.rng = self.rng.wrapping_add(0x9E3779B97F4A7C15);
        let mut z = self.rng;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58476D1CE4E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D049BB133111EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }

    /// The sensor is frozen at `tick` (it repeats the measurement of `freeze_at_tick`).
    pub fn frozen(&self, tick: u64) -> bool {
        self.cfg.freeze_at_tick.is_some_and(|t| tick >= t)
    }

    /// The joint that measures NaN at `tick`, if any.
    pub fn nan_joint(&self, tick: u64) -> Option<usize> {
        match (self.cfg.nan_joint, self.cfg.nan_at_tick) {
            (Some(j), Some(t)) if tick >= t => Some(j),
            _ => None,
        }
    }

    /// `read` fails at `tick`: `Some(true)` for good, `Some(false)` this tick only.
    pub fn read_error(&self, tick: u64) -> Option<bool> {
        if self.cfg.fatal_at_tick.is_some_and(|t| tick >= t) {
            return Some(true);
        }
        let window = |at: Option<u64>, n: u64| at.is_some_and(|t| tick >= t && tick < t.saturating_add(n));
        window(self.cfg.read_error_at_tick, self.cfg.read_error_ticks).then_some(false)
    }

    /// `apply` fails at `tick` (a transient error).
    pub fn apply_error(&self, tick: u64) -> bool {
        self.cfg.apply_error_at_tick.is_some_and(|t| tick >= t && tick < t.saturating_add(self.cfg.apply_error_ticks))
    }

    /// The loop faults of `tick`; call exactly once per tick, in order (the drop generator advances).
    pub fn loop_faults(&mut self, tick: u64) -> LoopFaults {
        let nth = |every: u64| every > 0 && (tick + 1).is_multiple_of(every);
        let random_drop = self.cfg.drop_probability > 0.0 && self.unit() < self.cfg.drop_probability;
        LoopFaults {
            drop_frame: random_drop || nth(self.cfg.drop_every),
            late: if nth(self.cfg.late_every) {
                Duration::from_secs_f64(self.cfg.late_ms / 1e3)
            } else {
                Duration::ZERO
            },
            stall: if self.cfg.stall_at_tick == Some(tick) {
                Duration::from_secs_f64(self.cfg.stall_ms / 1e3)
            } else {
                Duration::ZERO
            },
            crash: self.cfg.crash_at_tick == Some(tick),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_nth_drop_late_stall_and_crash_fire_exactly_when_configured() {
        let mut f = FaultInjector::new(FaultConfig {
            drop_every: 4,
            late_every: 5,
            late_ms: 2.0,
            stall_at_tick: Some(7),
            stall_ms: 30.0,
            crash_at_tick: Some(9),
            ..Default::default()
        });
        let faults: Vec<LoopFaults> = (0..10).map(|t| f.loop_faults(t)).collect();
        let dropped: Vec<u64> = (0..10).filter(|&t| faults[t as usize].drop_frame).collect();
        assert_eq!(dropped, [3, 7]);
        let late: Vec<u64> = (0..10).filter(|&t| !faults[t as usize].late.is_zero()).collect();
        assert_eq!(late, [4, 9]);
        assert_eq!(faults[4].late, Duration::from_millis(2));
        assert_eq!(faults[7].stall, Duration::from_millis(30));
        assert!((0..10).filter(|&t| t != 7).all(|t| faults[t].stall.is_zero()));
        assert_eq!((0..10).filter(|&t| faults[t].crash).collect::<Vec<_>>(), [9]);
    }

    #[test]
    fn backend_errors_fire_in_their_windows_and_a_fatal_one_for_good() {
        let f = FaultInjector::new(FaultConfig {
            read_error_at_tick: Some(5),
            read_error_ticks: 2,
            apply_error_at_tick: Some(1),
            apply_error_ticks: 1,
            fatal_at_tick: Some(20),
            ..Default::default()
        });
        let reads: Vec<(u64, bool)> = (0..25).filter_map(|t| f.read_error(t).map(|fatal| (t, fatal))).collect();
        assert_eq!(reads, [(5, false), (6, false), (20, true), (21, true), (22, true), (23, true), (24, true)]);
        assert_eq!((0..25).filter(|&t| f.apply_error(t)).collect::<Vec<_>>(), [1]);
    }

    #[test]
    fn random_drops_match_the_probability_and_repeat_with_the_seed() {
        let run = |seed| {
            let mut f = FaultInjector::new(FaultConfig { drop_probability: 0.1, seed, ..Default::default() });
            (0..20_000).map(|t| f.loop_faults(t).drop_frame).collect::<Vec<_>>()
        };
        let a = run(3);
        assert_eq!(a, run(3), "same seed, same drops");
        assert_ne!(a, run(4), "another seed, other drops");
        let rate = a.iter().filter(|&&d| d).count() as f64 / a.len() as f64;
        assert!((rate - 0.1).abs() < 0.01, "drop rate {rate}");
    }

    #[test]
    fn invalid_fault_configs_are_refused_naming_the_field() {
        let bad = |c: FaultConfig| c.validate(7).unwrap_err();
        assert!(bad(FaultConfig { drop_probability: 1.5, ..Default::default() }).contains("drop_probability"));
        assert!(
            bad(FaultConfig { nan_joint: Some(7), nan_at_tick: Some(0), ..Default::default() }).contains("7 joints")
        );
        assert!(bad(FaultConfig { nan_joint: Some(1), ..Default::default() }).contains("together"));
        assert!(bad(FaultConfig { stall_at_tick: Some(1), ..Default::default() }).contains("stall_ms"));
        assert!(bad(FaultConfig { late_every: 2, ..Default::default() }).contains("late_ms"));
        assert!(bad(FaultConfig { read_error_at_tick: Some(3), ..Default::default() }).contains("go together"));
        assert!(FaultConfig::default().validate(7).is_ok());
        assert!(!FaultConfig { seed: 9, ..Default::default() }.any());
        assert!(FaultConfig { drop_every: 2, ..Default::default() }.any());
    }
}
