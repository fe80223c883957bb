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

/// A policy that maps (observation, history of executed actions) to a chunk of future actions.
pub trait ChunkPolicy {
    fn action_dim(&self) -> usize;
    fn chunk_len(&self) -> usize;
    fn history_len(&self) -> usize;
    /// `history` is `history_len × action_dim`, row-major, oldest first; seeds any noise from its own state.
    fn predict(&mut self, observation: &[f32], history: &[f32]) -> anyhow::Result<Prediction>;
}
