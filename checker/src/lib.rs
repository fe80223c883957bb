//! An independent checker of what the HAL applied: [`record`] writes the HAL's published state frames to a file
//! from a process of its own; [`judge`] decides from that file alone whether every applied setpoint kept the robot's
//! limits, with its own copy of the FR3's position-dependent velocity formula ([`fr3_velocity`]) and the profile's
//! numbers read by [`limits`]. None of it calls the HAL's safety filter or marsd's limit checks, so a bug there
//! cannot hide itself from the verdict.

pub mod check;
pub mod fr3_velocity;
pub mod judge;
pub mod limits;
pub mod record;
pub mod stream;
