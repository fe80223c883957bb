//! The wire between the MARS controller and the robot's HAL process.
//!
//! Both sides meet only through iceoryx2 shared memory. Everything here is plain data or a thin, typed wrapper
//! around an iceoryx2 port, so the controller and `mars-hal` cannot disagree about layout, service names or
//! quality-of-service settings. No model code lives here.
//!
//! - [`clock`]: CLOCK_MONOTONIC nanoseconds, the timestamps of every frame (comparable across processes).
//! - [`schema`]: the schema version every frame carries in its user header, and the refusal of mismatches.
//! - [`state`], [`command`], [`image`], [`scene`]: the `#[repr(C)]` zero-copy payloads; [`live`]: what
//!   `marsd top` reads.
//! - [`names`]: the per-robot service namespace.
//! - [`wire`]: typed publishers/subscribers for state, command and camera frames.
//! - [`liveness`]: heartbeats over iceoryx2 events and a WaitSet watch that tells when the other side died.
//! - [`heartbeat_thread`]: a loop's heartbeat beaten from an ordinary thread while the loop makes progress.
//! - [`node`]: node creation that first cleans up what dead processes left behind.

pub mod clock;
pub mod command;
pub mod heartbeat_thread;
pub mod image;
pub mod live;
pub mod liveness;
pub mod names;
pub mod node;
mod peer_process;
pub mod scene;
pub mod schema;
pub mod state;
pub mod wire;

pub use command::{CommandMode, JointCommand};
pub use heartbeat_thread::{HeartbeatReport, HeartbeatThread};
pub use image::{ImageEncoding, ImageHeader};
pub use live::{HalLive, LIVE_CHANNELS, LiveChannel, LiveStats, ServoLive};
pub use liveness::{ControllerLiveness, HalLiveness, Heartbeat, Peer, PeerView, PeerWatch, Route, Side};
pub use names::{NameError, RobotNamespace};
pub use scene::{SceneAction, ScenePhase, SceneRequest, SceneState};
pub use schema::{FrameHeader, SCHEMA_VERSION, SchemaMismatch};
pub use state::{HoldReason, MAX_JOINTS, RobotState, fault, robot_mode, status};
pub use wire::{
    CommandReader, CommandWriter, FrameReceiveError, FrameSendError, ImageFrame, ImageReader, ImageReceiveError,
    ImageWriter, LiveReader, LiveWriter, SceneRequestReader, SceneRequestWriter, SceneStateReader, SceneStateWriter,
    StateReader, StateWriter, WireError,
};
