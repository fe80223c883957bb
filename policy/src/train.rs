//! Training: seeded batches, the losses each policy kind uses, AdamW, a progress bar and a per-epoch log.

use crate::config::{Gradients, PolicyConfig, PolicyKind};
use crate::dataset::{Dataset, DatasetTensors};
use crate::grad::{HandStep, HostData, StepTerms};
use crate::losses;
use crate::model::MarsModel;
use crate::nn::seeded_init::SeededInit;
use crate::normalize::Normalizer;
use crate::stats::quantile;
use candle_core::{Device, Tensor, Var};
use candle_nn::{AdamW, Optimizer, ParamsAdamW, VarMap};
use mars_tasks::demo::Demo;
use rand::rngs::StdRng;
use rand::seq::SliceRandom;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

pub use mars_policy_format::checkpoint::EpochLog;

pub struct Trained {
    pub cfg: PolicyConfig,
    pub model: MarsModel,
    pub varmap: VarMap,
    pub normalizer: Normalizer,
    pub log: Vec<EpochLog>,
    /// Wall-clock seconds of each epoch's batches (not the dataset's set-up nor snapshots): `mars bench-train`.
    pub epoch_seconds: Vec<f64>,
}

impl Trained {
    /// Writes the checkpoint directory `dir` (see [`crate::checkpoint::save_parts`]).
    pub fn save(&self, dir: &std::path::Path) -> Result<(), crate::checkpoint::CheckpointError> {
        crate::checkpoint::save_parts(dir, &self.cfg, &self.varmap, &self.normalizer, &self.log)
    }
}

/// One batch, gathered from the dataset tensors.
pub struct Batch {
    pub obs: Tensor,
    pub history: Tensor,
    pub next: Tensor,
    /// [B, m, H, D]
    pub neighbour_history: Tensor,
    pub s_next: Tensor,
}

impl Batch {
    pub fn gather(data: &DatasetTensors, idx: &[u32]) -> candle_core::Result<Self> {
        let dev = data.obs.device();
        let idx_t = Tensor::from_slice(idx, idx.len(), dev)?;
        let nbrs = data.neighbours.index_select(&idx_t, 0)?; // [B, m]
        let (b, m) = nbrs.dims2()?;
        let (_, h, d) = data.history.dims3()?;
        let neighbour_history = data.history.index_select(&nbrs.flatten_all()?, 0)?.reshape((b, m, h, d))?;
        Ok(Self {
            obs: data.obs.index_select(&idx_t, 0)?,
            history: data.history.index_select(&idx_t, 0)?,
            next: data.next.index_select(&idx_t, 0)?,
            neighbour_history,
            s_next: data.s_next.index_select(&idx_t, 0)?,
        })
    }
}

/// Standard normal noise from the seeded generator (candle's CPU RNG cannot be seeded).
pub fn randn(rng: &mut StdRng, shape: &[usize], dev: &Device) -> candle_core::Result<Tensor> {
    let n: usize = shape.iter().product();
    let v: Vec<f32> = (0..n).map(|_| rng.sample(StandardNormal)).collect();
    Tensor::from_vec(v, shape, dev)
}

pub struct LossTerms {
    pub total: Tensor,
    pub fm: Tensor,
    pub rec: Option<Tensor>,
    pub div: Option<Tensor>,
    pub w: Tensor,
}

