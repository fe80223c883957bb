//! Time-stamped action chunks and the reference the servo follows through them.
//!
//! The policy loop stamps every action with the time it is due: action i of a chunk is due at
//! `first_due_ns + i·period_ns`, and the next chunk's first action is due one period after this chunk's last.
//! The servo turns the due actions into a continuous reference: piecewise linear in time from one due action to
//! the next (the same interpolation the expert's demos were recorded with), with the segment's slope as the
//! reference velocity. A chunk that arrives late has its past actions dropped (as diffusion_policy's real-robot
//! loop does): the reference runs from where it is now to the first action still in the future.

use mars_ipc::MAX_JOINTS;

/// Longest chunk the fixed-size handoff carries.
pub const MAX_CHUNK: usize = 32;
/// Values per action: the joints, then the gripper.
pub const MAX_ACTION: usize = MAX_JOINTS + 1;

/// One chunk as handed from the policy loop to the servo loop: plain `Copy` data of fixed size, so the
/// handoff copies it into preallocated slots and never allocates.
#[derive(Debug, Clone, Copy)]
pub struct TimedChunk {
    /// 0 = no chunk yet; otherwise increasing.
    pub seq: u64,
    /// The episode it belongs to: a chunk of an ended episode is ignored.
    pub episode: u64,
    pub first_due_ns: u64,
    pub period_ns: u64,
    pub len: usize,
    pub actions: [[f64; MAX_ACTION]; MAX_CHUNK],
    /// When inference finished (for the "late chunk" accounting).
    pub ready_ns: u64,
    /// Capture time of the camera frame the chunk was computed from (0: no camera).
    pub capture_ns: u64,
}

impl Default for TimedChunk {
    fn default() -> Self {
        Self {
            seq: 0,
            episode: 0,
            first_due_ns: 0,
            period_ns: 1,
            len: 0,
            actions: [[0.0; MAX_ACTION]; MAX_CHUNK],
            ready_ns: 0,
            capture_ns: 0,
        }
    }
}

impl TimedChunk {
    pub fn due_ns(&self, i: usize) -> u64 {
        self.first_due_ns + i as u64 * self.period_ns
    }

    /// When its last action is due.
    pub fn last_due_ns(&self) -> u64 {
        self.due_ns(self.len.saturating_sub(1))
    }
}

/// The reference at one instant.
#[derive(Debug, Clone, Copy)]
pub struct Reference {
    pub position: [f64; MAX_ACTION],
    pub velocity: [f64; MAX_ACTION],
    /// The chunk's last action has been reached and no newer chunk was adopted: holding it.
    pub exhausted: bool,
}

/// What adopting a chunk did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Adoption {
    /// Actions already due when it was adopted, skipped.
    pub dropped: usize,
}

/// Follows the due actions of the current chunk; see the module docs.
#[derive(Debug, Clone)]
pub struct Schedule {
    width: usize,
    chunk: TimedChunk,
    /// Index of the next action not yet reached.
    next: usize,
    anchor_ns: u64,
    anchor: [f64; MAX_ACTION],
}

impl Schedule {
    pub fn new(width: usize) -> Self {
        assert!((1..=MAX_ACTION).contains(&width), "action width {width} out of 1..={MAX_ACTION}");
        Self { width, chunk: TimedChunk::default(), next: 0, anchor_ns: 0, anchor: [0.0; MAX_ACTION] }
    }

    /// No chunk: hold `position` (a start pose) from `now_ns` on.
    pub fn hold(&mut self, now_ns: u64, position: &[f64]) {
        self.chunk.len = 0;
        self.chunk.seq = 0;
        self.next = 0;
        self.anchor_ns = now_ns;
        self.anchor[..self.width].copy_from_slice(&position[..self.width]);
    }

    pub fn current_seq(&self) -> u64 {
        self.chunk.seq
    }

    /// Whether `pending` should replace the current chunk at `now_ns`: when the current one has no action
    /// left that is due before the pending one's first.
    pub fn ready_for(&self, pending: &TimedChunk, now_ns: u64) -> bool {
        self.next >= self.chunk.len || now_ns + pending.period_ns >= pending.first_due_ns
    }

