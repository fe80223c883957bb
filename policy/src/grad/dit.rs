//! The DiT velocity field (`crate::nn::dit`) forward, keeping what its backward needs, and the backward: from
//! dL/dv to every DiT parameter's gradient, to the conditioning input's (the observation embedding, and the
//! history if the model feeds it) and (for the rows asked for) the input actions'. Rows are `samples × tokens`; a sample's conditioning c [W] modulates all its tokens.

use super::attention::Attention;
use super::layers::{self, Modulation};
use super::linear::Lin;
use super::params::Params;

const LN_EPS: f32 = 1e-6;

/// The DiT's sizes (`crate::nn::dit::DitDims`).
#[derive(Debug, Clone, Copy)]
pub struct DitShape {
    pub action_dim: usize,
    pub tokens: usize,
    pub cond_dim: usize,
    pub width: usize,
    pub depth: usize,
    pub heads: usize,
    pub mlp_ratio: usize,
}

#[derive(Clone)]
struct Block {
    qkv: Lin,
    out: Lin,
    fc1: Lin,
    fc2: Lin,
    ada: Lin,
}

/// One block's forward values, for its backward.
#[derive(Default, Clone)]
struct BlockCache {
    m: Vec<f32>,
    n1: Vec<f32>,
    inv1: Vec<f32>,
    h1: Vec<f32>,
    qkv: Vec<f32>,
    probs: Vec<f32>,
    att: Vec<f32>,
    att_out: Vec<f32>,
    n2: Vec<f32>,
    inv2: Vec<f32>,
    h2: Vec<f32>,
    f_pre: Vec<f32>,
    f_act: Vec<f32>,
    mlp_out: Vec<f32>,
}

/// Scratch of the backward pass.
#[derive(Default, Clone)]
struct Scratch {
    dx: Vec<f32>,
    dh: Vec<f32>,
    dn: Vec<f32>,
    dbranch: Vec<f32>,
    dqkv: Vec<f32>,
    datt: Vec<f32>,
    df: Vec<f32>,
    dm: Vec<f32>,
    dc: Vec<f32>,
    dt: Vec<f32>,
}

/// Clones share nothing: each can run its own rows on its own thread.
#[derive(Clone)]
pub struct DitGrad {
    s: DitShape,
    freq: usize,
    action_in: Lin,
    pos: usize,
    time1: Lin,
    time2: Lin,
    cond_in: Lin,
    blocks: Vec<Block>,
    final_ada: Lin,
    action_out: Lin,
    attention: Attention,
    // Forward values.
    a: Vec<f32>,
    /// The conditioning input [r, cond_dim].
    cond: Vec<f32>,
    tfeat: Vec<f32>,
    t_pre: Vec<f32>,
    t_act: Vec<f32>,
    c_pre: Vec<f32>,
    c: Vec<f32>,
    caches: Vec<BlockCache>,
    x_last: Vec<f32>,
    mf: Vec<f32>,
    nf: Vec<f32>,
    invf: Vec<f32>,
    hf: Vec<f32>,
    /// The velocity [rows, D] of the last forward.
    pub v: Vec<f32>,
    sc: Scratch,
}

