//! The policy on an inference host, the servo at the robot, over Zenoh.
//!
//! Data flow: the robot's policy loop (marsd) builds a [`wire::Request`] — observation, the history of executed
//! actions, the time it can wait — and sends it as a Zenoh query with [`client::RemotePolicy::infer`]; on the
//! inference host, [`server::serve`] takes the queries of every robot it serves, runs the earliest deadline first
//! through that robot's engine, and answers each with a [`wire::Reply`] (the chunk, tagged with the request's seq).
//! A reply that does not come back in time is the robot's to replace: marsd then runs its local engine, or brings
//! the arm to rest (`[remote] on_miss`; see `mars_runtime::policy`). [`link`] opens the Zenoh session and names the
//! keys; [`clock`] measures the two machines' clock offset and round trip by ping-pong, so ages in the reports are
//! on the robot's clock. [`live`] carries each robot's live view (what `marsd top` shows) through the host to a
//! `marsd top` on any machine.
//!
//! Why Zenoh and not iceoryx2's own tunnel: `iceoryx2-tunnel-zenoh` is published for iceoryx2 0.8 only (0.8.1 on
//! crates.io), and marsd uses iceoryx2 0.10; a query/reply over Zenoh also gives a fleet one host with discovery,
//! routers and per-query timeouts without a protocol of ours.

pub mod client;
pub mod clock;
pub mod link;
pub mod live;
pub mod server;
pub mod wire;

/// CLOCK_MONOTONIC in ns: the clock of marsd's frames on the robot, and the host's own on the inference host.
pub use mars_ipc::clock::monotonic_ns;
