//! The kd-tree neighbours are exactly the brute-force ones.

use mars_policy::knn::{KnnError, brute_force, nearest_neighbours, sq_dist};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

#[test]
fn kd_tree_matches_brute_force_on_random_points() {
    let mut rng = StdRng::seed_from_u64(7);
    for &(n, dim, m) in &[(300usize, 16usize, 20usize), (200, 2, 5), (50, 3, 49)] {
        let pts: Vec<f32> = (0..n * dim).map(|_| rng.random_range(-1.0..1.0)).collect();
        let fast = nearest_neighbours(&pts, dim, m).unwrap();
        let slow = brute_force(&pts, dim, m).unwrap();
        assert_eq!(fast.len(), n * m);
        for i in 0..n {
            let p = &pts[i * dim..(i + 1) * dim];
            let dists = |v: &[u32]| -> Vec<f64> {
                v.iter().map(|&j| sq_dist(p, &pts[j as usize * dim..(j as usize + 1) * dim])).collect()
            };
            let (f, s) = (&fast[i * m..(i + 1) * m], &slow[i * m..(i + 1) * m]);
            assert!(!f.contains(&(i as u32)), "point {i} is its own neighbour");
            // Random continuous points have no ties, so the index lists must agree exactly.
            assert_eq!(
                f,
                s,
                "point {i}: kd-tree {f:?} vs brute force {s:?} (distances {:?} vs {:?})",
                dists(f),
                dists(s)
            );
        }
    }
}

#[test]
fn duplicate_points_give_equally_near_neighbours() {
    // Many identical histories (every demo starts at rest): any of the duplicates is a correct answer, so
    // compare distances, not indices.
    let mut pts = vec![0.0f32; 10 * 2];
    pts.extend_from_slice(&[1.0, 1.0, 2.0, 2.0]);
    let fast = nearest_neighbours(&pts, 2, 4).unwrap();
    for i in 0..10 {
        assert!(fast[i * 4..(i + 1) * 4].iter().all(|&j| j < 10 && j != i as u32));
    }
}

#[test]
fn too_few_points_and_non_finite_points_are_errors() {
    assert!(matches!(nearest_neighbours(&[0.0; 6], 2, 3), Err(KnnError::TooFewPoints { n: 3, m: 3 })));
    assert!(matches!(
        nearest_neighbours(&[0.0, 0.0, f32::NAN, 0.0, 1.0, 1.0], 2, 1),
        Err(KnnError::NonFinite { index: 1 })
    ));
}
