//! The arm as a Denavit–Hartenberg table, in Craig's (modified) convention: link i's frame is reached from link
//! i−1's by `RotX(α) · TransX(a) · RotZ(θ_i) · TransZ(d)`, θ_i being joint i's angle.

use crate::JOINTS;

/// One row of the table.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Link {
    pub a: f64,
    pub d: f64,
    pub alpha: f64,
}

/// A serial arm: one row per joint, the flange's fixed row, and the joint limits.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Arm {
    pub links: [Link; JOINTS],
    pub flange: Link,
    pub q_min: [f64; JOINTS],
    pub q_max: [f64; JOINTS],
}

const HALF_PI: f64 = std::f64::consts::FRAC_PI_2;

impl Arm {
    /// The Franka Research 3: Franka's published DH parameters ("Robot and interface specifications", the same
    /// table as the Panda's; the flange 0.107 m past joint 7) and its joint limits (configs/fr3.toml's `q_min`,
    /// `q_max`).
    pub fn fr3() -> Self {
        let l = |a, d, alpha| Link { a, d, alpha };
        Arm {
            links: [
                l(0.0, 0.333, 0.0),
                l(0.0, 0.0, -HALF_PI),
                l(0.0, 0.316, HALF_PI),
                l(0.0825, 0.0, HALF_PI),
                l(-0.0825, 0.384, -HALF_PI),
                l(0.0, 0.0, HALF_PI),
                l(0.088, 0.0, HALF_PI),
            ],
            flange: l(0.0, 0.107, 0.0),
            q_min: [-2.9007, -1.8361, -2.9007, -3.0770, -2.8763, 0.4398, -3.0508],
            q_max: [2.9007, 1.8361, 2.9007, -0.1169, 2.8763, 4.6216, 3.0508],
        }
    }
}
