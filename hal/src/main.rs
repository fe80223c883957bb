//! `mars-hal`: the robot-side process. Runs a profile's robot (the sim backend in this build) at the profile
//! rate and meets the controller only through iceoryx2.

use clap::Parser;
use mars_hal::cli::{HalArgs, report_and_exit_code, run_hal};

// Counts heap allocations per thread, so every run reports that the loop made none (but iceoryx2's pooled block
// per published frame).
#[global_allocator]
static ALLOC: mars_rt::alloc_count::CountingAlloc = mars_rt::alloc_count::CountingAlloc;

#[derive(Parser)]
#[command(version, about = "MARS robot-side HAL process (sim backend)")]
struct Args {
    #[command(flatten)]
    hal: HalArgs,
}

fn main() {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    std::process::exit(report_and_exit_code(run_hal(Args::parse().hal)));
}
