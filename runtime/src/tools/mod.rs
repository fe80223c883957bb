//! marsd's tools beside the daemon, each a subcommand: `marsd doctor` ([`doctor`]: this machine measured before
//! a run), `marsd top` ([`top`]: a running daemon's loops), `marsd replay` ([`replay`]: a recorded run's policy
//! calls again, offline) and `marsd camera` ([`camera_watch`]: one camera's frames through the policy's check).

pub mod camera_watch;
pub mod doctor;
pub mod replay;
pub mod top;
