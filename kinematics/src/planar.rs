//! The planar subset of end-effector space for tabletop pushing (the paper's Push-T): a policy acts in (x, y) on
//! the table, and the flange keeps a fixed height and a fixed orientation (pointing down).

use nalgebra::{Translation3, UnitQuaternion, Vector3};

use crate::Pose;

/// The plane the flange moves in.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Flange height above the base (m).
    pub height: f64,
    /// The flange's fixed orientation.
    pub orientation: UnitQuaternion<f64>,
}

impl Plane {
    /// Flange pointing straight down (its z axis along −z of the base), its x axis along the base's x.
    pub fn pointing_down(height: f64) -> Self {
        Plane { height, orientation: UnitQuaternion::from_axis_angle(&Vector3::x_axis(), std::f64::consts::PI) }
    }

    /// The flange pose for a planar action (x, y).
    pub fn pose(&self, x: f64, y: f64) -> Pose {
        Pose::from_parts(Translation3::new(x, y, self.height), self.orientation)
    }

    /// A pose's planar coordinates (its x, y; the height and orientation are the plane's by construction).
    pub fn xy(pose: &Pose) -> (f64, f64) {
        (pose.translation.x, pose.translation.y)
    }
}
