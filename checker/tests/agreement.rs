//! The checker's FR3 velocity formula (written from Franka's documentation) and the HAL's
//! (`mars_profile::velocity_limits`, which keeps libfranka's 1e-3 rad/s tolerance inside it) are two independent copies:
//! on a fine grid over every joint's range they must say the same bound, to that tolerance.

use mars_checker::fr3_velocity;
use mars_checker::limits::Limits;
use mars_profile::velocity_limits::{JointVelocityBound, VelocityLimits};

#[test]
fn the_checker_and_the_hal_agree_on_the_fr3_velocity_bounds_everywhere() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let lim = Limits::load(&root.join("configs/fr3.toml")).unwrap();
    // libfranka's kJointVelocityLimitsTolerance, which the HAL keeps off the robot's bound.
    let tolerance = 1e-3;
    let steps = 100_000;
    let mut compared = 0;
    for j in 0..fr3_velocity::JOINTS {
        let hal = JointVelocityBound::new(VelocityLimits::Fr3, j, lim.dq_max[j]);
        // A little beyond the profile's range on both sides, where the curves clip at zero.
        let (from, to) = (lim.q_min[j] - 0.1, lim.q_max[j] + 0.1);
        for s in 0..=steps {
            let q = from + (to - from) * s as f64 / steps as f64;
            let (lo, hi) = lim.velocity_bounds(j, q);
            let (h_lo, h_hi) = hal.hard(q);
            assert!((h_hi - (hi - tolerance)).abs() < 1e-12, "joint {j} q {q}: upper {hi} vs the HAL's {h_hi}");
            assert!((h_lo - (lo + tolerance)).abs() < 1e-12, "joint {j} q {q}: lower {lo} vs the HAL's {h_lo}");
            compared += 1;
        }
    }
    assert_eq!(compared, 7 * (steps + 1));
}
