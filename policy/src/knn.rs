//! Exact m-nearest neighbours in history-action space, computed once per dataset for the diversity loss.
//! A kd-tree (the `kdtree` crate, exact search) does the work; `brute_force` is the reference it is tested
//! against.

use kdtree::KdTree;
use kdtree::distance::squared_euclidean;

#[derive(Debug, thiserror::Error)]
pub enum KnnError {
    #[error("need more than m = {m} samples to find {m} neighbours of each, have {n}")]
    TooFewPoints { n: usize, m: usize },
    #[error("point {index} has a non-finite coordinate")]
    NonFinite { index: usize },
    #[error("kd-tree: {0}")]
    Tree(String),
}

fn check(points: &[f32], dim: usize, m: usize) -> Result<usize, KnnError> {
    let n = points.len() / dim;
    if n <= m {
        return Err(KnnError::TooFewPoints { n, m });
    }
    if let Some(i) = points.iter().position(|v| !v.is_finite()) {
        return Err(KnnError::NonFinite { index: i / dim });
    }
    Ok(n)
}

/// For each of the `n = points.len() / dim` points, the indices of its `m` nearest other points (itself
/// excluded), nearest first: a flat `n × m` vector.
pub fn nearest_neighbours(points: &[f32], dim: usize, m: usize) -> Result<Vec<u32>, KnnError> {
    let n = check(points, dim, m)?;
    let rows: Vec<Vec<f64>> = points.chunks_exact(dim).map(|r| r.iter().map(|&v| v as f64).collect()).collect();
    let mut tree = KdTree::with_capacity(dim, n);
    for (i, r) in rows.iter().enumerate() {
        tree.add(r.as_slice(), i).map_err(|e| KnnError::Tree(format!("{e:?}")))?;
    }
    let mut out = Vec::with_capacity(n * m);
    for (i, r) in rows.iter().enumerate() {
        let found = tree.nearest(r, m + 1, &squared_euclidean).map_err(|e| KnnError::Tree(format!("{e:?}")))?;
        // Drop the point itself; if exact duplicates pushed it out of the first m + 1, drop the farthest.
        let mut kept: Vec<u32> = found.iter().filter(|(_, j)| **j != i).map(|(_, j)| **j as u32).collect();
        kept.truncate(m);
        out.extend_from_slice(&kept);
    }
    Ok(out)
}

/// The O(n²) reference: same contract as `nearest_neighbours`.
pub fn brute_force(points: &[f32], dim: usize, m: usize) -> Result<Vec<u32>, KnnError> {
    let n = check(points, dim, m)?;
    let mut out = Vec::with_capacity(n * m);
    for i in 0..n {
        let pi = &points[i * dim..(i + 1) * dim];
        let mut d: Vec<(f64, usize)> =
            (0..n).filter(|&j| j != i).map(|j| (sq_dist(pi, &points[j * dim..(j + 1) * dim]), j)).collect();
        d.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        out.extend(d[..m].iter().map(|&(_, j)| j as u32));
    }
    Ok(out)
}

pub fn sq_dist(a: &[f32], b: &[f32]) -> f64 {
    a.iter().zip(b).map(|(&x, &y)| (x as f64 - y as f64).powi(2)).sum()
}
