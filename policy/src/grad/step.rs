//! One training step of a state policy by hand: the batch's rows → encoder → scheduler w → flow source a0 →
//! the DiT on (a_τ, τ | cond) and, for L_rec, on (a0, 0 | cond) as one batch (cond: the embedding, and the
//! history if the field sees it) → L_fm, L_rec, L_div → backward in reverse →
//! AdamW. The same objective, random draws (in the same order, from the same generator) and update as
//! `crate::train::batch_losses` + candle-nn's AdamW, without a graph or an allocation per step.

use super::dit::{DitGrad, DitShape};
use super::layers;
use super::linear::Lin;
use super::params::{AdamW, Params};
use crate::config::{EncoderConfig, PolicyConfig, PolicyKind};
use crate::dataset::DatasetTensors;
use candle_nn::VarMap;
use rand::Rng;
use rand::rngs::StdRng;
use rand_distr::StandardNormal;

/// The training samples on the host: what `DatasetTensors` holds, as plain vectors.
pub struct HostData {
    obs: Vec<f32>,
    history: Vec<f32>,
    next: Vec<f32>,
    neighbours: Vec<u32>,
    s_next: Vec<f32>,
    m: usize,
}

impl HostData {
    pub fn new(t: &DatasetTensors) -> candle_core::Result<Self> {
        Ok(Self {
            obs: t.obs.flatten_all()?.to_vec1()?,
            history: t.history.flatten_all()?.to_vec1()?,
            next: t.next.flatten_all()?.to_vec1()?,
            neighbours: t.neighbours.flatten_all()?.to_vec1()?,
            s_next: t.s_next.flatten_all()?.to_vec1()?,
            m: t.neighbours.dim(1)?,
        })
    }
}

/// The loss terms of one step (before its update), as `crate::train::LossTerms` reports them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct StepTerms {
    pub total: f32,
    pub fm: f32,
    pub rec: Option<f32>,
    pub div: Option<f32>,
    /// Mean over the batch of ‖w‖∞.
    pub w_inf: f32,
}

/// Whether `cfg` trains by hand: state policies (the vision encoder stays on candle's autograd).
pub fn supports(cfg: &PolicyConfig) -> bool {
    matches!(cfg.model.encoder, EncoderConfig::StateMlp { .. })
}

/// The L_rec pass: its weight, and whether its gate is w (else 0: FM's ablation applies it everywhere).
#[derive(Debug, Clone, Copy)]
struct Rec {
    weight: f32,
    gated_by_w: bool,
}

/// Per-sample buffers, sized for the largest batch.
#[derive(Default)]
struct Rows {
    obs: Vec<f32>,
    hist: Vec<f32>,
    next: Vec<f32>,
    nh: Vec<f32>,
    s_next: Vec<f32>,
    enc_pre: Vec<f32>,
    enc_act: Vec<f32>,
    emb: Vec<f32>,
    sched_in: Vec<f32>,
    sched_pre: Vec<f32>,
    sched_act: Vec<f32>,
    w: Vec<f32>,
    eps: Vec<f32>,
    tau: Vec<f32>,
    a0: Vec<f32>,
    eps_own: Vec<f32>,
    eps_nb: Vec<f32>,
    dit_a: Vec<f32>,
    dit_tau: Vec<f32>,
    /// The DiT's conditioning input per row: [emb ‖ history] or emb.
    dit_cond: Vec<f32>,
    v: Vec<f32>,
    dv: Vec<f32>,
    da: Vec<f32>,
    da0: Vec<f32>,
    dw: Vec<f32>,
    ddit_cond: Vec<f32>,
    demb: Vec<f32>,
    dsched: Vec<f32>,
    dsched_in: Vec<f32>,
    denc: Vec<f32>,
}

pub struct HandStep {
    pub params: Params,
    adam: AdamW,
    enc1: Lin,
    enc2: Lin,
    sched: Option<(Lin, Lin)>,
    /// The velocity field's rows in [`PARTS`] shares (with L_rec: the a_τ half and the a0 half), each with its own
    /// buffers: on as many threads, or one after the other.
    dits: Vec<DitGrad>,
    /// The gradient of each share after the first (the first adds into `params.grad`), summed after.
    part_grads: Vec<Vec<f32>>,
    concurrent: bool,
    fixed_w: Option<f32>,
    rec: Option<Rec>,
    div_weight: Option<f32>,
    source_std: f32,
    sched_uses_history: bool,
    t: usize,
    d: usize,
    o: usize,
    e: usize,
    /// The DiT's conditioning width: `e`, plus t·d when it sees the history.
    c: usize,
    rows: Rows,
}

