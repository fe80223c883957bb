//! The engine: one call = check inputs → normalise, encode, w, K(w) (`observe`) → noise and source → K capped
//! by the deadline (`budget`) → K Euler steps of the DiT (`velocity`) → unnormalise. Everything a call
//! touches was allocated by [`Engine::load`].

use crate::budget::{CostEstimate, Estimator, Plan};
use crate::buffers::Buffers;
use crate::cameras::Cameras;
use crate::config::EngineConfig;
use crate::continuity::{GUIDANCE_CAP, guidance_weight, guide};
use crate::dims::Dims;
use crate::error::{EngineError, Input, LoadError};
use crate::matmul::MatMul;
use crate::observe::{observe, source};
use crate::velocity::{conditioning, velocity};
use crate::weights::{Weights, with_bytes};
use mars_policy_format::checkpoint::{self, CheckpointError, CheckpointMeta, WEIGHTS_FILE};
use mars_policy_format::config::PolicyKind;
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;
use std::path::Path;
use std::time::{Duration, Instant};

/// A loaded policy with all its buffers, its own seeded noise generator and cost estimate. One engine serves
/// one thread (calls take `&mut self`); it is `Send`, so it can be built elsewhere and moved there.
pub struct Engine {
    meta: CheckpointMeta,
    dims: Dims,
    weights: Weights,
    /// A vision policy's image encoders (their cost is part of every call's fixed cost in the estimate).
    cameras: Option<Cameras>,
    buf: Buffers,
    rng: StdRng,
    estimator: Estimator,
    mm: MatMul,
    injected_step_delay: Duration,
}

/// The result of a call: borrowed views into the engine's buffers (valid until the next call) and the step
/// decision.
#[derive(Debug, Clone, Copy)]
pub struct Output<'a> {
    /// The action chunk [C, D], row-major, in task units.
    pub chunk: &'a [f32],
    /// The same chunk in the model's normalised units.
    pub chunk_normalized: &'a [f32],
    /// The modality weight w [D].
    pub w: &'a [f32],
    /// K(w) = ⌈K_max·‖w‖∞⌉: the steps the model asks for.
    pub k_requested: usize,
    /// The steps run: min(K(w), K_deadline), or the forced K of [`Engine::infer_with`].
    pub k_used: usize,
    /// The deadline cut the steps: `k_used < k_requested`.
    pub capped: bool,
    /// Even one step was estimated not to fit the budget; one step ran anyway (a chunk is always produced).
    pub over_budget: bool,
    /// The estimated cost of this call when K was chosen.
    pub estimated: Duration,
    /// Time spent encoding the observation (normalisation, the cameras' ResNets if any, the encoder MLP and the
    /// scheduler's w), before the ODE.
    pub encode: Duration,
    /// D, the length of each action in `chunk`.
    pub action_dim: usize,
}

impl<'a> Output<'a> {
    /// The chunk's C actions, in order, each D values in task units.
    pub fn actions(&self) -> std::slice::ChunksExact<'a, f32> {
        self.chunk.chunks_exact(self.action_dim)
    }
}

enum Noise<'a> {
    /// From the engine's generator.
    Draw,
    Given(&'a [f32]),
    /// ε = 0 (warm-up calls, which must not consume the generator's stream).
    Zero,
}

enum Steps {
    Budget(Duration),
    Forced(usize),
}

/// Busy-waits (no syscall, no allocation): the injected slowness must look like compute to the estimator.
fn spin_for(d: Duration) {
    if d.is_zero() {
        return;
    }
    let start = Instant::now();
    while start.elapsed() < d {
        std::hint::spin_loop();
    }
}

/// Cheap in-place validation: one pass, no allocation.
fn check(what: Input, x: &[f32], want: usize) -> Result<(), EngineError> {
    if x.len() != want {
        return Err(EngineError::Length { what, got: x.len(), want });
    }
    match x.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(EngineError::NonFinite { what, index, value: x[index] }),
        None => Ok(()),
    }
}

/// Committed actions are whole rows, fewer than the chunk's (a chunk wholly committed has nothing to compute).
fn check_committed(x: &[f32], d: &Dims) -> Result<(), EngineError> {
    if !x.len().is_multiple_of(d.action) || x.len() >= d.chunk_values() {
        return Err(EngineError::CommittedRows { got: x.len(), chunk: d.chunk, action: d.action });
    }
    match x.iter().position(|v| !v.is_finite()) {
        Some(index) => Err(EngineError::NonFinite { what: Input::Committed, index, value: x[index] }),
        None => Ok(()),
    }
}