/// The training objective of `kind` on one batch: L_fm (+ λ_rec L_rec) (+ λ_div L_div).
pub fn batch_losses(
    model: &MarsModel,
    batch: &Batch,
    cfg: &PolicyConfig,
    rng: &mut StdRng,
) -> candle_core::Result<LossTerms> {
    let dev = batch.obs.device();
    let (b, c, d) = batch.next.dims3()?;
    let emb = model.encode_train(&batch.obs, rng)?;
    let w = model.weights(&emb, &batch.history)?;
    let cond = model.conditioning(&emb, &batch.history)?;
    let eps = randn(rng, &[b, c, d], dev)?.affine(f64::from(cfg.model.source_std), 0.0)?;
    let a0 = MarsModel::source(&batch.history, &w, &eps)?;
    let a1 = &batch.next;

    let tau_v: Vec<f32> = (0..b).map(|_| rng.random::<f32>()).collect();
    let tau = Tensor::from_vec(tau_v, b, dev)?;
    let tau_b = tau.reshape((b, 1, 1))?;
    let a_tau = (a0.broadcast_mul(&tau_b.affine(-1.0, 1.0)?)? + a1.broadcast_mul(&tau_b)?)?;

    // L_fm needs v(a_τ, τ); L_rec needs v(a0, 0) from a source rebuilt with the detached w (so L_rec trains the
    // velocity field, never the scheduler). Both go through the DiT as one batch of 2B: half the op count.
    // FM has no w to gate L_rec with: the Fig. S4 ablation applies it to every dimension (gate weight 0).
    let (rec_weight, rec_gate) = match (cfg.kind, cfg.train.fm_lambda_rec) {
        (PolicyKind::Fm, Some(l)) => (Some(l), w.zeros_like()?),
        (kind, _) if kind.uses_rec_loss() => (Some(cfg.train.lambda_rec), w.clone()),
        _ => (None, w.clone()),
    };
    let (v_tau, v_zero) = if rec_weight.is_some() {
        let a0_d = MarsModel::source(&batch.history, &w.detach(), &eps)?;
        let zeros = Tensor::zeros(b, candle_core::DType::F32, dev)?;
        let v = model.velocity(
            &Tensor::cat(&[&a_tau, &a0_d], 0)?,
            &Tensor::cat(&[&tau, &zeros], 0)?,
            &Tensor::cat(&[&cond, &cond], 0)?,
        )?;
        (v.narrow(0, 0, b)?, Some((a0_d, v.narrow(0, b, b)?)))
    } else {
        (model.velocity(&a_tau, &tau, &cond)?, None)
    };
    let fm = losses::flow_matching(&v_tau, &a0, a1)?;
    let mut total = fm.clone();

    let rec = match (v_zero, rec_weight) {
        (Some((a0_d, v0)), Some(weight)) => {
            let rec = losses::reconstruction(&(a0_d + v0)?, a1, &rec_gate)?;
            total = (total + (&rec * weight)?)?;
            Some(rec)
        }
        _ => None,
    };

    let div = if cfg.kind.uses_div_loss() {
        let m = batch.neighbour_history.dim(1)?;
        let own = MarsModel::source(&batch.history, &w, &randn(rng, &[b, c, d], dev)?)?;
        let others = losses::neighbour_sources(&batch.neighbour_history, &w, &randn(rng, &[b, m, c, d], dev)?)?;
        let div = losses::diversity(&batch.s_next, &losses::dispersion(&own, &others)?)?;
        total = (total + (&div * cfg.train.lambda_div)?)?;
        Some(div)
    } else {
        None
    };
    Ok(LossTerms { total, fm, rec, div, w })
}

/// AdamW decays weight matrices only: decaying biases and embeddings toward zero is not regularisation.
fn optimizers(varmap: &VarMap, cfg: &PolicyConfig) -> candle_core::Result<Vec<AdamW>> {
    let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
    let mut names: Vec<&String> = data.keys().collect();
    names.sort(); // HashMap order is random; the optimiser's variable order must not be.
    let (mut decay, mut no_decay): (Vec<Var>, Vec<Var>) = (Vec::new(), Vec::new());
    for name in names {
        let var = data[name].clone();
        if var.rank() >= 2 && !name.ends_with("pos_embed") { decay.push(var) } else { no_decay.push(var) }
    }
    let params = |wd| ParamsAdamW { lr: cfg.train.lr, weight_decay: wd, ..Default::default() };
    Ok(vec![AdamW::new(decay, params(cfg.train.weight_decay))?, AdamW::new(no_decay, params(0.0))?])
}

fn scalar(t: &Tensor) -> candle_core::Result<f32> {
    t.to_scalar::<f32>()
}

/// How a batch's gradients and update are made: by hand (`crate::grad`: state policies, unless the config asks
/// for autograd) or through candle's autograd and AdamW. Same draws from the generator either way.
enum Stepper {
    Hand(Box<HandStep>, HostData),
    Autograd(Vec<AdamW>),
}

impl Stepper {
    fn new(cfg: &PolicyConfig, varmap: &VarMap, tensors: &DatasetTensors) -> anyhow::Result<Self> {
        let by_hand = crate::grad::supports(cfg);
        if cfg.train.gradients == Gradients::Hand && by_hand {
            let mut hand = HandStep::new(cfg, varmap)?;
            // The training's share of the cores (`cli::init_runtime_env`: cores / parallel jobs).
            let threads = candle_core::utils::get_num_threads();
            hand.set_threads(threads);
            tracing::info!(policy = %cfg.kind, threads, "gradients by hand (mars_policy::grad)");
            Ok(Stepper::Hand(Box::new(hand), HostData::new(tensors)?))
        } else {
            let why = if by_hand { "train.gradients = \"autograd\"" } else { "a vision encoder" };
            tracing::info!(policy = %cfg.kind, why, "gradients through candle's autograd");
            Ok(Stepper::Autograd(optimizers(varmap, cfg)?))
        }
    }