    /// Switches to `chunk` at `now_ns`, continuing from the reference's current value; actions already due are
    /// dropped.
    pub fn adopt(&mut self, chunk: &TimedChunk, now_ns: u64) -> Adoption {
        let here = self.sample(now_ns).position;
        self.chunk = *chunk;
        self.next = (0..chunk.len).find(|&i| chunk.due_ns(i) > now_ns).unwrap_or(chunk.len);
        // Continuity: the first segment starts at the reference's value now. On time, it is timed from one
        // period before the first action (the previous chunk's last due time), as the actions were planned.
        self.anchor_ns = if self.next > 0 {
            now_ns
        } else {
            now_ns.min(chunk.first_due_ns.saturating_sub(chunk.period_ns)).max(self.anchor_ns)
        };
        self.anchor = here;
        Adoption { dropped: self.next }
    }

    /// The reference at `t_ns` (not before the last call's time: the schedule only moves forward).
    pub fn sample(&mut self, t_ns: u64) -> Reference {
        let w = self.width;
        while self.next < self.chunk.len && self.chunk.due_ns(self.next) <= t_ns {
            self.anchor_ns = self.chunk.due_ns(self.next);
            self.anchor[..w].copy_from_slice(&self.chunk.actions[self.next][..w]);
            self.next += 1;
        }
        let mut r = Reference { position: self.anchor, velocity: [0.0; MAX_ACTION], exhausted: true };
        if self.next < self.chunk.len {
            let due = self.chunk.due_ns(self.next);
            let span = (due - self.anchor_ns).max(1) as f64;
            let s = (t_ns.saturating_sub(self.anchor_ns) as f64 / span).clamp(0.0, 1.0);
            let target = &self.chunk.actions[self.next];
            for (i, &goal) in target[..w].iter().enumerate() {
                let delta = goal - self.anchor[i];
                r.position[i] = self.anchor[i] + s * delta;
                r.velocity[i] = delta / (span * 1e-9);
            }
            r.exhausted = false;
        }
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const MS: u64 = 1_000_000;

    fn chunk(seq: u64, first_due_ns: u64, values: &[f64]) -> TimedChunk {
        let mut c =
            TimedChunk { seq, episode: 1, first_due_ns, period_ns: 100 * MS, len: values.len(), ..Default::default() };
        for (i, v) in values.iter().enumerate() {
            c.actions[i][0] = *v;
        }
        c
    }

    #[test]
    fn interpolates_linearly_between_due_actions_with_the_segment_slope() {
        let mut s = Schedule::new(1);
        s.hold(0, &[0.0]);
        assert_eq!(s.adopt(&chunk(1, 100 * MS, &[1.0, 3.0]), 0), Adoption { dropped: 0 });
        let r = s.sample(50 * MS);
        assert!((r.position[0] - 0.5).abs() < 1e-12 && (r.velocity[0] - 10.0).abs() < 1e-9, "{r:?}");
        let r = s.sample(150 * MS);
        assert!((r.position[0] - 2.0).abs() < 1e-12 && (r.velocity[0] - 20.0).abs() < 1e-9, "{r:?}");
        let r = s.sample(250 * MS);
        assert!(r.exhausted && r.position[0] == 3.0 && r.velocity[0] == 0.0);
    }

    #[test]
    fn a_late_chunk_drops_past_actions_and_continues_from_the_current_reference() {
        let mut s = Schedule::new(1);
        s.hold(0, &[0.0]);
        // Arrives at 250 ms: actions due at 100 and 200 ms are in the past.
        let a = s.adopt(&chunk(1, 100 * MS, &[1.0, 2.0, 3.0, 4.0]), 250 * MS);
        assert_eq!(a, Adoption { dropped: 2 });
        let r = s.sample(250 * MS);
        assert_eq!(r.position[0], 0.0, "no jump at adoption");
        let r = s.sample(300 * MS);
        assert!((r.position[0] - 3.0).abs() < 1e-12);
    }

    #[test]
    fn the_next_chunk_waits_until_the_current_one_is_used_up() {
        let mut s = Schedule::new(1);
        s.hold(0, &[0.0]);
        s.adopt(&chunk(1, 100 * MS, &[1.0, 2.0]), 0);
        let next = chunk(2, 300 * MS, &[5.0, 6.0]);
        assert!(!s.ready_for(&next, 150 * MS));
        assert!(s.ready_for(&next, 200 * MS));
        assert_eq!(s.adopt(&next, 200 * MS).dropped, 0);
        let r = s.sample(250 * MS);
        assert!((r.position[0] - 3.5).abs() < 1e-12, "{r:?}");
    }
}
