//! Creating an iceoryx2 node for one side of the wire.

use iceoryx2::prelude::*;

use crate::wire::WireError;

/// Create an inter-process node named `name`, after removing the shared-memory resources of nodes whose
/// process died (a SIGKILLed controller leaves its ports registered; without this a restarted one could find
/// the services full). Returns the node and how many dead nodes were cleaned up.
pub fn create_node(name: &str) -> Result<(Node<ipc::Service>, usize), WireError> {
    // iceoryx2's own warnings (no config file found; a heartbeat's last notification after its peer is gone)
    // are noise for our users and dump whole port states; `IOX2_LOG_LEVEL=warn` brings them back.
    set_log_level_from_env_or(LogLevel::Error);
    let node_name = NodeName::new(name).map_err(|e| WireError::Node(format!("node name {name:?}: {e:?}")))?;
    let node = NodeBuilder::new()
        .name(&node_name)
        // SIGINT/SIGTERM end `Node::wait` with an error instead of the process, so a loop can stop cleanly
        // and report.
        .signal_handling_mode(SignalHandlingMode::HandleTerminationRequests)
        .create::<ipc::Service>()
        .map_err(|e| WireError::Node(format!("creating node {name:?}: {e:?}")))?;
    let cleanup = node.try_cleanup_dead_nodes();
    Ok((node, cleanup.cleanups as usize))
}
