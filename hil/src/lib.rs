//! `mars-hil`, the hardware-in-the-loop rig around marsd (crate `mars-runtime`), as a library (so tests drive the
//! code the binary runs).
//!
//! Data flow: [`demo`] starts the robot side (the HAL, and franka-sim or the R1 Lite's [`standin`] where the backend
//! needs one) and marsd as processes of this executable, watches them ([`stall_watch`]) and stops them as systemd
//! would; for Push-T, [`scene`] is the world marsd's camera looks at. Around the demo: [`bench`] (the report's
//! figures side by side, and across backends), [`faults`] (marsd killed or stopped at random, each trial judged by
//! mars-checker), [`soak`] (the demo loop for an hour), [`hil_replay`] (a recording's chunks through the HAL
//! again), and the pick [`task`]'s expert demos and in-process evaluation. The remote tests' links: [`shaped_link`]
//! (a TCP relay that delays and cuts) and [`netns`] (a namespace of its own over veth, nftables dropping packets).

pub mod bench;
pub mod demo;
pub mod faults;
pub mod franka_sim;
pub mod hil_replay;
pub mod netns;
pub mod scene;
pub mod shaped_link;
pub mod soak;
pub mod stall_watch;
pub mod standin;
pub mod task;
