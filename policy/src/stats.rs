//! Small statistics shared by training and the commands.

/// The nearest-rank q-quantile (q in [0, 1]) of `v`; 0 for an empty slice. Sorts `v`.
pub fn quantile(v: &mut [f32], q: f64) -> f32 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f32::total_cmp);
    let rank = ((q.clamp(0.0, 1.0) * v.len() as f64).ceil() as usize).clamp(1, v.len());
    v[rank - 1]
}
