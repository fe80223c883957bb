//! marsd's tools beside the daemon, each a subcommand: `marsd doctor` ([`doctor`]: this machine measured before
//! a run), `marsd top` ([`top`]: a running daemon's loops; [`top_network`]: a fleet's, through its inference host), `marsd replay` ([`replay`]: a recorded run's policy
//! calls again, offline), `marsd camera` ([`camera_watch`]: one camera's frames through the policy's check) and
//! `marsd serve` ([`serve`]: this machine as the inference host of robots whose marsd has `[remote]`).

pub mod camera_watch;
pub mod doctor;
pub mod replay;
pub mod serve;
pub mod top;
pub mod top_network;