impl HandStep {
    /// For `cfg` (a state policy: see [`supports`]), with the initial weights of `varmap`.
    pub fn new(cfg: &PolicyConfig, varmap: &VarMap) -> anyhow::Result<Self> {
        let m = &cfg.model;
        let EncoderConfig::StateMlp { hidden } = m.encoder else {
            anyhow::bail!("hand-written gradients are for state policies; this one has a vision encoder")
        };
        let (t, d, o, e, b) = (m.chunk_len, m.action_dim, m.obs_dim, m.obs_embed_dim, cfg.train.batch_size);
        let mut params = Params::default();
        let enc1 = params.linear("encoder.state_mlp.fc1", o, hidden);
        let enc2 = params.linear("encoder.state_mlp.fc2", hidden, e);
        let fixed_w = cfg.kind.fixed_w(m);
        let (sched_in, c) = (m.scheduler_input_dim(), m.velocity_cond_dim());
        let sched = fixed_w.is_none().then(|| {
            let fc1 = params.linear("scheduler.mlp.fc1", sched_in, m.scheduler_hidden);
            (fc1, params.linear("scheduler.mlp.fc2", m.scheduler_hidden, d))
        });
        let shape = DitShape {
            action_dim: d,
            tokens: t,
            cond_dim: c,
            width: m.dit_width,
            depth: m.dit_depth,
            heads: m.dit_heads,
            mlp_ratio: m.dit_mlp_ratio,
        };
        let dit = DitGrad::new(shape, "velocity", &mut params, 2 * b);
        let dits = vec![dit; PARTS];
        params.load(varmap)?;
        let rec = match (cfg.kind, cfg.train.fm_lambda_rec) {
            (PolicyKind::Fm, Some(l)) => Some(Rec { weight: l as f32, gated_by_w: false }),
            (kind, _) if kind.uses_rec_loss() => Some(Rec { weight: cfg.train.lambda_rec as f32, gated_by_w: true }),
            _ => None,
        };
        let z = |n: usize| vec![0f32; n];
        let km = cfg.train.knn_m;
        let rows = Rows {
            obs: z(b * o),
            hist: z(b * t * d),
            next: z(b * t * d),
            nh: z(b * km * t * d),
            s_next: z(b * d),
            enc_pre: z(b * hidden),
            enc_act: z(b * hidden),
            emb: z(b * e),
            sched_in: z(b * sched_in),
            sched_pre: z(b * m.scheduler_hidden),
            sched_act: z(b * m.scheduler_hidden),
            w: z(b * d),
            eps: z(b * t * d),
            tau: z(b),
            a0: z(b * t * d),
            eps_own: z(b * t * d),
            eps_nb: z(b * km * t * d),
            dit_a: z(2 * b * t * d),
            dit_tau: z(2 * b),
            dit_cond: z(2 * b * c),
            v: z(2 * b * t * d),
            dv: z(2 * b * t * d),
            da: z(b * t * d),
            da0: z(b * t * d),
            dw: z(b * d),
            ddit_cond: z(2 * b * c),
            demb: z(b * e),
            dsched: z(b * m.scheduler_hidden),
            dsched_in: z(b * sched_in),
            denc: z(b * hidden),
        };
        let adam = AdamW::new(&params, cfg.train.lr, cfg.train.weight_decay);
        Ok(Self {
            part_grads: vec![vec![0.0; params.grad.len()]; PARTS - 1],
            params,
            adam,
            enc1,
            enc2,
            sched,
            dits,
            concurrent: false,
            fixed_w,
            rec,
            div_weight: cfg.kind.uses_div_loss().then_some(cfg.train.lambda_div as f32),
            source_std: m.source_std,
            sched_uses_history: m.scheduler_uses_history,
            t,
            d,
            o,
            e,
            c,
            rows,
        })
    }

    /// Runs the velocity field's shares of the rows on their own threads when `threads` > 1. The shares are the
    /// same either way, so the sums round alike: one thread or two train the same weights.
    pub fn set_threads(&mut self, threads: usize) {
        self.concurrent = threads > 1;
    }

