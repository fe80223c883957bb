//! A DDS domain for one run of this machine: tests and demos that start a peer (the R1 Lite stand-in) each take a
//! domain no other run holds, so their topics never meet. The reservation is an flock on a file named after the
//! domain in the temp dir, held for as long as the returned file lives (a crashed run releases it).

use std::fs::{File, OpenOptions};
use std::io;

/// Domains 1–101: 0 is left to a real robot's default, and from 102 on a domain's well-known ports (7400 + 250 ×
/// domain + …) lie in Linux's ephemeral range (32768–60999), where any socket of the machine may already hold
/// one (ROS 2's documentation advises the same). A test's HAL once went 30 s without the stand-in's feedback in
/// domain 113; whether a port was the cause is not established, but these domains cannot have that one.
const DOMAINS: u32 = 101;

/// The first free domain (1–101) from `start` on, and the file whose lock holds it.
pub fn reserve_domain(start: u32) -> io::Result<(u16, File)> {
    for k in 0..DOMAINS {
        let domain = (start.wrapping_add(k) % DOMAINS + 1) as u16;
        let path = std::env::temp_dir().join(format!("mars-dds-domain-{domain}.lock"));
        let file = OpenOptions::new().create(true).truncate(false).write(true).open(&path)?;
        if file.try_lock().is_ok() {
            return Ok((domain, file));
        }
    }
    Err(io::Error::new(io::ErrorKind::AddrInUse, "all 101 DDS domains are held by other runs on this machine"))
}
