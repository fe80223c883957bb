//! Every trained parameter in one flat vector (and its gradient beside it), by the names the candle model gives
//! them (`velocity.blocks.0.attn.qkv.weight`, …), copied from and back to the model's `VarMap`; and AdamW over
//! them, as candle-nn's `AdamW` steps them (the two groups `crate::train` makes: weight matrices decayed, the
//! rest not).

use multiversion::multiversion;

use super::linear::Lin;
use candle_core::Tensor;
use candle_nn::VarMap;

struct Slot {
    name: String,
    at: usize,
    shape: Vec<usize>,
    /// Weight decay applies (a matrix, not the positional embedding): `crate::train::optimizers`' rule.
    decay: bool,
}

#[derive(Default)]
pub struct Params {
    pub value: Vec<f32>,
    pub grad: Vec<f32>,
    slots: Vec<Slot>,
}

impl Params {
    /// Adds the parameter `name` of `shape`; returns where it starts.
    pub fn add(&mut self, name: &str, shape: &[usize]) -> usize {
        let at = self.value.len();
        let len: usize = shape.iter().product();
        let decay = shape.len() >= 2 && !name.ends_with("pos_embed");
        self.slots.push(Slot { name: name.to_string(), at, shape: shape.to_vec(), decay });
        self.value.resize(at + len, 0.0);
        self.grad.resize(at + len, 0.0);
        at
    }

    /// Adds `prefix.weight` [out, inp] and `prefix.bias` [out].
    pub fn linear(&mut self, prefix: &str, inp: usize, out: usize) -> Lin {
        let w = self.add(&format!("{prefix}.weight"), &[out, inp]);
        let b = self.add(&format!("{prefix}.bias"), &[out]);
        Lin { w, b, inp, out }
    }

    /// Copies every parameter's value from `varmap`, which must hold exactly these names and shapes.
    pub fn load(&mut self, varmap: &VarMap) -> anyhow::Result<()> {
        let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        anyhow::ensure!(
            data.len() == self.slots.len(),
            "the model has {} parameters, the hand-written gradients know {}",
            data.len(),
            self.slots.len()
        );
        for s in &self.slots {
            let var = data.get(&s.name).ok_or_else(|| anyhow::anyhow!("the model has no parameter {}", s.name))?;
            anyhow::ensure!(
                var.dims() == s.shape.as_slice(),
                "{}: shape {:?}, expected {:?}",
                s.name,
                var.dims(),
                s.shape
            );
            let v = var.as_tensor().flatten_all()?.to_vec1::<f32>()?;
            self.value[s.at..s.at + v.len()].copy_from_slice(&v);
        }
        Ok(())
    }

    /// Writes every parameter's value back into `varmap` (for checkpoints and the candle model's inference).
    pub fn store(&self, varmap: &VarMap) -> anyhow::Result<()> {
        let data = varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        for s in &self.slots {
            let var = data.get(&s.name).ok_or_else(|| anyhow::anyhow!("the model has no parameter {}", s.name))?;
            let len: usize = s.shape.iter().product();
            var.set(&Tensor::from_slice(&self.value[s.at..s.at + len], s.shape.as_slice(), var.device())?)?;
        }
        Ok(())
    }

    /// The gradient of parameter `name` (for tests against autograd).
    pub fn grad_of(&self, name: &str) -> Option<&[f32]> {
        let s = self.slots.iter().find(|s| s.name == name)?;
        Some(&self.grad[s.at..s.at + s.shape.iter().product::<usize>()])
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.slots.iter().map(|s| s.name.as_str())
    }
}

/// AdamW's moments and step count over a [`Params`].
pub struct AdamW {
    m: Vec<f32>,
    v: Vec<f32>,
    step: i32,
    pub lr: f64,
    pub weight_decay: f64,
}

const BETA1: f64 = 0.9;
const BETA2: f64 = 0.999;
const EPS: f64 = 1e-8;

impl AdamW {
    pub fn new(params: &Params, lr: f64, weight_decay: f64) -> Self {
        let n = params.value.len();
        Self { m: vec![0.0; n], v: vec![0.0; n], step: 0, lr, weight_decay }
    }

