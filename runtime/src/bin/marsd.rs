//! `marsd`: the MARS controller daemon. Drives a robot's HAL process over iceoryx2 with a MARS policy: a
//! pinned servo loop with jerk-limited smoothing, a deadline-capped policy loop, a watchdog.

use clap::Parser;

// Counts heap allocations per thread, so every run reports that the servo tick made none.
#[global_allocator]
static ALLOC: mars_runtime::alloc_count::CountingAlloc = mars_runtime::alloc_count::CountingAlloc;
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
