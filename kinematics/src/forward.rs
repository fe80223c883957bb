//! Forward kinematics: the flange's pose, and the geometric Jacobian that says how it moves with each joint.

use nalgebra::{Isometry3, SMatrix, Translation3, UnitQuaternion, Vector3};

use crate::dh::{Arm, Link};
use crate::{JOINTS, Joints, Pose};

/// The 6 × 7 geometric Jacobian: rows 0–2 the flange's linear velocity, rows 3–5 its angular velocity (base
/// frame), per unit joint velocity.
pub type Jacobian = SMatrix<f64, 6, JOINTS>;

/// The transform a link adds, at joint angle `theta`.
fn link(l: &Link, theta: f64) -> Isometry3<f64> {
    Isometry3::from_parts(
        Translation3::new(l.a, 0.0, 0.0),
        UnitQuaternion::from_axis_angle(&Vector3::x_axis(), l.alpha),
    ) * Isometry3::from_parts(
        Translation3::new(0.0, 0.0, l.d),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), theta),
    )
}

/// The flange's pose in the base frame at `q`.
pub fn flange_pose(arm: &Arm, q: &Joints) -> Pose {
    frames(arm, q).1
}

/// Each joint's frame (its z axis is the joint's axis), and the flange's pose.
fn frames(arm: &Arm, q: &Joints) -> ([Isometry3<f64>; JOINTS], Pose) {
    let mut joint = [Isometry3::identity(); JOINTS];
    let mut t = Isometry3::identity();
    for (i, l) in arm.links.iter().enumerate() {
        t *= link(l, q[i]);
        joint[i] = t;
    }
    (joint, t * link(&arm.flange, 0.0))
}

/// The flange's pose and the geometric Jacobian at `q`.
pub fn jacobian(arm: &Arm, q: &Joints) -> (Pose, Jacobian) {
    let (joint, flange) = frames(arm, q);
    let p = flange.translation.vector;
    let mut j = Jacobian::zeros();
    for (i, f) in joint.iter().enumerate() {
        let z = f.rotation * Vector3::z();
        let v = z.cross(&(p - f.translation.vector));
        j.fixed_view_mut::<3, 1>(0, i).copy_from(&v);
        j.fixed_view_mut::<3, 1>(3, i).copy_from(&z);
    }
    (flange, j)
}