impl DitGrad {
    /// Registers the DiT's parameters under `prefix` and sizes its buffers for up to `max_samples` samples.
    pub fn new(s: DitShape, prefix: &str, params: &mut Params, max_samples: usize) -> Self {
        let (w, f) = (s.width, s.width * s.mlp_ratio);
        let freq = w.max(32);
        let action_in = params.linear(&format!("{prefix}.action_in"), s.action_dim, w);
        let pos = params.add(&format!("{prefix}.pos_embed"), &[s.tokens, w]);
        let time1 = params.linear(&format!("{prefix}.time.mlp.fc1"), freq, w);
        let time2 = params.linear(&format!("{prefix}.time.mlp.fc2"), w, w);
        let cond_in = params.linear(&format!("{prefix}.cond_in"), s.cond_dim, w);
        let blocks = (0..s.depth)
            .map(|i| {
                let p = format!("{prefix}.blocks.{i}");
                Block {
                    qkv: params.linear(&format!("{p}.attn.qkv"), w, 3 * w),
                    out: params.linear(&format!("{p}.attn.out"), w, w),
                    fc1: params.linear(&format!("{p}.mlp.fc1"), w, f),
                    fc2: params.linear(&format!("{p}.mlp.fc2"), f, w),
                    ada: params.linear(&format!("{p}.ada"), w, 6 * w),
                }
            })
            .collect();
        let final_ada = params.linear(&format!("{prefix}.final_ada"), w, 2 * w);
        let action_out = params.linear(&format!("{prefix}.action_out"), w, s.action_dim);
        let (r, rt) = (max_samples, max_samples * s.tokens);
        let z = |n: usize| vec![0f32; n];
        let cache = || BlockCache {
            m: z(r * 6 * w),
            n1: z(rt * w),
            inv1: z(rt),
            h1: z(rt * w),
            qkv: z(rt * 3 * w),
            probs: z(r * s.heads * s.tokens * s.tokens),
            att: z(rt * w),
            att_out: z(rt * w),
            n2: z(rt * w),
            inv2: z(rt),
            h2: z(rt * w),
            f_pre: z(rt * f),
            f_act: z(rt * f),
            mlp_out: z(rt * w),
        };
        let sc = Scratch {
            dx: z(rt * w),
            dh: z(rt * w),
            dn: z(rt * w),
            dbranch: z(rt * w),
            dqkv: z(rt * 3 * w),
            datt: z(rt * w),
            df: z(rt * f),
            dm: z(r * 6 * w),
            dc: z(r * w),
            dt: z(r * w),
        };
        Self {
            s,
            freq,
            action_in,
            pos,
            time1,
            time2,
            cond_in,
            blocks,
            final_ada,
            action_out,
            attention: Attention::new(s.tokens, w, s.heads),
            a: z(rt * s.action_dim),
            cond: z(r * s.cond_dim),
            tfeat: z(r * freq),
            t_pre: z(r * w),
            t_act: z(r * w),
            c_pre: z(r * w),
            c: z(r * w),
            caches: (0..s.depth).map(|_| cache()).collect(),
            x_last: z(rt * w),
            mf: z(r * 2 * w),
            nf: z(rt * w),
            invf: z(rt),
            hf: z(rt * w),
            v: z(rt * s.action_dim),
            sc,
        }
    }

    fn modulation(&self, m_width: usize, shift_at: usize) -> Modulation {
        let w = self.s.width;
        Modulation { tokens: self.s.tokens, width: w, m_width, shift_at, scale_at: shift_at + w }
    }

    /// v for `r` samples: `a` [r·T, D], `tau` [r], `cond` [r, cond_dim]; into `self.v`.
    pub fn forward(&mut self, p: &[f32], a: &[f32], tau: &[f32], cond: &[f32], r: usize) {
        let (t, w, d, e) = (self.s.tokens, self.s.width, self.s.action_dim, self.s.cond_dim);
        let rt = r * t;
        self.a[..rt * d].copy_from_slice(&a[..rt * d]);
        self.cond[..r * e].copy_from_slice(&cond[..r * e]);
        // c = SiLU(time MLP(features(τ)) + cond_in(cond)).
        layers::time_features(&tau[..r], self.freq, &mut self.tfeat);
        self.time1.forward(p, &self.tfeat, r, &mut self.t_pre);
        layers::silu(&self.t_pre[..r * w], &mut self.t_act);
        self.time2.forward(p, &self.t_act, r, &mut self.c_pre);
        self.cond_in.forward(p, &self.cond, r, &mut self.sc.dt);
        for (c, o) in self.c_pre[..r * w].iter_mut().zip(&self.sc.dt) {
            *c += o;
        }
        layers::silu(&self.c_pre[..r * w], &mut self.c);
        // Tokens: action_in(a) + pos.
        let mut x = std::mem::take(&mut self.x_last);
        self.action_in.forward(p, &self.a, rt, &mut x);
        for (i, row) in x[..rt * w].chunks_exact_mut(w).enumerate() {
            for (v, q) in row.iter_mut().zip(&p[self.pos + (i % t) * w..]) {
                *v += q;
            }
        }
        for i in 0..self.blocks.len() {
            self.block_forward(i, p, &mut x, r);
        }
        self.x_last = x;
        // Final: action_out(modulate(LN(x), shift, scale)).
        self.final_ada.forward(p, &self.c, r, &mut self.mf);
        layers::layer_norm(&self.x_last[..rt * w], w, LN_EPS, &mut self.nf, &mut self.invf);
        self.modulation(2 * w, 0).forward(&self.nf[..rt * w], &self.mf, &mut self.hf);
        self.action_out.forward(p, &self.hf, rt, &mut self.v);
    }

