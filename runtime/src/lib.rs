//! `marsd`, the controller daemon, as a library (so tests and benchmarks drive the code the binary runs).
//!
//! Data flow, one folder per part: a state frame enters in [`servo::servo_loop`] (from the HAL over iceoryx2) and
//! is judged by [`servo::frame`]; the servo thread shares the newest usable state with the [`policy`] loop through
//! [`shared`]; what the policy sees besides comes in through [`observe`] (cameras, a task's scene); the policy
//! loop's time-stamped chunk ([`servo::chunk`]) comes back the same way; [`servo`] turns it into a reference,
//! smooths it with ruckig ([`servo::smoothing`]), checks it ([`servo::limits`]) and the command leaves in
//! [`servo::servo_loop`], under the [`servo::watchdog`]. Around them: [`daemon`] (setup, signals, systemd), the
//! liveness heartbeat (`mars_ipc::heartbeat_thread`, off the RT thread), [`report`] (latency histograms, plots,
//! traces, what marsd says at exit), [`record`] (a run as a LeRobot dataset), [`rt`] (pinning, SCHED_FIFO, the
//! ticker), [`alloc_count`], the HIL [`task`] as marsd runs it, marsd's command line ([`cli`]) and its tools
//! ([`tools`]: doctor, top, replay, camera). The HIL rig around it (`mars-hil`: the demo, benchmarks, faults, soak, the Push-T scene) is the
//! crate `mars-hil` (folder `hil/`).

pub mod cli;
pub mod config;
pub mod daemon;
pub mod observe;
pub mod policy;
pub mod record;
pub mod report;
pub mod servo;
pub mod shared;
pub mod task;
pub mod tools;

/// The real-time discipline shared with the HAL (crate `mars-rt`), under the names this crate's modules use.
pub use mars_rt as rt;
pub use mars_rt::alloc_count;
