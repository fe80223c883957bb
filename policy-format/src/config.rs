//! Policy configuration: which policy (MARS or a baseline), the network sizes, and the training settings.
//! Read from TOML (`configs/policy.toml`); every field is checked before anything is built.

use serde::{Deserialize, Serialize};
use std::path::Path;

#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config {path}: {source}")]
    Read { path: String, source: std::io::Error },
    #[error("config {path} is not valid TOML for a policy config: {source}")]
    Parse { path: String, source: toml::de::Error },
    #[error("config field `{field}` {problem}")]
    Invalid { field: &'static str, problem: String },
}

fn invalid(field: &'static str, problem: impl Into<String>) -> ConfigError {
    ConfigError::Invalid { field, problem: problem.into() }
}

/// The largest sizes a model may have, checked wherever a config is read (a TOML file, a checkpoint's
/// `policy.json`) before anything is sized by them. Far above any model trained here (widths 64–512, K_max 10,
/// 96-pixel images), they keep every product of sizes far from overflow and every buffer a size a machine has
/// (a `k_max` of 10⁹ would ask the engine for 256 GB).
pub mod limits {
    /// `obs_dim` (the state, then every camera's pixels), and the state's share of it.
    pub const MAX_OBS_DIM: usize = 1 << 26;
    /// `action_dim`.
    pub const MAX_ACTION_DIM: usize = 1024;
    /// `chunk_len` (= `history_len`).
    pub const MAX_CHUNK_LEN: usize = 1024;
    /// Widths: `obs_embed_dim`, `scheduler_hidden`, `dit_width`, an encoder's `hidden`, `resnet.width`, keypoints.
    pub const MAX_WIDTH: usize = 1 << 14;
    /// `dit_depth`.
    pub const MAX_DEPTH: usize = 64;
    /// `dit_mlp_ratio`.
    pub const MAX_MLP_RATIO: usize = 16;
    /// `k_max`: Euler steps of one call (the paper's 10; FM is commonly run with 10 to 100).
    pub const MAX_K: usize = 1000;
    /// A vision encoder's `cameras`.
    pub const MAX_CAMERAS: usize = 16;
    /// A camera image's height and width (and the crop's).
    pub const MAX_IMAGE_SIDE: usize = 4096;
    /// `train.batch_size`, `train.knn_m`.
    pub const MAX_BATCH: usize = 1 << 16;
}

/// `v` in 1..=`max`, or the error naming `field`.
fn size_in(field: &'static str, v: usize, max: usize) -> Result<(), ConfigError> {
    if (1..=max).contains(&v) {
        Ok(())
    } else if v == 0 {
        Err(invalid(field, "must be at least 1"))
    } else {
        Err(invalid(field, format!("is {v}, more than this build's limit of {max}")))
    }
}

/// MARS and the baselines it is compared with; all share one network and differ in source, losses and K.
/// Named on a command line and in TOML by [`PolicyKind::name`] (`"noise-a2a"`); each kind's one-line summary is
/// [`PolicyKind::summary`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PolicyKind {
    /// Learned per-dimension w; L_fm + L_rec + L_div; K = K(w).
    Mars,
    /// Flow matching: Gaussian source (w ≡ 1), L_fm only, K = K_max.
    Fm,
    /// Action-to-action: history source (w ≡ 0), L_fm + L_rec, K = 1.
    A2a,
    /// A2A with a small constant noise weight (`model.noise_a2a_w`).
    NoiseA2a,
}

impl PolicyKind {
    pub const ALL: [PolicyKind; 4] = [PolicyKind::Mars, PolicyKind::Fm, PolicyKind::A2a, PolicyKind::NoiseA2a];