    /// One block on `x` [r·T, W] in place.
    fn block_forward(&mut self, i: usize, p: &[f32], x: &mut [f32], r: usize) {
        let (t, w) = (self.s.tokens, self.s.width);
        let (rt, f) = (r * t, w * self.s.mlp_ratio);
        let (mod1, mod2) = (self.modulation(6 * w, 0), self.modulation(6 * w, 3 * w));
        let (b, k) = (&self.blocks[i], &mut self.caches[i]);
        b.ada.forward(p, &self.c, r, &mut k.m);
        layers::layer_norm(&x[..rt * w], w, LN_EPS, &mut k.n1, &mut k.inv1);
        mod1.forward(&k.n1[..rt * w], &k.m, &mut k.h1);
        b.qkv.forward(p, &k.h1, rt, &mut k.qkv);
        self.attention.forward(&k.qkv, r, &mut k.probs, &mut k.att);
        b.out.forward(p, &k.att, rt, &mut k.att_out);
        layers::gated_add(&mut x[..rt * w], &k.att_out, &k.m, &mod1, 2 * w);
        layers::layer_norm(&x[..rt * w], w, LN_EPS, &mut k.n2, &mut k.inv2);
        mod2.forward(&k.n2[..rt * w], &k.m, &mut k.h2);
        b.fc1.forward(p, &k.h2, rt, &mut k.f_pre);
        layers::silu(&k.f_pre[..rt * f], &mut k.f_act);
        b.fc2.forward(p, &k.f_act, rt, &mut k.mlp_out);
        layers::gated_add(&mut x[..rt * w], &k.mlp_out, &k.m, &mod2, 5 * w);
    }

    /// From `dv` [r·T, D] (dL/dv of the last forward): every DiT gradient added into `g` (the parameter vector's
    /// layout; `p` the values), dL/dcond [r, cond_dim] into `dcond`, and dL/da for the first `da_samples` samples into `da` [da_samples·T, D].
    #[allow(clippy::too_many_arguments)]
    pub fn backward(
        &mut self,
        p: &[f32],
        g: &mut [f32],
        dv: &[f32],
        r: usize,
        dcond: &mut [f32],
        da_samples: usize,
        da: &mut [f32],
    ) {
        let (t, w) = (self.s.tokens, self.s.width);
        let rt = r * t;
        let sc = &mut self.sc;
        // Final layer.
        self.action_out.backward_input(p, dv, rt, &mut sc.dh, false);
        self.action_out.backward_params(g, &self.hf, dv, rt);
        let fin = Modulation { tokens: t, width: w, m_width: 2 * w, shift_at: 0, scale_at: w };
        sc.dm[..r * 2 * w].fill(0.0);
        fin.backward(&sc.dh[..rt * w], &self.nf, &self.mf, &mut sc.dn, &mut sc.dm);
        sc.dx[..rt * w].fill(0.0);
        layers::layer_norm_backward(&sc.dn[..rt * w], &self.nf, &self.invf, w, &mut sc.dx);
        self.final_ada.backward_params(g, &self.c, &sc.dm, r);
        self.final_ada.backward_input(p, &sc.dm, r, &mut sc.dc, false);
        for i in (0..self.blocks.len()).rev() {
            Self::block_backward(
                &self.blocks[i],
                &self.caches[i],
                &mut self.attention,
                &self.c,
                p,
                g,
                sc,
                t,
                w,
                self.s.mlp_ratio,
                r,
            );
        }
        // Tokens.
        self.action_in.backward_params(g, &self.a, &sc.dx, rt);
        for (i, row) in sc.dx[..rt * w].chunks_exact(w).enumerate() {
            for (q, v) in g[self.pos + (i % t) * w..][..w].iter_mut().zip(row) {
                *q += v;
            }
        }
        if da_samples > 0 {
            self.action_in.backward_input(p, &sc.dx, da_samples * t, da, false);
        }
        // Conditioning: c = SiLU(c_pre).
        layers::silu_backward(&self.c_pre[..r * w], &mut sc.dc[..r * w]);
        self.cond_in.backward_params(g, &self.cond, &sc.dc, r);
        self.cond_in.backward_input(p, &sc.dc, r, dcond, false);
        self.time2.backward_params(g, &self.t_act, &sc.dc, r);
        self.time2.backward_input(p, &sc.dc, r, &mut sc.dt, false);
        layers::silu_backward(&self.t_pre[..r * w], &mut sc.dt[..r * w]);
        self.time1.backward_params(g, &self.tfeat, &sc.dt, r);
    }

