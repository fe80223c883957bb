//! Chunks adopted late (in-process, `mars_hil::task::delay`) on the shipped Pick Cup MARS checkpoint: with no delay
//! every way to continue is today's loop bit for bit; at a delay of two policy periods (200 ms at 10 Hz) guiding
//! the late chunk toward the rows already executed lowers the jerk at chunk boundaries against dropping them, by a
//! paired interval over 200 seeds (README: 500 seeds, `mars-hil delay-sweep`).

use std::path::{Path, PathBuf};

use mars_hil::task::delay::{Continuity, Delay};
use mars_hil::task::eval::{EvalReport, evaluate, evaluate_delayed};
use mars_profile::Profile;
use mars_runtime::task::{Pick, arm};
use mars_tasks::stats::mean_over_seeds;

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join(path)
}

fn shipped() -> (Pick, Profile, PathBuf) {
    let profile = Profile::load(&repo("configs/fr3.toml")).unwrap();
    let task = Pick::load(&repo("configs/pick_cup.toml"), &arm(&profile)).unwrap();
    (task, profile, repo("assets/checkpoints/fr3_pick_cup/mars"))
}

fn same_episodes(a: &EvalReport, b: &EvalReport) {
    assert_eq!(a.n, b.n);
    for (x, y) in a.episodes.iter().zip(&b.episodes) {
        assert_eq!((x.success, x.mode, x.steps, &x.k_per_call), (y.success, y.mode, y.steps, &y.k_per_call));
        assert_eq!(x.smoothness, y.smoothness, "seed {}", x.seed);
    }
}

#[test]
fn with_no_delay_every_continuity_is_todays_loop() {
    let (task, profile, dir) = shipped();
    let today = evaluate(&dir, &task, &profile, 10, 1000).unwrap();
    for continuity in Continuity::ALL {
        let delayed = evaluate_delayed(&dir, &task, &profile, 10, 1000, Delay { periods: 0, continuity }).unwrap();
        same_episodes(&today, &delayed);
    }
}

#[test]
fn guidance_lowers_the_boundary_jerk_of_a_chunk_two_periods_late() {
    let (task, profile, dir) = shipped();
    let run = |continuity| evaluate_delayed(&dir, &task, &profile, 200, 1000, Delay { periods: 2, continuity });
    let (dropped, guided) = (run(Continuity::DropLate).unwrap(), run(Continuity::Guided).unwrap());
    let diff: Vec<f64> = guided
        .episodes
        .iter()
        .zip(&dropped.episodes)
        .map(|(g, d)| g.smoothness.boundary_jerk - d.smoothness.boundary_jerk)
        .collect();
    let e = mean_over_seeds(&diff).unwrap();
    eprintln!("boundary jerk, guided − drop-late, 2 periods late, 200 seeds: {e:.1} rad/s³");
    assert!(e.hi < 0.0, "guided − drop-late boundary jerk {e:.1} rad/s³: not lower");
    // Both still solve the task (500 seeds: 98.0 % and 99.2 %).
    assert!(dropped.successes >= 180 && guided.successes >= 180, "{dropped}\n{guided}");
    // Actions the policy put outside the FR3's limits (the sim clamps them, as marsd's filter would): no more.
    assert!(guided.limit_violations <= dropped.limit_violations, "{dropped}\n{guided}");
}

#[test]
fn a_delay_over_half_a_chunk_is_refused_with_the_reason() {
    let (task, profile, dir) = shipped();
    let err = evaluate_delayed(&dir, &task, &profile, 1, 0, Delay { periods: 5, continuity: Continuity::Guided })
        .unwrap_err()
        .to_string();
    assert!(err.contains("over half the chunk of 8"), "{err}");
}
