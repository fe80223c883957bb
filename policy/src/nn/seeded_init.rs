//! A `VarBuilder` backend whose initial weights come from a seeded generator.
//!
//! candle's CPU RNG cannot be seeded, so a `VarMap` would give different weights on every run. This backend
//! honours the same `Init` hints but draws from a `StdRng`, and stores the variables in a `VarMap` so the
//! optimiser and safetensors saving work as usual. Variables are created in model-construction order, which is
//! fixed, so the same seed gives the same weights.

use candle_core::{DType, Device, Result, Shape, Tensor, Var};
use candle_nn::init::{FanInOut, NormalOrUniform};
use candle_nn::{Init, VarBuilder, VarMap};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::{Distribution, Normal};
use std::sync::Mutex;

pub struct SeededInit {
    varmap: VarMap,
    rng: Mutex<StdRng>,
}

impl SeededInit {
    /// A fresh `VarMap` and a `VarBuilder` that fills it with seeded initial values.
    pub fn var_builder(seed: u64, device: &Device) -> (VarMap, VarBuilder<'static>) {
        let varmap = VarMap::new();
        let backend = SeededInit { varmap: varmap.clone(), rng: Mutex::new(StdRng::seed_from_u64(seed)) };
        (varmap, VarBuilder::from_backend(Box::new(backend), DType::F32, device.clone()))
    }

    fn sample(&self, shape: &Shape, init: Init) -> Vec<f32> {
        let n = shape.elem_count();
        let mut rng = self.rng.lock().unwrap_or_else(|e| e.into_inner());
        let normal = |rng: &mut StdRng, mean: f64, std: f64| -> Vec<f32> {
            // std > 0 always here; Normal::new only fails on a negative or NaN std.
            let d = Normal::new(mean, std.max(0.0)).unwrap_or_else(|_| Normal::new(0.0, 0.0).unwrap());
            (0..n).map(|_| d.sample(rng) as f32).collect()
        };
        match init {
            Init::Const(v) => vec![v as f32; n],
            Init::Randn { mean, stdev } => normal(&mut rng, mean, stdev),
            Init::Uniform { lo, up } => (0..n).map(|_| rng.random_range(lo..up) as f32).collect(),
            Init::Kaiming { dist, fan, non_linearity } => {
                let fan = match fan {
                    FanInOut::FanIn => FanInOut::FanIn.for_shape(shape),
                    FanInOut::FanOut => FanInOut::FanOut.for_shape(shape),
                };
                let std = non_linearity.gain() / (fan as f64).sqrt();
                match dist {
                    NormalOrUniform::Normal => normal(&mut rng, 0.0, std),
                    NormalOrUniform::Uniform => {
                        let bound = 3f64.sqrt() * std;
                        (0..n).map(|_| rng.random_range(-bound..bound) as f32).collect()
                    }
                }
            }
        }
    }
}

impl candle_nn::var_builder::SimpleBackend for SeededInit {
    fn get(&self, s: Shape, name: &str, h: Init, dtype: DType, dev: &Device) -> Result<Tensor> {
        let mut vars = self.varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        if let Some(var) = vars.get(name) {
            if var.shape() != &s {
                candle_core::bail!("variable {name} requested with shape {s:?} but exists with {:?}", var.shape());
            }
            return Ok(var.as_tensor().clone());
        }
        let values = self.sample(&s, h);
        let var = Var::from_tensor(&Tensor::from_vec(values, s, dev)?.to_dtype(dtype)?)?;
        let tensor = var.as_tensor().clone();
        vars.insert(name.to_string(), var);
        Ok(tensor)
    }

    fn get_unchecked(&self, name: &str, _dtype: DType, _dev: &Device) -> Result<Tensor> {
        let vars = self.varmap.data().lock().unwrap_or_else(|e| e.into_inner());
        match vars.get(name) {
            Some(v) => Ok(v.as_tensor().clone()),
            None => candle_core::bail!("variable {name} does not exist yet"),
        }
    }

    fn contains_tensor(&self, name: &str) -> bool {
        self.varmap.data().lock().map(|v| v.contains_key(name)).unwrap_or(false)
    }
}
