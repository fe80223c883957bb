//! The `mars` binary, as the command-line tests run it (a module of its own: other crates' tests share common.rs,
//! which cannot name this crate's binary).

use std::process::Command;

/// `mars <args>`, run from the repository root on one thread.
#[allow(dead_code)] // not every test binary that includes this module runs it without environment
pub fn mars(args: &[&str]) -> std::process::Output {
    mars_with_env(args, &[])
}

/// [`mars`] with environment variables set.
#[allow(dead_code)] // not every test binary that includes this module sets any
pub fn mars_with_env(args: &[&str], env: &[(&str, &std::path::Path)]) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_mars"))
        .envs(env.iter().copied())
        .args(args)
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
        .env("RAYON_NUM_THREADS", "1")
        .output()
        .expect("mars runs")
}
