//! Where the Zenoh session connects and listens, and the keys a robot's queries use.

use serde::Deserialize;

/// How a machine joins the Zenoh network (the `[remote]` table of marsd's config, `marsd serve`'s options).
#[derive(Debug, Clone, Default, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LinkConfig {
    /// Zenoh locators to connect to, e.g. `tcp/192.168.1.20:7447` (the inference host, or a router).
    #[serde(default)]
    pub connect: Vec<String>,
    /// Zenoh locators to listen on, e.g. `tcp/0.0.0.0:7447`.
    #[serde(default)]
    pub listen: Vec<String>,
    /// Find peers by UDP multicast as well (off: only `connect` and `listen`, so a test's peers meet no one else).
    #[serde(default)]
    pub multicast_scouting: bool,
}

#[derive(Debug, thiserror::Error)]
pub enum LinkError {
    #[error("zenoh locator `{0}`: {1}")]
    Locator(String, String),
    #[error("key prefix `{0}`: must be non-empty, without `*`, `$`, `?`, `#` or empty segments")]
    Prefix(String),
    #[error("robot name `{0}`: must be one non-empty key segment (no `/`, `*`, `$`, `?`, `#`)")]
    Robot(String),
    #[error("opening the zenoh session: {0}")]
    Open(String),
}

impl LinkConfig {
    /// A peer that listens on `listen` and connects to nothing (a test's host).
    pub fn listening(listen: &str) -> Self {
        Self { listen: vec![listen.to_owned()], ..Self::default() }
    }

    /// A peer that connects to `connect` (a test's robot).
    pub fn connecting(connect: &str) -> Self {
        Self { connect: vec![connect.to_owned()], ..Self::default() }
    }

    /// Opens a session in peer mode: blocks until the listeners are up (connecting retries in the background).
    pub fn open(&self) -> Result<zenoh::Session, LinkError> {
        self.open_as(Role::Peer)
    }

    /// Opens a session in the given role (see [`Role`]).
    pub fn open_as(&self, role: Role) -> Result<zenoh::Session, LinkError> {
        use zenoh::Wait;
        let mut c = zenoh::Config::default();
        let set = |c: &mut zenoh::Config, key: &str, value: String| {
            c.insert_json5(key, &value).map_err(|e| LinkError::Locator(value.clone(), e.to_string()))
        };
        set(&mut c, "mode", format!("\"{}\"", role.mode()))?;
        for (key, list) in [("connect/endpoints", &self.connect), ("listen/endpoints", &self.listen)] {
            for l in list {
                l.parse::<zenoh::config::EndPoint>().map_err(|e| LinkError::Locator(l.clone(), e.to_string()))?;
            }
            set(&mut c, key, serde_json::to_string(list).expect("a list of strings serialises"))?;
        }
        set(&mut c, "scouting/multicast/enabled", self.multicast_scouting.to_string())?;
        zenoh::open(c).wait().map_err(|e| LinkError::Open(e.to_string()))
    }
}

/// What a session is to the network. Zenoh's peers talk to the peers they are connected to and forward nothing;
/// a router also forwards between the sessions connected to it, and a client reaches everything through the one
/// router it is connected to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// A robot (marsd with `[remote]`): its queries and live frames go to the host it is connected to.
    Peer,
    /// The inference host (`marsd serve`): it also forwards the robots' live frames to the watchers connected to it.
    Router,
    /// A watcher (`marsd top --connect`): it reaches every robot through the host.
    Client,
}

impl Role {
    fn mode(self) -> &'static str {
        match self {
            Role::Peer => "peer",
            Role::Router => "router",
            Role::Client => "client",
        }
    }
}

/// The key a robot's inference queries go to: `<prefix>/<robot>/infer`.
pub fn infer_key(prefix: &str, robot: &str) -> Result<String, LinkError> {
    check_prefix(prefix)?;
    check_robot(robot)?;
    Ok(format!("{prefix}/{robot}/infer"))
}

/// Every robot's inference key under `prefix` (what the host answers): `<prefix>/*/infer`.
pub fn all_infer_keys(prefix: &str) -> Result<String, LinkError> {
    check_prefix(prefix)?;
    Ok(format!("{prefix}/*/infer"))
}

/// The host's clock, for the ping-pong of [`crate::clock`]: `<prefix>/clock`.
pub fn clock_key(prefix: &str) -> Result<String, LinkError> {
    check_prefix(prefix)?;
    Ok(format!("{prefix}/clock"))
}

/// The robot a query's key names (`<prefix>/<robot>/infer`), if it is one.
pub fn robot_of<'a>(prefix: &str, key: &'a str) -> Option<&'a str> {
    key.strip_prefix(prefix)?.strip_prefix('/')?.strip_suffix("/infer").filter(|r| !r.contains('/'))
}

pub(crate) fn check_prefix(prefix: &str) -> Result<(), LinkError> {
    let bad = prefix.is_empty() || prefix.contains(['*', '$', '?', '#']) || prefix.split('/').any(str::is_empty);
    if bad { Err(LinkError::Prefix(prefix.to_owned())) } else { Ok(()) }
}

pub(crate) fn check_robot(robot: &str) -> Result<(), LinkError> {
    let bad = robot.is_empty() || robot.contains(['/', '*', '$', '?', '#']);
    if bad { Err(LinkError::Robot(robot.to_owned())) } else { Ok(()) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn keys_name_the_robot_and_refuse_wildcards() {
        assert_eq!(infer_key("mars/lab", "fr3-a").unwrap(), "mars/lab/fr3-a/infer");
        assert_eq!(robot_of("mars/lab", "mars/lab/fr3-a/infer"), Some("fr3-a"));
        assert_eq!(robot_of("mars/lab", "mars/lab/x/y/infer"), None);
        assert_eq!(robot_of("mars/lab", "mars/labx/infer"), None);
        assert!(infer_key("mars/*", "a").is_err());
        assert!(infer_key("mars//lab", "a").is_err());
        assert!(infer_key("mars", "a/b").is_err());
        assert!(infer_key("mars", "").is_err());
    }

    #[test]
    fn a_bad_locator_is_named() {
        let err = LinkConfig::connecting("nonsense").open().unwrap_err();
        assert!(err.to_string().contains("nonsense"), "{err}");
    }
}
