//! The fault runner's own view of the HAL's state frames: when a session starts, when the arm is held at rest. It
//! only times the trials; the verdict is the checker's (`mars-checker check`), from its own recording.

use std::time::{Duration, Instant};

use iceoryx2::prelude::*;
use mars_ipc::node::create_node;
use mars_ipc::{RobotNamespace, RobotState, StateReader, status};

/// A subscriber to `mars/<robot>/state`, read on the thread that opened it.
pub struct StateWatch {
    _node: Node<ipc::Service>,
    reader: StateReader,
    /// The newest frame read.
    pub last: Option<RobotState>,
}

impl StateWatch {
    pub fn open(robot: &str) -> anyhow::Result<Self> {
        let ns = RobotNamespace::new(robot)?;
        let (node, _) = create_node(&format!("faults-watch-{}", std::process::id()))?;
        let reader = StateReader::new(&node, &ns)?;
        Ok(Self { _node: node, reader, last: None })
    }

    /// The first frame read from now on for which `pred` holds, within `timeout`; `None` when none came or
    /// `give_up` said to stop waiting (checked every millisecond).
    pub fn wait(
        &mut self,
        timeout: Duration,
        pred: impl Fn(&RobotState) -> bool,
        mut give_up: impl FnMut() -> bool,
    ) -> Option<RobotState> {
        let end = Instant::now() + timeout;
        while Instant::now() < end {
            while let Ok(Some(s)) = self.reader.receive() {
                self.last = Some(s);
                if pred(&s) {
                    return Some(s);
                }
            }
            if give_up() {
                return None;
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        None
    }

    /// Reads what is waiting, so that `last` is the newest frame.
    pub fn drain(&mut self) {
        while let Ok(Some(s)) = self.reader.receive() {
            self.last = Some(s);
        }
    }
}

/// The HAL holds the arm at rest.
pub fn held_at_rest(s: &RobotState) -> bool {
    s.is(status::HOLDING) && s.is(status::AT_REST)
}
