//! Every activation buffer a call needs, sized from the dims and allocated once at load time. A call only
//! writes into these, which is what makes it allocation-free.

use crate::dims::Dims;

/// The most `f32` values the engine allocates for one model's buffers (1 GiB): a checkpoint whose sizes ask for
/// more (the config's limits allow products far beyond any trained model: K_max = 1000 steps of a 64-block DiT) is
/// refused at load, not aborted on.
pub const MAX_BUFFER_VALUES: usize = 1 << 28;

/// Allocates zeroed buffers whose sizes are checked products, until their total would pass
/// [`MAX_BUFFER_VALUES`]: then the error names the buffer and its factors.
#[derive(Default)]
pub(crate) struct Allocator {
    total: usize,
}

impl Allocator {
    pub(crate) fn zeros(&mut self, what: &str, factors: &[usize]) -> Result<Box<[f32]>, String> {
        let n = factors.iter().try_fold(1usize, |n, &f| n.checked_mul(f));
        match n.and_then(|n| self.total.checked_add(n)).filter(|&t| t <= MAX_BUFFER_VALUES) {
            Some(total) => {
                self.total = total;
                Ok(vec![0.0; n.unwrap_or(0)].into_boxed_slice())
            }
            None => Err(format!(
                "its {what} buffer of {} values makes more than the engine's {MAX_BUFFER_VALUES} in all",
                factors.iter().map(usize::to_string).collect::<Vec<_>>().join(" × ")
            )),
        }
    }
}

pub struct Buffers {
    /// Normalised observation.
    pub obs: Box<[f32]>,
    /// Normalised history [C, D].
    pub hist: Box<[f32]>,
    /// A vision encoder's MLP input [camera features ‖ state]; empty for a state encoder (it reads `obs`).
    pub enc_in: Box<[f32]>,
    pub enc_hidden: Box<[f32]>,
    /// Observation embedding [E].
    pub emb: Box<[f32]>,
    /// [emb ‖ history] when the scheduler sees the history, else empty.
    pub sched_in: Box<[f32]>,
    pub sched_hidden: Box<[f32]>,
    /// The modality weight w [D].
    pub w: Box<[f32]>,
    /// ε [C, D].
    pub eps: Box<[f32]>,
    /// The committed actions of [`crate::Engine::infer_after`] (normalised) [C, D]; only their first rows are used.
    pub committed: Box<[f32]>,
    /// The ODE state a (normalised) [C, D]: the source a0, then the chunk.
    pub a: Box<[f32]>,
    /// The chunk in task units [C, D].
    pub chunk: Box<[f32]>,
    /// [emb ‖ history] when the velocity field sees the history, else empty (cond_in reads `emb`).
    pub cond_input: Box<[f32]>,
    /// cond_in(emb [‖ history]) [W]: the observation's share of the DiT conditioning, the same at every step.
    pub cond: Box<[f32]>,
    /// Sinusoid features of each step's τ [K_max, freq].
    pub freq: Box<[f32]>,
    pub time_hidden: Box<[f32]>,
    pub time_emb: Box<[f32]>,
    /// c = silu(time_emb + cond) per step [K_max, W].
    pub c: Box<[f32]>,
    /// All adaLN outputs of every step [K_max, (6·depth + 2)·W].
    pub mods: Box<[f32]>,
    /// Residual stream [C, W].
    pub x: Box<[f32]>,
    /// Normalised and modulated tokens [C, W].
    pub h: Box<[f32]>,
    pub qkv: Box<[f32]>,
    pub attn: Box<[f32]>,
    /// Output of the attention projection or of the MLP [C, W].
    pub proj: Box<[f32]>,
    pub mlp_hidden: Box<[f32]>,
    pub scores: Box<[f32]>,
    /// Velocity [C, D].
    pub v: Box<[f32]>,
}

impl Buffers {
    /// The buffers of `d` (a validated config's sizes), or why they are too large (see [`Allocator`]).
    pub fn new(d: &Dims) -> Result<Self, String> {
        let mut a = Allocator::default();
        let (c, w, cd) = (d.chunk, d.width, [d.chunk, d.action]);
        let sched = d.scheduler;
        Ok(Self {
            obs: a.zeros("observation", &[d.obs])?,
            hist: a.zeros("history", &cd)?,
            enc_in: a.zeros("encoder input", &[if d.vision.is_some() { d.enc_input } else { 0 }])?,
            enc_hidden: a.zeros("encoder hidden", &[d.enc_hidden])?,
            emb: a.zeros("embedding", &[d.embed])?,
            sched_in: a.zeros("scheduler input", &[sched.filter(|s| s.uses_history).map_or(0, |s| s.input)])?,
            sched_hidden: a.zeros("scheduler hidden", &[sched.map_or(0, |s| s.hidden)])?,
            w: a.zeros("w", &[d.action])?,
            eps: a.zeros("noise", &cd)?,
            committed: a.zeros("committed actions", &cd)?,
            a: a.zeros("ODE state", &cd)?,
            chunk: a.zeros("chunk", &cd)?,
            cond_input: a.zeros("conditioning input", &[if d.cond_input > d.embed { d.cond_input } else { 0 }])?,
            cond: a.zeros("conditioning", &[w])?,
            freq: a.zeros("time features", &[d.k_max, d.freq])?,
            time_hidden: a.zeros("time hidden", &[d.k_max, w])?,
            time_emb: a.zeros("time embedding", &[d.k_max, w])?,
            c: a.zeros("step conditioning", &[d.k_max, w])?,
            mods: a.zeros("adaLN outputs", &[d.k_max, 6 * d.depth + 2, w])?,
            x: a.zeros("residual stream", &[c, w])?,
            h: a.zeros("normalised tokens", &[c, w])?,
            qkv: a.zeros("qkv", &[c, 3, w])?,
            attn: a.zeros("attention", &[c, w])?,
            proj: a.zeros("projection", &[c, w])?,
            mlp_hidden: a.zeros("MLP hidden", &[c, d.mlp_hidden])?,
            scores: a.zeros("scores", &[c])?,
            v: a.zeros("velocity", &cd)?,
        })
    }
}
