//! A DDS domain for one run of this machine: tests and demos that start a peer (the R1 Lite stand-in) each take a
//! domain no other run holds, so their topics never meet. The reservation is an flock on a file named after the
//! domain in the temp dir, held for as long as the returned file lives (a crashed run releases it).

use std::fs::{File, OpenOptions};
use std::io;

/// ROS 2's usable domain ids on one host are 0–232; 0 is left to a real robot's default.
const DOMAINS: u32 = 232;

/// The first free domain (1–232) from `start` on, and the file whose lock holds it.
pub fn reserve_domain(start: u32) -> io::Result<(u16, File)> {
    for k in 0..DOMAINS {
        let domain = (start.wrapping_add(k) % DOMAINS + 1) as u16;
        let path = std::env::temp_dir().join(format!("mars-dds-domain-{domain}.lock"));
        let file = OpenOptions::new().create(true).truncate(false).write(true).open(&path)?;
        if file.try_lock().is_ok() {
            return Ok((domain, file));
        }
    }
    Err(io::Error::new(io::ErrorKind::AddrInUse, "all 232 DDS domains are held by other runs on this machine"))
}