    /// One line on what the kind is (a command's `--help` lists it beside the name).
    pub fn summary(self) -> &'static str {
        match self {
            PolicyKind::Mars => "Learned per-dimension w; L_fm + L_rec + L_div; K = K(w)",
            PolicyKind::Fm => "Flow matching: Gaussian source (w ≡ 1), L_fm only, K = K_max",
            PolicyKind::A2a => "Action-to-action: history source (w ≡ 0), L_fm + L_rec, K = 1",
            PolicyKind::NoiseA2a => "A2A with a small constant noise weight (`model.noise_a2a_w`)",
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            PolicyKind::Mars => "mars",
            PolicyKind::Fm => "fm",
            PolicyKind::A2a => "a2a",
            PolicyKind::NoiseA2a => "noise-a2a",
        }
    }

    /// The fixed modality weight of a baseline, or `None` when a scheduler network learns it.
    pub fn fixed_w(self, model: &ModelConfig) -> Option<f32> {
        match self {
            PolicyKind::Mars => None,
            PolicyKind::Fm => Some(1.0),
            PolicyKind::A2a => Some(0.0),
            PolicyKind::NoiseA2a => Some(model.noise_a2a_w),
        }
    }

    pub fn uses_rec_loss(self) -> bool {
        self != PolicyKind::Fm
    }

    pub fn uses_div_loss(self) -> bool {
        self == PolicyKind::Mars
    }
}

impl std::str::FromStr for PolicyKind {
    type Err = String;

    /// The inverse of [`PolicyKind::name`].
    fn from_str(s: &str) -> Result<Self, String> {
        PolicyKind::ALL.into_iter().find(|k| k.name() == s).ok_or_else(|| {
            let names: Vec<&str> = PolicyKind::ALL.iter().map(|k| k.name()).collect();
            format!("unknown policy kind `{s}`; one of {}", names.join(", "))
        })
    }
}

impl std::fmt::Display for PolicyKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Observation encoder choice; the model only sees the `ObsEncoder` trait.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "kebab-case", deny_unknown_fields)]
pub enum EncoderConfig {
    /// A state vector through an MLP.
    StateMlp { hidden: usize },
    /// Camera images through ResNet-18 (one per camera), their features and the low-dimensional state through an
    /// MLP. The observation vector is the state followed by each camera's image: height × width × 3 values in
    /// [0, 1], channels last (row-major H, W, RGB; see `mars_policy::vision`), left unnormalised.
    Vision(VisionConfig),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VisionConfig {
    pub cameras: usize,
    /// The stored image size.
    pub image_height: usize,
    pub image_width: usize,
    /// What the network sees: a random crop in training, the centre crop at inference (diffusion_policy crops 84
    /// of 96). Equal to the image size: no crop.
    pub crop_height: usize,
    pub crop_width: usize,
    pub resnet: crate::encoder::ResNetConfig,
    /// Hidden width of the MLP over [features of every camera, state].
    pub hidden: usize,
}

impl VisionConfig {
    /// Values of one camera's image in the observation.
    pub fn image_len(&self) -> usize {
        self.image_height * self.image_width * 3
    }

    /// Values of the low-dimensional state at the front of an observation of `obs_dim` values.
    pub fn state_dim(&self, obs_dim: usize) -> usize {
        obs_dim.saturating_sub(self.cameras * self.image_len())
    }