impl Engine {
    /// Loads a checkpoint directory of any policy kind, allocates every buffer and runs the warm-up calls.
    ///
    /// `policy.json` is checked by the checkpoint format's own reader (`mars_policy_format::checkpoint`, the
    /// trainer's too: every size within its limits, statistics of the right lengths), the engine refuses a config
    /// it cannot run, and then every tensor is checked as it is read (F32, the config's shape, finite values),
    /// and a file holding tensors the config's network does not have is refused.
    pub fn load(dir: &Path, cfg: EngineConfig) -> Result<Self, LoadError> {
        cfg.validate().map_err(LoadError::Config)?;
        let meta_path = dir.join(checkpoint::META_FILE);
        let io = |path: &Path, source| LoadError::Checkpoint(CheckpointError::Io { path: path.to_owned(), source });
        let meta = std::fs::read_to_string(&meta_path).map_err(|e| io(&meta_path, e))?;
        let weights_path = dir.join(WEIGHTS_FILE);
        let weights = std::fs::read(&weights_path).map_err(|e| io(&weights_path, e))?;
        Self::load_from(dir, &meta, &weights, cfg)
    }

    /// [`Engine::load`] of the checkpoint `dir`'s files as read: `policy.json`'s text and `model.safetensors`'
    /// bytes.
    pub fn load_from(dir: &Path, meta_text: &str, weights: &[u8], cfg: EngineConfig) -> Result<Self, LoadError> {
        cfg.validate().map_err(LoadError::Config)?;
        let meta = checkpoint::parse_meta(dir, meta_text)?;
        let dims = Dims::new(&meta.model, meta.kind)
            .map_err(|problem| LoadError::Unsupported { path: dir.to_path_buf(), problem })?;
        let mm = MatMul::detect(cfg.threads, cfg.portable_kernels);
        let fixed_w = meta.kind.fixed_w(&meta.model);
        let path = dir.join(WEIGHTS_FILE);
        let (cameras, weights) = with_bytes(&path, weights, mm, |r| {
            let cameras = dims.vision.as_ref().map(|v| Cameras::read(r, v, cfg.portable_kernels)).transpose()?;
            let weights = Weights::read(r, &dims, fixed_w)?;
            r.refuse_unread(&format!("`{}` model", meta.kind))?;
            Ok((cameras, weights))
        })?;
        let buf = Buffers::new(&dims).map_err(|problem| LoadError::Unsupported { path: dir.to_path_buf(), problem })?;
        let mut engine = Self {
            meta,
            cameras,
            buf,
            dims,
            weights,
            rng: StdRng::seed_from_u64(cfg.seed),
            estimator: Estimator::default(),
            mm,
            injected_step_delay: cfg.injected_step_delay,
        };
        engine.warm_up(cfg.warmup_calls)?;
        Ok(engine)
    }

    /// Full-length calls on the dataset's mean observation and history with zero noise. The first, cold call
    /// (page faults on fresh buffers, cold caches) is run but not counted; the next `timed` seed the cost
    /// estimate.
    fn warm_up(&mut self, timed: usize) -> Result<(), LoadError> {
        let obs = self.meta.normalizer.obs.mean.clone();
        let hist: Vec<f32> = self.meta.normalizer.action.mean.repeat(self.dims.chunk);
        for i in 0..=timed {
            if i == 1 {
                self.estimator = Estimator::default();
            }
            self.run(&obs, &hist, &[], Noise::Zero, Steps::Forced(self.dims.k_max))
                .map_err(|e| LoadError::Config(format!("warm-up call failed: {e}")))?;
        }
        Ok(())
    }

