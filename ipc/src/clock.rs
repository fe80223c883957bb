//! The clock every frame is stamped with: CLOCK_MONOTONIC in nanoseconds. It is the same clock in every
//! process on the machine (unlike an `Instant` taken at process start), so a controller can compute the age
//! of a HAL state frame by subtraction, and it never jumps with NTP or the wall clock.

/// Nanoseconds on CLOCK_MONOTONIC. A vDSO call: no syscall, no allocation, safe in a real-time loop.
pub fn monotonic_ns() -> u64 {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a valid, writable timespec; CLOCK_MONOTONIC is always supported on Linux.
    let rc = unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    debug_assert_eq!(rc, 0);
    ts.tv_sec as u64 * 1_000_000_000 + ts.tv_nsec as u64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn monotonic_advances_with_real_time() {
        let a = monotonic_ns();
        std::thread::sleep(std::time::Duration::from_millis(5));
        let b = monotonic_ns();
        assert!(b - a >= 5_000_000, "{} ns", b - a);
    }
}
