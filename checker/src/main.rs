//! `mars-checker`: record the HAL's applied stream (`record`), judge a recording (`check`). Exit status of
//! `check`: 0 clean, 1 a violation, a reflex, or the arm not left at rest; 2 input that cannot be judged.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use mars_checker::{check, record};

#[derive(Parser)]
#[command(name = "mars-checker", version, about = "An independent checker of the HAL's applied setpoint stream")]
struct Args {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Subscribe to a robot's state frames and write each to a file until SIGTERM/SIGINT (or --duration-s).
    Record(record::RecordArgs),
    /// Judge a recording with the profile's limits (the FR3's position-dependent velocity bounds included).
    Check(check::CheckArgs),
}

fn main() -> ExitCode {
    match Args::parse().command {
        Command::Record(a) => match record::run(&a) {
            Ok(()) => ExitCode::SUCCESS,
            Err(e) => {
                eprintln!("mars-checker record: {e:#}");
                ExitCode::FAILURE
            }
        },
        Command::Check(a) => match check::report(&a) {
            Ok(r) => {
                if a.json {
                    println!("{}", serde_json::to_string(&r).unwrap_or_else(|e| format!("{{\"error\":\"{e}\"}}")));
                } else {
                    print!("{r}");
                }
                if r.clean { ExitCode::SUCCESS } else { ExitCode::from(1) }
            }
            Err(e) => {
                eprintln!("mars-checker check: {e:#}");
                ExitCode::from(2)
            }
        },
    }
}