    /// The DiT on `samples` rows of `rows.dit_*`, split across the threads; v into `rows.v`.
    fn dit_forward(&mut self, samples: usize) {
        let (chunk, c) = (self.t * self.d, self.c);
        let parts = shares(samples, PARTS);
        let (p, r) = (&self.params.value, &self.rows);
        let jobs = self.dits.iter_mut().zip(parts.clone()).map(|(dit, range)| {
            let (a, tau) = (&r.dit_a[range.start * chunk..], &r.dit_tau[range.clone()]);
            let cond = &r.dit_cond[range.start * c..];
            move || dit.forward(p, a, tau, cond, range.len())
        });
        run_all(jobs.collect(), self.concurrent);
        for (dit, range) in self.dits.iter().zip(parts) {
            let n = range.len() * chunk;
            self.rows.v[range.start * chunk..][..n].copy_from_slice(&dit.v[..n]);
        }
    }

    /// The DiT's backward from `rows.dv`, each thread its share: parameter gradients summed into
    /// `params.grad`, dL/dcond into `rows.ddit_cond`, dL/da of the first `da_samples` samples into `rows.da`.
    fn dit_backward(&mut self, samples: usize, da_samples: usize) {
        let (chunk, c) = (self.t * self.d, self.c);
        let parts = shares(samples, PARTS);
        let p = &self.params.value;
        let r = &mut self.rows;
        let (mut dcond, mut da): (&mut [f32], &mut [f32]) = (&mut r.ddit_cond, &mut r.da);
        let mut grads: Vec<&mut [f32]> = vec![&mut self.params.grad];
        grads.extend(self.part_grads.iter_mut().map(|g| {
            g.fill(0.0);
            g.as_mut_slice()
        }));
        let mut jobs = Vec::with_capacity(parts.len());
        for ((dit, range), g) in self.dits.iter_mut().zip(parts).zip(grads) {
            let (my_cond, rest_cond) = std::mem::take(&mut dcond).split_at_mut(range.len() * c);
            dcond = rest_cond;
            let want = da_samples.clamp(range.start, range.end) - range.start;
            let (my_da, rest_da) = std::mem::take(&mut da).split_at_mut(want * chunk);
            da = rest_da;
            let dv = &r.dv[range.start * chunk..];
            jobs.push(move || dit.backward(p, g, dv, range.len(), my_cond, want, my_da));
        }
        run_all(jobs, self.concurrent);
        for g in &self.part_grads {
            for (a, b) in self.params.grad.iter_mut().zip(g) {
                *a += b;
            }
        }
    }

    /// Writes the trained weights back into the model's variables.
    pub fn store(&self, varmap: &VarMap) -> anyhow::Result<()> {
        self.params.store(varmap)
    }

    /// The gradients of one batch (samples `idx` of `data`) into `self.params.grad`, without the update; the
    /// random draws come from `rng` in `batch_losses`' order.
    pub fn gradients(&mut self, data: &HostData, idx: &[u32], rng: &mut StdRng) -> StepTerms {
        let b = idx.len();
        assert!(b <= self.rows.tau.len(), "a batch of {b}; this step was sized for {}", self.rows.tau.len());
        self.gather(data, idx);
        self.forward_source(b, rng);
        let (fm, rec) = self.velocity_losses(b, rng);
        let div = self.div_weight.map(|_| self.diversity(b, data.m, rng));
        self.params.grad.fill(0.0);
        self.backward(b);
        let total =
            fm + self.rec.map_or(0.0, |r| rec * r.weight) + self.div_weight.map_or(0.0, |l| div.unwrap_or(0.0) * l);
        let w_inf = self.rows.w[..b * self.d]
            .chunks_exact(self.d)
            .map(|w| w.iter().copied().fold(f32::MIN, f32::max))
            .sum::<f32>()
            / b as f32;
        StepTerms { total, fm, rec: self.rec.map(|_| rec), div, w_inf }
    }

    /// [`Self::gradients`] and the AdamW update.
    pub fn step(&mut self, data: &HostData, idx: &[u32], rng: &mut StdRng) -> StepTerms {
        let terms = self.gradients(data, idx, rng);
        self.adam.step(&mut self.params);
        terms
    }