    /// One batch (samples `idx`): its loss terms, and the update unless the loss is not finite.
    fn step(
        &mut self,
        model: &MarsModel,
        tensors: &DatasetTensors,
        cfg: &PolicyConfig,
        idx: &[u32],
        rng: &mut StdRng,
    ) -> anyhow::Result<StepTerms> {
        let opts = match self {
            Stepper::Hand(hand, host) => return Ok(hand.step(host, idx, rng)),
            Stepper::Autograd(opts) => opts,
        };
        let terms = batch_losses(model, &Batch::gather(tensors, idx)?, cfg, rng)?;
        let total = scalar(&terms.total)?;
        if total.is_finite() {
            let grads = terms.total.backward()?;
            for opt in opts {
                opt.step(&grads)?;
            }
        }
        Ok(StepTerms {
            total,
            fm: scalar(&terms.fm)?,
            rec: terms.rec.as_ref().map(scalar).transpose()?,
            div: terms.div.as_ref().map(scalar).transpose()?,
            w_inf: scalar(&terms.w.max(1)?.mean_all()?)?,
        })
    }

    /// The weights trained by hand into the model's variables (autograd trains them in place).
    fn store(&self, varmap: &VarMap) -> anyhow::Result<()> {
        match self {
            Stepper::Hand(hand, _) => hand.store(varmap),
            Stepper::Autograd(_) => Ok(()),
        }
    }
}

/// A fresh model with seeded initial weights.
pub fn init_model(cfg: &PolicyConfig, device: &Device) -> candle_core::Result<(MarsModel, VarMap)> {
    let (varmap, vb) = SeededInit::var_builder(cfg.train.seed, device);
    Ok((MarsModel::new(&cfg.model, cfg.kind, vb)?, varmap))
}

/// Trains `cfg.kind` on `demos`. Same config, demos and machine → same weights.
pub fn train(cfg: &PolicyConfig, demos: &[Demo], show_progress: bool) -> anyhow::Result<Trained> {
    let bar = if show_progress { progress_bar(cfg.kind) } else { indicatif::ProgressBar::hidden() };
    train_with_progress(cfg, demos, bar)
}

/// `train`, reporting to the given bar (the benchmark shows one bar per policy trained in parallel).
pub fn train_with_progress(cfg: &PolicyConfig, demos: &[Demo], bar: indicatif::ProgressBar) -> anyhow::Result<Trained> {
    train_with_snapshots(cfg, demos, bar, None)
}

/// Checkpoints of the model in training, every `every` epochs, as `<dir>/epoch_NNNN/` (the final epoch
/// included): the training-efficiency curves evaluate them. Each is a complete checkpoint (K(w) calibrated as
/// the final one is), so any evaluator loads it like any other.
#[derive(Debug, Clone)]
pub struct Snapshots {
    pub every: usize,
    pub dir: std::path::PathBuf,
}

impl Snapshots {
    pub fn path(&self, epochs_done: usize) -> std::path::PathBuf {
        self.dir.join(format!("epoch_{epochs_done:04}"))
    }
}

/// `train_with_progress`, saving `snapshots` along the way.
pub fn train_with_snapshots(
    cfg: &PolicyConfig,
    demos: &[Demo],
    bar: indicatif::ProgressBar,
    snapshots: Option<&Snapshots>,
) -> anyhow::Result<Trained> {
    train_normalised_by(cfg, demos, None, bar, snapshots)
}