    /// One block's backward: `sc.dx` holds dL/d(block output) and leaves holding dL/d(block input); dL/dc is
    /// added to `sc.dc`.
    #[allow(clippy::too_many_arguments)]
    fn block_backward(
        b: &Block,
        k: &BlockCache,
        attention: &mut Attention,
        c: &[f32],
        p: &[f32],
        g: &mut [f32],
        sc: &mut Scratch,
        t: usize,
        w: usize,
        mlp_ratio: usize,
        r: usize,
    ) {
        let (rt, f) = (r * t, w * mlp_ratio);
        let mod1 = Modulation { tokens: t, width: w, m_width: 6 * w, shift_at: 0, scale_at: w };
        let mod2 = Modulation { tokens: t, width: w, m_width: 6 * w, shift_at: 3 * w, scale_at: 4 * w };
        sc.dm[..r * 6 * w].fill(0.0);
        // x_out = x_mid + MLP(h2)·gate2.
        layers::gated_add_backward(&sc.dx[..rt * w], &k.mlp_out, &k.m, &mod2, 5 * w, &mut sc.dbranch, &mut sc.dm);
        b.fc2.backward_input(p, &sc.dbranch, rt, &mut sc.df, false);
        b.fc2.backward_params(g, &k.f_act, &sc.dbranch, rt);
        layers::silu_backward(&k.f_pre[..rt * f], &mut sc.df[..rt * f]);
        b.fc1.backward_input(p, &sc.df, rt, &mut sc.dh, false);
        b.fc1.backward_params(g, &k.h2, &sc.df, rt);
        mod2.backward(&sc.dh[..rt * w], &k.n2, &k.m, &mut sc.dn, &mut sc.dm);
        layers::layer_norm_backward(&sc.dn[..rt * w], &k.n2, &k.inv2, w, &mut sc.dx);
        // x_mid = x_in + Attn(h1)·gate1.
        layers::gated_add_backward(&sc.dx[..rt * w], &k.att_out, &k.m, &mod1, 2 * w, &mut sc.dbranch, &mut sc.dm);
        b.out.backward_input(p, &sc.dbranch, rt, &mut sc.datt, false);
        b.out.backward_params(g, &k.att, &sc.dbranch, rt);
        attention.backward(&k.qkv, &k.probs, &sc.datt, r, &mut sc.dqkv);
        b.qkv.backward_input(p, &sc.dqkv, rt, &mut sc.dh, false);
        b.qkv.backward_params(g, &k.h1, &sc.dqkv, rt);
        mod1.backward(&sc.dh[..rt * w], &k.n1, &k.m, &mut sc.dn, &mut sc.dm);
        layers::layer_norm_backward(&sc.dn[..rt * w], &k.n1, &k.inv1, w, &mut sc.dx);
        // m = ada(c).
        b.ada.backward_params(g, c, &sc.dm, r);
        b.ada.backward_input(p, &sc.dm, r, &mut sc.dc, true);
    }
}
