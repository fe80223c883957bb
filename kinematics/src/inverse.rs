//! Inverse kinematics by damped least squares: from a seed (in the servo tick, the previous solution), step the
//! joints along `Jᵀ (J Jᵀ + λ² I)⁻¹ e` toward the target pose, with a pull toward the middle of each joint's
//! range in the Jacobian's null space (the FR3 has one redundant joint), every step bounded and clamped inside
//! the joint limits.
//!
//! Why damped: near a singularity (a stretched or folded arm, or joints 5 and 7 aligned) the plain pseudo-inverse
//! asks for huge joint steps; the damping trades a little accuracy there for bounded steps, so a singular target
//! comes back as the nearest reachable pose with a reason, never as a jump or a NaN.

use nalgebra::{Matrix6, SMatrix, Vector6};

use crate::dh::Arm;
use crate::forward::jacobian;
use crate::{JOINTS, Joints, Pose};

/// Below this error (m, a radian weighing 0.1 m) the damping fades out.
const DAMPING_FADE: f64 = 0.01;
/// A floor under the damping, so the 6 × 6 system stays invertible at an exact singularity.
const TIKHONOV_FLOOR: f64 = 1e-10;

/// How the solver works and when it is done.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkParams {
    /// Done when the flange is this close to the target (m) …
    pub position_tolerance: f64,
    /// … and turned this little from it (rad).
    pub orientation_tolerance: f64,
    pub max_iterations: usize,
    /// λ of the damped step (m): bounds the step near singularities.
    pub damping: f64,
    /// The largest change of any joint in one iteration (rad).
    pub max_step: f64,
    /// Gain of the null-space pull toward the middle of the joint ranges.
    pub centering: f64,
    /// Joints are kept this far inside their limits (rad).
    pub limit_margin: f64,
}

impl Default for IkParams {
    fn default() -> Self {
        IkParams {
            position_tolerance: 1e-5,
            orientation_tolerance: 1e-4,
            max_iterations: 200,
            damping: 0.02,
            max_step: 0.2,
            centering: 0.05,
            limit_margin: 0.02,
        }
    }
}

/// A configuration that puts the flange at the target within the tolerances.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IkSolution {
    pub q: Joints,
    pub iterations: usize,
    pub position_error: f64,
    pub orientation_error: f64,
}

#[derive(Debug, Clone, Copy, PartialEq, thiserror::Error)]
pub enum IkError {
    #[error("the {0} is not finite")]
    NotFinite(&'static str),
    /// Not reached within the tolerances: out of reach, beyond the joint limits, or a singular direction. `closest`
    /// is the best configuration found (within the limits), for a caller that clamps rather than refuses.
    #[error(
        "target not reached: {position_error:.4} m and {orientation_error:.4} rad off after {iterations} iterations \
         (out of reach, past the joint limits, or along a singular direction)"
    )]
    Unreachable { closest: Joints, position_error: f64, orientation_error: f64, iterations: usize },
}

/// The pose error (position m; orientation as a rotation vector, rad) from `at` to `target`, base frame.
fn pose_error(at: &Pose, target: &Pose) -> Vector6<f64> {
    let p = target.translation.vector - at.translation.vector;
    let r = (target.rotation * at.rotation.inverse()).scaled_axis();
    Vector6::new(p.x, p.y, p.z, r.x, r.y, r.z)
}

/// Joint angles that put `arm`'s flange at `target`, starting from `seed`.
pub fn solve(arm: &Arm, target: &Pose, seed: &Joints, params: &IkParams) -> Result<IkSolution, IkError> {
    if !(target.translation.vector.iter().all(|x| x.is_finite())
        && target.rotation.coords.iter().all(|x| x.is_finite()))
    {
        return Err(IkError::NotFinite("target pose"));
    }
    if !seed.iter().all(|x| x.is_finite()) {
        return Err(IkError::NotFinite("seed"));
    }
    let (lo, hi) = limits(arm, params.limit_margin);
    let mut q = seed.zip_zip_map(&lo, &hi, |x, l, h| x.clamp(l, h));
    let mid = (lo + hi) * 0.5;
    let range = hi - lo;
    let mut best = (f64::INFINITY, q, 0.0, 0.0);
    let mut iterations = 0;
    for iteration in 0..=params.max_iterations {
        iterations = iteration;
        let (pose, j) = jacobian(arm, &q);
        let e = pose_error(&pose, target);
        let (ep, er) = (e.fixed_rows::<3>(0).norm(), e.fixed_rows::<3>(3).norm());
        if ep <= params.position_tolerance && er <= params.orientation_tolerance {
            return Ok(IkSolution { q, iterations: iteration, position_error: ep, orientation_error: er });
        }
        // Compare errors in metres: a radian of turn weighs as 0.1 m of travel at the flange.
        let score = ep + 0.1 * er;
        if score < best.0 {
            best = (score, q, ep, er);
        }
        if iteration == params.max_iterations {
            break;
        }
        // Full damping far from the target, fading as it closes in: damping at the target would bias the answer
        // (the step and the null-space pull balance short of it) and slow the last iterations to a crawl.
        let lambda = params.damping * (score / DAMPING_FADE).min(1.0);
        let a: Matrix6<f64> = j * j.transpose() + Matrix6::identity() * (lambda * lambda + TIKHONOV_FLOOR);
        let Some(a_inv) = a.try_inverse() else { break };
        let pinv: SMatrix<f64, JOINTS, 6> = j.transpose() * a_inv;
        let mut dq = pinv * e;
        // Toward the middle of each range, only where it does not move the flange.
        let centre = (mid - q).component_div(&range.component_mul(&range)) * params.centering;
        dq += centre - pinv * (j * centre);
        let largest = dq.amax();
        if largest > params.max_step {
            dq *= params.max_step / largest;
        }
        if !dq.iter().all(|x| x.is_finite()) {
            break;
        }
        q = (q + dq).zip_zip_map(&lo, &hi, |x, l, h| x.clamp(l, h));
    }
    let (_, closest, position_error, orientation_error) = best;
    Err(IkError::Unreachable { closest, position_error, orientation_error, iterations })
}

/// The joint limits less `margin`.
fn limits(arm: &Arm, margin: f64) -> (Joints, Joints) {
    (Joints::from_fn(|i, _| arm.q_min[i] + margin), Joints::from_fn(|i, _| arm.q_max[i] - margin))
}
