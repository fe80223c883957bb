//! What a task's evaluation loop needs from a policy: one call per re-plan, a chunk out.

/// One policy call's answer.
#[derive(Debug, Clone, PartialEq)]
pub struct Prediction {
    /// `chunk_len × action_dim`, row-major, in the task's (unnormalised) action units.
    pub chunk: Vec<f32>,
    /// The modality weight w, one per action dimension (all 1 for flow matching, all 0 for A2A).
    pub w: Vec<f32>,
    /// ODE steps the policy used for this chunk.
    pub k: usize,
}

/// The sizes an evaluation needs of a policy, whether it is called one rollout or many at a time.
pub trait PolicyShape {
    fn action_dim(&self) -> usize;
    fn chunk_len(&self) -> usize;
    fn history_len(&self) -> usize;
}

/// A policy that maps (observation, history of executed actions) to a chunk of future actions.
pub trait ChunkPolicy: PolicyShape {
    /// `history` is `history_len × action_dim`, row-major, oldest first; seeds any noise from its own state.
    fn predict(&mut self, observation: &[f32], history: &[f32]) -> anyhow::Result<Prediction>;
}

/// A policy that answers many rollouts' calls in one pass (an evaluation's rollouts batched through the model).
///
/// Each call's noise comes from its `noise_key` alone (with the policy's own seed), never from the order or the
/// company of the calls in a batch: a rollout then samples the same chunks whatever batch it runs in.
pub trait BatchPolicy: PolicyShape {
    /// `observations`: B × obs_dim, `histories`: B × history_len × action_dim (row-major, oldest first),
    /// `noise_keys`: B; one [`Prediction`] per row, in order.
    fn predict_batch(
        &mut self,
        observations: &[f32],
        histories: &[f32],
        noise_keys: &[u64],
    ) -> anyhow::Result<Vec<Prediction>>;
}

/// The noise key of a rollout's `call`-th call: SplitMix64 of the pair, so nearby seeds and calls give
/// unrelated keys.
pub fn noise_key(rollout_seed: u64, call: u64) -> u64 {
    let mut z = rollout_seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ call.wrapping_add(0xD1B5_4A32_D192_ED03);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
