//! The actions handed to the servo, by the policy period each is due in: where a call's history (the C actions
//! before its chunk) and its committed rows (those the previous chunk will have executed when an early-asked chunk
//! arrives, `[policy] ask_ahead_periods`) are read from.
//!
//! Row i of the chunk asked at period k is due in period k + 1 + i. A period no chunk covered (a call dropped over
//! budget) holds the last action before it, as the servo does when a chunk runs out. Fixed capacity, no
//! allocation after [`Timeline::new`].

pub struct Timeline {
    d: usize,
    /// Capacity in rows: enough for a history and the committed rows after it.
    rows: usize,
    values: Vec<f32>,
    /// One past the last period written.
    end: i64,
}

impl Timeline {
    /// Every period up to period 0 holds `rest`; `capacity` rows are kept.
    pub fn new(rest: &[f32], capacity: usize) -> Self {
        let d = rest.len();
        Self { d, rows: capacity, values: rest.repeat(capacity), end: 1 }
    }

    /// `actions` (whole rows) due from period `first` on. A gap since the last write is filled with its last row.
    pub fn write(&mut self, first: i64, actions: &[f32]) {
        while self.end < first {
            self.copy_row(self.end - 1, self.end);
            self.end += 1;
        }
        for (i, row) in actions.chunks_exact(self.d).enumerate() {
            let at = self.slot(first + i as i64);
            self.values[at..at + self.d].copy_from_slice(row);
        }
        self.end = self.end.max(first + (actions.len() / self.d) as i64);
    }

    /// The rows due from period `first` on, into `out` (whole rows); periods past the last written hold its last
    /// row, periods before the kept window are not asked for (the caller reads at most `capacity` back).
    pub fn read(&self, first: i64, out: &mut [f32]) {
        for (i, row) in out.chunks_exact_mut(self.d).enumerate() {
            let at = self.slot((first + i as i64).min(self.end - 1));
            row.copy_from_slice(&self.values[at..at + self.d]);
        }
    }

    fn copy_row(&mut self, from: i64, to: i64) {
        let (a, b) = (self.slot(from), self.slot(to));
        self.values.copy_within(a..a + self.d, b);
    }

    fn slot(&self, period: i64) -> usize {
        period.rem_euclid(self.rows as i64) as usize * self.d
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn read(t: &Timeline, first: i64, n: usize) -> Vec<f32> {
        let mut out = vec![0.0; n];
        t.read(first, &mut out);
        out
    }

    #[test]
    fn history_before_the_first_chunk_is_the_rest_pose() {
        let t = Timeline::new(&[7.0], 16);
        assert_eq!(read(&t, -7, 8), [7.0; 8]);
        assert_eq!(read(&t, 1, 2), [7.0; 2]);
    }

    #[test]
    fn rows_are_read_back_by_period_and_a_gap_holds_the_last_row() {
        let mut t = Timeline::new(&[0.0], 16);
        t.write(1, &[1.0, 2.0, 3.0, 4.0]);
        assert_eq!(read(&t, 0, 6), [0.0, 1.0, 2.0, 3.0, 4.0, 4.0]);
        // Periods 5..=8 had no chunk (a dropped call): they held 4.
        t.write(9, &[9.0, 10.0]);
        assert_eq!(read(&t, 3, 8), [3.0, 4.0, 4.0, 4.0, 4.0, 4.0, 9.0, 10.0]);
        // An early-asked chunk overwrites rows not yet due.
        t.write(10, &[20.0, 21.0]);
        assert_eq!(read(&t, 9, 3), [9.0, 20.0, 21.0]);
    }

    #[test]
    fn the_ring_wraps_without_losing_the_window() {
        let mut t = Timeline::new(&[0.0, 0.0], 4);
        for k in 0..10 {
            t.write(1 + k, &[k as f32, -(k as f32)]);
        }
        assert_eq!(read(&t, 7, 3 * 2), [6.0, -6.0, 7.0, -7.0, 8.0, -8.0]);
    }
}
