//! `mars-hal`: the robot-side process. Runs a profile's robot (the sim backend in this build) at the profile
//! rate and meets the controller only through iceoryx2.

use clap::Parser;
use mars_hal::cli::{HalArgs, run_hal};

#[derive(Parser)]
#[command(version, about = "MARS robot-side HAL process (sim backend)")]
struct Args {
    #[command(flatten)]
    hal: HalArgs,
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    let report = run_hal(Args::parse().hal)?;
    println!("{report}");
    Ok(())
}
