//! The robot side of the MARS runtime: robot profiles, the safety filter, the backend interface with its sim
//! implementation, and the `mars-hal` process loop.

pub mod backend;
pub mod cli;
pub mod events;
pub mod fault;
pub mod profile;
pub mod runner;
pub mod safety;
pub mod session;
pub mod sim;