    fn gather(&mut self, data: &HostData, idx: &[u32]) {
        let (t, d, o, m) = (self.t, self.d, self.o, data.m);
        let r = &mut self.rows;
        let chunk = t * d;
        for (row, &i) in idx.iter().enumerate() {
            let i = i as usize;
            r.obs[row * o..][..o].copy_from_slice(&data.obs[i * o..][..o]);
            r.hist[row * chunk..][..chunk].copy_from_slice(&data.history[i * chunk..][..chunk]);
            r.next[row * chunk..][..chunk].copy_from_slice(&data.next[i * chunk..][..chunk]);
            r.s_next[row * d..][..d].copy_from_slice(&data.s_next[i * d..][..d]);
            for j in 0..m {
                let n = data.neighbours[i * m + j] as usize;
                r.nh[(row * m + j) * chunk..][..chunk].copy_from_slice(&data.history[n * chunk..][..chunk]);
            }
        }
    }

    /// Encoder, w, ε and a0 = (1 − w)⊙history + w⊙ε.
    fn forward_source(&mut self, b: usize, rng: &mut StdRng) {
        let (t, d, e) = (self.t, self.d, self.e);
        let p = &self.params.value;
        let r = &mut self.rows;
        self.enc1.forward(p, &r.obs, b, &mut r.enc_pre);
        layers::silu(&r.enc_pre[..b * self.enc1.out], &mut r.enc_act);
        self.enc2.forward(p, &r.enc_act, b, &mut r.emb);
        match (self.sched, self.fixed_w) {
            (Some((fc1, fc2)), _) => {
                let width = fc1.inp;
                for row in 0..b {
                    let dst = &mut r.sched_in[row * width..][..width];
                    dst[..e].copy_from_slice(&r.emb[row * e..][..e]);
                    if self.sched_uses_history {
                        dst[e..].copy_from_slice(&r.hist[row * t * d..][..t * d]);
                    }
                }
                fc1.forward(p, &r.sched_in, b, &mut r.sched_pre);
                layers::silu(&r.sched_pre[..b * fc1.out], &mut r.sched_act);
                fc2.forward(p, &r.sched_act, b, &mut r.w);
                layers::sigmoid_in_place(&mut r.w[..b * d]);
            }
            (None, w) => r.w[..b * d].fill(w.unwrap_or(1.0)),
        }
        fill_randn(rng, &mut r.eps[..b * t * d]);
        for v in &mut r.eps[..b * t * d] {
            *v *= self.source_std;
        }
        source(&r.hist, &r.w, &r.eps, b, t, d, &mut r.a0);
    }

    /// τ, the DiT on (a_τ, τ) [and (a0, 0)], L_fm and L_rec (0 without the pass), and their dL/dv.
    fn velocity_losses(&mut self, b: usize, rng: &mut StdRng) -> (f32, f32) {
        let samples = self.dit_inputs(b, rng);
        self.dit_forward(samples);
        let fm = self.flow_matching(b);
        (fm, self.rec.map_or(0.0, |rec| self.reconstruction(b, rec)))
    }

    /// The DiT's rows: (a_τ = (1 − τ)a0 + τa1, τ, cond), then with L_rec (a0, 0, cond); returns how many.
    fn dit_inputs(&mut self, b: usize, rng: &mut StdRng) -> usize {
        let (n, chunk, e, c) = (b * self.t * self.d, self.t * self.d, self.e, self.c);
        let r = &mut self.rows;
        for tau in &mut r.tau[..b] {
            *tau = rng.random::<f32>();
        }
        for row in 0..b {
            let tau = r.tau[row];
            for i in row * chunk..(row + 1) * chunk {
                r.dit_a[i] = r.a0[i] * (-tau + 1.0) + r.next[i] * tau;
            }
        }
        r.dit_tau[..b].copy_from_slice(&r.tau[..b]);
        for row in 0..b {
            let (emb, hist) = r.dit_cond[row * c..][..c].split_at_mut(e);
            emb.copy_from_slice(&r.emb[row * e..][..e]);
            hist.copy_from_slice(&r.hist[row * chunk..][..c - e]);
        }
        if self.rec.is_none() {
            return b;
        }
        r.dit_a[n..2 * n].copy_from_slice(&r.a0[..n]);
        r.dit_tau[b..2 * b].fill(0.0);
        r.dit_cond.copy_within(..b * c, b * c);
        2 * b
    }

