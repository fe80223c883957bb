//! A chunk that arrives late, in-process: the chunk asked for at step u (from the observation then) is adopted δ
//! policy periods later, as it would be after a round trip of δ periods to an inference host. What the robot does
//! meanwhile is the previous chunk's, so the new chunk's first δ rows are *committed* by the time it arrives. Three
//! ways to continue from them:
//!
//! - [`Continuity::DropLate`]: today's adoption: the chunk from the observation at u, its first δ rows dropped.
//! - [`Continuity::Guided`]: the same chunk with every Euler step guided toward the committed rows (real-time
//!   chunking, `mars_engine::continuity`), its first δ rows dropped.
//! - [`Continuity::History`]: the committed rows appended to the history the policy sees, so that the chunk starts
//!   after them (at u + δ) and all C rows are executed: MARS's source is the history, so it continues from them.
//!
//! With δ = 0 all three are today's loop, bit for bit.

use std::str::FromStr;

#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum Continuity {
    DropLate,
    Guided,
    History,
}

impl Continuity {
    pub const ALL: [Continuity; 3] = [Continuity::DropLate, Continuity::Guided, Continuity::History];

    pub fn name(self) -> &'static str {
        match self {
            Continuity::DropLate => "drop-late",
            Continuity::Guided => "guided",
            Continuity::History => "history",
        }
    }
}

impl FromStr for Continuity {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|c| c.name() == s)
            .ok_or_else(|| format!("unknown continuity {s:?}: one of drop-late, guided, history"))
    }
}

/// How late each chunk is adopted (policy periods) and how it continues the committed rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Delay {
    pub periods: usize,
    pub continuity: Continuity,
}

impl Delay {
    pub const NONE: Delay = Delay { periods: 0, continuity: Continuity::DropLate };

    /// At most half a chunk, so that a chunk is adopted before the next is asked for.
    pub fn check(&self, chunk_len: usize) -> Result<(), String> {
        if 2 * self.periods > chunk_len {
            return Err(format!("a delay of {} periods is over half the chunk of {chunk_len}", self.periods));
        }
        Ok(())
    }
}

/// Which chunk is in force at each step, and when the next is asked for.
#[derive(Debug)]
pub struct Schedule {
    delay: Delay,
    c: usize,
    d: usize,
    active: Vec<f32>,
    /// The step of the active chunk's first row.
    active_start: usize,
    pending: Vec<f32>,
    /// (step the pending chunk is adopted at, step of its first row).
    pending_at: Option<(usize, usize)>,
    /// The step the active chunk was adopted at.
    adopted_at: Option<usize>,
    next_call: usize,
}

impl Schedule {
    /// Before the first chunk arrives the robot holds `rest` (one action).
    pub fn new(delay: Delay, c: usize, rest: &[f32]) -> Self {
        let d = rest.len();
        Self {
            delay,
            c,
            d,
            active: rest.repeat(c),
            active_start: 0,
            pending: vec![0.0; c * d],
            pending_at: None,
            adopted_at: None,
            next_call: 0,
        }
    }

    /// Whether a chunk is asked for at `step`.
    pub fn calls_at(&self, step: usize) -> bool {
        step == self.next_call
    }

    /// The rows in force for steps `step .. step + δ` (the last row held past the chunk's end), appended to `out`.
    pub fn committed(&self, step: usize, out: &mut Vec<f32>) {
        out.clear();
        for s in step..step + self.delay.periods {
            out.extend_from_slice(self.row(s));
        }
    }

    /// The chunk asked for at `step` came back: adopted δ steps later.
    pub fn arrived(&mut self, step: usize, chunk: &[f32]) {
        // At δ = C/2 the previous chunk is adopted at the very step this one is asked: adopt it before it is
        // overwritten.
        self.adopt_due(step);
        let delta = self.delay.periods;
        self.pending.copy_from_slice(chunk);
        let first_row_at = if self.delay.continuity == Continuity::History { step + delta } else { step };
        self.pending_at = Some((step + delta, first_row_at));
        self.next_call = first_row_at + self.c - delta;
    }

