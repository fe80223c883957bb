//! The network's weights, read once from `model.safetensors` and laid out for the kernels.
//!
//! Linear weights stay as stored, [out, in] row-major, which is what gemm's matrix-vector kernels read. Two
//! changes of layout, both done here once:
//! - the linears applied to several rows at once (the C tokens, or the K steps' conditioning) are also packed
//!   into the panel layout of gemm's microkernels (see `matmul`), when the engine uses them;
//! - the adaLN projections of all blocks and of the final layer take the same input c, so they are stacked
//!   into one [(6·depth + 2)·W, W] matrix: one matrix-vector product per step instead of depth + 1.

use crate::dims::Dims;
use crate::error::LoadError;
use crate::matmul::{Linear, MatMul, Panels, pack_panels};
use mars_policy_format::checkpoint::CheckpointError;
use safetensors::{Dtype, SafeTensorError, SafeTensors};
use std::cell::{Cell, RefCell};
use std::collections::BTreeSet;
use std::path::Path;

#[derive(Debug, Clone)]
pub struct Block {
    pub qkv: Linear,
    pub attn_out: Linear,
    pub fc1: Linear,
    pub fc2: Linear,
}

/// Where the modality weight w comes from.
#[derive(Debug, Clone)]
pub enum Modality {
    /// MARS: an MLP ending in a sigmoid.
    Scheduler { fc1: Linear, fc2: Linear },
    /// The baselines: a constant.
    Fixed(f32),
}

#[derive(Debug, Clone)]
pub struct Weights {
    pub enc_fc1: Linear,
    pub enc_fc2: Linear,
    pub modality: Modality,
    pub action_in: Linear,
    /// [C, W]
    pub pos: Box<[f32]>,
    pub time_fc1: Linear,
    pub time_fc2: Linear,
    pub cond_in: Linear,
    pub blocks: Vec<Block>,
    /// Every block's `ada` then `final_ada`, stacked (see the module doc).
    pub ada: Linear,
    pub action_out: Linear,
    /// The time embedding's sinusoid frequencies, computed as the candle model does (in f32).
    pub freqs: Box<[f32]>,
}

/// Reads named tensors of one safetensors file, each checked before use: F32, the shape the config makes,
/// finite values. It remembers which tensors were read, so a file holding more than the config's network (a
/// MARS checkpoint relabelled FM, say) is refused rather than run as something else ([`Reader::refuse_unread`]).
pub(crate) struct Reader<'a> {
    st: SafeTensors<'a>,
    path: &'a Path,
    /// How the linears read now are packed (the cameras' encoders use their own; see [`Reader::with_mm`]).
    mm: Cell<MatMul>,
    read: RefCell<BTreeSet<String>>,
}

/// Reads the safetensors file `path` and hands `read` a [`Reader`] over it (the bytes live for the call).
pub(crate) fn with_reader<T>(
    path: &Path,
    mm: MatMul,
    read: impl FnOnce(&Reader) -> Result<T, LoadError>,
) -> Result<T, LoadError> {
    let err = |problem: String| LoadError::Tensor { path: path.into(), name: "*".into(), problem };
    let bytes = std::fs::read(path).map_err(|e| err(e.to_string()))?;
    with_bytes(path, &bytes, mm, read)
}

/// [`with_reader`] over the bytes of the safetensors file `path`.
pub(crate) fn with_bytes<T>(
    path: &Path,
    bytes: &[u8],
    mm: MatMul,
    read: impl FnOnce(&Reader) -> Result<T, LoadError>,
) -> Result<T, LoadError> {
    let corrupt = |problem: String| CheckpointError::Corrupt { path: path.into(), problem };
    let st = SafeTensors::deserialize(bytes).map_err(|e| corrupt(e.to_string()))?;
    read(&Reader { st, path, mm: Cell::new(mm), read: RefCell::default() })
}

impl<'a> Reader<'a> {
    pub(crate) fn mm(&self) -> MatMul {
        self.mm.get()
    }

    /// `read` with the linears packed for `mm` (then back to this reader's own).
    pub(crate) fn with_mm<T>(&self, mm: MatMul, read: impl FnOnce(&Self) -> T) -> T {
        let own = self.mm.replace(mm);
        let out = read(self);
        self.mm.set(own);
        out
    }

    /// The first tensor of the file nothing has read, as an error: it belongs to another network than the
    /// config's `what` (e.g. "`mars` model").
    pub(crate) fn refuse_unread(&self, what: &str) -> Result<(), LoadError> {
        let read = self.read.borrow();
        match self.st.names().into_iter().find(|n| !read.contains(*n)) {
            None => Ok(()),
            Some(name) => Err(LoadError::Tensor {
                path: self.path.to_path_buf(),
                name: name.to_string(),
                problem: format!("not part of a {what} with this config (wrong policy kind or config?)"),
            }),
        }
    }

