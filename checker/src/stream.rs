//! The recorded stream: one CSV line per state frame the HAL published, with the checker's own receive time. Floats
//! are written in Rust's shortest round-trip form, so the checker reads back exactly the HAL's f64 setpoints.

use std::fmt::Write as _;

use anyhow::{Context, ensure};

/// The header line; the joint positions follow `joints` as `q0 … q{n-1}`.
pub const HEADER: &str = "recv_ns,seq,hal_ns,session,status,hold_reason,fault,robot_mode,robot_cycles,robot_errors,\
                          robot_reflex_errors,joints,q…";

/// What the checker needs of one state frame.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Frame {
    /// CLOCK_MONOTONIC when the recorder received it (ns; comparable with any process's on this machine).
    pub recv_ns: u64,
    pub seq: u64,
    /// The HAL's own stamp.
    pub hal_ns: u64,
    pub session: u64,
    pub status: u32,
    pub hold_reason: u32,
    pub fault: u32,
    pub robot_mode: u32,
    /// The robot's control cycles since the previous frame (fci: 1, more after states the HAL never saw; 0 for a
    /// HAL paced by its own timer).
    pub robot_cycles: u32,
    pub robot_errors: u64,
    pub robot_reflex_errors: u64,
    /// The setpoint the HAL applied (rad).
    pub q: Vec<f64>,
}

/// Status bits and codes of the wire, as the HAL documents them (mars-ipc `status`, `HoldReason`, `robot_mode`,
/// `fault`); the checker reads them, it does not compute them.
pub mod bits {
    pub const ACTIVE: u32 = 1 << 0;
    pub const HOLDING: u32 = 1 << 1;
    pub const AT_REST: u32 = 1 << 2;
    pub const FAULT_ROBOT_REFLEX: u32 = 1 << 4;
    pub const MODE_REFLEX: u32 = 5;

    /// The name of a hold reason code.
    pub fn hold_reason(code: u32) -> &'static str {
        match code {
            0 => "none",
            1 => "no session",
            2 => "command timeout",
            3 => "controller requested",
            4 => "controller lost",
            5 => "HAL error",
            6 => "robot fault",
            7 => "HAL stopping",
            _ => "unknown",
        }
    }
}

impl Frame {
    pub fn is(&self, bit: u32) -> bool {
        self.status & bit != 0
    }

    /// The robot reports a reflex in this frame (its mode, its reflex reasons, or the HAL's fault bit for it).
    pub fn in_reflex(&self) -> bool {
        self.robot_mode == bits::MODE_REFLEX
            || self.robot_reflex_errors != 0
            || self.fault & bits::FAULT_ROBOT_REFLEX != 0
    }

    /// Appends this frame as one CSV line (with its newline) to `out`.
    pub fn write_line(&self, out: &mut String) {
        let _ = write!(
            out,
            "{},{},{},{},{},{},{},{},{},{},{},{}",
            self.recv_ns,
            self.seq,
            self.hal_ns,
            self.session,
            self.status,
            self.hold_reason,
            self.fault,
            self.robot_mode,
            self.robot_cycles,
            self.robot_errors,
            self.robot_reflex_errors,
            self.q.len()
        );
        for q in &self.q {
            let _ = write!(out, ",{q}");
        }
        out.push('\n');
    }

    /// One CSV line back into a frame.
    pub fn parse_line(line: &str) -> anyhow::Result<Self> {
        let fields: Vec<&str> = line.trim_end().split(',').collect();
        ensure!(fields.len() >= 12, "{} fields, need at least 12", fields.len());
        let int = |i: usize| fields[i].parse::<u64>().with_context(|| format!("field {}: {:?}", i + 1, fields[i]));
        let small = |i: usize| -> anyhow::Result<u32> { Ok(u32::try_from(int(i)?)?) };
        let joints = int(11)? as usize;
        ensure!(fields.len() == 12 + joints, "{joints} joints but {} positions", fields.len() - 12);
        let q = fields[12..]
            .iter()
            .map(|f| f.parse::<f64>().with_context(|| format!("position {f:?}")))
            .collect::<anyhow::Result<Vec<f64>>>()?;
        Ok(Self {
            recv_ns: int(0)?,
            seq: int(1)?,
            hal_ns: int(2)?,
            session: int(3)?,
            status: small(4)?,
            hold_reason: small(5)?,
            fault: small(6)?,
            robot_mode: small(7)?,
            robot_cycles: small(8)?,
            robot_errors: int(9)?,
            robot_reflex_errors: int(10)?,
            q,
        })
    }
}

/// Every frame of a recorded file's text (its header first).
pub fn parse(text: &str) -> anyhow::Result<Vec<Frame>> {
    let mut lines = text.lines().enumerate();
    let (_, header) = lines.next().context("the file is empty")?;
    ensure!(header == HEADER, "not a checker recording: its first line is {header:?}");
    lines
        .filter(|(_, l)| !l.is_empty())
        .map(|(i, l)| Frame::parse_line(l).with_context(|| format!("line {}", i + 1)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_frame_round_trips_exactly() {
        let f = Frame {
            recv_ns: 123,
            seq: 7,
            hal_ns: 99,
            session: 3,
            status: bits::ACTIVE,
            hold_reason: 0,
            fault: 0,
            robot_mode: 3,
            robot_cycles: 1,
            robot_errors: 0,
            robot_reflex_errors: 0,
            q: vec![0.1 + 0.2, -2.356_194_490_192_345, 1e-17],
        };
        let mut text = format!("{HEADER}\n");
        f.write_line(&mut text);
        assert_eq!(parse(&text).unwrap(), vec![f]);
    }

    #[test]
    fn a_damaged_file_is_refused_with_the_line() {
        let e = parse("no header\n").unwrap_err();
        assert!(format!("{e:#}").contains("not a checker recording"), "{e:#}");
        let e = parse(&format!("{HEADER}\n1,2,3,4,5,6,7,8,9,10,11,2,0.5\n")).unwrap_err();
        assert!(format!("{e:#}").contains("line 2") && format!("{e:#}").contains("2 joints but 1"), "{e:#}");
        let e = parse(&format!("{HEADER}\n1,2,3,4,5,6,7,8,9,10,11,1,abc\n")).unwrap_err();
        assert!(format!("{e:#}").contains("\"abc\""), "{e:#}");
    }
}
