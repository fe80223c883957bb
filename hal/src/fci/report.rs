//! What the fci backend adds to the HAL's exit report: the robot's own view of the run.

/// The robot's side of a run, printed under the HAL's report.
#[derive(Debug, Clone, Default)]
pub struct RobotLoopReport {
    pub addr: String,
    /// Cycles of the robot's control loop our callback answered.
    pub cycles: u64,
    /// States the robot sent that the loop never saw (the robot's period counted past one cycle).
    pub lost_states: u64,
    /// States that reached the loop less than half a period after the one before: that one came late (the robot,
    /// the network or the machine held it up), so our answer to it most likely missed the robot's cycle, which
    /// the robot's success rate then counts as a lost command.
    pub bunched_states: u64,
    /// Cycles in which the robot reported another setpoint than our last command (it extrapolated over a lost
    /// one), and the filter continued from the robot's.
    pub resyncs: u64,
    /// Of them: after a late command of ours that franka-sim threw away for our next one (it kept its guess).
    pub resyncs_thrown_away: u64,
    /// Commands kept within the limits from two histories: after a state that showed our last command late, the
    /// robot may yet throw it away (franka-sim), and judges the next against its guess instead.
    pub judged_twice: u64,
    /// The robot's control command success rate: the lowest seen once 100 cycles of a motion had passed (and when,
    /// CLOCK_MONOTONIC ns: a test asks the stall witness about that moment), and the last one.
    pub min_success_rate: Option<f64>,
    pub min_success_rate_at_ns: u64,
    pub last_success_rate: f64,
    /// Each reflex, with the robot's own reasons (libfranka's error names).
    pub reflexes: Vec<String>,
    pub recoveries: u64,
    /// Why the connection ended, when it broke.
    pub connection_lost: Option<String>,
    /// The Franka Hand's counters, when it is driven.
    pub gripper: Option<super::hand::HandCounts>,
}

impl RobotLoopReport {
    /// The robot's success rate of this cycle, kept when it is the lowest so far (with the time: a clock read, no
    /// allocation, fit for the robot's callback).
    pub fn success_rate(&mut self, r: f64) {
        if self.min_success_rate.is_none_or(|m| r < m) {
            self.min_success_rate = Some(r);
            self.min_success_rate_at_ns = mars_ipc::clock::monotonic_ns();
        }
    }
}

impl crate::runner::DriverReport for RobotLoopReport {
    fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "addr": self.addr,
            "cycles": self.cycles,
            "lost_states": self.lost_states,
            "bunched_states": self.bunched_states,
            "resyncs": self.resyncs,
            "resyncs_thrown_away": self.resyncs_thrown_away,
            "judged_twice": self.judged_twice,
            "min_success_rate": self.min_success_rate,
            "last_success_rate": self.last_success_rate,
            "reflexes": self.reflexes,
            "recoveries": self.recoveries,
            "connection_lost": self.connection_lost,
        })
    }
}

impl std::fmt::Display for RobotLoopReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "  robot {}: {} cycles, {} lost states, {} bunched states, {} setpoint resyncs ({} after a late command \
             thrown away), {} commands judged from two histories, control success rate min {}{} last {:.3}; \
             {} reflexes, {} recoveries",
            self.addr,
            self.cycles,
            self.lost_states,
            self.bunched_states,
            self.resyncs,
            self.resyncs_thrown_away,
            self.judged_twice,
            self.min_success_rate.map_or("n/a".to_string(), |r| format!("{r:.3}")),
            self.min_success_rate.map_or(String::new(), |_| format!(" (at {})", utc_of(self.min_success_rate_at_ns))),
            self.last_success_rate,
            self.reflexes.len(),
            self.recoveries
        )?;
        for (i, r) in self.reflexes.iter().enumerate() {
            write!(f, "\n  reflex {}: {r}", i + 1)?;
        }
        if let Some(why) = &self.connection_lost {
            write!(f, "\n  connection lost: {why}")?;
        }
        if let Some(g) = &self.gripper {
            write!(
                f,
                "\n  gripper: {} moves, {} grasps ({} failed: nothing held), {} errors",
                g.moves, g.grasps, g.grasp_failures, g.errors
            )?;
        }
        Ok(())
    }
}

/// A CLOCK_MONOTONIC time as a UTC time of day (`13:30:43.672805 UTC`, the clock of the logs' timestamps), by the
/// two clocks' offset now.
fn utc_of(monotonic_ns: u64) -> String {
    let now = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap_or_default();
    let ago = mars_ipc::clock::monotonic_ns().saturating_sub(monotonic_ns);
    let at = now.saturating_sub(std::time::Duration::from_nanos(ago));
    let secs = at.as_secs() % 86_400;
    format!("{:02}:{:02}:{:02}.{:06} UTC", secs / 3600, secs / 60 % 60, secs % 60, at.subsec_micros())
}