    fn validate(&self, obs_dim: usize) -> Result<(), ConfigError> {
        size_in("model.encoder.cameras", self.cameras, limits::MAX_CAMERAS)?;
        size_in("model.encoder.hidden", self.hidden, limits::MAX_WIDTH)?;
        size_in("model.encoder.resnet.width", self.resnet.width, limits::MAX_WIDTH / 8)?;
        if let crate::encoder::ResNetHead::SpatialSoftmax { keypoints } = self.resnet.head {
            size_in("model.encoder.resnet.head.keypoints", keypoints, limits::MAX_WIDTH)?;
        }
        size_in("model.encoder.image_height", self.image_height, limits::MAX_IMAGE_SIDE)?;
        size_in("model.encoder.image_width", self.image_width, limits::MAX_IMAGE_SIDE)?;
        if self.crop_height < 32 || self.crop_width < 32 {
            let size = format!("{}×{}: a ResNet-18 needs at least 32×32", self.crop_height, self.crop_width);
            return Err(invalid("model.encoder.crop_height", size));
        }
        let map = |side: usize| (0..5).fold(side, |s, _| (s - 1) / 2 + 1);
        if matches!(self.resnet.head, crate::encoder::ResNetHead::SpatialSoftmax { .. })
            && (map(self.crop_height) < 2 || map(self.crop_width) < 2)
        {
            let why = format!(
                "{}×{} leaves a {}×{} feature map after ResNet-18's five halvings: a spatial softmax over a 1×1 \
                 feature map says \"the centre\" whatever the image; crop more than 32 pixels a side, or use the \
                 avg-pool head",
                self.crop_height,
                self.crop_width,
                map(self.crop_height),
                map(self.crop_width)
            );
            return Err(invalid("model.encoder.resnet.head", why));
        }
        if self.crop_height > self.image_height || self.crop_width > self.image_width {
            return Err(invalid(
                "model.encoder.crop_height",
                format!(
                    "crop {}×{} does not fit the {}×{} image",
                    self.crop_height, self.crop_width, self.image_height, self.image_width
                ),
            ));
        }
        if obs_dim < self.cameras * self.image_len() {
            return Err(invalid(
                "model.obs_dim",
                format!(
                    "is {obs_dim}, fewer than the {} values of {} camera image(s) of {}×{}×3",
                    self.cameras * self.image_len(),
                    self.cameras,
                    self.image_height,
                    self.image_width
                ),
            ));
        }
        Ok(())
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelConfig {
    pub obs_dim: usize,
    pub action_dim: usize,
    /// C: future actions per chunk.
    pub chunk_len: usize,
    /// H: executed actions in the history. Must equal C: the history chunk is the flow source.
    pub history_len: usize,
    pub encoder: EncoderConfig,
    /// Width of the observation embedding that conditions the scheduler and the DiT.
    pub obs_embed_dim: usize,
    pub scheduler_hidden: usize,
    /// Also feed the (flattened) history to the modal scheduler.
    pub scheduler_uses_history: bool,
    /// Also condition the velocity field on the (flattened) history: the DiT's conditioning input is
    /// [obs_emb ‖ history] instead of obs_emb. The paper leaves this open; without it the history reaches MARS
    /// only as its flow source and FM never sees it. Absent in older checkpoints: false.
    #[serde(default)]
    pub velocity_uses_history: bool,
    pub dit_width: usize,
    pub dit_depth: usize,
    pub dit_heads: usize,
    pub dit_mlp_ratio: usize,
    pub k_max: usize,
    pub noise_a2a_w: f32,
    /// The ‖w‖∞ that gets the full K_max steps: K(w) = ⌈K_max · min(1, ‖w‖∞ / k_full_w)⌉. The paper's K(w)
    /// is the case 1. Training with `train.k_full_quantile` sets it to that quantile of ‖w‖∞ over the
    /// training samples, because the diversity loss's equilibrium (w ≈ S_next / E|ε_i − ε_j|) puts w well below 1 even
    /// at a real fork, and few Euler steps there average the modes (see `mars diagnose`, README).
    #[serde(default = "one")]
    pub k_full_w: f32,
    /// Standard deviation of the Gaussian ε in the flow source (1 everywhere in the paper's method). Only the
    /// paper's Fig. S3 ablation (FM's loss and success against its initial variance, `mars ablate --knob
    /// source-std`) changes it; the engine refuses a checkpoint where it is not 1.
    #[serde(default = "one")]
    pub source_std: f32,
}

fn one() -> f32 {
    1.0
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    pub epochs: usize,
    pub batch_size: usize,
    pub lr: f64,
    pub weight_decay: f64,
    pub lambda_rec: f64,
    pub lambda_div: f64,
    /// m: nearest neighbours in history space for the diversity loss.
    pub knn_m: usize,
    /// After training MARS, set `model.k_full_w` to this quantile of ‖w‖∞ over the training samples, so the
    /// most multimodal share 1 − q of the samples gets K_max steps (absent: the paper's K(w), k_full_w = 1).
    #[serde(default)]
    pub k_full_quantile: Option<f64>,
    /// Rescale the diversity target (ours, not the paper's): S_next is multiplied by one factor so that this
    /// quantile of the samples' ‖S_next‖∞ equals E|ε_i − ε_j| = 2/√π, the spread of pure noise. The paper's
    /// loss settles w near S_next / (2/√π), about 0.5 at a nav2d fork, where the (1 − w)-gated reconstruction
    /// loss still pulls the one-step map toward the demos' median route; rescaled, the forks ask for w ≈ 1
    /// (the source is FM's there) and the unimodal phases keep their proportionally small w. Never shrinks the
    /// target (factor ≥ 1). Absent: the paper's target.
    #[serde(default)]
    pub div_target_quantile: Option<f64>,
    /// FM with an *ungated* reconstruction loss of this weight: the paper's Fig. S4 ablation (`mars ablate
    /// --knob fm-lambda-rec`), which shows L_rec pulling FM toward the central passages. Absent: plain FM.
    #[serde(default)]
    pub fm_lambda_rec: Option<f64>,
    /// How the gradients are computed: by hand (`mars_policy::grad`, state policies) or through candle's autograd
    /// (always for a vision encoder). The two agree to float rounding (policy/tests/hand_gradients.rs).
    #[serde(default)]
    pub gradients: Gradients,
    pub seed: u64,
}

/// See [`TrainConfig::gradients`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Gradients {
    #[default]
    Hand,
    Autograd,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PolicyConfig {
    pub kind: PolicyKind,
    pub model: ModelConfig,
    pub train: TrainConfig,
}

impl PolicyConfig {
    pub fn load(path: &Path) -> Result<Self, ConfigError> {
        let text = std::fs::read_to_string(path)
            .map_err(|source| ConfigError::Read { path: path.display().to_string(), source })?;
        Self::from_toml(&text).map_err(|e| match e {
            ConfigError::Parse { source, .. } => ConfigError::Parse { path: path.display().to_string(), source },
            other => other,
        })
    }

    pub fn from_toml(text: &str) -> Result<Self, ConfigError> {
        let cfg: PolicyConfig =
            toml::from_str(text).map_err(|source| ConfigError::Parse { path: "<string>".into(), source })?;
        cfg.validate()?;
        Ok(cfg)
    }

    /// The config as TOML, as [`Self::load`] reads it back (a run writes the config it used beside its output).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a PolicyConfig is plain TOML data")
    }

    /// The same policy with a model `width` wide (the encoder's hidden layer, the observation embedding, the
    /// scheduler and the DiT) and `depth` DiT blocks: what a test or a smoke run trains in seconds on 2 cores. The
    /// task's sizes, chunk, history, K and training stay as they are.
    pub fn shrunk(mut self, width: usize, depth: usize) -> Self {
        let m = &mut self.model;
        match &mut m.encoder {
            EncoderConfig::StateMlp { hidden } => *hidden = width,
            EncoderConfig::Vision(v) => v.hidden = width,
        }
        (m.obs_embed_dim, m.scheduler_hidden, m.dit_width, m.dit_depth) = (width, width, width, depth);
        self
    }

    pub fn validate(&self) -> Result<(), ConfigError> {
        self.model.validate()?;
        self.train.validate()?;
        // The two FM ablations (Fig. S3, S4) are FM's knobs: on another kind they would silently change the
        // method (its diversity loss measures spreads in units of ε).
        if self.kind != PolicyKind::Fm && self.model.source_std != 1.0 {
            return Err(invalid(
                "model.source_std",
                format!("is {}; only the fm ablation may change it", self.model.source_std),
            ));
        }
        if self.kind != PolicyKind::Fm && self.train.fm_lambda_rec.is_some() {
            return Err(invalid(
                "train.fm_lambda_rec",
                format!("is set for a {} policy; it is an fm ablation", self.kind),
            ));
        }
        Ok(())
    }
}

impl ModelConfig {
    /// K(w) for this model: ⌈K_max · min(1, ‖w‖∞ / k_full_w)⌉, at least 1.
    pub fn steps_for(&self, w_inf: f32) -> usize {
        crate::steps::steps_for(w_inf / self.k_full_w, self.k_max)
    }