    /// The action for `step`; true if a new chunk was adopted at it.
    pub fn action(&mut self, step: usize) -> (&[f32], bool) {
        self.adopt_due(step);
        (self.row(step), self.adopted_at == Some(step))
    }

    fn adopt_due(&mut self, step: usize) {
        if let Some((at, start)) = self.pending_at.filter(|(at, _)| *at <= step) {
            std::mem::swap(&mut self.active, &mut self.pending);
            (self.active_start, self.adopted_at, self.pending_at) = (start, Some(at), None);
        }
    }

    fn row(&self, step: usize) -> &[f32] {
        let i = step.saturating_sub(self.active_start).min(self.c - 1);
        &self.active[i * self.d..][..self.d]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chunk(tag: f32, c: usize) -> Vec<f32> {
        (0..c).map(|i| tag + i as f32).collect()
    }

    /// Drop-late: asked at 0, adopted at δ = 2 from its row 2; the next asked at C − δ = 6, adopted at 8.
    #[test]
    fn a_late_chunk_is_adopted_delta_steps_on_from_its_row_delta() {
        let d = Delay { periods: 2, continuity: Continuity::DropLate };
        let mut s = Schedule::new(d, 8, &[-1.0]);
        assert!(s.calls_at(0));
        s.arrived(0, &chunk(100.0, 8));
        let first: Vec<(f32, bool)> = (0..3).map(|u| (s.action(u).0[0], s.action(u).1)).collect();
        assert_eq!(first[0].0, -1.0);
        assert_eq!(first[2].0, 102.0);
        assert!(!s.calls_at(5) && s.calls_at(6));
        let mut committed = Vec::new();
        s.committed(6, &mut committed);
        assert_eq!(committed, [106.0, 107.0]);
        s.arrived(6, &chunk(200.0, 8));
        assert_eq!(s.action(7).0[0], 107.0);
        assert_eq!(s.action(8), (&[202.0][..], true));
    }

    /// History: the chunk's first row is due at u + δ, and all of it runs; the next is asked δ before its end.
    #[test]
    fn history_chunks_run_whole_from_their_arrival() {
        let d = Delay { periods: 2, continuity: Continuity::History };
        let mut s = Schedule::new(d, 8, &[-1.0]);
        s.arrived(0, &chunk(100.0, 8));
        assert_eq!(s.action(1).0[0], -1.0);
        assert_eq!(s.action(2), (&[100.0][..], true));
        assert!(s.calls_at(8));
        s.arrived(8, &chunk(200.0, 8));
        assert_eq!(s.action(9).0[0], 107.0);
        assert_eq!(s.action(10).0[0], 200.0);
    }

    /// δ = C/2: the next chunk is asked at the step the previous one is adopted, which is still adopted.
    #[test]
    fn at_half_a_chunk_each_chunk_is_still_adopted() {
        let d = Delay { periods: 4, continuity: Continuity::Guided };
        let mut s = Schedule::new(d, 8, &[-1.0]);
        s.arrived(0, &chunk(100.0, 8));
        assert!(s.calls_at(4));
        s.arrived(4, &chunk(200.0, 8));
        assert_eq!(s.action(4), (&[104.0][..], true));
        assert_eq!(s.action(8), (&[204.0][..], true));
    }

    #[test]
    fn no_delay_is_whole_chunks_back_to_back() {
        for continuity in Continuity::ALL {
            let mut s = Schedule::new(Delay { periods: 0, continuity }, 4, &[0.0]);
            s.arrived(0, &chunk(10.0, 4));
            assert_eq!(s.action(0), (&[10.0][..], true));
            assert!(s.calls_at(4));
        }
    }

    #[test]
    fn a_delay_over_half_a_chunk_is_refused() {
        assert!(Delay { periods: 5, continuity: Continuity::Guided }.check(8).is_err());
        assert!(Delay { periods: 4, continuity: Continuity::Guided }.check(8).is_ok());
        assert!("sideways".parse::<Continuity>().is_err());
    }
}
