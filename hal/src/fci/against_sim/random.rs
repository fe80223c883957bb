//! Random streams like marsd's and random schedules of franka-sim's reads, for the HAL against franka-sim's rules.

use super::*;

/// States per run: 3 s of control.
const STATES: u64 = 3000;

/// Deterministic draws for the schedules and streams (a seed each).
struct Lcg(pub u64);

impl Lcg {
    fn unit(&mut self) -> f64 {
        self.0 = self.0.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
        (self.0 >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// A stream like marsd's: every joint tracks a velocity drawn anew every 150 ms (within ±0.4 rad/s), its
/// acceleration toward 20/s of the velocity error within 9 rad/s² (marsd plans at 0.9 of the FR3's limits), ramped
/// at up to `jerk` rad/s³ (jerk-limited phases where the goal changes, smooth between), from rest at home.
fn random_stream(seed: u64, states: u64, jerk: f64) -> Vec<[f64; MAX_JOINTS]> {
    let mut rng = Lcg(seed);
    let start = home_with(0, (fr3().home[0], 0.0, 0.0));
    let (mut h, mut goal) = (start, [0.0; JOINTS]);
    let mut out = vec![[0.0; MAX_JOINTS]; states as usize + 1];
    for (k, c) in out.iter_mut().enumerate() {
        c[..JOINTS].copy_from_slice(&h.q);
        if k % 150 == 0 {
            goal = std::array::from_fn(|_| 0.8 * rng.unit() - 0.4);
        }
        for (j, goal) in goal.iter().enumerate() {
            let a_goal = (20.0 * (goal - h.v[j])).clamp(-9.0, 9.0);
            let a = h.a[j] + (0.5 * (a_goal - h.a[j])).clamp(-jerk * 1e-3, jerk * 1e-3);
            h.v[j] += a * 1e-3;
            h.q[j] += h.v[j] * 1e-3;
            h.a[j] = a;
        }
    }
    out
}

/// A schedule drawn per command: late with probability `late.0` (by 1 to `late.1` cycles), in the race window with
/// probability `race`, in its cycle otherwise.
fn random_reads(seed: u64, states: u64, late: (f64, u64), race: f64) -> Vec<Read> {
    let mut rng = Lcg(seed);
    (0..=states)
        .map(|_| {
            let u = rng.unit();
            if u < race {
                Read::Race
            } else if u < race + late.0 {
                Read::Late(1 + (rng.unit() * late.1 as f64) as u64)
            } else {
                Read::Fresh
            }
        })
        .collect()
}

/// Which states the HAL sees: now and then (probability `unseen` per state) it misses 1 to 3 in a row.
fn random_seen(seed: u64, states: u64, unseen: f64) -> Vec<bool> {
    let mut rng = Lcg(seed);
    let mut seen = vec![true; states as usize + 1];
    let mut k = 10;
    while k + 4 < seen.len() {
        if rng.unit() < unseen {
            let n = 1 + (rng.unit() * 3.0) as usize;
            seen[k..k + n].fill(false);
            k += n;
        }
        k += 1;
    }
    seen
}

/// The HAL against franka-sim along `random_stream(seed)`, reads and unseen states drawn from seeds after it.
fn random_run(seed: u64, late: (f64, u64), race: f64, unseen: f64) -> Outcome {
    let stream = random_stream(seed, STATES + 1, 4500.0);
    let reads = random_reads(seed + 100, STATES, late, race);
    let seen = random_seen(seed + 200, STATES, unseen);
    let target = |k: u64| stream[k as usize + 1];
    let start = home_with(0, (fr3().home[0], 0.0, 0.0));
    run(&Scenario { start, target: &target, read: &|k| reads[k as usize], seen: &|k| seen[k as usize], states: STATES })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Random streams like marsd's (jerk up to 4500 rad/s³), commands late one time in twenty (by 1–3 cycles), in
    /// three (by 1–4) or in two (by 1–8), the HAL missing 1–3 states now and then (none, 1 % or 3 % of states):
    /// franka-sim judges every command within its limits.
    #[test]
    fn late_commands_and_unseen_states_keep_every_command_within_the_limits() {
        for (late, unseen) in [((0.05, 3), 0.0), ((0.3, 4), 0.01), ((0.5, 8), 0.03)] {
            for seed in 0..6 {
                let o = random_run(seed, late, 0.0, unseen);
                let v = o.violations();
                assert_eq!(v.len(), 0, "late {late:?}, unseen {unseen}, seed {seed}: {:?}", &v[..v.len().min(5)]);
            }
        }
    }

    /// Random streams and schedules with a command thrown away now and then (1 % of them, each followed by ours in
    /// its cycle or late): franka-sim judges out of its limits only the commands right after one thrown away and
    /// followed by ours in its cycle (above); counted and printed (`--nocapture`).
    #[test]
    fn commands_thrown_away_are_followed_where_the_states_tell() {
        let (mut races, mut then_on_time, mut violations) = (0, 0, 0);
        for seed in 0..6 {
            let reads = random_reads(seed + 100, STATES, (0.3, 4), 0.01);
            let o = random_run(seed, (0.3, 4), 0.01, 0.0);
            let race_then_on_time = |k: u64| reads[k as usize] == Read::Race && reads[k as usize + 1] == Read::Fresh;
            races += reads.iter().filter(|&&r| r == Read::Race).count();
            then_on_time += (0..STATES).filter(|&k| race_then_on_time(k)).count();
            for v in o.violations() {
                // The command after the one thrown away, or the next (its history's acceleration out of limits).
                let explained = (1..=2).any(|back| v.id > back && race_then_on_time(v.id - back));
                assert!(explained, "seed {seed}: {v:?} not right after a command thrown away");
                violations += 1;
            }
        }
        eprintln!(
            "{races} commands thrown away ({then_on_time} followed by one in its cycle): {violations} commands judged out \
             of limits"
        );
    }
}