    /// The velocity field's conditioning width: E, plus H·D when it sees the history.
    pub fn velocity_cond_dim(&self) -> usize {
        self.obs_embed_dim + if self.velocity_uses_history { self.history_len * self.action_dim } else { 0 }
    }

    /// The modal scheduler's input width: E, plus H·D when it sees the history.
    pub fn scheduler_input_dim(&self) -> usize {
        self.obs_embed_dim + if self.scheduler_uses_history { self.history_len * self.action_dim } else { 0 }
    }

    pub fn validate(&self) -> Result<(), ConfigError> {
        use limits::*;
        let sizes = [
            ("model.obs_dim", self.obs_dim, MAX_OBS_DIM),
            ("model.action_dim", self.action_dim, MAX_ACTION_DIM),
            ("model.chunk_len", self.chunk_len, MAX_CHUNK_LEN),
            ("model.history_len", self.history_len, MAX_CHUNK_LEN),
            ("model.obs_embed_dim", self.obs_embed_dim, MAX_WIDTH),
            ("model.scheduler_hidden", self.scheduler_hidden, MAX_WIDTH),
            ("model.dit_width", self.dit_width, MAX_WIDTH),
            ("model.dit_depth", self.dit_depth, MAX_DEPTH),
            ("model.dit_heads", self.dit_heads, MAX_WIDTH),
            ("model.dit_mlp_ratio", self.dit_mlp_ratio, MAX_MLP_RATIO),
            ("model.k_max", self.k_max, MAX_K),
        ];
        for (field, v, max) in sizes {
            size_in(field, v, max)?;
        }
        match &self.encoder {
            EncoderConfig::StateMlp { hidden } => size_in("model.encoder.hidden", *hidden, MAX_WIDTH)?,
            EncoderConfig::Vision(v) => v.validate(self.obs_dim)?,
        }
        if self.history_len != self.chunk_len {
            return Err(invalid(
                "model.history_len",
                format!(
                    "is {} but chunk_len is {}: the history chunk is the flow source, so they must match",
                    self.history_len, self.chunk_len
                ),
            ));
        }
        if !self.dit_width.is_multiple_of(self.dit_heads) {
            return Err(invalid(
                "model.dit_heads",
                format!("({}) must divide model.dit_width ({})", self.dit_heads, self.dit_width),
            ));
        }
        if !(self.source_std.is_finite() && self.source_std >= 0.0) {
            return Err(invalid("model.source_std", format!("is {}, must be a finite number ≥ 0", self.source_std)));
        }
        if !(self.k_full_w > 0.0 && self.k_full_w <= 1.0) {
            return Err(invalid("model.k_full_w", format!("is {}, must lie in (0, 1]", self.k_full_w)));
        }
        if !(0.0..=1.0).contains(&self.noise_a2a_w) {
            return Err(invalid("model.noise_a2a_w", format!("is {}, must lie in [0, 1]", self.noise_a2a_w)));
        }
        Ok(())
    }
}

impl TrainConfig {
    pub fn validate(&self) -> Result<(), ConfigError> {
        if self.epochs == 0 {
            return Err(invalid("train.epochs", "must be at least 1"));
        }
        if self.batch_size < 2 {
            return Err(invalid("train.batch_size", "must be at least 2"));
        }
        size_in("train.batch_size", self.batch_size, limits::MAX_BATCH)?;
        size_in("train.knn_m", self.knn_m, limits::MAX_BATCH)?;
        for (field, v) in [
            ("train.lr", self.lr),
            ("train.weight_decay", self.weight_decay),
            ("train.lambda_rec", self.lambda_rec),
            ("train.lambda_div", self.lambda_div),
        ] {
            if !v.is_finite() || v < 0.0 {
                return Err(invalid(field, format!("is {v}, must be a finite number ≥ 0")));
            }
        }
        if let Some(l) = self.fm_lambda_rec
            && (!l.is_finite() || l < 0.0)
        {
            return Err(invalid("train.fm_lambda_rec", format!("is {l}, must be a finite number ≥ 0")));
        }
        if let Some(q) = self.div_target_quantile
            && (!(q > 0.0 && q <= 1.0))
        {
            return Err(invalid("train.div_target_quantile", format!("is {q}, must lie in (0, 1]")));
        }
        if let Some(q) = self.k_full_quantile
            && (!(q > 0.0 && q <= 1.0))
        {
            return Err(invalid("train.k_full_quantile", format!("is {q}, must lie in (0, 1]")));
        }
        if self.lr == 0.0 {
            return Err(invalid("train.lr", "must be > 0"));
        }
        Ok(())
    }
}
