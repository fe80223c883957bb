//! Kinematics for end-effector actions: where the flange is for a joint configuration ([`forward`]), and which
//! joint configuration puts it where a policy wants it ([`inverse`]), for a full pose or a point on a plane
//! ([`planar`], for tabletop pushing).
//!
//! Everything is fixed-size (nalgebra's stack types, [`JOINTS`] = 7), so a call in the servo tick allocates
//! nothing (`tests/alloc_free.rs` counts it). The arm is described by its Denavit–Hartenberg table ([`dh`]); the
//! FR3's is Franka's published one.

pub mod dh;
pub mod forward;
pub mod inverse;
pub mod planar;

/// Joints of the arms described here (the FR3's 7).
pub const JOINTS: usize = 7;

/// A joint configuration (rad).
pub type Joints = nalgebra::SVector<f64, JOINTS>;
/// A rigid transform: the flange's pose in the base frame.
pub type Pose = nalgebra::Isometry3<f64>;

pub use dh::{Arm, Link};
pub use forward::{flange_pose, jacobian};
pub use inverse::{IkError, IkParams, IkSolution, solve};
pub use planar::Plane;