    /// L_fm = mean (v − (a1 − a0))² over the a_τ rows; its dL/dv into `rows.dv`.
    fn flow_matching(&mut self, b: usize) -> f32 {
        let n = b * self.t * self.d;
        let r = &mut self.rows;
        let mut fm = 0.0;
        for i in 0..n {
            let diff = r.v[i] - (r.next[i] - r.a0[i]);
            fm += diff * diff;
            r.dv[i] = 2.0 * diff / n as f32;
        }
        fm / n as f32
    }

    /// L_rec = mean_(b, d) [(1 − gate) · mean_t |a0 + v(a0, 0) − a1|] over the a0 rows (gate detached); its
    /// dL/dv, λ_rec included, into `rows.dv`.
    fn reconstruction(&mut self, b: usize, rec: Rec) -> f32 {
        let (t, d) = (self.t, self.d);
        let (n, chunk) = (b * t * d, t * d);
        let r = &mut self.rows;
        let mut total = 0.0;
        for row in 0..b {
            for k in 0..d {
                let keep = if rec.gated_by_w { -r.w[row * d + k] + 1.0 } else { 1.0 };
                let mut sum = 0.0;
                for s in 0..t {
                    let i = row * chunk + s * d + k;
                    let x = r.a0[i] + r.v[n + i] - r.next[i];
                    sum += x.abs();
                    // |x|'s derivative with candle's sign(0) = +1.
                    let sign = if x >= 0.0 { 1.0 } else { -1.0 };
                    r.dv[n + i] = rec.weight * sign * keep / (t * b * d) as f32;
                }
                total += sum / t as f32 * keep;
            }
        }
        total / (b * d) as f32
    }

    /// L_div = mean ReLU(S_next − S), S the spread of the sample's source and its neighbours' (fresh noise, the
    /// sample's w); its dL/dw (λ_div included) into `rows.dw`, which it initialises.
    fn diversity(&mut self, b: usize, m: usize, rng: &mut StdRng) -> f32 {
        let (t, d) = (self.t, self.d);
        let chunk = t * d;
        let lambda = self.div_weight.unwrap_or(0.0);
        let r = &mut self.rows;
        fill_randn(rng, &mut r.eps_own[..b * chunk]);
        fill_randn(rng, &mut r.eps_nb[..b * m * chunk]);
        let mut loss = 0.0;
        for row in 0..b {
            for k in 0..d {
                let w = r.w[row * d + k];
                // Per (neighbour, step): the difference of the two sources and its derivative in w.
                let (mut spread, mut slope) = (0.0, 0.0);
                for j in 0..m {
                    for s in 0..t {
                        let (i, nb) = (row * chunk + s * d + k, (row * m + j) * chunk + s * d + k);
                        let own = r.hist[i] * (-w + 1.0) + r.eps_own[i] * w;
                        let other = r.nh[nb] * (-w + 1.0) + r.eps_nb[nb] * w;
                        let diff = other - own;
                        spread += diff.abs();
                        // d|diff|/dw, with candle's sign(0) = +1.
                        let sign = if diff >= 0.0 { 1.0 } else { -1.0 };
                        slope += sign * ((r.eps_nb[nb] - r.nh[nb]) - (r.eps_own[i] - r.hist[i]));
                    }
                }
                let gap = r.s_next[row * d + k] - spread / m as f32 / t as f32;
                loss += gap.max(0.0);
                // ReLU's derivative is 1 at 0 too (candle's); S = spread / (m·T); L = mean over B·D.
                let active = if gap >= 0.0 { 1.0 } else { 0.0 };
                r.dw[row * d + k] = -lambda * active * slope / (m * t) as f32 / (b * d) as f32;
            }
        }
        loss / (b * d) as f32
    }

    /// Every gradient from dL/dv (`rows.dv`) and dL/dw from L_div (`rows.dw`).
    fn backward(&mut self, b: usize) {
        let samples = if self.rec.is_some() { 2 * b } else { b };
        if self.div_weight.is_none() {
            self.rows.dw[..b * self.d].fill(0.0);
        }
        self.dit_backward(samples, if self.sched.is_some() { b } else { 0 });
        // dL/demb: the embedding's share of each row's dL/dcond (the history's is data's); the DiT's halves see
        // the same embedding.
        let (r, e, c) = (&mut self.rows, self.e, self.c);
        for row in 0..b {
            r.demb[row * e..][..e].copy_from_slice(&r.ddit_cond[row * c..][..e]);
            if samples == 2 * b {
                for (a, x) in r.demb[row * e..][..e].iter_mut().zip(&r.ddit_cond[(b + row) * c..][..e]) {
                    *a += x;
                }
            }
        }
        if self.sched.is_some() {
            self.scheduler_backward(b);
        }
        let (p, g, r) = (&self.params.value, &mut self.params.grad, &mut self.rows);
        self.enc2.backward_params(g, &r.enc_act, &r.demb, b);
        self.enc2.backward_input(p, &r.demb, b, &mut r.denc, false);
        layers::silu_backward(&r.enc_pre[..b * self.enc1.out], &mut r.denc[..b * self.enc1.out]);
        self.enc1.backward_params(g, &r.obs, &r.denc, b);
    }

