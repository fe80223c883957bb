//! The episode traces kept for the episodes plot: a bounded ring of the last N, so a run with `episodes = 0`
//! (how the systemd unit runs marsd) holds a fixed amount of (locked) memory however long it runs. Once the ring
//! is full, the oldest trace's buffers are reused for the next episode: the policy thread allocates no more.

use std::collections::VecDeque;

use crate::report::plots::EpisodeTrace;

/// Steps one trace can hold before it stops growing (no reallocation in the policy loop).
pub const TRACE_CAPACITY: usize = 4096;

pub struct TraceRing {
    kept: usize,
    ring: VecDeque<EpisodeTrace>,
    /// A dropped trace whose buffers the next episode reuses.
    spare: Option<EpisodeTrace>,
    dropped: u64,
}

impl TraceRing {
    /// Keeps the last `kept` traces (0: none).
    pub fn new(kept: usize) -> Self {
        Self { kept, ring: VecDeque::with_capacity(kept), spare: None, dropped: 0 }
    }

    /// An empty trace for the next episode: a dropped one's buffers when there is one, else new ones.
    pub fn start(&mut self) -> EpisodeTrace {
        match self.spare.take() {
            Some(mut t) => {
                t.mode = None;
                t.success = false;
                t.q.clear();
                t.w_inf.clear();
                t.first_frame.clear();
                t.last_frame.clear();
                t
            }
            None => EpisodeTrace {
                mode: None,
                success: false,
                q: Vec::with_capacity(TRACE_CAPACITY),
                w_inf: Vec::with_capacity(TRACE_CAPACITY),
                first_frame: Vec::new(),
                last_frame: Vec::new(),
            },
        }
    }

    /// Keeps a finished episode's trace, dropping the oldest if the ring is full.
    pub fn push(&mut self, trace: EpisodeTrace) {
        if self.kept == 0 {
            self.dropped += 1;
            self.spare = Some(trace);
            return;
        }
        if self.ring.len() == self.kept {
            self.spare = self.ring.pop_front();
            self.dropped += 1;
        }
        self.ring.push_back(trace);
    }

    /// Traces dropped so far (older than the last `kept`).
    pub fn dropped(&self) -> u64 {
        self.dropped
    }

    /// The kept traces, oldest first.
    pub fn into_vec(self) -> Vec<EpisodeTrace> {
        self.ring.into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn trace(ring: &mut TraceRing, tag: f64) -> EpisodeTrace {
        let mut t = ring.start();
        t.q.push([tag; mars_ipc::MAX_JOINTS]);
        t.w_inf.push(tag as f32);
        t
    }

    #[test]
    fn keeps_the_last_n_in_order_and_reuses_the_oldest_buffers() {
        let mut ring = TraceRing::new(3);
        let mut first_buffers = None;
        for e in 0..5 {
            let t = trace(&mut ring, e as f64);
            if e == 0 {
                first_buffers = Some(t.q.as_ptr());
            }
            if e == 4 {
                // Pushing episode 3 dropped episode 0: episode 4 writes into its buffers, allocating nothing.
                assert_eq!(Some(t.q.as_ptr()), first_buffers);
                assert_eq!(t.q.len(), 1, "a reused trace starts empty");
            }
            ring.push(t);
        }
        assert_eq!(ring.dropped(), 2);
        let kept: Vec<f64> = ring.into_vec().iter().map(|t| t.q[0][0]).collect();
        assert_eq!(kept, [2.0, 3.0, 4.0]);
    }

    #[test]
    fn keeping_none_drops_every_trace() {
        let mut ring = TraceRing::new(0);
        for e in 0..3 {
            let t = trace(&mut ring, e as f64);
            ring.push(t);
        }
        assert_eq!(ring.dropped(), 3);
        assert!(ring.into_vec().is_empty());
    }
}
