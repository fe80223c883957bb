//! The servo's ruckig smoother: allocation-free ticks, limits checked the way the HIL test checks the wire (finite
//! differences of the commanded positions), settling and braking times against closed-form time-optimal durations,
//! and agreement with the official ruckig (C++ core) as an oracle.

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::path::Path;

use mars_ipc::MAX_JOINTS;
use mars_profile::Profile;
use mars_runtime::servo::smoothing::{DEFAULT_SAFETY_FACTOR, Kinematics, Limits, Smoother, SmoothingError};
use rand::rngs::StdRng;
use rand::{Rng, SeedableRng};

// Counts allocations of the current thread only, and only while armed: the other tests run on other threads.
struct Counting;
thread_local! {
    static ARMED: Cell<bool> = const { Cell::new(false) };
    static ALLOCS: Cell<usize> = const { Cell::new(0) };
}
fn note_alloc() {
    let _ = ARMED.try_with(|armed| {
        if armed.get() {
            let _ = ALLOCS.try_with(|n| n.set(n.get() + 1));
        }
    });
}
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        note_alloc();
        unsafe { System.alloc(layout) }
    }
    unsafe fn alloc_zeroed(&self, layout: Layout) -> *mut u8 {
        note_alloc();
        unsafe { System.alloc_zeroed(layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        note_alloc();
        unsafe { System.realloc(ptr, layout, new_size) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}
#[global_allocator]
static GLOBAL: Counting = Counting;

/// Allocations made by `f` on this thread.
fn allocations_in(f: impl FnOnce()) -> usize {
    ALLOCS.with(|n| n.set(0));
    ARMED.with(|a| a.set(true));
    f();
    ARMED.with(|a| a.set(false));
    ALLOCS.with(|n| n.get())
}

/// The FR3 with constant velocity limits (`dq_max`): the official ruckig and the closed forms, the oracles of most
/// tests here, plan with constant limits. The FR3's position-dependent bounds have a test of their own below.
fn fr3() -> Profile {
    let mut p = fr3_position_dependent();
    p.velocity_limits = mars_profile::velocity_limits::VelocityLimits::Constant;
    p.velocity_headroom = 0.0;
    p
}

fn fr3_position_dependent() -> Profile {
    Profile::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")).unwrap()
}

fn smoother(p: &Profile, n: usize) -> Smoother {
    let mut s = Smoother::new(n, p.period_s(), &Limits::from_profile(p)).unwrap();
    s.reset(&p.home).unwrap();
    s
}

/// One tick's command to the smoother.
#[derive(Clone, Copy)]
enum Cmd {
    Track([f64; MAX_JOINTS], [f64; MAX_JOINTS]),
    Brake,
}

/// A seeded command stream for `n` joints starting at `home`: mostly the servo's timed piecewise-linear reference
/// through random waypoints (segment velocity passed along, sometimes above the limits so it gets clamped), mixed
/// with abrupt target jumps, velocity reversals, constant targets and braking episodes.
fn commands(seed: u64, n: usize, home: &[f64], p: &Profile, ticks: usize) -> Vec<Cmd> {
    let mut rng = StdRng::seed_from_u64(seed);
    let dt = p.period_s();
    let mut out = Vec::with_capacity(ticks);
    let mut q = [0.0; MAX_JOINTS];
    q[..n].copy_from_slice(&home[..n]);
    while out.len() < ticks {
        let len = rng.random_range(20..600usize);
        match rng.random_range(0..10u32) {
            // Timed linear segment to a random waypoint.
            0..=4 => {
                let duration = len as f64 * dt;
                let mut v = [0.0; MAX_JOINTS];
                for i in 0..n {
                    let goal = home[i] + rng.random_range(-1.0..1.0);
                    v[i] = (goal - q[i]) / duration;
                }
                for _ in 0..len {
                    for i in 0..n {
                        q[i] += v[i] * dt;
                    }
                    out.push(Cmd::Track(q, v));
                }
            }
            // Abrupt jump, possibly with a target velocity pointing the other way (reversal).
            5..=6 => {
                let mut v = [0.0; MAX_JOINTS];
                for i in 0..n {
                    q[i] = home[i] + rng.random_range(-1.5..1.5);
                    v[i] = rng.random_range(-1.2..1.2) * p.dq_max[i];
                }
                for _ in 0..len {
                    for i in 0..n {
                        q[i] += v[i] * dt;
                    }
                    out.push(Cmd::Track(q, v));
                }
                // And straight back the other way.
                for vi in &mut v[..n] {
                    *vi = -*vi;
                }
                for _ in 0..len / 2 {
                    for i in 0..n {
                        q[i] += v[i] * dt;
                    }
                    out.push(Cmd::Track(q, v));
                }
            }
            // Constant target at rest.
            7..=8 => {
                for i in 0..n {
                    q[i] = home[i] + rng.random_range(-1.0..1.0);
                }
                out.extend(std::iter::repeat_n(Cmd::Track(q, [0.0; MAX_JOINTS]), len));
            }
            _ => out.extend(std::iter::repeat_n(Cmd::Brake, len / 4)),
        }
    }
    out.truncate(ticks);
    out
}

fn apply(s: &mut Smoother, cmd: &Cmd) -> Kinematics {
    match cmd {
        Cmd::Track(q, v) => *s.track(q, v).unwrap(),
        Cmd::Brake => *s.brake().unwrap(),
    }
}

#[test]
fn track_and_brake_do_not_allocate() {
    // With the FR3's position-dependent bounds: their per-step limits must not allocate either.
    let p = fr3_position_dependent();
    let cmds = commands(1, 7, &p.home, &p, 5000);
    let mut s = smoother(&p, 7);
    let mut last = Kinematics::default();
    let n = allocations_in(|| {
        for cmd in &cmds {
            last = apply(&mut s, cmd);
        }
        s.reset(&p.home).unwrap();
        for _ in 0..100 {
            last = *s.brake().unwrap();
        }
    });
    assert_eq!(n, 0, "{n} allocations in {} ticks", cmds.len() + 100);
    // The counter is live: it does see an allocation on this thread.
    assert_eq!(allocations_in(|| drop(std::hint::black_box(vec![0u8; 16]))), 1);
    assert!(s.is_at_rest() && last.position[..7] == p.home[..]);
}

/// Max over the stream of |finite difference| / limit, for velocity, acceleration and jerk.
fn finite_difference_ratios(p: &Profile, n: usize, start: &[f64], stream: &[Kinematics]) -> [f64; 3] {
    let dt = p.period_s();
    // At rest at `start` before the first tick, as after `reset`.
    let q: Vec<[f64; MAX_JOINTS]> = {
        let mut rest = [0.0; MAX_JOINTS];
        rest[..n].copy_from_slice(&start[..n]);
        [rest; 3].into_iter().chain(stream.iter().map(|k| k.position)).collect()
    };
    let mut worst = [0.0f64; 3];
    for k in 3..q.len() {
        #[allow(clippy::needless_range_loop)] // several arrays indexed by joint
        for i in 0..n {
            let v = (q[k][i] - q[k - 1][i]) / dt;
            let a = (q[k][i] - 2.0 * q[k - 1][i] + q[k - 2][i]) / (dt * dt);
            let j = (q[k][i] - 3.0 * q[k - 1][i] + 3.0 * q[k - 2][i] - q[k - 3][i]) / (dt * dt * dt);
            worst[0] = worst[0].max(v.abs() / p.dq_max[i]);
            worst[1] = worst[1].max(a.abs() / p.ddq_max[i]);
            worst[2] = worst[2].max(j.abs() / p.jerk_max[i]);
        }
    }
    worst
}

#[test]
fn finite_differences_of_the_command_stream_stay_inside_the_profile_limits() {
    let p = fr3();
    let mut worst = [0.0f64; 3];
    // SMOOTHING_SEEDS=500 for a soak run.
    let seeds = std::env::var("SMOOTHING_SEEDS").ok().and_then(|s| s.parse().ok()).unwrap_or(12u64);
    for (seed, n) in (0..seeds).map(|s| (s, if s % 3 == 0 { 6 } else { 7 })) {
        let cmds = commands(100 + seed, n, &p.home, &p, 6000);
        let mut s = smoother(&p, n);
        let stream: Vec<Kinematics> = cmds.iter().map(|c| apply(&mut s, c)).collect();
        let r = finite_difference_ratios(&p, n, &p.home, &stream);
        for (w, r) in worst.iter_mut().zip(r) {
            *w = w.max(r);
        }
    }
    eprintln!("worst |Δq|/dq_max, |Δ²q|/ddq_max, |Δ³q|/jerk_max: {worst:.9?}");
    // Ruckig plans at DEFAULT_SAFETY_FACTOR of the limits; the finite differences are weighted means of the continuous
    // derivative, so they stay at that factor up to rounding — a 10 % margin to the robot's hard limits.
    for (what, w) in ["velocity", "acceleration", "jerk"].iter().zip(worst) {
        assert!(w <= DEFAULT_SAFETY_FACTOR + 1e-6, "{what}: {w} of the limit");
    }
    // The streams do push against the limits, or the test would prove nothing.
    assert!(worst.iter().all(|w| *w > 0.8 * DEFAULT_SAFETY_FACTOR), "{worst:?}");
}

/// The FR3's velocity bound shrinks toward each position limit: random targets anywhere in marsd's target range
/// (the profile's range less marsd's 0.02 rad margin), many right at its ends, held for random times or braked
/// from: the finite differences stay within the bound at the position reached, less the profile's velocity
/// headroom (the planning bound), and the accelerations and jerks within their limits.
#[test]
fn finite_differences_stay_inside_the_fr3_position_dependent_velocity_bound() {
    let p = fr3_position_dependent();
    assert!(p.velocity_headroom > 0.0);
    let bounds = p.planning_velocity_bounds();
    let (lo, hi) = p.position_limits();
    let dt = p.period_s();
    let mut rng = StdRng::seed_from_u64(5);
    let mut s = smoother(&p, 7);
    let mut prev = [p.home.clone(), p.home.clone(), p.home.clone()];
    let (mut worst_v, mut near_limit_ticks) = (0.0f64, 0usize);
    let seeds_ticks = std::env::var("SMOOTHING_SEEDS").ok().and_then(|s| s.parse::<usize>().ok()).unwrap_or(12);
    for _ in 0..seeds_ticks * 6 {
        let mut target = [0.0; 7];
        for i in 0..7 {
            let (a, b) = (lo[i] + 0.02, hi[i] - 0.02);
            target[i] = match rng.random_range(0..4u32) {
                0 => a,
                1 => b,
                _ => rng.random_range(a..b),
            };
        }
        let brake_after = rng.random_range(100..2500usize);
        for tick in 0..2500 {
            let out = if tick < brake_after { *s.track(&target, &[0.0; 7]).unwrap() } else { *s.brake().unwrap() };
            for i in 0..7 {
                let q = out.position[i];
                let v = (q - prev[0][i]) / dt;
                let a = (q - 2.0 * prev[0][i] + prev[1][i]) / (dt * dt);
                let j = (q - 3.0 * prev[0][i] + 3.0 * prev[1][i] - prev[2][i]) / (dt * dt * dt);
                let (v_lo, v_hi) = bounds[i].hard(q);
                assert!(v <= v_hi + 1e-9 && v >= v_lo - 1e-9, "joint {i} at {q}: v {v} not in [{v_lo}, {v_hi}]");
                assert!(a.abs() <= p.ddq_max[i] * (1.0 + 1e-6), "joint {i}: a {a}");
                assert!(j.abs() <= p.jerk_max[i] * (1.0 + 1e-6), "joint {i}: j {j}");
                if v_hi < 0.9 * p.dq_max[i] && v > 0.0 {
                    near_limit_ticks += 1;
                    worst_v = worst_v.max(v / v_hi);
                }
            }
            prev = [out.position[..7].to_vec(), prev[0].clone(), prev[1].clone()];
        }
    }
    eprintln!(
        "moving up where the bound is below 90 % of dq_max: {near_limit_ticks} joint-ticks, at most {worst_v:.3} of the bound"
    );
    assert!(near_limit_ticks > 1000, "the targets must drive joints into the narrowed zone: {near_limit_ticks}");
}

/// Closed-form time-optimal rest-to-rest duration of one DoF over `d` with limits `v`, `a`, `j`.
fn rest_to_rest_time(d: f64, v: f64, a: f64, j: f64) -> f64 {
    let d = d.abs();
    // Time to reach peak velocity `vp` from rest (and the distance covered accelerating and braking: vp · t).
    let ramp = |vp: f64| if vp >= a * a / j { vp / a + a / j } else { 2.0 * (vp / j).sqrt() };
    if d >= v * ramp(v) {
        return ramp(v) + d / v;
    }
    // No cruise: the peak velocity solves d = vp · ramp(vp).
    let vp_a = 0.5 * a * (-a / j + (a * a / (j * j) + 4.0 * d / a).sqrt());
    if vp_a >= a * a / j { 2.0 * ramp(vp_a) } else { 4.0 * (d / (2.0 * j)).cbrt() }
}

#[test]
fn reaches_a_constant_target_in_the_time_optimal_time_and_stays() {
    let p = fr3();
    let f = DEFAULT_SAFETY_FACTOR;
    let dt = p.period_s();
    for (k, delta) in
        [[0.5, -0.3, 0.2, 0.4, -1.0, 0.8, 1.5], [0.001; 7], [0.02, 0.0, -0.05, 0.0, 0.0, 0.0, 0.0]].iter().enumerate()
    {
        let mut s = smoother(&p, 7);
        let target: Vec<f64> = p.home.iter().zip(delta).map(|(h, d)| h + d).collect();
        // Time synchronisation of a rest-to-rest move ends every joint with the slowest one.
        let t_opt = (0..7)
            .map(|i| rest_to_rest_time(delta[i], f * p.dq_max[i], f * p.ddq_max[i], f * p.jerk_max[i]))
            .fold(0.0, f64::max);
        let mut settled_at = None;
        for tick in 1..=((t_opt / dt) as usize + 2000) {
            let out = *s.track(&target, &[0.0; 7]).unwrap();
            let there = (0..7).all(|i| (out.position[i] - target[i]).abs() < 1e-9);
            match (settled_at, there && s.is_at_rest()) {
                (None, true) => settled_at = Some(tick),
                (Some(_), false) => panic!("case {k}: left the target at tick {tick}"),
                _ => {}
            }
        }
        let settled = settled_at.unwrap_or_else(|| panic!("case {k}: never settled")) as f64 * dt;
        assert!((settled - t_opt).abs() <= 1.5 * dt, "case {k}: settled after {settled} s, time-optimal {t_opt} s");
    }
}

#[test]
fn brake_stops_in_the_time_optimal_time_and_holds() {
    let p = fr3();
    let f = DEFAULT_SAFETY_FACTOR;
    let dt = p.period_s();
    let mut s = smoother(&p, 7);
    // Cruise towards a far target, with zero acceleration; time synchronisation holds the faster joints (4-6) below
    // their limits, the others cruise at theirs.
    let far: Vec<f64> = p.home.iter().map(|h| h + 50.0).collect();
    for _ in 0..3000 {
        s.track(&far, &[0.0; 7]).unwrap();
    }
    let cruising = *s.state();
    assert!((cruising.velocity[0] - f * p.dq_max[0]).abs() < 1e-9);
    assert!(cruising.acceleration.iter().all(|a| a.abs() < 1e-9));
    // From (v, a = 0) the time-optimal stop takes v/a + a/j once the acceleration limit is reached; the velocity
    // interface synchronises the joints to the slowest stop.
    let t_stop = (0..7)
        .map(|i| {
            let (v, a, j) = (cruising.velocity[i], f * p.ddq_max[i], f * p.jerk_max[i]);
            if v >= a * a / j { v / a + a / j } else { 2.0 * (v / j).sqrt() }
        })
        .fold(0.0, f64::max);
    let mut stream = vec![cruising];
    let mut stopped_at = None;
    for tick in 1..=((t_stop / dt) as usize + 500) {
        let out = *s.brake().unwrap();
        stream.push(out);
        match (stopped_at, s.is_at_rest()) {
            (None, true) => stopped_at = Some((tick, out.position)),
            (Some((_, q)), rest) => {
                assert!(rest && (0..7).all(|i| (out.position[i] - q[i]).abs() < 1e-12), "moved again at tick {tick}")
            }
            _ => {}
        }
    }
    let (tick, _) = stopped_at.expect("never came to rest");
    assert!(
        (tick as f64 * dt - t_stop).abs() <= 1.5 * dt,
        "stopped after {} s, time-optimal {t_stop} s",
        tick as f64 * dt
    );
    // The stop itself respects the limits on the wire too (velocity checked from the cruise on).
    let q = stream;
    for k in 3..q.len() {
        for i in 0..7 {
            let a = (q[k].position[i] - 2.0 * q[k - 1].position[i] + q[k - 2].position[i]) / (dt * dt);
            let jerk = (q[k].position[i] - 3.0 * q[k - 1].position[i] + 3.0 * q[k - 2].position[i]
                - q[k - 3].position[i])
                / (dt * dt * dt);
            assert!(a.abs() <= f * p.ddq_max[i] + 1e-6 && jerk.abs() <= f * p.jerk_max[i] + 1e-3);
        }
    }
}

#[test]
fn invalid_construction_is_refused_with_the_reason() {
    let p = fr3();
    let l = Limits::from_profile(&p);
    assert_eq!(Smoother::new(0, 0.001, &l).err(), Some(SmoothingError::JointCount(0)));
    assert_eq!(Smoother::new(MAX_JOINTS + 1, 0.001, &l).err(), Some(SmoothingError::JointCount(MAX_JOINTS + 1)));
    // FR3 has 7 joints: the 8th limit is missing (0).
    assert!(matches!(Smoother::new(8, 0.001, &l), Err(SmoothingError::Limit { joint: 7, kind: "velocity", .. })));
    assert!(matches!(Smoother::new(7, 0.0, &l), Err(SmoothingError::TimeStep(_))));
    assert!(matches!(Smoother::new(7, f64::NAN, &l), Err(SmoothingError::TimeStep(_))));
    assert!(matches!(Smoother::with_safety_factor(7, 0.001, &l, 1.2), Err(SmoothingError::SafetyFactor(_))));
    let mut bad = l;
    bad.jerk[3] = f64::INFINITY;
    let e = Smoother::new(7, 0.001, &bad).err().unwrap();
    assert_eq!(e, SmoothingError::Limit { joint: 3, kind: "jerk", value: f64::INFINITY });
    assert_eq!(e.to_string(), "joint 3: jerk limit inf must be finite and positive");
    bad = l;
    bad.acceleration[0] = -1.0;
    assert!(matches!(Smoother::new(7, 0.001, &bad), Err(SmoothingError::Limit { joint: 0, kind: "acceleration", .. })));
    assert_eq!(Smoother::new(6, 0.001, &l).unwrap().joints(), 6);
}

#[test]
fn bad_input_is_an_error_and_changes_nothing() {
    let p = fr3();
    let mut s = smoother(&p, 7);
    let target: Vec<f64> = p.home.iter().map(|h| h + 0.3).collect();
    for _ in 0..50 {
        s.track(&target, &[0.0; 7]).unwrap();
    }
    let before = *s.state();
    let mut nan = target.clone();
    nan[2] = f64::NAN;
    assert!(matches!(
        s.track(&nan, &[0.0; 7]),
        Err(SmoothingError::NonFinite { what: "target_position", joint: 2, .. })
    ));
    assert!(matches!(
        s.track(&target, &[0.0, 0.0, 0.0, 0.0, f64::INFINITY, 0.0, 0.0]),
        Err(SmoothingError::NonFinite { what: "target_velocity", joint: 4, .. })
    ));
    assert_eq!(
        s.track(&target[..6], &[0.0; 7]).err(),
        Some(SmoothingError::Length { what: "target_position", expected: 7, got: 6 })
    );
    assert!(matches!(
        s.track(&[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1e6], &[0.0; 7]),
        Err(SmoothingError::OutOfRange { what: "target_position", joint: 6, .. })
    ));
    assert_eq!(*s.state(), before);
    // The next valid tick continues exactly where an undisturbed smoother would be.
    let mut twin = smoother(&p, 7);
    for _ in 0..50 {
        twin.track(&target, &[0.0; 7]).unwrap();
    }
    assert_eq!(s.track(&target, &[0.0; 7]).unwrap(), twin.track(&target, &[0.0; 7]).unwrap());
    // Target velocities beyond the limits are clamped, not refused.
    assert!(s.track(&target, &[100.0; 7]).is_ok());
    // A non-finite, short or absurd reset position is refused and changes nothing (0 would be outside FR3
    // joint 4's range: the next command would jump there).
    let before = *s.state();
    let mut one_nan = p.home.clone();
    one_nan[3] = f64::NAN;
    assert!(matches!(s.reset(&one_nan), Err(SmoothingError::NonFinite { what: "position", joint: 3, .. })));
    assert!(matches!(s.reset(&p.home[..6]), Err(SmoothingError::Length { what: "position", .. })));
    let mut far = p.home.clone();
    far[1] = 1e9;
    assert!(matches!(s.reset(&far), Err(SmoothingError::OutOfRange { what: "position", joint: 1, .. })));
    assert_eq!(*s.state(), before);
    s.reset(&p.home).unwrap();
    assert!(s.is_at_rest() && s.state().position[..7] == p.home[..7]);
}

/// Limits of the official crate's problems: the smoother's scaled FR3 limits.
fn official_input(p: &Profile) -> ruckig::InputParameter {
    let mut inp = ruckig::InputParameter::new(7);
    for i in 0..7 {
        inp.max_velocity[i] = DEFAULT_SAFETY_FACTOR * p.dq_max[i];
        inp.max_acceleration[i] = DEFAULT_SAFETY_FACTOR * p.ddq_max[i];
        inp.max_jerk[i] = DEFAULT_SAFETY_FACTOR * p.jerk_max[i];
    }
    inp
}

#[test]
fn online_stream_agrees_with_the_official_ruckig() {
    // The official crate (C++ core) is the oracle: the same online problem tick by tick, no intermediate waypoints
    // (so its cloud client is never used). Its wrapper allocates per update, which is fine in a test.
    let p = fr3();
    let mut worst = 0.0f64;
    for seed in 0..4 {
        let cmds = commands(200 + seed, 7, &p.home, &p, 4000);
        let mut s = smoother(&p, 7);
        let mut otg = ruckig::Ruckig::new_direct(7, p.period_s());
        let mut inp = official_input(&p);
        // As the smoother plans: every joint time-optimal on its own (see `smoothing.rs`).
        inp.synchronization = ruckig::Synchronization::None;
        let mut out = ruckig::OutputParameter::new_direct(7);
        inp.current_position.copy_from_slice(&p.home);
        for cmd in &cmds {
            let ours = apply(&mut s, cmd);
            match cmd {
                Cmd::Track(q, v) => {
                    inp.control_interface = ruckig::ControlInterface::Position;
                    for i in 0..7 {
                        let v_max = inp.max_velocity[i];
                        inp.target_position[i] = q[i];
                        inp.target_velocity[i] = v[i].clamp(-v_max, v_max);
                    }
                }
                Cmd::Brake => {
                    inp.control_interface = ruckig::ControlInterface::Velocity;
                    inp.target_velocity.fill(0.0);
                }
            }
            let r = otg.update(&mut inp, &mut out);
            assert!(matches!(r, ruckig::Result::Working | ruckig::Result::Finished), "{r:?}");
            out.pass_to_input(&mut inp);
            for i in 0..7 {
                worst = worst.max((ours.position[i] - out.new_position[i]).abs());
                worst = worst.max((ours.velocity[i] - out.new_velocity[i]).abs() * p.period_s());
            }
        }
    }
    eprintln!("max |Δq| (and |Δv|·dt) against the official ruckig: {worst:e}");
    assert!(worst < 1e-9, "{worst}");
}

#[test]
fn offline_durations_and_positions_agree_with_the_official_ruckig() {
    // Random state-to-state problems (moving start and goal) through rsruckig's heap-allocated, runtime-DoF storage
    // against the official C++ core: time-optimal durations and sampled positions must agree.
    use rsruckig::prelude::*;
    let p = fr3();
    let mut rng = StdRng::seed_from_u64(7);
    let (mut worst_t, mut worst_q) = (0.0f64, 0.0f64);
    for _ in 0..500 {
        let mut theirs = official_input(&p);
        let mut ours = InputParameter::<0>::new(Some(7));
        for i in 0..7 {
            let (v, a) = (theirs.max_velocity[i], theirs.max_acceleration[i]);
            let (q0, v0, a0) =
                (rng.random_range(-2.0..2.0), rng.random_range(-0.5..0.5) * v, rng.random_range(-0.3..0.3) * a);
            let (qf, vf) = (rng.random_range(-2.0..2.0), rng.random_range(-0.5..0.5) * v);
            (theirs.current_position[i], theirs.current_velocity[i], theirs.current_acceleration[i]) = (q0, v0, a0);
            (theirs.target_position[i], theirs.target_velocity[i]) = (qf, vf);
            (ours.current_position[i], ours.current_velocity[i], ours.current_acceleration[i]) = (q0, v0, a0);
            (ours.target_position[i], ours.target_velocity[i]) = (qf, vf);
            ours.max_velocity[i] = v;
            ours.max_acceleration[i] = a;
            ours.max_jerk[i] = theirs.max_jerk[i];
        }
        let mut traj = Trajectory::<0>::new(Some(7));
        Ruckig::<0, ThrowErrorHandler>::new(Some(7), p.period_s()).calculate(&ours, &mut traj).unwrap();
        let mut oracle = ruckig::Trajectory::new_direct(7);
        let r = ruckig::Ruckig::new_direct_and_offline(7).calculate(&mut theirs, &mut oracle);
        assert_eq!(r, ruckig::Result::Working);
        worst_t = worst_t.max((traj.get_duration() - oracle.get_duration()).abs());
        for k in 0..=20 {
            let t = traj.get_duration() * k as f64 / 20.0;
            let mut q = DataArrayOrVec::<f64, 0>::new(Some(7), 0.0);
            traj.at_time(t, &mut Some(&mut q), &mut None, &mut None, &mut None, &mut None);
            let (q_oracle, _, _) = oracle.at_time(t);
            for i in 0..7 {
                worst_q = worst_q.max((q[i] - q_oracle[i]).abs());
            }
        }
    }
    eprintln!("500 problems: max |Δduration| {worst_t:e} s, max |Δq| {worst_q:e} rad");
    assert!(worst_t < 1e-9 && worst_q < 1e-9, "{worst_t} {worst_q}");
}

#[test]
fn one_joint_matches_the_closed_form_time_optimal_duration() {
    // An oracle independent of any ruckig: 1-DoF rest-to-rest motions in the three regimes (cruise, acceleration
    // limit without cruise, jerk-only), through the smoother's 1-joint configuration.
    let (v, a, j) = (2.0, 10.0, 5000.0);
    let mut l = Limits {
        velocity: [0.0; MAX_JOINTS],
        acceleration: [0.0; MAX_JOINTS],
        jerk: [0.0; MAX_JOINTS],
        position_dependent: None,
    };
    (l.velocity[0], l.acceleration[0], l.jerk[0]) = (v, a, j);
    let dt = 0.001;
    for d in [3.0, 0.2, 1e-4, -0.7] {
        let mut s = Smoother::with_safety_factor(1, dt, &l, 1.0).unwrap();
        s.reset(&[0.0]).unwrap();
        let t_opt = rest_to_rest_time(d, v, a, j);
        let tick = (1..100_000).find(|_| {
            let out = s.track(&[d], &[0.0]).unwrap();
            (out.position[0] - d).abs() < 1e-12 && s.is_at_rest()
        });
        let t = tick.expect("never arrived") as f64 * dt;
        assert!((t - t_opt).abs() <= 1.5 * dt, "d = {d}: arrived after {t} s, closed form {t_opt} s");
    }
}

/// `set_speed` caps every joint's velocity at that fraction of its planning limit (a long move reaches the cap and
/// never passes it), with both kinds of velocity limits; back at full speed the same move goes faster; a speed
/// outside (0, 1] is refused and changes nothing; and changing it allocates nothing.
#[test]
fn set_speed_caps_the_velocity_at_its_fraction_of_the_limits() {
    for p in [fr3(), fr3_position_dependent()] {
        let n = 7;
        let full = Limits::from_profile(&p);
        let peak = |speed: f64| {
            let mut s = smoother(&p, n);
            let allocs = allocations_in(|| s.set_speed(speed).unwrap());
            assert_eq!(allocs, 0);
            let mut target = [0.0; MAX_JOINTS];
            target[..n].copy_from_slice(&p.home);
            target[0] += 1.5; // joint 1: ±2.9 rad of range, so the bound stays the constant cap here
            let mut peak: f64 = 0.0;
            for _ in 0..3000 {
                let k = s.track(&target, &[0.0; MAX_JOINTS]).unwrap();
                peak = peak.max(k.velocity[0].abs());
            }
            peak
        };
        let cap = DEFAULT_SAFETY_FACTOR * full.velocity[0];
        let (half, whole) = (peak(0.5), peak(1.0));
        assert!(half <= 0.5 * cap + 1e-9 && half > 0.49 * cap, "half speed: peak {half}, cap {cap}");
        assert!(whole > 0.9 * cap, "full speed: peak {whole}, cap {cap}");
        let mut s = smoother(&p, n);
        for bad in [0.0, -0.5, 1.5, f64::NAN] {
            assert!(s.set_speed(bad).is_err(), "{bad}");
        }
    }
}