    /// w's gradient from a0 (L_fm directly, and through a_τ = (1 − τ)a0 + τa1; a0 = hist + w(ε − hist)) added to
    /// `rows.dw`, then through the scheduler into its weights and `rows.demb`.
    fn scheduler_backward(&mut self, b: usize) {
        let Some((fc1, fc2)) = self.sched else { return };
        let (t, d, e, chunk) = (self.t, self.d, self.e, self.t * self.d);
        let (p, g, r) = (&self.params.value, &mut self.params.grad, &mut self.rows);
        for row in 0..b {
            let keep = -r.tau[row] + 1.0;
            for i in row * chunk..(row + 1) * chunk {
                r.da0[i] = r.dv[i] + r.da[i] * keep;
            }
            for k in 0..d {
                let steps = (0..t).map(|s| row * chunk + s * d + k);
                r.dw[row * d + k] += steps.map(|i| r.da0[i] * (r.eps[i] - r.hist[i])).sum::<f32>();
            }
        }
        // w = σ(z).
        for (dw, w) in r.dw[..b * d].iter_mut().zip(&r.w) {
            *dw *= w * (1.0 - w);
        }
        fc2.backward_params(g, &r.sched_act, &r.dw, b);
        fc2.backward_input(p, &r.dw, b, &mut r.dsched, false);
        layers::silu_backward(&r.sched_pre[..b * fc1.out], &mut r.dsched[..b * fc1.out]);
        fc1.backward_params(g, &r.sched_in, &r.dsched, b);
        fc1.backward_input(p, &r.dsched, b, &mut r.dsched_in, false);
        for row in 0..b {
            for (a, x) in r.demb[row * e..][..e].iter_mut().zip(&r.dsched_in[row * fc1.inp..][..e]) {
                *a += x;
            }
        }
    }
}

/// How many shares the velocity field's rows are split into (see [`HandStep::set_threads`]).
const PARTS: usize = 2;

/// Runs the jobs: the first on this thread and each other on a thread of its own, all at once, when
/// `concurrent`; else one after the other. Returns when all are done.
fn run_all<F: FnOnce() + Send>(jobs: Vec<F>, concurrent: bool) {
    let mut jobs = jobs.into_iter();
    let Some(first) = jobs.next() else { return };
    if !concurrent {
        first();
        jobs.for_each(|job| job());
        return;
    }
    std::thread::scope(|scope| {
        for job in jobs {
            scope.spawn(job);
        }
        first();
    });
}

/// `n` split into `parts` contiguous ranges, as even as can be (the first ones one longer).
fn shares(n: usize, parts: usize) -> Vec<std::ops::Range<usize>> {
    let parts = parts.clamp(1, n.max(1));
    let (size, extra) = (n / parts, n % parts);
    let mut start = 0;
    (0..parts)
        .map(|i| {
            let len = size + usize::from(i < extra);
            start += len;
            start - len..start
        })
        .collect()
}

/// a0 = (1 − w)⊙history + w⊙ε, w [B, D] shared by the chunk's steps.
#[allow(clippy::too_many_arguments)]
fn source(hist: &[f32], w: &[f32], eps: &[f32], b: usize, t: usize, d: usize, a0: &mut [f32]) {
    for row in 0..b {
        for s in 0..t {
            for k in 0..d {
                let (i, w) = ((row * t + s) * d + k, w[row * d + k]);
                a0[i] = hist[i] * (-w + 1.0) + eps[i] * w;
            }
        }
    }
}

/// Standard normal draws, as `crate::train::randn` makes them.
fn fill_randn(rng: &mut StdRng, out: &mut [f32]) {
    for v in out {
        *v = rng.sample(StandardNormal);
    }
}
