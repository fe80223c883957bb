//! `marsd`, the controller daemon, as a library (so tests and benchmarks drive the code the binary runs).
//!
//! Data flow: a state frame enters in [`servo_loop`] (from the HAL over iceoryx2) and is judged by [`frame`];
//! the servo thread shares the newest usable state with the [`policy_loop`] through [`shared`]; the policy
//! loop's time-stamped chunk ([`chunk`]) comes back the same way; [`servo`] turns it into a reference, smooths
//! it with ruckig ([`smoothing`]), checks it ([`limits`]) and the command leaves in [`servo_loop`]. Around
//! them: [`watchdog`], [`daemon`] (setup, signals, systemd), the liveness heartbeat (`mars_ipc::heartbeat_thread`, off the RT thread), [`latency`] + [`plots`] + [`traces`] + [`report`], [`rt`]
//! (pinning, SCHED_FIFO, the ticker), [`alloc_count`], the HIL [`task`] as marsd runs it, and marsd's command line
//! ([`cli`]). The HIL rig around it (`mars-hil`: the demo, benchmarks, faults, soak, the Push-T scene) is the
//! crate `mars-hil` (folder `hil/`).

pub mod camera;
pub mod camera_watch;
pub mod chunk;
pub mod cli;
pub mod config;
pub mod daemon;
pub mod doctor;
pub mod effector;
pub mod frame;
pub mod latency;
pub mod limits;
pub mod live;
pub mod plots;
pub mod policy_loop;
pub mod record;
pub mod recorded_actions;
pub mod replay;
pub mod report;
pub mod scene_link;
pub mod servo;
pub mod servo_loop;
pub mod shared;
pub mod smoothing;
pub mod stall;
pub mod tally;
pub mod task;
pub mod timeliness;
pub mod top;
pub mod traces;
pub mod watchdog;

/// The real-time discipline shared with the HAL (crate `mars-rt`), under the names this crate's modules use.
pub use mars_rt as rt;
pub use mars_rt::alloc_count;
