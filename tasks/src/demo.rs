//! A demonstration: what the expert saw and what it commanded, step by step.
//!
//! This is the only thing a task hands to training, so any simulator (nav2d, the FR3 HIL task) or a
//! recorder on a real robot produces it.

use serde::{Deserialize, Serialize};

/// One expert episode. `observations[t]` is what the expert saw before it issued `actions[t]`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Demo {
    pub observations: Vec<Vec<f32>>,
    pub actions: Vec<Vec<f32>>,
    /// The action that means "stay where you are" at the start (for position targets: the start position).
    /// It pads the action history before the first real action, the same way at training and at run time.
    pub rest_action: Vec<f32>,
    /// Which mode the expert took (e.g. the passage index), when the task has discrete modes.
    pub mode: Option<usize>,
}

impl Demo {
    pub fn len(&self) -> usize {
        self.actions.len()
    }

    pub fn is_empty(&self) -> bool {
        self.actions.is_empty()
    }
}

/// A set of demos as written to disk by `mars demos`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct DemoSet {
    pub task: String,
    pub demos: Vec<Demo>,
}
