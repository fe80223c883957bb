//! Every size the engine needs, derived once from the checkpoint's `ModelConfig`, and the analytic FLOP
//! count of a call (for the benchmark's achieved-FLOP/s figure).

use mars_policy_format::config::{EncoderConfig, ModelConfig, PolicyKind};
use mars_policy_format::encoder::ResNetConfig;

#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dims {
    pub obs: usize,
    /// D: action dimensions.
    pub action: usize,
    /// C: actions per chunk = DiT tokens (= H, the history length).
    pub chunk: usize,
    /// The encoder MLP's input: the observation (state encoder), or every camera's features and the state.
    pub enc_input: usize,
    pub enc_hidden: usize,
    /// The cameras of a vision encoder.
    pub vision: Option<VisionDims>,
    /// E: observation embedding width.
    pub embed: usize,
    /// The DiT conditioning's input: E, plus C·D when the velocity field also sees the history.
    pub cond_input: usize,
    /// `None` for the baselines, whose w is a constant.
    pub scheduler: Option<SchedulerDims>,
    /// W: DiT width.
    pub width: usize,
    pub depth: usize,
    pub heads: usize,
    pub mlp_hidden: usize,
    /// Sinusoid features of the time embedding: max(W, 32).
    pub freq: usize,
    pub k_max: usize,
    /// ‖w‖∞ that gets K_max steps (`ModelConfig::k_full_w`).
    pub k_full_w: f32,
}

/// A vision encoder's layout: the observation is [state (`state` values), camera 0's image, camera 1's, …],
/// each image H × W × 3 channels last; each is centre-cropped and encoded into `features` values.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VisionDims {
    pub cameras: usize,
    pub image_hw: (usize, usize),
    pub crop_hw: (usize, usize),
    pub resnet: ResNetConfig,
    pub state: usize,
    pub features: usize,
}

impl VisionDims {
    pub fn image_len(&self) -> usize {
        self.image_hw.0 * self.image_hw.1 * 3
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SchedulerDims {
    /// E, plus C·D when the scheduler also sees the history.
    pub input: usize,
    pub hidden: usize,
    pub uses_history: bool,
}

impl Dims {
    /// The sizes of `cfg`, or why the engine cannot run it. `cfg` has passed `ModelConfig::validate`.
    pub fn new(cfg: &ModelConfig, kind: PolicyKind) -> Result<Self, String> {
        // A new encoder type added to mars-policy must be refused here, not mis-run: the match stays
        // non-exhaustive on purpose.
        #[allow(unreachable_patterns)]
        let (enc_input, enc_hidden, vision) = match &cfg.encoder {
            EncoderConfig::StateMlp { hidden } => (cfg.obs_dim, *hidden, None),
            EncoderConfig::Vision(v) => {
                let vd = VisionDims {
                    cameras: v.cameras,
                    image_hw: (v.image_height, v.image_width),
                    crop_hw: (v.crop_height, v.crop_width),
                    resnet: v.resnet,
                    state: v.state_dim(cfg.obs_dim),
                    features: v.resnet.out_dim(),
                };
                (vd.cameras * vd.features + vd.state, v.hidden, Some(vd))
            }
            other => return Err(format!("encoder {other:?} is not supported (state-mlp and vision are)")),
        };
        if cfg.source_std != 1.0 {
            // Only the Fig. S3 ablation trains with another source scale; nothing deploys it.
            return Err(format!("model.source_std is {}: the engine samples ε ~ N(0, I) only", cfg.source_std));
        }
        let freq = cfg.dit_width.max(32);
        if !freq.is_multiple_of(2) {
            // The sinusoid gives 2·⌊freq/2⌋ features but the time MLP expects freq: the candle model cannot
            // run such a checkpoint either.
            return Err(format!("dit_width {} is odd: the time embedding needs an even width", cfg.dit_width));
        }
        let scheduler = kind.fixed_w(cfg).is_none().then(|| SchedulerDims {
            input: cfg.scheduler_input_dim(),
            hidden: cfg.scheduler_hidden,
            uses_history: cfg.scheduler_uses_history,
        });
        Ok(Self {
            obs: cfg.obs_dim,
            action: cfg.action_dim,
            chunk: cfg.chunk_len,
            enc_input,
            enc_hidden,
            vision,
            embed: cfg.obs_embed_dim,
            cond_input: cfg.velocity_cond_dim(),
            scheduler,
            width: cfg.dit_width,
            depth: cfg.dit_depth,
            heads: cfg.dit_heads,
            mlp_hidden: cfg.dit_width * cfg.dit_mlp_ratio,
            freq,
            k_max: cfg.k_max,
            k_full_w: cfg.k_full_w,
        })
    }

    /// C·D: values in a chunk (and in the history, since H = C).
    pub fn chunk_values(&self) -> usize {
        self.chunk * self.action
    }

    /// Rows of the stacked adaLN matrix: 6W per block, then 2W for the final layer.
    pub fn ada_rows(&self) -> usize {
        (6 * self.depth + 2) * self.width
    }

    /// Floating-point operations of one call with `k` Euler steps: 2 per multiply-add of every matrix
    /// product (linear layers and attention). Element-wise work (norms, activations, softmax) is left out,
    /// as FLOP/s figures usually do: it is a few percent here. Camera encoders are not counted here (see
    /// `Engine::flops_per_call`).
    pub fn flops(&self, k: usize) -> u64 {
        let mm = |m: usize, n: usize, kk: usize| 2 * (m * n * kk) as u64;
        let (c, w) = (self.chunk, self.width);
        let mut fixed =
            mm(1, self.enc_hidden, self.enc_input) + mm(1, self.embed, self.enc_hidden) + mm(1, w, self.cond_input);
        if let Some(s) = self.scheduler {
            fixed += mm(1, s.hidden, s.input) + mm(1, self.action, s.hidden);
        }
        let block =
            mm(c, 3 * w, w) + 2 * mm(c, c, w) + mm(c, w, w) + mm(c, self.mlp_hidden, w) + mm(c, w, self.mlp_hidden);
        let step = mm(1, w, self.freq)
            + mm(1, w, w)
            + mm(1, self.ada_rows(), w)
            + mm(c, w, self.action)
            + self.depth as u64 * block
            + mm(c, self.action, w);
        fixed + k as u64 * step
    }
}
