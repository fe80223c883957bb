//! `marsd`: the MARS controller daemon. Drives a robot's HAL process over iceoryx2 with a MARS policy: a
//! pinned servo loop with jerk-limited smoothing, a deadline-capped policy loop, a watchdog.

use clap::Parser;

// Counts heap allocations per thread, so every run reports that the servo tick made none.
#[global_allocator]
static ALLOC: mars_runtime::alloc_count::CountingAlloc = mars_runtime::alloc_count::CountingAlloc;
use mars_runtime::cli::{MarsdCommandLine, init_logging, run_command_line};

#[derive(Parser)]
#[command(version, about = "MARS controller daemon: servo loop, deadline-capped policy, watchdog")]
#[command(args_conflicts_with_subcommands = true)]
struct Args {
    #[command(flatten)]
    command_line: MarsdCommandLine,
}

fn main() -> std::process::ExitCode {
    init_logging();
    run_command_line(Args::parse().command_line)
}
