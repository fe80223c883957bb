//! Guidance toward committed actions: real-time chunking for a flow policy whose chunk arrives after the robot has
//! already executed its first rows from the previous chunk (Black, Galliker, Levine, "Real-Time Execution of Action
//! Chunking Flow Policies", 2025).
//!
//! Each Euler step's velocity v at flow time τ is corrected on the committed rows toward the committed actions Y,
//! through the step's estimate of the final chunk, Â₁ = a + (1 − τ)·v:
//!
//! v ← v + c(τ)·(Y − Â₁) on the committed rows, c(τ) = min(β, (1 − τ)/(τ·r²_τ), 1/Δτ), r²_τ = (1 − τ)²/(τ² + (1 − τ)²).
//!
//! The paper's guidance is the vector–Jacobian product (Y − Â₁)ᵀ·∂Â₁/∂a; this engine has no backward pass, so it
//! takes ∂Â₁/∂a = I (the velocity field's own dependence on a is left out). The rows after the committed ones then
//! follow the committed rows only through the network's attention at the next steps. The cap 1/Δτ keeps a step from
//! carrying the estimate past Y (with Δτ = 1, a single step, the committed rows land on Y exactly).

/// The paper's cap on the guidance weight (β = 5 in its experiments).
pub const GUIDANCE_CAP: f32 = 5.0;

/// c(τ) for an Euler step of `dt` from flow time `tau` (both in [0, 1]).
///
/// ```
/// use mars_engine::continuity::{guidance_weight, GUIDANCE_CAP};
/// assert_eq!(guidance_weight(0.0, 0.2, GUIDANCE_CAP), GUIDANCE_CAP); // (1 − τ)/(τ r²) is infinite at τ = 0
/// assert!((guidance_weight(0.5, 0.1, GUIDANCE_CAP) - 2.0).abs() < 1e-6); // (0.25 + 0.25)/(0.5 · 0.5)
/// assert_eq!(guidance_weight(0.0, 1.0, GUIDANCE_CAP), 1.0); // one step: c·Δτ = 1 lands on Y
/// ```
pub fn guidance_weight(tau: f32, dt: f32, beta: f32) -> f32 {
    let one_minus = 1.0 - tau;
    // (1 − τ)/(τ·r²) = (τ² + (1 − τ)²)/(τ·(1 − τ)); infinite at either end, where β caps it.
    let denom = tau * one_minus;
    let pigdm = if denom > 0.0 { (tau * tau + one_minus * one_minus) / denom } else { f32::INFINITY };
    pigdm.min(beta).min(1.0 / dt)
}

/// Adds the guidance to `v` on the committed rows: `committed` holds the first rows' values (normalised units),
/// `v` and `a` the whole chunk's velocity and state; rows beyond `committed.len()` are untouched.
pub fn guide(v: &mut [f32], a: &[f32], committed: &[f32], tau: f32, weight: f32) {
    let one_minus = 1.0 - tau;
    for ((v, &a), &y) in v.iter_mut().zip(a).zip(committed) {
        let estimate = a + one_minus * *v;
        *v += weight * (y - estimate);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Euler steps of a zero field from a = 0 with the guidance: the committed value is approached, never
    /// overshot, and reached at the last step when c·Δτ = 1 there.
    #[test]
    fn guided_steps_approach_the_committed_value_without_overshoot() {
        for k in 1..=10 {
            let dt = 1.0 / k as f32;
            let (mut a, y) = ([0.0f32], [1.0f32]);
            for step in 0..k {
                let tau = step as f32 * dt;
                let mut v = [0.0f32];
                guide(&mut v, &a, &y, tau, guidance_weight(tau, dt, GUIDANCE_CAP));
                let before = a[0];
                a[0] += v[0] * dt;
                assert!(a[0] >= before && a[0] <= 1.0 + 1e-6, "k {k} step {step}: {before} → {}", a[0]);
            }
            assert!(a[0] > 0.6, "k {k}: ended at {}", a[0]);
        }
    }

    #[test]
    fn rows_beyond_the_committed_ones_are_untouched() {
        let (mut v, a) = ([0.5f32, 0.5, 0.5], [0.0f32; 3]);
        guide(&mut v, &a, &[2.0], 0.3, 1.0);
        assert_eq!(v[1..], [0.5, 0.5]);
        assert!(v[0] > 0.5);
    }
}