/// `train_with_snapshots` with the normalisation `given` (a dataset's own statistics) rather than the demos'.
pub fn train_normalised_by(
    cfg: &PolicyConfig,
    demos: &[Demo],
    given: Option<&Normalizer>,
    bar: indicatif::ProgressBar,
    snapshots: Option<&Snapshots>,
) -> anyhow::Result<Trained> {
    cfg.validate()?;
    if let Some(s) = snapshots {
        anyhow::ensure!(s.every > 0, "snapshots every 0 epochs: give at least 1");
    }
    let device = Device::Cpu;
    let mut data = Dataset::from_demos_with(demos, &cfg.model, cfg.train.knn_m, given)?;
    if let (Some(q), PolicyKind::Mars) = (cfg.train.div_target_quantile, cfg.kind) {
        let factor = data.rescale_target_spread(q);
        tracing::info!(policy = %cfg.kind, quantile = q, factor, "diversity target S_next rescaled");
    }
    let tensors = data.tensors(&cfg.model, &device)?;
    let (mut model, varmap) = init_model(cfg, &device)?;
    let mut stepper = Stepper::new(cfg, &varmap, &tensors)?;
    let mut rng = StdRng::seed_from_u64(cfg.train.seed ^ 0x4d41_5253); // "MARS": batches ≠ init stream
    let mut order: Vec<u32> = (0..data.len as u32).collect();
    let batches_per_epoch = data.len.div_ceil(cfg.train.batch_size);

    bar.set_length((cfg.train.epochs * batches_per_epoch) as u64);
    let mut log = Vec::with_capacity(cfg.train.epochs);
    let mut epoch_seconds = Vec::with_capacity(cfg.train.epochs);
    for epoch in 0..cfg.train.epochs {
        let started = std::time::Instant::now();
        order.shuffle(&mut rng);
        let mut sums = EpochLog { epoch, ..Default::default() };
        for idx in order.chunks(cfg.train.batch_size) {
            if idx.len() < 2 {
                continue; // a batch of one has no spread to learn from
            }
            let terms = stepper.step(&model, &tensors, cfg, idx, &mut rng)?;
            if !terms.total.is_finite() {
                anyhow::bail!("{} training diverged at epoch {epoch}: loss is {}", cfg.kind, terms.total);
            }
            sums.total += terms.total;
            sums.fm += terms.fm;
            sums.rec += terms.rec.unwrap_or(0.0);
            sums.div += terms.div.unwrap_or(0.0);
            sums.w_inf += terms.w_inf;
            bar.inc(1);
        }
        epoch_seconds.push(started.elapsed().as_secs_f64());
        let n = batches_per_epoch as f32;
        let e = EpochLog {
            epoch,
            total: sums.total / n,
            fm: sums.fm / n,
            rec: sums.rec / n,
            div: sums.div / n,
            w_inf: sums.w_inf / n,
        };
        bar.set_message(format!("epoch {} loss {:.4}", epoch + 1, e.total));
        if bar.is_hidden() {
            // No terminal to draw a bar on (a log file, CI): one line per epoch instead.
            tracing::info!(policy = %cfg.kind, epoch = epoch + 1, loss = e.total, fm = e.fm, rec = e.rec, div = e.div, w_inf = e.w_inf, "epoch");
        }
        log.push(e);
        if let Some(s) = snapshots.filter(|s| (epoch + 1) % s.every == 0 || epoch + 1 == cfg.train.epochs) {
            stepper.store(&varmap)?;
            let mut snap_cfg = cfg.clone();
            snap_cfg.train.epochs = epoch + 1;
            calibrate_k(&mut snap_cfg, &mut model, &tensors, false)?;
            crate::checkpoint::save_parts(&s.path(epoch + 1), &snap_cfg, &varmap, &data.normalizer, &log)?;
        }
    }
    bar.finish_and_clear();
    stepper.store(&varmap)?;
    let mut cfg = cfg.clone();
    calibrate_k(&mut cfg, &mut model, &tensors, true)?;
    Ok(Trained { cfg, model, varmap, normalizer: data.normalizer, log, epoch_seconds })
}

/// MARS with `train.k_full_quantile`: `model.k_full_w` ← that quantile of ‖w‖∞ over the training samples (in
/// `cfg` and in the model). It only scales K(w) at inference; training never reads it.
fn calibrate_k(
    cfg: &mut PolicyConfig,
    model: &mut MarsModel,
    tensors: &DatasetTensors,
    log: bool,
) -> anyhow::Result<()> {
    let (Some(q), PolicyKind::Mars) = (cfg.train.k_full_quantile, cfg.kind) else { return Ok(()) };
    let top = quantile(&mut w_inf_values(model, tensors)?, q);
    if top > 1e-3 {
        cfg.model.k_full_w = top.min(1.0);
        if log {
            tracing::info!(policy = %cfg.kind, k_full_w = cfg.model.k_full_w, "K(w) calibrated: this ‖w‖∞ gets K_max steps");
        }
    } else {
        // A scheduler that never left 0 has no fork to give the budget to: keep the paper's scale.
        cfg.model.k_full_w = 1.0;
        if log {
            tracing::warn!(policy = %cfg.kind, quantile = q, w_inf = top, "K(w) not calibrated: ‖w‖∞ ≈ 0 on the training samples; k_full_w stays 1");
        }
    }
    model.cfg.k_full_w = cfg.model.k_full_w;
    Ok(())
}

/// ‖w‖∞ of the trained scheduler on every training sample.
pub fn w_inf_values(model: &MarsModel, data: &DatasetTensors) -> candle_core::Result<Vec<f32>> {
    let n = data.obs.dim(0)?;
    let mut out = Vec::with_capacity(n);
    for start in (0..n).step_by(4096) {
        let len = (n - start).min(4096);
        let emb = model.encode(&data.obs.narrow(0, start, len)?)?;
        let w = model.weights(&emb, &data.history.narrow(0, start, len)?)?;
        out.extend(w.max(1)?.to_vec1::<f32>()?);
    }
    Ok(out)
}

pub fn progress_bar(kind: PolicyKind) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(0);
    let style = indicatif::ProgressStyle::with_template("{prefix:>10} [{bar:30}] {pos}/{len} batches {msg} ({eta})")
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
        .progress_chars("=> ");
    bar.set_style(style);
    bar.set_prefix(kind.name());
    bar
}
