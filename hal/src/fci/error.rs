//! Why talking to a robot failed, in words a person at the robot can act on: every message names the address
//! tried and what to check, because the usual causes (FCI not activated in Desk, a wrong IP, no route) look
//! the same from here.

use std::time::Duration;

/// What to check when a robot does not answer (shared by every "could not reach" message).
pub const WHAT_TO_CHECK: &str = "check that the robot is switched on and FCI is activated in Desk, that this is \
     the robot's IP (its Control's address, e.g. 172.16.0.2), and that this machine reaches it over the network \
     (ping it; wired Ethernet to the Control)";

#[derive(Debug, thiserror::Error)]
pub enum FciError {
    /// The address cannot be an FCI address at all (nothing was sent).
    #[error("invalid robot address {addr:?}: expected an IP or host name, optionally with :port (e.g. 172.16.0.2)")]
    BadAddress { addr: String },
    /// Nothing came back in time. franka-rs has no deadline on TCP replies, so without ours a silent peer would
    /// hang the caller forever.
    #[error("no answer from the robot at {addr} within {after_s:.1} s while {during}: {WHAT_TO_CHECK}")]
    Timeout { addr: String, during: &'static str, after_s: f64 },
    /// The connection failed or broke (refused, unreachable, no state stream, reset).
    #[error("cannot talk to the robot at {addr} ({detail}): {WHAT_TO_CHECK}")]
    Network { addr: String, detail: String },
    /// The robot speaks another FCI protocol version than franka-rs 0.4 (v10 for an FR3, v5 for an FER).
    #[error(
        "the robot at {addr} speaks FCI protocol version {server}, this build speaks {library}: check the robot's \
         system version in Desk against franka-rs 0.4's supported FCI versions (v10 FR3, v5 FER)"
    )]
    IncompatibleVersion { addr: String, server: u16, library: u16 },
    /// franka-rs panicked on the worker thread (the panic stays there).
    #[error("talking to the robot at {addr} failed inside franka-rs while {during} (it panicked; see above)")]
    Panicked { addr: String, during: &'static str },
    /// No thread could be started to talk to the robot.
    #[error("could not start a thread to talk to the robot at {addr}: {source}")]
    Thread {
        addr: String,
        #[source]
        source: std::io::Error,
    },
    /// Anything else the robot or franka-rs reported (protocol, model, refused command).
    #[error("the robot at {addr}: {source}")]
    Robot {
        addr: String,
        #[source]
        source: franka::FrankaError,
    },
}

impl FciError {
    /// Sorts a franka-rs error into the cases above, naming `addr`.
    pub fn from_franka(addr: &str, e: franka::FrankaError) -> Self {
        let addr = addr.to_string();
        match e {
            franka::FrankaError::Network(detail) => FciError::Network { addr, detail },
            franka::FrankaError::IncompatibleVersion { server_version, library_version } => {
                FciError::IncompatibleVersion { addr, server: server_version, library: library_version }
            }
            source => FciError::Robot { addr, source },
        }
    }

    pub fn timeout(addr: &str, during: &'static str, after: Duration) -> Self {
        FciError::Timeout { addr: addr.to_string(), during, after_s: after.as_secs_f64() }
    }
}
