//! Service names under a per-robot namespace: `mars/<robot>/state`, `mars/<robot>/command`,
//! `mars/<robot>/camera/<camera>`, `mars/<robot>/scene/{state,request}`, `mars/<robot>/live`.
//!
//! One namespace per robot lets two arms (or a sim and a test) run side by side on one machine; tests use a
//! robot id with their pid and a counter so they never meet each other's services.

use iceoryx2::prelude::ServiceName;

/// Longest robot or camera id; keeps every derived name far below iceoryx2's 255-byte service name limit.
pub const MAX_ID_LEN: usize = 64;

#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NameError {
    #[error("{what} id must not be empty")]
    Empty { what: &'static str },
    #[error("{what} id {id:?} is {len} bytes long; at most {MAX_ID_LEN} are allowed")]
    TooLong { what: &'static str, id: String, len: usize },
    #[error("{what} id {id:?} contains {ch:?}; only a-z, 0-9, '_' and '-' are allowed")]
    BadChar { what: &'static str, id: String, ch: char },
    #[error("iceoryx2 refused service name {name:?}: {reason}")]
    Iceoryx { name: String, reason: String },
}

fn check_id(what: &'static str, id: &str) -> Result<(), NameError> {
    if id.is_empty() {
        return Err(NameError::Empty { what });
    }
    if id.len() > MAX_ID_LEN {
        return Err(NameError::TooLong { what, id: id.to_owned(), len: id.len() });
    }
    if let Some(ch) = id.chars().find(|c| !(c.is_ascii_lowercase() || c.is_ascii_digit() || *c == '_' || *c == '-')) {
        return Err(NameError::BadChar { what, id: id.to_owned(), ch });
    }
    Ok(())
}

/// The validated service namespace of one robot.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RobotNamespace {
    robot: String,
}

impl RobotNamespace {
    pub fn new(robot: &str) -> Result<Self, NameError> {
        check_id("robot", robot)?;
        Ok(Self { robot: robot.to_owned() })
    }

    pub fn robot(&self) -> &str {
        &self.robot
    }

    /// Where the HAL publishes [`crate::RobotState`].
    pub fn state(&self) -> Result<ServiceName, NameError> {
        service_name(format!("mars/{}/state", self.robot))
    }

    /// Where the controller publishes [`crate::JointCommand`].
    pub fn command(&self) -> Result<ServiceName, NameError> {
        service_name(format!("mars/{}/command", self.robot))
    }

    /// Where the scene's referee publishes [`crate::SceneState`].
    pub fn scene_state(&self) -> Result<ServiceName, NameError> {
        service_name(format!("mars/{}/scene/state", self.robot))
    }

    /// Where the controller asks the scene for resets ([`crate::SceneRequest`]).
    pub fn scene_request(&self) -> Result<ServiceName, NameError> {
        service_name(format!("mars/{}/scene/request", self.robot))
    }

    /// Where the controller's latency collector publishes [`crate::LiveStats`] (`marsd top`).
    pub fn live(&self) -> Result<ServiceName, NameError> {
        service_name(format!("mars/{}/live", self.robot))
    }

    /// Where a camera of this robot publishes images.
    pub fn camera(&self, camera: &str) -> Result<ServiceName, NameError> {
        check_id("camera", camera)?;
        service_name(format!("mars/{}/camera/{camera}", self.robot))
    }
}

fn service_name(name: String) -> Result<ServiceName, NameError> {
    ServiceName::new(&name).map_err(|e| NameError::Iceoryx { name, reason: format!("{e:?}") })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_live_under_the_robot_namespace() {
        let ns = RobotNamespace::new("fr3").unwrap();
        assert_eq!(ns.state().unwrap().as_str(), "mars/fr3/state");
        assert_eq!(ns.command().unwrap().as_str(), "mars/fr3/command");
        assert_eq!(ns.camera("wrist").unwrap().as_str(), "mars/fr3/camera/wrist");
        assert_eq!(ns.scene_state().unwrap().as_str(), "mars/fr3/scene/state");
        assert_eq!(ns.scene_request().unwrap().as_str(), "mars/fr3/scene/request");
    }

    #[test]
    fn bad_ids_are_refused_with_the_reason() {
        assert_eq!(RobotNamespace::new(""), Err(NameError::Empty { what: "robot" }));
        assert!(matches!(RobotNamespace::new("FR3"), Err(NameError::BadChar { ch: 'F', .. })));
        assert!(matches!(RobotNamespace::new("a/b"), Err(NameError::BadChar { ch: '/', .. })));
        assert!(matches!(RobotNamespace::new(&"x".repeat(65)), Err(NameError::TooLong { len: 65, .. })));
        let ns = RobotNamespace::new("r1_lite").unwrap();
        assert!(matches!(ns.camera("Head Cam"), Err(NameError::BadChar { what: "camera", .. })));
        assert!(RobotNamespace::new(&"x".repeat(64)).unwrap().camera(&"c".repeat(64)).is_ok());
    }
}
