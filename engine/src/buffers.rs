//! Every activation buffer a call needs, sized from the dims and allocated once at load time. A call only
//! writes into these, which is what makes it allocation-free.

use crate::dims::Dims;

fn zeros(n: usize) -> Box<[f32]> {
    vec![0.0; n].into_boxed_slice()
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
    /// The ODE state a (normalised) [C, D]: the source a0, then the chunk.
    pub a: Box<[f32]>,
    /// The chunk in task units [C, D].
    pub chunk: Box<[f32]>,
    /// cond_in(emb) [W]: the observation's share of the DiT conditioning, the same at every step.
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
    pub fn new(d: &Dims) -> Self {
        let (c, w, cd) = (d.chunk, d.width, d.chunk_values());
        let sched = d.scheduler;
        Self {
            obs: zeros(d.obs),
            hist: zeros(cd),
            enc_in: zeros(if d.vision.is_some() { d.enc_input } else { 0 }),
            enc_hidden: zeros(d.enc_hidden),
            emb: zeros(d.embed),
            sched_in: zeros(sched.filter(|s| s.uses_history).map_or(0, |s| s.input)),
            sched_hidden: zeros(sched.map_or(0, |s| s.hidden)),
            w: zeros(d.action),
            eps: zeros(cd),
            a: zeros(cd),
            chunk: zeros(cd),
            cond: zeros(w),
            freq: zeros(d.k_max * d.freq),
            time_hidden: zeros(d.k_max * w),
            time_emb: zeros(d.k_max * w),
            c: zeros(d.k_max * w),
            mods: zeros(d.k_max * d.ada_rows()),
            x: zeros(c * w),
            h: zeros(c * w),
            qkv: zeros(c * 3 * w),
            attn: zeros(c * w),
            proj: zeros(c * w),
            mlp_hidden: zeros(c * d.mlp_hidden),
            scores: zeros(c),
            v: zeros(cd),
        }
    }
}
