//! Mutation fuzzing of every decoder of untrusted input, on stable Rust: LeRobot metadata and data files,
//! checkpoints (`policy.json` and safetensors, through mars-policy and the engine), the TOML of marsd, its tasks and
//! the HAL's profiles, the iceoryx2 frames' checks, the ros2 backend's CDR messages and its cameras' JPEG.
//!
//! Each target mutates seeds taken from the repository ([`mutate`]) with a generator of its own per case, so a run
//! is the same for the same `--seed` and any case can be made again; [`runner`] decodes each input under
//! `catch_unwind`, and [`guard`] catches what a panic cannot report (aborts, huge allocations).

pub mod guard;
pub mod mutate;
pub mod runner;
pub mod targets;
