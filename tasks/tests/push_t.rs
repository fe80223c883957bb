//! Push-T's world, expert and camera: the expert completes the task by both routes and the route it took is read
//! back from its path; the world is deterministic for a seed; the pusher keeps its speed limit; the camera shows
//! the block, the pusher and the goal where they are.

use mars_tasks::push_t::expert::{Expert, Route, route_taken};
use mars_tasks::push_t::render::Camera;
use mars_tasks::push_t::{PushT, PushTConfig, PushTState};

/// One expert episode: (success, steps, route taken, the states).
fn episode(cfg: &PushTConfig, seed: u64, route: Route) -> (bool, usize, Option<Route>, Vec<PushTState>) {
    let mut world = PushT::new(cfg, seed);
    let mut expert = Expert::new(cfg, route);
    let mut states = vec![world.state()];
    while !world.done() {
        let a = expert.act(&world.state());
        world.step(a);
        states.push(world.state());
    }
    let pusher: Vec<[f32; 2]> = states.iter().map(|s| s.pusher).collect();
    let block: Vec<[f32; 3]> = states.iter().map(|s| s.block).collect();
    (world.success(), world.steps(), route_taken(&pusher, &block), states)
}

#[test]
fn the_expert_pushes_the_t_home_by_either_route() {
    let cfg = PushTConfig::default();
    for route in [Route::Upper, Route::Lower] {
        let mut ok = 0;
        for seed in 0..10 {
            let (success, steps, taken, states) = episode(&cfg, seed, route);
            let last = states.last().unwrap().block;
            eprintln!("{route:?} seed {seed}: success {success} in {steps} steps, route {taken:?}, block {last:?}");
            assert_eq!(taken, Some(route), "seed {seed}: the pusher went the other way");
            ok += usize::from(success);
        }
        assert!(ok >= 9, "{route:?}: {ok} of 10 episodes succeeded");
    }
}

#[test]
fn a_seed_gives_the_same_episode_and_the_pusher_keeps_its_speed() {
    let cfg = PushTConfig::default();
    let (_, _, _, a) = episode(&cfg, 4, Route::Upper);
    let (_, _, _, b) = episode(&cfg, 4, Route::Upper);
    assert_eq!(a, b);
    let (_, _, _, c) = episode(&cfg, 5, Route::Upper);
    assert_ne!(a[0], c[0], "another seed, another start");
    let most = cfg.pusher_speed * cfg.control_period * 1.0001;
    for w in a.windows(2) {
        let d = ((w[1].pusher[0] - w[0].pusher[0]).powi(2) + (w[1].pusher[1] - w[0].pusher[1]).powi(2)).sqrt();
        assert!(d <= most, "the pusher moved {d} m in one period (at most {most})");
    }
}

#[test]
fn the_camera_shows_each_thing_where_it_is() {
    let cfg = PushTConfig::default();
    let mut cam = Camera::push_t(96);
    let world = PushT::new(&cfg, 0);
    let s = world.state();
    let mut rgb = vec![0u8; 96 * 96 * 3];
    cam.render(&cfg, &s, &mut rgb);
    // Table point → pixel (the view: x from 0.16, y from −0.2, 0.4 m across 96 px; the image's top is +y).
    let px = |x: f32, y: f32| {
        let (u, v) = (((x - 0.16) / 0.4 * 96.0) as usize, ((0.2 - y) / 0.4 * 96.0) as usize);
        let i = (v * 96 + u) * 3;
        [rgb[i], rgb[i + 1], rgb[i + 2]]
    };
    assert_eq!(px(s.pusher[0], s.pusher[1]), [40, 70, 200], "the pusher is blue");
    assert_eq!(px(s.block[0], s.block[1]), [200, 60, 50], "the bar is red");
    assert_eq!(px(s.block[0] + 0.05, s.block[1]), [200, 60, 50], "the stem is red");
    assert_eq!(px(0.2, 0.15), [226, 222, 210], "the table");
    if let Ok(dir) = std::env::var("PUSH_T_PNG") {
        write_strip(&cfg, &dir);
    }
}

/// `PUSH_T_PNG=dir cargo test -p mars-tasks --test push_t camera`: one frame every 10 steps of each route.
fn write_strip(cfg: &PushTConfig, dir: &str) {
    let mut cam = Camera::push_t(96);
    for route in [Route::Upper, Route::Lower] {
        let (_, _, _, states) = episode(cfg, 0, route);
        let frames: Vec<&PushTState> = states.iter().step_by(10).collect();
        let (w, h) = (96 * frames.len(), 96);
        let mut strip = vec![0u8; w * h * 3];
        let mut rgb = vec![0u8; 96 * 96 * 3];
        for (k, s) in frames.iter().enumerate() {
            cam.render(cfg, s, &mut rgb);
            for y in 0..96 {
                strip[(y * w + k * 96) * 3..][..96 * 3].copy_from_slice(&rgb[y * 96 * 3..][..96 * 3]);
            }
        }
        let path = std::path::Path::new(dir).join(format!("push_t_{route:?}.png").to_lowercase());
        let mut enc = png::Encoder::new(std::fs::File::create(&path).unwrap(), w as u32, h as u32);
        enc.set_color(png::ColorType::Rgb);
        enc.write_header().unwrap().write_image_data(&strip).unwrap();
    }
}

/// A demo's action is where the pusher got to in its period (a robot log's setpoint), not the expert's waypoint:
/// the next observation starts there, and no action is farther than the pusher can go in one period — so the HIL
/// servo, which interpolates actions one period apart, moves the arm as the demo's pusher moved.
#[test]
fn demo_actions_are_the_positions_the_pusher_reached() {
    use mars_tasks::push_t::episode::{Observe, expert_demos};
    let cfg = PushTConfig::default();
    let reach = cfg.pusher_speed * cfg.control_period * 1.0001;
    for d in expert_demos(&cfg, 6, 3, Observe::State) {
        for t in 0..d.len() {
            let (p, a) = (&d.observations[t][..2], &d.actions[t]);
            let step = ((a[0] - p[0]).powi(2) + (a[1] - p[1]).powi(2)).sqrt();
            assert!(step <= reach, "step {t}: action {a:?} is {step} m from the pusher at {p:?}");
            if let Some(next) = d.observations.get(t + 1) {
                assert_eq!(&next[..2], &a[..], "step {t}: the next observation's pusher is the action");
            }
        }
    }
}
