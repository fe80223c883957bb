//! Checkpoints: a directory with `model.safetensors` (the weights) and `policy.json` (its format is
//! `mars_policy_format::checkpoint`). This half writes the candle model's weights and builds the candle model
//! back from them; loading checks everything before a model exists: a corrupt, truncated or wrong-shape
//! checkpoint is an error that names the file or tensor, never a panic.

use crate::config::PolicyConfig;
use crate::model::MarsModel;
use crate::normalize::Normalizer;
use candle_core::{DType, Device, Shape, Tensor};
use candle_nn::{Init, VarBuilder, VarMap};
use mars_policy_format::checkpoint::EpochLog;
use std::collections::BTreeSet;
use std::path::Path;
use std::sync::{Arc, Mutex};

pub use mars_policy_format::checkpoint::{
    CheckpointError, CheckpointMeta, META_FILE, WEIGHTS_FILE, load_meta, parse_meta,
};

pub struct Loaded {
    pub model: MarsModel,
    pub meta: CheckpointMeta,
}

/// Writes both files through temporary names and renames, so a crash never leaves a half-written checkpoint
/// under the real names. From the pieces, so a model still in training can be saved (`train::Snapshots`);
/// a trained one: `Trained::save`.
pub fn save_parts(
    dir: &Path,
    cfg: &PolicyConfig,
    varmap: &VarMap,
    normalizer: &Normalizer,
    log: &[EpochLog],
) -> Result<(), CheckpointError> {
    let io = |source| CheckpointError::Io { path: dir.to_path_buf(), source };
    std::fs::create_dir_all(dir).map_err(io)?;
    let meta = CheckpointMeta::new(cfg.kind, cfg.model.clone(), cfg.train.clone(), normalizer.clone(), log.to_vec());
    let tmp_weights = dir.join(format!(".{WEIGHTS_FILE}.tmp"));
    varmap
        .save(&tmp_weights)
        .map_err(|e| CheckpointError::Model { path: tmp_weights.clone(), problem: e.to_string() })?;
    let json = serde_json::to_string_pretty(&meta)
        .map_err(|e| CheckpointError::Meta { path: dir.join(META_FILE), problem: e.to_string() })?;
    let tmp_meta = dir.join(format!(".{META_FILE}.tmp"));
    std::fs::write(&tmp_meta, json).map_err(io)?;
    std::fs::rename(&tmp_weights, dir.join(WEIGHTS_FILE)).map_err(io)?;
    std::fs::rename(&tmp_meta, dir.join(META_FILE)).map_err(io)?;
    Ok(())
}

pub fn load(dir: &Path, device: &Device) -> Result<Loaded, CheckpointError> {
    let meta = load_meta(dir)?;
    let path = dir.join(WEIGHTS_FILE);
    let bytes = std::fs::read(&path).map_err(|source| CheckpointError::Io { path: path.clone(), source })?;
    load_weights(dir, meta, &bytes, device)
}

/// [`load`] of `dir`'s files as read (`policy.json`'s text, `model.safetensors`' bytes).
pub fn load_from(dir: &Path, meta_text: &str, weights: &[u8], device: &Device) -> Result<Loaded, CheckpointError> {
    load_weights(dir, parse_meta(dir, meta_text)?, weights, device)
}

fn load_weights(dir: &Path, meta: CheckpointMeta, bytes: &[u8], device: &Device) -> Result<Loaded, CheckpointError> {
    let path = dir.join(WEIGHTS_FILE);
    let st = safetensors::SafeTensors::deserialize(bytes)
        .map_err(|e| CheckpointError::Corrupt { path: path.clone(), problem: e.to_string() })?;
    let names: Vec<String> = st.names().into_iter().map(str::to_owned).collect();
    let used: Arc<Mutex<BTreeSet<String>>> = Arc::default();
    let backend = CheckedTensors { st, used: used.clone() };
    let vb = VarBuilder::from_backend(Box::new(backend), DType::F32, device.clone());
    let model = MarsModel::new(&meta.model, meta.kind, vb)
        .map_err(|e| CheckpointError::Model { path: path.clone(), problem: e.to_string() })?;
    let used = used.lock().unwrap_or_else(|e| e.into_inner());
    if let Some(extra) = names.into_iter().find(|n| !used.contains(n)) {
        return Err(CheckpointError::Tensor {
            path,
            name: extra,
            problem: format!("not part of a `{}` model with this config (wrong policy kind or config?)", meta.kind),
        });
    }
    Ok(Loaded { model, meta })
}

/// A `VarBuilder` backend over the safetensors file that hands out a tensor only once its shape is the one the
/// config makes (checked before the tensor is copied out of the file: a hostile header cannot size an allocation),
/// its dtype F32 and its values finite; it reports a missing or wrong tensor by name and records which tensors the
/// model used, so leftovers can be reported too.
struct CheckedTensors<'a> {
    st: safetensors::SafeTensors<'a>,
    /// Shared with `load`, which keeps a handle: the backend itself moves into the `VarBuilder`.
    used: Arc<Mutex<BTreeSet<String>>>,
}

impl CheckedTensors<'_> {
    fn tensor(&self, name: &str, shape: Option<&Shape>, dev: &Device) -> candle_core::Result<Tensor> {
        let Ok(view) = self.st.tensor(name) else {
            let shape = shape.map_or(String::new(), |s| format!(" (shape {:?})", s.dims()));
            candle_core::bail!("tensor `{name}`{shape} is missing from the checkpoint");
        };
        if let Some(s) = shape
            && view.shape() != s.dims()
        {
            candle_core::bail!(
                "tensor `{name}` has shape {:?} in the checkpoint, the config needs {:?}",
                view.shape(),
                s.dims()
            );
        }
        if view.dtype() != safetensors::Dtype::F32 {
            candle_core::bail!("tensor `{name}`: dtype {:?}, expected F32", view.dtype());
        }
        let t = candle_core::safetensors::Load::load(&view, dev)?;
        if t.flatten_all()?.to_vec1::<f32>()?.iter().any(|v| !v.is_finite()) {
            candle_core::bail!("tensor `{name}` contains NaN or infinite values");
        }
        self.used.lock().unwrap_or_else(|e| e.into_inner()).insert(name.to_string());
        Ok(t)
    }
}

impl candle_nn::var_builder::SimpleBackend for CheckedTensors<'_> {
    fn get(&self, s: Shape, name: &str, _h: Init, dtype: DType, dev: &Device) -> candle_core::Result<Tensor> {
        self.tensor(name, Some(&s), dev)?.to_dtype(dtype)
    }

    fn get_unchecked(&self, name: &str, dtype: DType, dev: &Device) -> candle_core::Result<Tensor> {
        self.tensor(name, None, dev)?.to_dtype(dtype)
    }

    fn contains_tensor(&self, name: &str) -> bool {
        self.st.tensor(name).is_ok()
    }
}