    /// One inference: the chunk for `observation` (obs_dim values) after `history` (the last C executed
    /// actions, oldest first, C·D values), both in task units, with K = min(K(w), the most steps whose
    /// estimated cost fits `budget`). Noise comes from the engine's seeded generator. Allocation-free.
    pub fn infer(&mut self, observation: &[f32], history: &[f32], budget: Duration) -> Result<Output<'_>, EngineError> {
        self.run(observation, history, &[], Noise::Draw, Steps::Budget(budget))
    }

    /// [`Engine::infer`] for a chunk that arrives after the robot has executed its first rows from the previous
    /// chunk: `committed` (task units, whole rows, fewer than C) are those actions, and every Euler step is guided
    /// toward them ([`crate::continuity`]). With no committed rows this is [`Engine::infer`], bit for bit.
    /// Allocation-free.
    pub fn infer_after(
        &mut self,
        observation: &[f32],
        history: &[f32],
        committed: &[f32],
        budget: Duration,
    ) -> Result<Output<'_>, EngineError> {
        self.run(observation, history, committed, Noise::Draw, Steps::Budget(budget))
    }

    /// [`Engine::infer`] with explicit noise ε (C·D values, normalised units; `None` draws from the generator)
    /// and/or a forced step count in 1..=K_max (`None` runs K(w)); the budget is not consulted. For comparing with the
    /// candle model and for benchmarks. Allocation-free.
    pub fn infer_with(
        &mut self,
        observation: &[f32],
        history: &[f32],
        noise: Option<&[f32]>,
        steps: Option<usize>,
    ) -> Result<Output<'_>, EngineError> {
        let noise = noise.map_or(Noise::Draw, Noise::Given);
        self.run(observation, history, &[], noise, steps.map_or(Steps::Budget(Duration::MAX), Steps::Forced))
    }

    fn run(
        &mut self,
        obs: &[f32],
        hist: &[f32],
        committed: &[f32],
        noise: Noise<'_>,
        steps: Steps,
    ) -> Result<Output<'_>, EngineError> {
        let start = Instant::now();
        let (d, mm) = (self.dims, self.mm);
        check(Input::Observation, obs, d.obs)?;
        check(Input::History, hist, d.chunk_values())?;
        check_committed(committed, &d)?;
        if let Noise::Given(eps) = noise {
            check(Input::Noise, eps, d.chunk_values())?;
        }
        if let Steps::Forced(k) = steps
            && !(1..=d.k_max).contains(&k)
        {
            return Err(EngineError::Steps { k, k_max: d.k_max });
        }
        let (wt, b, norm) = (&self.weights, &mut self.buf, &self.meta.normalizer);

        let k_requested = observe(wt, &d, norm, obs, hist, self.cameras.as_mut(), b, mm);
        let n_committed = committed.len();
        for (i, (y, &c)) in b.committed.iter_mut().zip(committed).enumerate() {
            *y = (c - norm.action.mean[i % d.action]) / norm.action.std[i % d.action];
        }
        let encode = start.elapsed();
        match noise {
            Noise::Draw => b.eps.iter_mut().for_each(|e| *e = self.rng.sample(StandardNormal)),
            Noise::Given(eps) => b.eps.copy_from_slice(eps),
            Noise::Zero => b.eps.fill(0.0),
        }
        source(&d, b);

        let estimate = self.estimator.estimate();
        let (k, plan) = match steps {
            Steps::Forced(k) => (k, Plan { k, over_budget: false }),
            Steps::Budget(budget) => {
                let plan = self.estimator.plan(budget, k_requested);
                (plan.k, plan)
            }
        };

        // Everything from here to the end of the Euler loop scales with K: the per-step cost.
        let loop_start = Instant::now();
        conditioning(wt, &d, b, k, mm);
        let dt32 = (1.0 / k as f64) as f32; // as the candle model rounds it
        for step in 0..k {
            velocity(wt, &d, b, step, mm);
            if n_committed > 0 {
                let tau = step as f32 * dt32;
                let c = guidance_weight(tau, dt32, GUIDANCE_CAP);
                guide(&mut b.v[..n_committed], &b.a[..n_committed], &b.committed[..n_committed], tau, c);
            }
            spin_for(self.injected_step_delay);
            for (a, &v) in b.a.iter_mut().zip(b.v.iter()) {
                *a += v * dt32;
            }
        }
        let loop_end = Instant::now();

        for (i, (o, &a)) in b.chunk.iter_mut().zip(b.a.iter()).enumerate() {
            *o = a * norm.action.std[i % d.action] + norm.action.mean[i % d.action];
        }
        // Finite inputs far outside the training range can overflow inside the network; a NaN or infinite
        // action must never reach a robot.
        let finite = b.chunk.iter().all(|v| v.is_finite());
        let end = Instant::now();
        let in_loop = loop_end - loop_start;
        self.estimator.record((end - start).saturating_sub(in_loop), in_loop, k);
        if !finite {
            return Err(EngineError::NonFiniteOutput);
        }

        let b = &self.buf;
        Ok(Output {
            chunk: &b.chunk,
            chunk_normalized: &b.a,
            w: &b.w,
            k_requested,
            k_used: k,
            capped: matches!(steps, Steps::Budget(_)) && k < k_requested,
            over_budget: plan.over_budget,
            estimated: estimate.call(k),
            encode,
            action_dim: d.action,
        })
    }

    /// Re-seeds the noise generator (as `MarsPolicy::reseed`).
    pub fn reseed(&mut self, seed: u64) {
        self.rng = StdRng::seed_from_u64(seed);
    }

    /// The current estimate of a call's cost, as used for the next deadline.
    pub fn cost_estimate(&self) -> CostEstimate {
        self.estimator.estimate()
    }

    /// The checkpoint's metadata: policy kind, network config, normalisation, training log.
    pub fn meta(&self) -> &CheckpointMeta {
        &self.meta
    }

    pub fn kind(&self) -> PolicyKind {
        self.meta.kind
    }

    pub fn obs_dim(&self) -> usize {
        self.dims.obs
    }

    pub fn action_dim(&self) -> usize {
        self.dims.action
    }

    pub fn chunk_len(&self) -> usize {
        self.dims.chunk
    }

    pub fn k_max(&self) -> usize {
        self.dims.k_max
    }

    /// How this engine computes its matrix products (chosen at load from the CPU and the config).
    pub fn kernels(&self) -> &'static str {
        self.mm.describe()
    }

    /// Floating-point operations of a call with `k` steps (multiply-adds of all matrix products, ×2).
    pub fn flops_per_call(&self, k: usize) -> u64 {
        self.dims.flops(k) + 2 * self.cameras.as_ref().map_or(0, |c| c.macs() as u64)
    }
}
