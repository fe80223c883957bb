//! Episodes as training demos: the observation is the state vector then each camera's image (bytes / 255,
//! channels last: what `mars_policy::vision` takes), the action the action vector.

use mars_tasks::demo::Demo;

use crate::EpisodeFrames;

/// What pads the action history before an episode's first action (`Demo::rest_action`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RestAction {
    /// The first frame's state: right when the actions are position targets in the state's space (a joint
    /// position policy, Push-T's (x, y)), the robot's "stay where you are".
    FirstState,
    /// The first action: for any other action space.
    FirstAction,
}

impl std::str::FromStr for RestAction {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        match s {
            "first-state" => Ok(Self::FirstState),
            "first-action" => Ok(Self::FirstAction),
            _ => Err(format!("`{s}`: give first-state or first-action")),
        }
    }
}

pub fn to_demos(
    episodes: &[EpisodeFrames],
    state_dim: usize,
    action_dim: usize,
    rest: RestAction,
) -> Result<Vec<Demo>, String> {
    if rest == RestAction::FirstState && state_dim != action_dim {
        return Err(format!(
            "rest action = first state needs a state of action_dim values: state has {state_dim}, action {action_dim} \
             (use first-action)"
        ));
    }
    Ok(episodes
        .iter()
        .map(|e| {
            let frame = |t: usize| {
                let mut o = e.state[t * state_dim..(t + 1) * state_dim].to_vec();
                for frames in &e.images {
                    let n = frames.len() / e.len;
                    o.extend(frames[t * n..(t + 1) * n].iter().map(|&p| f32::from(p) / 255.0));
                }
                o
            };
            let actions: Vec<Vec<f32>> = e.action.chunks_exact(action_dim).map(<[f32]>::to_vec).collect();
            let rest_action = match rest {
                RestAction::FirstState => e.state[..state_dim].to_vec(),
                RestAction::FirstAction => actions[0].clone(),
            };
            Demo { observations: (0..e.len).map(frame).collect(), actions, rest_action, mode: None }
        })
        .collect())
}
