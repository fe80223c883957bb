//! The robot's limits as the profile file states them (e.g. configs/fr3.toml), read by the checker itself.

use std::path::Path;

use anyhow::{Context, bail, ensure};

use crate::fr3_velocity;

/// What every applied setpoint must keep.
#[derive(Debug, Clone, PartialEq)]
pub struct Limits {
    pub joints: usize,
    /// One control period (s).
    pub dt: f64,
    pub q_min: Vec<f64>,
    pub q_max: Vec<f64>,
    /// Each joint's maximum speed; under `fr3` velocity limits the cap of the position-dependent bound.
    pub dq_max: Vec<f64>,
    pub ddq_max: Vec<f64>,
    pub jerk_max: Vec<f64>,
    /// The FR3's position-dependent velocity bounds apply (the profile says `velocity_limits = "fr3"`).
    pub fr3_velocity: bool,
}

impl Limits {
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let text = std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
        Self::parse(&text).with_context(|| format!("profile {}", path.display()))
    }

    pub fn parse(text: &str) -> anyhow::Result<Self> {
        let t: toml::Table = toml::from_str(text)?;
        let joints = t.get("joints").and_then(toml::Value::as_integer).context("`joints` (an integer) is missing")?;
        ensure!((1..=64).contains(&joints), "`joints` must be 1–64, got {joints}");
        let joints = joints as usize;
        let rate = t.get("rate_hz").and_then(toml::Value::as_float).context("`rate_hz` (a number) is missing")?;
        ensure!(rate.is_finite() && rate > 0.0, "`rate_hz` must be positive, got {rate}");
        let list = |key: &str| -> anyhow::Result<Vec<f64>> {
            let values = t.get(key).and_then(toml::Value::as_array).with_context(|| format!("`{key}` is missing"))?;
            ensure!(values.len() == joints, "`{key}` has {} values for {joints} joints", values.len());
            values
                .iter()
                .map(|v| {
                    let x = v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
                    x.filter(|x| x.is_finite()).with_context(|| format!("`{key}`: {v} is not a finite number"))
                })
                .collect()
        };
        let fr3_velocity = match t.get("velocity_limits").map(|v| v.as_str()) {
            None | Some(Some("constant")) => false,
            Some(Some("fr3")) => true,
            Some(other) => bail!("`velocity_limits` must be \"constant\" or \"fr3\", got {other:?}"),
        };
        ensure!(!fr3_velocity || joints == fr3_velocity::JOINTS, "FR3 velocity limits need 7 joints, not {joints}");
        let l = Self {
            joints,
            dt: 1.0 / rate,
            q_min: list("q_min")?,
            q_max: list("q_max")?,
            dq_max: list("dq_max")?,
            ddq_max: list("ddq_max")?,
            jerk_max: list("jerk_max")?,
            fr3_velocity,
        };
        for j in 0..joints {
            ensure!(l.q_min[j] < l.q_max[j], "joint {j}: q_min {} is not below q_max {}", l.q_min[j], l.q_max[j]);
            for (name, v) in [("dq_max", l.dq_max[j]), ("ddq_max", l.ddq_max[j]), ("jerk_max", l.jerk_max[j])] {
                ensure!(v > 0.0, "joint {j}: {name} must be positive, got {v}");
            }
        }
        Ok(l)
    }

    /// (lowest, highest) velocity joint `j` may have at `q`.
    pub fn velocity_bounds(&self, j: usize, q: f64) -> (f64, f64) {
        let cap = self.dq_max[j];
        if self.fr3_velocity { (fr3_velocity::lower(j, q, cap), fr3_velocity::upper(j, q, cap)) } else { (-cap, cap) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fr3() -> Limits {
        Limits::load(&Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")).unwrap()
    }

    #[test]
    fn the_shipped_fr3_profile_reads() {
        let l = fr3();
        assert_eq!((l.joints, l.dt, l.fr3_velocity), (7, 1e-3, true));
        assert_eq!(l.dq_max[4], 5.26);
        // Near joint 1's upper limit the bound is the braking curve's, far below the cap.
        let (_, hi) = l.velocity_bounds(0, 2.74);
        assert!(hi < 0.1 && hi > 0.0, "{hi}");
    }

    #[test]
    fn a_bad_profile_is_refused_with_the_reason() {
        let good = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/fr3.toml")).unwrap();
        for (from, to, says) in [
            ("joints = 7", "joints = 6", "FR3 velocity limits need 7 joints, not 6"),
            ("q_min = [-2.9007,", "q_min = [", "`q_min` has 6 values for 7 joints"),
            ("rate_hz = 1000.0", "rate_hz = 0.0", "rate_hz"),
            ("velocity_limits = \"fr3\"", "velocity_limits = \"fast\"", "velocity_limits"),
            ("jerk_max = [5000.0,", "jerk_max = [-5000.0,", "jerk_max must be positive"),
        ] {
            let e = Limits::parse(&good.replacen(from, to, 1)).unwrap_err();
            assert!(format!("{e:#}").contains(says), "{from} → {to}: {e:#}");
        }
    }
}
