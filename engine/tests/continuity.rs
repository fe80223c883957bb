//! `Engine::infer_after` on the shipped FR3 Pick Cup MARS checkpoint: with no committed rows it is `infer` bit for
//! bit; committed rows pull the chunk's first rows to them (the guidance of `mars_engine::continuity`); bad
//! committed rows are refused with an error that says why.

use std::path::Path;
use std::time::Duration;

use mars_engine::{Engine, EngineConfig, EngineError, Input};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};
use rand_distr::StandardNormal;

fn engine() -> Engine {
    let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../assets/checkpoints/fr3_pick_cup/mars"));
    Engine::load(dir, EngineConfig::with_seed(0)).unwrap()
}

/// Observations and histories around the dataset's means (half a standard deviation of spread).
fn inputs(e: &Engine, rng: &mut StdRng) -> (Vec<f32>, Vec<f32>) {
    let n = &e.meta().normalizer;
    let near = |mean: &[f32], std: &[f32], i: usize, rng: &mut StdRng| {
        mean[i % mean.len()] + 0.5 * std[i % std.len()] * rng.sample::<f32, _>(StandardNormal)
    };
    let obs = (0..e.obs_dim()).map(|i| near(&n.obs.mean, &n.obs.std, i, rng)).collect();
    let hist = (0..e.chunk_len() * e.action_dim()).map(|i| near(&n.action.mean, &n.action.std, i, rng)).collect();
    (obs, hist)
}

fn distance(a: &[f32], b: &[f32]) -> f32 {
    a.iter().zip(b).map(|(a, b)| (a - b).powi(2)).sum::<f32>().sqrt()
}

#[test]
fn no_committed_rows_is_infer_bit_for_bit() {
    let mut e = engine();
    let mut rng = StdRng::seed_from_u64(1);
    for seed in 0..8 {
        let (obs, hist) = inputs(&e, &mut rng);
        e.reseed(seed);
        let plain = e.infer(&obs, &hist, Duration::MAX).unwrap().chunk.to_vec();
        e.reseed(seed);
        let after = e.infer_after(&obs, &hist, &[], Duration::MAX).unwrap().chunk.to_vec();
        assert_eq!(plain, after);
    }
}

/// Committed rows half a standard deviation away from where the unguided chunk's first rows go: the guided
/// chunk's first rows end at least 3× nearer to them, on each of 32 inputs, at 1, 2 and 3 committed rows.
#[test]
fn committed_rows_pull_the_first_rows_to_them() {
    let mut e = engine();
    let (c, d) = (e.chunk_len(), e.action_dim());
    let std = e.meta().normalizer.action.std.clone();
    let mut rng = StdRng::seed_from_u64(2);
    for rows in 1..=3.min(c - 1) {
        for seed in 0..32 {
            let (obs, hist) = inputs(&e, &mut rng);
            e.reseed(seed);
            let free = e.infer(&obs, &hist, Duration::MAX).unwrap().chunk[..rows * d].to_vec();
            let committed: Vec<f32> = free.iter().enumerate().map(|(i, v)| v + 0.5 * std[i % d]).collect();
            e.reseed(seed);
            let guided = e.infer_after(&obs, &hist, &committed, Duration::MAX).unwrap();
            let (before, after) = (distance(&free, &committed), distance(&guided.chunk[..rows * d], &committed));
            assert!(
                after * 3.0 <= before,
                "{rows} rows, seed {seed}, K {}: {after:.4} from the committed rows, unguided {before:.4}",
                guided.k_used
            );
        }
    }
}

#[test]
fn bad_committed_rows_are_refused_with_the_reason() {
    let mut e = engine();
    let (c, d) = (e.chunk_len(), e.action_dim());
    let (obs, hist) = inputs(&e, &mut StdRng::seed_from_u64(3));
    let part_row = e.infer_after(&obs, &hist, &hist[..d + 1], Duration::MAX).unwrap_err();
    assert!(matches!(part_row, EngineError::CommittedRows { got, .. } if got == d + 1), "{part_row}");
    let whole = e.infer_after(&obs, &hist, &hist[..c * d], Duration::MAX).unwrap_err();
    assert!(whole.to_string().contains(&format!("fewer than {c} whole rows")), "{whole}");
    let mut nan = hist[..d].to_vec();
    nan[2] = f32::NAN;
    let err = e.infer_after(&obs, &hist, &nan, Duration::MAX).unwrap_err();
    assert!(matches!(err, EngineError::NonFinite { what: Input::Committed, index: 2, .. }), "{err}");
}
