//! What the policy sees besides the robot's state, and where it comes in: camera frames and the gate that judges
//! them ([`camera`]), and a task's scene (Push-T's top-down camera, its resets: [`scene_link`]).

pub mod camera;
pub mod scene_link;
