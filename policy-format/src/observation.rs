//! How a camera frame enters a policy's observation: the one conversion the trainer, the engine's callers and
//! `marsd replay` must agree on to the bit.

/// A camera's RGB8 bytes (row-major H, W, RGB) as the observation's image values: each byte / 255.
///
/// ```
/// let mut out = [0.0f32; 3];
/// mars_policy_format::observation::pixels_to_observation(&[0, 51, 255], &mut out);
/// assert_eq!(out, [0.0, 0.2, 1.0]);
/// ```
pub fn pixels_to_observation(rgb: &[u8], out: &mut [f32]) {
    for (o, &p) in out.iter_mut().zip(rgb) {
        *o = f32::from(p) / 255.0;
    }
}
