//! When a logged failure happened, on the witness's clock: the processes under test log with a UTC timestamp at
//! the start of each line (`2026-11-21T11:51:57.722514Z …`, tracing's format); the witness records
//! CLOCK_MONOTONIC.

use std::time::{SystemTime, UNIX_EPOCH};

use crate::monotonic_ns;

/// Seconds since UTC midnight of the timestamp a log line starts with.
pub fn time_of_day(line: &str) -> Option<f64> {
    if line.get(10..11)? != "T" {
        return None;
    }
    let t = line.get(11..)?;
    let end = t.find(|c: char| !(c.is_ascii_digit() || c == ':' || c == '.')).unwrap_or(t.len());
    let mut parts = t[..end].split(':');
    let (h, m, s) = (parts.next()?.parse::<f64>().ok()?, parts.next()?.parse::<f64>().ok()?, parts.next()?);
    Some(h * 3600.0 + m * 60.0 + s.parse::<f64>().ok()?)
}

/// The CLOCK_MONOTONIC time (ns) of a log line's timestamp, if it has one within the last 12 hours.
pub fn monotonic_of_line(line: &str) -> Option<u64> {
    monotonic_of_time_of_day(time_of_day(line)?)
}

/// The CLOCK_MONOTONIC time (ns) of a UTC time of day (s since midnight) within the last 12 hours.
pub fn monotonic_of_time_of_day(tod: f64) -> Option<u64> {
    let now = SystemTime::now().duration_since(UNIX_EPOCH).ok()?;
    let now_tod = (now.as_secs() % 86_400) as f64 + f64::from(now.subsec_nanos()) * 1e-9;
    let ago = (now_tod - tod).rem_euclid(86_400.0);
    let ago = if ago > 43_200.0 { ago - 86_400.0 } else { ago };
    let ns = monotonic_ns() as f64 - ago * 1e9;
    (ns >= 0.0).then_some(ns as u64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_tracing_timestamp_reads_as_its_time_of_day() {
        let line = "2026-11-21T11:51:57.722514Z  WARN mars_hal: the robot stopped itself";
        assert!((time_of_day(line).unwrap() - (11.0 * 3600.0 + 51.0 * 60.0 + 57.722514)).abs() < 1e-9);
        assert_eq!(time_of_day("  reflex 1: joint_reflex"), None);
        assert_eq!(time_of_day("2026-11-21 11:51:57"), None);
    }

    #[test]
    fn a_line_logged_now_is_now_on_the_monotonic_clock() {
        let now = SystemTime::now().duration_since(UNIX_EPOCH).unwrap();
        let (s, ms) = (now.as_secs() % 86_400, now.subsec_millis());
        let line = format!("2026-01-01T{:02}:{:02}:{:02}.{ms:03}000Z x", s / 3600, s / 60 % 60, s % 60);
        let got = monotonic_of_line(&line).unwrap() as f64;
        assert!((got - monotonic_ns() as f64).abs() < 50e6, "{got} vs {}", monotonic_ns());
    }
}
