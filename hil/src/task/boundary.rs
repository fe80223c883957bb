//! How smooth the executed actions are across chunk boundaries: the second and third finite differences of the
//! joint targets (the gripper left out), as acceleration (rad/s²) and jerk (rad/s³) at the policy rate, the largest
//! over joints, at each step where a new chunk took over and, for reference, at every other step.
//!
//! At a boundary b (the new chunk's first executed row): acceleration x_b − 2x_{b−1} + x_{b−2}, jerk
//! x_{b+1} − 3x_b + 3x_{b−1} − x_{b−2} (marsd's own handover stencil, `mars_runtime::policy::handover`); both
//! straddle the switch from x_{b−1} (old chunk) to x_b (new).

use mars_runtime::policy::handover::jerk_across;

#[derive(Debug, Clone, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Smoothness {
    /// Mean over the episode's boundaries of the largest |acceleration| over joints (rad/s²).
    pub boundary_accel: f64,
    /// Mean over the boundaries of the largest |jerk| over joints (rad/s³).
    pub boundary_jerk: f64,
    /// The same at every step that is not a boundary.
    pub inner_accel: f64,
    pub inner_jerk: f64,
    pub boundaries: usize,
}

/// `actions` [steps × d] as executed, `adopted[s]` true where a new chunk took over at step s, `joints` the
/// leading dims that are joint targets, `rate_hz` the policy rate.
pub fn smoothness(actions: &[f32], d: usize, joints: usize, adopted: &[bool], rate_hz: f64) -> Smoothness {
    let x = |s: usize, j: usize| actions[s * d + j] as f64;
    let steps = adopted.len();
    let (mut b, mut inner) = ((0.0, 0.0, 0usize), (0.0, 0.0, 0usize));
    // Steps with two before and one after: the first chunk's adoption (from rest) is not a boundary between chunks.
    for (s, &boundary) in adopted.iter().enumerate().take(steps.saturating_sub(1)).skip(2) {
        let acc = (0..joints).map(|j| (x(s, j) - 2.0 * x(s - 1, j) + x(s - 2, j)).abs()).fold(0.0, f64::max);
        let jerk = jerk_across(&actions[(s - 2) * d..(s + 2) * d], d, joints);
        let sum = if boundary { &mut b } else { &mut inner };
        sum.0 += acc;
        sum.1 += jerk;
        sum.2 += 1;
    }
    let mean = |v: f64, n: usize| if n == 0 { 0.0 } else { v / n as f64 };
    Smoothness {
        boundary_accel: mean(b.0, b.2) * rate_hz.powi(2),
        boundary_jerk: mean(b.1, b.2) * rate_hz.powi(3),
        inner_accel: mean(inner.0, inner.2) * rate_hz.powi(2),
        inner_jerk: mean(inner.1, inner.2) * rate_hz.powi(3),
        boundaries: b.2,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ramp is smooth everywhere; a step of 0.1 rad at a boundary shows there as 0.1·rate² and 0.2·rate³ (the
    /// jerk stencil sees a step between x_{b−1} and x_b as 1 − 3 = −2 times it), and nowhere else as much.
    #[test]
    fn a_jump_at_a_boundary_is_seen_there() {
        let steps = 10;
        let mut actions: Vec<f32> = (0..steps).map(|s| 0.01 * s as f32).collect();
        let mut adopted = vec![false; steps];
        let ramp = smoothness(&actions, 1, 1, &adopted, 10.0);
        assert!(ramp.inner_accel < 1e-4 && ramp.inner_jerk < 1e-3);
        adopted[5] = true;
        for a in &mut actions[5..] {
            *a += 0.1;
        }
        let s = smoothness(&actions, 1, 1, &adopted, 10.0);
        assert_eq!(s.boundaries, 1);
        assert!((s.boundary_accel - 0.1 * 100.0).abs() < 1e-3, "{s:?}");
        assert!((s.boundary_jerk - 0.2 * 1000.0).abs() < 1e-2, "{s:?}");
        assert!(s.inner_accel < s.boundary_accel && s.inner_jerk < s.boundary_jerk, "{s:?}");
    }
}
