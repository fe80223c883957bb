//! `marsd`: the MARS controller daemon. Drives a robot's HAL process over iceoryx2 with a MARS policy: a
//! pinned servo loop with jerk-limited smoothing, a deadline-capped policy loop, a watchdog.

use clap::Parser;
use mars_runtime::cli::{MarsdArgs, init_logging, marsd};

#[derive(Parser)]
#[command(version, about = "MARS controller daemon: servo loop, deadline-capped policy, watchdog")]
struct Args {
    #[command(flatten)]
    marsd: MarsdArgs,
}

fn main() -> std::process::ExitCode {
    init_logging();
    marsd(Args::parse().marsd)
}
