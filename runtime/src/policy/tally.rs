//! Episode results in bounded memory: totals over every episode, and the last few results in full.
//!
//! Under systemd marsd runs with `episodes = 0` (until SIGTERM) for hours; a list of every episode's result would
//! grow without end on the policy thread. The totals are what the report needs; the last `kept` results (a
//! ring preallocated at start, so adding one never allocates) are what summary.json shows per episode.

use std::collections::VecDeque;

use serde::Serialize;

use mars_tasks::pick::DoneReason;

/// One episode's outcome.
#[derive(Debug, Clone, Serialize)]
pub struct EpisodeResult {
    pub episode: u64,
    pub success: bool,
    pub mode: Option<usize>,
    pub reason: Option<DoneReason>,
    pub duration_s: f64,
    pub chunks: u64,
    pub mean_k_used: f64,
    pub late_chunks: u64,
    /// Servo periods missed while the episode ran (a stalled machine: the robot's commands came late).
    pub servo_missed_periods: u64,
}

#[derive(Debug, Clone, Default, Serialize)]
pub struct EpisodeTally {
    pub episodes: u64,
    pub successes: u64,
    /// Successful episodes per mode (the task's grasps), by index.
    pub mode_successes: Vec<u64>,
    /// The last results, oldest first (at most `kept`).
    pub recent: VecDeque<EpisodeResult>,
    kept: usize,
}

impl EpisodeTally {
    /// For a task with `modes` modes, keeping the last `kept` results in full.
    pub fn new(modes: usize, kept: usize) -> Self {
        Self { episodes: 0, successes: 0, mode_successes: vec![0; modes], recent: VecDeque::with_capacity(kept), kept }
    }

    pub fn add(&mut self, r: EpisodeResult) {
        self.episodes += 1;
        if r.success {
            self.successes += 1;
            if let Some(count) = r.mode.and_then(|m| self.mode_successes.get_mut(m)) {
                *count += 1;
            }
        }
        if self.kept == 0 {
            return;
        }
        if self.recent.len() == self.kept {
            self.recent.pop_front();
        }
        self.recent.push_back(r);
    }

    pub fn success_rate(&self) -> f64 {
        if self.episodes == 0 { 0.0 } else { self.successes as f64 / self.episodes as f64 }
    }

    /// The paper's balance measure over the successful episodes' modes: k · min / Σ (1 when balanced, 0 when a
    /// mode is never used).
    pub fn gamma(&self) -> f64 {
        let total: u64 = self.mode_successes.iter().sum();
        match self.mode_successes.iter().min() {
            Some(&min) if total > 0 => self.mode_successes.len() as f64 * min as f64 / total as f64,
            _ => 0.0,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn result(episode: u64, success: bool, mode: Option<usize>) -> EpisodeResult {
        EpisodeResult {
            episode,
            success,
            mode,
            reason: None,
            duration_s: 1.0,
            chunks: 1,
            mean_k_used: 1.0,
            late_chunks: 0,
            servo_missed_periods: 0,
        }
    }

    #[test]
    fn totals_cover_every_episode_while_only_the_last_are_kept_without_reallocating() {
        let mut t = EpisodeTally::new(2, 3);
        let capacity = t.recent.capacity();
        for e in 1..=1000 {
            t.add(result(e, e % 4 != 0, Some((e % 2) as usize)));
        }
        assert_eq!((t.episodes, t.successes), (1000, 750));
        assert_eq!(t.mode_successes, [250, 500]);
        assert_eq!(t.recent.iter().map(|r| r.episode).collect::<Vec<_>>(), [998, 999, 1000]);
        assert_eq!(t.recent.capacity(), capacity, "the ring never grew");
        assert!((t.success_rate() - 0.75).abs() < 1e-12);
        assert!((t.gamma() - 2.0 * 250.0 / 750.0).abs() < 1e-12);
    }

    #[test]
    fn gamma_is_zero_without_successes_or_with_an_unused_mode() {
        let mut t = EpisodeTally::new(2, 0);
        assert_eq!(t.gamma(), 0.0);
        t.add(result(1, true, Some(0)));
        assert_eq!((t.gamma(), t.recent.len()), (0.0, 0));
        t.add(result(2, true, Some(1)));
        assert_eq!(t.gamma(), 1.0);
    }
}