    pub(crate) fn tensor(&self, name: &str, shape: &[usize]) -> Result<Box<[f32]>, LoadError> {
        let err = |problem: String| LoadError::Tensor { path: self.path.to_path_buf(), name: name.into(), problem };
        let view = match self.st.tensor(name) {
            Ok(view) => view,
            Err(SafeTensorError::TensorNotFound(_)) => {
                return Err(err(format!("missing from the checkpoint (shape {shape:?})")));
            }
            Err(e) => return Err(err(e.to_string())),
        };
        if view.dtype() != Dtype::F32 {
            return Err(err(format!("dtype {:?}, expected F32", view.dtype())));
        }
        if view.shape() != shape {
            return Err(err(format!("shape {:?}, the config needs {shape:?}", view.shape())));
        }
        let values: Box<[f32]> =
            view.data().chunks_exact(4).map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]])).collect();
        if let Some(i) = values.iter().position(|v| !v.is_finite()) {
            return Err(err(format!("value {i} is {}: the weights must be finite", values[i])));
        }
        self.read.borrow_mut().insert(name.to_string());
        Ok(values)
    }

    /// A linear applied to one row (a matrix-vector product).
    fn linear(&self, prefix: &str, input: usize, output: usize) -> Result<Linear, LoadError> {
        Ok(Linear {
            weight: self.tensor(&format!("{prefix}.weight"), &[output, input])?,
            bias: self.tensor(&format!("{prefix}.bias"), &[output])?,
            input,
            output,
            panels: Panels::default(),
        })
    }

    /// A linear applied to several rows at once (the C tokens, or the K steps' conditioning).
    fn token_linear(&self, prefix: &str, input: usize, output: usize) -> Result<Linear, LoadError> {
        Ok(self.panels(self.linear(prefix, input, output)?))
    }

    /// `l` with its weights also in panel layout, when the engine's products use it.
    pub(crate) fn panels(&self, mut l: Linear) -> Linear {
        let mm = self.mm.get();
        if mm.uses_panels() {
            l.panels = pack_panels(&l.weight, l.output, l.input, mm);
        }
        l
    }
}

/// Stacks linears with the same input along the output dimension.
fn stack(parts: &[Linear]) -> Linear {
    Linear {
        weight: parts.iter().flat_map(|l| l.weight.iter().copied()).collect(),
        bias: parts.iter().flat_map(|l| l.bias.iter().copied()).collect(),
        input: parts[0].input,
        output: parts.iter().map(|l| l.output).sum(),
        panels: Panels::default(),
    }
}

impl Weights {
    /// Reads the network's weights (all but the cameras' encoders), each checked against the config (`d`) by
    /// the [`Reader`]. `fixed_w`: `PolicyKind::fixed_w` (`Some` for a baseline, which has no scheduler;
    /// `d.scheduler` follows it too).
    pub(crate) fn read(r: &Reader, d: &Dims, fixed_w: Option<f32>) -> Result<Self, LoadError> {
        let w = d.width;
        let modality = match (d.scheduler, fixed_w) {
            (Some(s), None) => Modality::Scheduler {
                fc1: r.linear("scheduler.mlp.fc1", s.input, s.hidden)?,
                fc2: r.linear("scheduler.mlp.fc2", s.hidden, d.action)?,
            },
            (_, w) => Modality::Fixed(w.unwrap_or(1.0)),
        };
        let mut blocks = Vec::with_capacity(d.depth);
        let mut ada = Vec::with_capacity(d.depth + 1);
        for i in 0..d.depth {
            let p = format!("velocity.blocks.{i}");
            blocks.push(Block {
                qkv: r.token_linear(&format!("{p}.attn.qkv"), w, 3 * w)?,
                attn_out: r.token_linear(&format!("{p}.attn.out"), w, w)?,
                fc1: r.token_linear(&format!("{p}.mlp.fc1"), w, d.mlp_hidden)?,
                fc2: r.token_linear(&format!("{p}.mlp.fc2"), d.mlp_hidden, w)?,
            });
            ada.push(r.linear(&format!("{p}.ada"), w, 6 * w)?);
        }
        ada.push(r.linear("velocity.final_ada", w, 2 * w)?);
        let half = d.freq / 2;
        let enc = if d.vision.is_some() { "encoder.vision.mlp" } else { "encoder.state_mlp" };
        Ok(Self {
            enc_fc1: r.linear(&format!("{enc}.fc1"), d.enc_input, d.enc_hidden)?,
            enc_fc2: r.linear(&format!("{enc}.fc2"), d.enc_hidden, d.embed)?,
            modality,
            action_in: r.token_linear("velocity.action_in", d.action, w)?,
            pos: r.tensor("velocity.pos_embed", &[d.chunk, w])?,
            time_fc1: r.token_linear("velocity.time.mlp.fc1", d.freq, w)?,
            time_fc2: r.token_linear("velocity.time.mlp.fc2", w, w)?,
            cond_in: r.linear("velocity.cond_in", d.cond_input, w)?,
            blocks,
            ada: r.panels(stack(&ada)),
            action_out: r.token_linear("velocity.action_out", w, d.action)?,
            freqs: (0..half).map(|i| (-(10_000f32.ln()) * i as f32 / half as f32).exp()).collect(),
        })
    }
}