    /// One step on `params.grad`, in candle-nn's order of operations (f32 tensors, f64 scalars cast to f32).
    pub fn step(&mut self, params: &mut Params) {
        self.step += 1;
        let (b1, b2) = (BETA1 as f32, BETA2 as f32);
        let (one_b1, one_b2) = ((1.0 - BETA1) as f32, (1.0 - BETA2) as f32);
        let scale_m = (1.0 / (1.0 - BETA1.powi(self.step))) as f32;
        let scale_v = (1.0 / (1.0 - BETA2.powi(self.step))) as f32;
        let (lr, eps) = (self.lr as f32, EPS as f32);
        for s in &params.slots {
            let keep = if s.decay { (1.0 - self.lr * self.weight_decay) as f32 } else { 1.0 };
            let range = s.at..s.at + s.shape.iter().product::<usize>();
            let (theta, g) = (&mut params.value[range.clone()], &params.grad[range.clone()]);
            let (m, v) = (&mut self.m[range.clone()], &mut self.v[range]);
            let c = Constants { b1, b2, one_b1, one_b2, scale_m, scale_v, lr, eps, keep };
            update(&c, theta, g, m, v);
        }
    }
}

/// One step's scalars, as f32.
struct Constants {
    b1: f32,
    b2: f32,
    one_b1: f32,
    one_b2: f32,
    scale_m: f32,
    scale_v: f32,
    lr: f32,
    eps: f32,
    keep: f32,
}

/// The element-wise update of one parameter, compiled for the CPU's widest vectors (as `super::layers`).
#[multiversion(targets = "simd")]
fn update(c: &Constants, theta: &mut [f32], g: &[f32], m: &mut [f32], v: &mut [f32]) {
    let n = theta.len();
    let (g, m, v) = (&g[..n], &mut m[..n], &mut v[..n]);
    for i in 0..n {
        m[i] = m[i] * c.b1 + g[i] * c.one_b1;
        v[i] = v[i] * c.b2 + (g[i] * g[i]) * c.one_b2;
        let adjusted = (m[i] * c.scale_m) / ((v[i] * c.scale_v).sqrt() + c.eps);
        theta[i] = theta[i] * c.keep - adjusted * c.lr;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::{DType, Device, Var};
    use candle_nn::Optimizer;

    /// Three AdamW steps by hand against candle-nn's `AdamW` in `crate::train`'s two groups (a matrix decayed,
    /// a bias and the positional embedding not), on the same gradients.
    #[test]
    fn adamw_steps_as_candle_s_does() {
        let dev = Device::Cpu;
        let varmap = VarMap::new();
        let shapes: [(&str, &[usize]); 3] = [("l.weight", &[2, 3]), ("l.bias", &[3]), ("x.pos_embed", &[2, 2])];
        let mut params = Params::default();
        for (name, shape) in shapes {
            params.add(name, shape);
            varmap.get(shape, name, candle_nn::init::Init::Randn { mean: 0.0, stdev: 1.0 }, DType::F32, &dev).unwrap();
        }
        params.load(&varmap).unwrap();
        let (lr, wd) = (0.01, 0.1);
        let vars = |decay: bool| -> Vec<Var> {
            let data = varmap.data().lock().unwrap();
            shapes.iter().filter(|(n, _)| (*n == "l.weight") == decay).map(|(n, _)| data[*n].clone()).collect()
        };
        let adam = |vars, wd| {
            candle_nn::AdamW::new(vars, candle_nn::ParamsAdamW { lr, weight_decay: wd, ..Default::default() }).unwrap()
        };
        let mut candle = [adam(vars(true), wd), adam(vars(false), 0.0)];
        let mut ours = AdamW::new(&params, lr, wd);
        for step in 0..3 {
            // loss = Σ c_i θ_i with c_i fixed per step: the gradient is c.
            let data = varmap.data().lock().unwrap();
            let mut loss = Tensor::zeros((), DType::F32, &dev).unwrap();
            for (k, (name, _)) in shapes.iter().enumerate() {
                let var = &data[*name];
                let n = var.elem_count();
                let c: Vec<f32> = (0..n).map(|i| ((i + k * 7 + step * 3) as f32 * 0.37).sin()).collect();
                let slot = params.slots.iter().find(|s| s.name == *name).unwrap();
                params.grad[slot.at..slot.at + n].copy_from_slice(&c);
                let c = Tensor::from_vec(c, var.shape(), &dev).unwrap();
                loss = (loss + (var.as_tensor() * c).unwrap().sum_all().unwrap()).unwrap();
            }
            drop(data);
            let grads = loss.backward().unwrap();
            for opt in &mut candle {
                opt.step(&grads).unwrap();
            }
            ours.step(&mut params);
        }
        let data = varmap.data().lock().unwrap();
        for s in &params.slots {
            let want = data[&s.name].as_tensor().flatten_all().unwrap().to_vec1::<f32>().unwrap();
            for (a, b) in params.value[s.at..].iter().zip(&want) {
                assert!((a - b).abs() < 1e-6, "{}: by hand {a}, candle {b}", s.name);
            }
        }
    }
}
