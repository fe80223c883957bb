//! `mars-hal`: the robot-side process. Runs a profile's robot (the sim, a Franka robot over FCI, or a robot over
//! ROS 2) at the profile rate and meets the controller only through iceoryx2.

use clap::{CommandFactory, FromArgMatches, Parser};
use mars_hal::cli::{FciStatusArgs, HalArgs, RecoverArgs, fci_status, recover, report_and_exit_code, run_hal};

// Counts heap allocations per thread, so every run reports that the loop made none (but iceoryx2's pooled block
// per published frame).
#[global_allocator]
static ALLOC: mars_rt::alloc_count::CountingAlloc = mars_rt::alloc_count::CountingAlloc;

#[derive(Parser)]
#[command(version, about = "MARS robot-side HAL process (sim backend, a Franka robot over FCI, or a robot over ROS 2)")]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true)]
struct Args {
    /// The HAL process's arguments: only used to build the command line; `main` reads them from the matches itself,
    /// because a derived `Args` would demand `--profile` even when a subcommand was given.
    #[command(flatten)]
    hal: HalArgs,
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(clap::Subcommand)]
enum Command {
    /// Reach a Franka robot over FCI, read one state and print its joint positions, mode, control success rate
    /// and errors; commands nothing (run it first with a real arm). Exit 0 read, 1 unreachable, 2 bad argument.
    FciStatus(FciStatusArgs),
    /// Clear a reflex on a Franka robot no HAL is driving (libfranka's automatic error recovery), then print its
    /// state. With a HAL running, send it SIGUSR1 instead. Exit 0 ready, 1 not reached or still not ready.
    Recover(RecoverArgs),
}

fn main() {
    mars_rt::logging::init_logging();
    let matches = Args::command().get_matches();
    std::process::exit(if matches.subcommand().is_some() {
        match Command::from_arg_matches(&matches).unwrap_or_else(|e| e.exit()) {
            Command::FciStatus(a) => fci_status(a),
            Command::Recover(a) => recover(a),
        }
    } else {
        report_and_exit_code(run_hal(HalArgs::from_arg_matches(&matches).unwrap_or_else(|e| e.exit())))
    });
}
