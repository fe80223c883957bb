//! Per-feature statistics as LeRobot writes them (`meta/stats.json` and each episode's `stats/<feature>/…`
//! columns): min, max, mean, std, count and the 1/10/50/90/99 % quantiles, per dimension of a vector and per
//! channel of a camera (values in [0, 1], each shaped [1][1] as LeRobot's image statistics are).

use serde_json::{Value, json};

pub const QUANTILES: [(&str, f64); 5] = [("q01", 0.01), ("q10", 0.10), ("q50", 0.50), ("q90", 0.90), ("q99", 0.99)];

/// How often each of the 256 levels occurs, per RGB channel: image statistics exactly, in 3 KB.
#[derive(Debug, Clone, PartialEq)]
pub struct Histogram(pub [[u64; 256]; 3]);

impl Default for Histogram {
    fn default() -> Self {
        Self([[0; 256]; 3])
    }
}

impl Histogram {
    /// Counts RGB8 pixels (channels last).
    pub fn add(&mut self, rgb: &[u8]) {
        for px in rgb.chunks_exact(3) {
            for (h, &v) in self.0.iter_mut().zip(px) {
                h[v as usize] += 1;
            }
        }
    }

    pub fn merge(&mut self, other: &Histogram) {
        for (a, b) in self.0.iter_mut().zip(&other.0) {
            a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        }
    }
}

/// One feature's statistics, one value per dimension (or camera channel).
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureStats {
    pub min: Vec<f64>,
    pub max: Vec<f64>,
    pub mean: Vec<f64>,
    pub std: Vec<f64>,
    pub count: usize,
    /// In the order of [`QUANTILES`].
    pub quantiles: [Vec<f64>; 5],
    /// A camera's: each value written as [[v]], as LeRobot does.
    pub image: bool,
}

/// Linear interpolation between the nearest ranks (numpy's default).
fn quantile(sorted: &[f64], q: f64) -> f64 {
    let pos = q * (sorted.len() - 1) as f64;
    let (lo, hi) = (pos.floor() as usize, pos.ceil() as usize);
    sorted[lo] + (sorted[hi] - sorted[lo]) * (pos - lo as f64)
}

impl FeatureStats {
    /// `rows` of `dim` values each, flat.
    pub fn of_vectors(rows: &[f64], dim: usize) -> Self {
        let n = rows.len() / dim.max(1);
        let mut s = Self::empty(dim, n, false);
        for d in 0..dim {
            let mut col: Vec<f64> = rows.iter().skip(d).step_by(dim).copied().collect();
            col.sort_by(f64::total_cmp);
            let mean = col.iter().sum::<f64>() / n as f64;
            let var = col.iter().map(|v| (v - mean).powi(2)).sum::<f64>() / n as f64;
            (s.min[d], s.max[d], s.mean[d], s.std[d]) = (col[0], col[n - 1], mean, var.sqrt());
            for (k, (_, q)) in QUANTILES.iter().enumerate() {
                s.quantiles[k][d] = quantile(&col, *q);
            }
        }
        s
    }

    /// A camera's frames through their [`Histogram`]; values as the policy sees them, byte / 255.
    pub fn of_images(hist: &Histogram, frames: usize) -> Self {
        let mut s = Self::empty(3, frames, true);
        for (c, h) in hist.0.iter().enumerate() {
            let n: u64 = h.iter().sum::<u64>().max(1);
            let level = |i: usize| i as f64 / 255.0;
            let mean = h.iter().enumerate().map(|(i, &k)| level(i) * k as f64).sum::<f64>() / n as f64;
            let var = h.iter().enumerate().map(|(i, &k)| (level(i) - mean).powi(2) * k as f64).sum::<f64>() / n as f64;
            // The value of rank r (0-based) among the sorted values.
            let at_rank = |r: u64| {
                let mut seen = 0;
                for (i, &k) in h.iter().enumerate() {
                    seen += k;
                    if seen > r {
                        return level(i);
                    }
                }
                1.0
            };
            s.min[c] = level(h.iter().position(|&k| k > 0).unwrap_or(0));
            s.max[c] = level(h.iter().rposition(|&k| k > 0).unwrap_or(255));
            (s.mean[c], s.std[c]) = (mean, var.sqrt());
            for (k, (_, q)) in QUANTILES.iter().enumerate() {
                let pos = q * (n - 1) as f64;
                let (lo, hi) = (at_rank(pos.floor() as u64), at_rank(pos.ceil() as u64));
                s.quantiles[k][c] = lo + (hi - lo) * (pos - pos.floor());
            }
        }
        s
    }

    fn empty(dim: usize, count: usize, image: bool) -> Self {
        let z = vec![0.0; dim];
        Self {
            min: z.clone(),
            max: z.clone(),
            mean: z.clone(),
            std: z.clone(),
            count,
            quantiles: [z.clone(), z.clone(), z.clone(), z.clone(), z],
            image,
        }
    }

    /// The named statistics in LeRobot's order, each a vector of values (count apart).
    pub fn named(&self) -> Vec<(&'static str, &[f64])> {
        let mut v: Vec<(&'static str, &[f64])> =
            vec![("min", &self.min), ("max", &self.max), ("mean", &self.mean), ("std", &self.std)];
        v.extend(QUANTILES.iter().zip(&self.quantiles).map(|((n, _), q)| (*n, q.as_slice())));
        v
    }

    /// As in `meta/stats.json`.
    pub fn to_json(&self) -> Value {
        let shape =
            |v: &[f64]| -> Value { if self.image { v.iter().map(|x| json!([[x]])).collect() } else { json!(v) } };
        let mut m = serde_json::Map::new();
        for (name, values) in self.named() {
            m.insert(name.into(), shape(values));
        }
        m.insert("count".into(), json!([self.count]));
        Value::Object(m)
    }
}
