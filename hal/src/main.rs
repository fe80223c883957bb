//! `mars-hal`: the robot-side process. Runs a profile's robot (the sim backend in this build) at the profile
//! rate and meets the controller only through iceoryx2.

use std::path::PathBuf;
use std::time::Duration;

use clap::Parser;
use mars_hal::profile::Profile;
use mars_hal::runner::{RunOptions, run};
use mars_hal::sim::SimBackend;

#[derive(Parser)]
#[command(version, about = "MARS robot-side HAL process (sim backend)")]
struct Args {
    /// Robot profile (TOML), e.g. configs/fr3.toml.
    #[arg(long)]
    profile: PathBuf,
    /// Robot id of the iceoryx2 service namespace; defaults to the profile's name.
    #[arg(long)]
    robot: Option<String>,
    /// Stop after this many seconds (default: until SIGINT/SIGTERM).
    #[arg(long)]
    duration_s: Option<f64>,
    /// Pin the loop to this CPU core.
    #[arg(long)]
    core: Option<usize>,
}

fn main() -> anyhow::Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "info".into()))
        .with_writer(std::io::stderr)
        .init();
    let args = Args::parse();
    let profile = Profile::load(&args.profile)?;
    if let Some(d) = args.duration_s {
        anyhow::ensure!(d.is_finite() && d > 0.0, "--duration-s must be a positive number of seconds, got {d}");
    }
    let opts = RunOptions {
        robot: args.robot.unwrap_or_else(|| profile.name.clone()),
        duration: args.duration_s.map(Duration::from_secs_f64),
        core: args.core,
    };
    let mut backend = SimBackend::new(&profile);
    let report = run(&profile, &mut backend, &opts)?;
    println!("{report}");
    Ok(())
}
