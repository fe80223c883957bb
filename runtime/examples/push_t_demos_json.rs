//! Push-T expert demos as JSON, for a peer's tool to write as a dataset (the LeRobot fixture under
//! `tests/fixtures/lerobot/push_t`; its README says how). Per demo: the route (mode), the pusher's (x, y) before
//! each action, the action, and the top-down camera's RGB8 frame, flat.
//!
//! `cargo run --release -p mars-runtime --example push_t_demos_json -- <n> <seed> <out.json>`

use std::path::Path;

use mars_profile::Profile;
use mars_runtime::task::PushTHil;
use mars_tasks::push_t::episode::expert_demos;

fn main() -> anyhow::Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    anyhow::ensure!(args.len() == 3, "usage: push_t_demos_json <n> <seed> <out.json>");
    let (n, seed): (usize, u64) = (args[0].parse()?, args[1].parse()?);
    let task = PushTHil::load(Path::new("configs/push_t.toml"), &Profile::load(Path::new("configs/fr3.toml"))?)?;
    let size = task.cfg.camera.size as usize;
    let demos = expert_demos(&task.cfg.world, n, seed, task.observe());
    let episodes: Vec<_> = demos
        .iter()
        .map(|d| {
            let state: Vec<&[f32]> = d.observations.iter().map(|o| &o[..2]).collect();
            // The observation holds byte / 255; ×255 rounds back to the camera's bytes exactly.
            let image: Vec<Vec<u8>> =
                d.observations.iter().map(|o| o[2..].iter().map(|v| (v * 255.0).round() as u8).collect()).collect();
            serde_json::json!({ "mode": d.mode, "state": state, "action": d.actions, "image": image })
        })
        .collect();
    let fps = task.cfg.policy_rate_hz;
    let doc =
        serde_json::json!({ "task": "push_t", "fps": fps, "image_size": size, "seed": seed, "episodes": episodes });
    std::fs::write(&args[2], serde_json::to_string(&doc)?)?;
    println!("wrote {} demos ({} steps) to {}", demos.len(), demos.iter().map(|d| d.len()).sum::<usize>(), args[2]);
    Ok(())
}
