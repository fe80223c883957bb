//! K(w): how many Euler steps a chunk gets from its modality weight.

/// K(w) = ⌈K_max·‖w‖∞⌉ clamped to [1, K_max]. The small slack keeps float noise (0.1·10 = 1.0000001) from
/// costing a whole extra step.
///
/// ```
/// use mars_policy_format::steps::steps_for;
/// assert_eq!(steps_for(0.1, 10), 1);
/// assert_eq!(steps_for(0.25, 10), 3);
/// assert_eq!(steps_for(0.0, 10), 1); // a unimodal chunk still takes one step
/// assert_eq!(steps_for(f32::NAN, 10), 10); // an unknown w gets the full budget, never fewer
/// ```
pub fn steps_for(w_inf: f32, k_max: usize) -> usize {
    let k = (k_max as f32 * w_inf - 1e-5).ceil();
    if k.is_nan() { k_max } else { (k as i64).clamp(1, k_max as i64) as usize }
}
