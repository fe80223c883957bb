//! The `mars` binary, as the command-line tests run it (a module of its own: other crates' tests share common.rs,
//! which cannot name this crate's binary).

use std::process::Command;

/// `mars <args>`, run from the repository root on one thread.
pub fn mars(args: &[&str]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_mars"))
        .args(args)
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
        .env("RAYON_NUM_THREADS", "1")
        .output()
        .expect("mars runs")
}
