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
    /// The robot's control command success rate: the lowest seen once 100 cycles of a motion had passed, and the
    /// last one.
    pub min_success_rate: Option<f64>,
    pub last_success_rate: f64,
    /// Each reflex, with the robot's own reasons (libfranka's error names).
    pub reflexes: Vec<String>,
    pub recoveries: u64,
    /// Why the connection ended, when it broke.
    pub connection_lost: Option<String>,
    /// The Franka Hand's counters, when it is driven.
    pub gripper: Option<super::hand::HandCounts>,
}

impl std::fmt::Display for RobotLoopReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "  robot {}: {} cycles, {} lost states, {} bunched states, {} setpoint resyncs ({} after a late command \
             thrown away), {} commands judged from two histories, control success rate min {} last {:.3}; \
             {} reflexes, {} recoveries",
            self.addr,
            self.cycles,
            self.lost_states,
            self.bunched_states,
            self.resyncs,
            self.resyncs_thrown_away,
            self.judged_twice,
            self.min_success_rate.map_or("n/a".to_string(), |r| format!("{r:.3}")),
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
