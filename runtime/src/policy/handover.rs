//! How smoothly one chunk hands over to the next, as the policy's actions go (before the servo's jerk-limited
//! smoothing): the third difference of the joint targets across each switch, x_{b+1} − 3x_b + 3x_{b−1} − x_{b−2}
//! with b the new chunk's first row, the largest over joints, per s³ at the policy rate (rad/s³ for a joint-space
//! policy). A chunk that ignores
//! what the previous one was doing shows here; the servo then absorbs the jump at its jerk limit.

use serde::Serialize;

/// Over an episode's or a run's handovers (the first chunk of an episode, from rest, is not one).
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct HandoverJerk {
    pub handovers: u64,
    /// In the action's units per s³ (rad/s³ for a joint-space policy).
    pub mean_rad_s3: f64,
    pub max_rad_s3: f64,
    /// The sum of squared deviations from the mean (Welford's), for the spread.
    #[serde(skip)]
    m2: f64,
    /// The standard deviation over the handovers.
    pub std_rad_s3: f64,
}

impl HandoverJerk {
    /// `rows`: four actions of `d` values due in consecutive periods, the new chunk's first third among them.
    pub fn add(&mut self, rows: &[f32], d: usize, joints: usize, rate_hz: f64) {
        let jerk = jerk_across(rows, d, joints) * rate_hz.powi(3);
        self.handovers += 1;
        let delta = jerk - self.mean_rad_s3;
        self.mean_rad_s3 += delta / self.handovers as f64;
        self.m2 += delta * (jerk - self.mean_rad_s3);
        self.std_rad_s3 = if self.handovers > 1 { (self.m2 / (self.handovers - 1) as f64).sqrt() } else { 0.0 };
        self.max_rad_s3 = self.max_rad_s3.max(jerk);
    }
}

/// The largest |x₃ − 3x₂ + 3x₁ − x₀| over the first `joints` of four consecutive rows of `d` values (per period³).
pub fn jerk_across(rows: &[f32], d: usize, joints: usize) -> f64 {
    let x = |r: usize, j: usize| f64::from(rows[r * d + j]);
    (0..joints).map(|j| (x(3, j) - 3.0 * x(2, j) + 3.0 * x(1, j) - x(0, j)).abs()).fold(0.0, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A step of h between the old chunk's last row and the new chunk's first is 2h·rate³ (the stencil's 1 − 3).
    #[test]
    fn a_step_at_the_handover_is_twice_its_size_times_rate_cubed() {
        let mut h = HandoverJerk::default();
        h.add(&[0.0, 9.0, 0.0, 9.0, 0.1, 9.0, 0.1, 9.0], 2, 1, 10.0);
        h.add(&[0.0, 5.0, 0.1, 5.0, 0.2, 5.0, 0.3, 5.0], 2, 1, 10.0); // a ramp: no jerk
        assert_eq!(h.handovers, 2);
        assert!((h.max_rad_s3 - 200.0).abs() < 1e-3, "{h:?}");
        assert!((h.mean_rad_s3 - 100.0).abs() < 1e-3, "{h:?}");
        assert!((h.std_rad_s3 - 200f64.sqrt() * 10.0).abs() < 1e-3, "{h:?}"); // √((100² + 100²)/1)
    }
}
