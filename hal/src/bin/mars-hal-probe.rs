//! `mars-hal-probe`: the smallest possible controller, for tests and benchmarks. It starts a session and
//! answers every state frame with a command that holds the HAL's current setpoint, until it is killed.

use std::time::Duration;

use clap::Parser;
use mars_ipc::liveness::{Heartbeat, Side};
use mars_ipc::node::create_node;
use mars_ipc::{CommandWriter, JointCommand, RobotNamespace, StateReader};

#[derive(Parser)]
struct Args {
    #[arg(long)]
    robot: String,
    #[arg(long)]
    session: u64,
    /// Also send the controller heartbeat (so the HAL sees this process die through iceoryx2 events).
    #[arg(long)]
    heartbeat: bool,
}

fn main() -> anyhow::Result<()> {
    let args = Args::parse();
    anyhow::ensure!(args.session != 0, "--session must be non-zero");
    let ns = RobotNamespace::new(&args.robot)?;
    let (node, _) = create_node(&format!("mars-hal-probe-{}", args.robot))?;
    let states = StateReader::new(&node, &ns)?;
    let commands = CommandWriter::new(&node, &ns)?;
    let mut heartbeat = if args.heartbeat { Some(Heartbeat::new(&node, &ns, Side::Controller)?) } else { None };
    let mut seq = 0;
    while node.wait(Duration::from_micros(100)).is_ok() {
        if let Some(h) = heartbeat.as_mut() {
            h.beat()?;
        }
        while let Some(s) = states.receive()? {
            seq += 1;
            let n = s.num_joints as usize;
            commands.send(&JointCommand::position(args.session, seq, s.seq, &s.applied_position[..n]))?;
        }
    }
    Ok(())
}
