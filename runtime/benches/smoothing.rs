//! ns per servo tick of the ruckig smoother (7 DoF, FR3 limits, 1 kHz) against the official ruckig crate on the same
//! target stream: a new target every tick (the servo's moving reference), so every tick re-plans.
//!
//! `nice -n 19 cargo bench -p mars-runtime --bench smoothing`

use std::hint::black_box;
use std::path::Path;
use std::time::Instant;

use mars_hal::profile::Profile;
use mars_runtime::smoothing::{DEFAULT_SAFETY_FACTOR, Limits, Smoother};

const TICKS: usize = 20_000;
const ROUNDS: usize = 3;

/// A seeded moving reference: new linear segment every 200 ticks (xorshift, so no dev-dependency).
fn targets(home: &[f64], dq_max: &[f64]) -> Vec<([f64; 7], [f64; 7])> {
    let mut state = 0x9e37_79b9_7f4a_7c15u64;
    let mut sym = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    let (mut q, mut v) = ([0.0; 7], [0.0; 7]);
    (0..TICKS)
        .map(|k| {
            if k % 200 == 0 {
                for i in 0..7 {
                    q[i] = home[i] + sym();
                    v[i] = 0.5 * DEFAULT_SAFETY_FACTOR * dq_max[i] * sym();
                }
            }
            for i in 0..7 {
                q[i] += v[i] * 1e-3;
            }
            (q, v)
        })
        .collect()
}

fn report(name: &str, mut ns: Vec<u64>) {
    ns.sort_unstable();
    let at = |f: f64| ns[((ns.len() - 1) as f64 * f) as usize];
    println!(
        "{name:<40} median {:>6} ns   p99 {:>6} ns   max {:>8} ns   ({} ticks)",
        at(0.5),
        at(0.99),
        at(1.0),
        ns.len()
    );
}

fn main() {
    let p = Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")).unwrap();
    let stream = targets(&p.home, &p.dq_max);

    let mut ours = Vec::with_capacity(TICKS * ROUNDS);
    for _ in 0..ROUNDS {
        let mut s = Smoother::new(7, p.period_s(), &Limits::from_profile(&p)).unwrap();
        s.reset(&p.home).expect("the profile's home is a valid start");
        for (q, v) in &stream {
            let t = Instant::now();
            black_box(s.track(black_box(q), black_box(v)).unwrap());
            ours.push(t.elapsed().as_nanos() as u64);
        }
    }
    report("marsd Smoother::track (rsruckig, 8 slots)", ours);

    let mut theirs = Vec::with_capacity(TICKS * ROUNDS);
    for _ in 0..ROUNDS {
        let mut otg = ruckig::Ruckig::new_direct(7, p.period_s());
        let mut inp = ruckig::InputParameter::new(7);
        let mut out = ruckig::OutputParameter::new_direct(7);
        for i in 0..7 {
            inp.current_position[i] = p.home[i];
            inp.max_velocity[i] = DEFAULT_SAFETY_FACTOR * p.dq_max[i];
            inp.max_acceleration[i] = DEFAULT_SAFETY_FACTOR * p.ddq_max[i];
            inp.max_jerk[i] = DEFAULT_SAFETY_FACTOR * p.jerk_max[i];
        }
        for (q, v) in &stream {
            let t = Instant::now();
            inp.target_position.copy_from_slice(q);
            inp.target_velocity.copy_from_slice(v);
            black_box(otg.update(&mut inp, &mut out));
            out.pass_to_input(&mut inp);
            theirs.push(t.elapsed().as_nanos() as u64);
        }
    }
    report("official ruckig 0.19 update+pass_to_input", theirs);
}
