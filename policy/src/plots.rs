//! PNG plots of demos, rollouts, ODE steps and training losses (paper Fig. 1 (b)–(f)).
//!
//! Everything takes plain data (layouts, demos, episodes, numbers) so plotting never touches the model.
//! Text is rendered with the bundled DejaVu Sans Mono through plotters' `ab_glyph` feature, so no system
//! fonts are needed.

use std::path::Path;

use plotters::coord::ranged1d::{AsRangedCoord, ValueFormatter};
use plotters::coord::types::RangedCoordf32;
use plotters::prelude::*;

use mars_tasks::demo::Demo;
use mars_tasks::nav2d::env::clip_norm;
use mars_tasks::nav2d::eval::{Episode, Termination};
use mars_tasks::nav2d::layout::Layout;

/// Pixel size of the world-map plots (demos, rollouts): roughly the world's 3:2 plus a colour bar.
pub const MAP_SIZE: (u32, u32) = (1000, 640);
/// Pixel size of the line plots (K per step, losses).
pub const LINE_SIZE: (u32, u32) = (900, 520);

pub(crate) use mars_plots::{Area, FONT, legend, plot_err, to_png};
pub use mars_plots::{ensure_font, palette, w_color};

/// Short tick labels: integers without a decimal point, otherwise at most 3 decimals, scientific outside
/// [1e-3, 1e4). Also keeps '.' rare, which plotters' ab_glyph renderer places badly in a monospace font.
fn tick_label(v: f32) -> String {
    let a = v.abs();
    if a == 0.0 {
        "0".into()
    } else if (1e-3..1e4).contains(&a) {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

type MapChart<'a, 'b> = ChartContext<'a, BitMapBackend<'b>, Cartesian2d<RangedCoordf32, RangedCoordf32>>;

/// Axes over the world with obstacles and the goal drawn in.
fn world_chart<'a, 'b>(area: &'a Area<'b>, layout: &Layout, title: &str) -> anyhow::Result<MapChart<'a, 'b>> {
    let w = layout.world;
    let mut chart = ChartBuilder::on(area)
        .caption(title, (FONT, 22))
        .margin(12)
        .margin_right(25)
        .x_label_area_size(40)
        .y_label_area_size(45)
        .build_cartesian_2d(w.x[0]..w.x[1], w.y[0]..w.y[1])
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc("x")
        .y_desc("y")
        .label_style((FONT, 15))
        .x_label_formatter(&|v| tick_label(*v))
        .y_label_formatter(&|v| tick_label(*v))
        .draw()
        .map_err(plot_err)?;
    let grey = RGBColor(150, 150, 150);
    chart
        .draw_series(
            layout.obstacles.iter().map(|o| Rectangle::new([(o.x[0], o.y[0]), (o.x[1], o.y[1])], grey.filled())),
        )
        .map_err(plot_err)?;
    let g = layout.goal;
    let green = RGBColor(60, 170, 90);
    chart
        .draw_series([
            Rectangle::new([(g.x[0], g.y[0]), (g.x[1], g.y[1])], green.mix(0.25).filled()),
            Rectangle::new([(g.x[0], g.y[0]), (g.x[1], g.y[1])], green.stroke_width(2)),
        ])
        .map_err(plot_err)?;
    chart
        .draw_series(std::iter::once(Text::new(
            "goal",
            (g.x[0] + 0.1, g.y[1] + 0.35),
            (FONT, 15).into_font().color(&green),
        )))
        .map_err(plot_err)?;
    let s = layout.agent.start;
    chart.draw_series(std::iter::once(Circle::new((s[0], s[1]), 4, BLACK.filled()))).map_err(plot_err)?;
    Ok(chart)
}

/// Expert demos over the layout, coloured by mode (paper Fig. 1(b)).
pub fn plot_demos(layout: &Layout, demos: &[Demo], path: &Path) -> anyhow::Result<()> {
    to_png(path, MAP_SIZE, |root| draw_demos(root, layout, demos))
}

fn draw_demos(root: &Area, layout: &Layout, demos: &[Demo]) -> anyhow::Result<()> {
    root.fill(&WHITE).map_err(plot_err)?;
    let title = format!("{}: {} expert demos", layout.name, demos.len());
    let mut chart = world_chart(root, layout, &title)?;
    let n_modes = layout.n_passages().max(demos.iter().filter_map(|d| d.mode).map(|m| m + 1).max().unwrap_or(0));
    // One series per mode so each gets one legend entry; demos without a mode are drawn in black.
    for mode in (0..n_modes).map(Some).chain([None]) {
        let color = mode.map_or(BLACK, palette);
        let paths: Vec<Vec<(f32, f32)>> =
            demos.iter().filter(|d| d.mode == mode).map(|d| demo_path(d, layout.agent.max_speed)).collect();
        if paths.is_empty() {
            continue;
        }
        let name = match mode.and_then(|m| layout.passages.get(m)) {
            Some(p) => p.name.clone(),
            None => mode.map_or("no mode".into(), |m| format!("mode {m}")),
        };
        let n = paths.len();
        chart
            .draw_series(paths.into_iter().map(|p| PathElement::new(p, color.mix(0.6).stroke_width(1))))
            .map_err(plot_err)?
            .label(format!("{name} ({n})"))
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3)));
    }
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}

/// The positions a demo visited, including the one its last action led to (observations stop one short).
fn demo_path(demo: &Demo, max_speed: f32) -> Vec<(f32, f32)> {
    let xy = |v: &Vec<f32>| (v.len() >= 2).then(|| [v[0], v[1]]);
    let mut path: Vec<(f32, f32)> = demo.observations.iter().filter_map(xy).map(|p| (p[0], p[1])).collect();
    if let (Some(o), Some(a)) = (demo.observations.last().and_then(xy), demo.actions.last().and_then(xy)) {
        let d = clip_norm([a[0] - o[0], a[1] - o[1]], max_speed);
        path.push((o[0] + d[0], o[1] + d[1]));
    }
    path
}

/// Policy rollouts over the layout, each step coloured by the ‖w‖∞ of its chunk, with a colour bar;
/// collisions are marked ✕, other failures ○ (paper Fig. 1(d)).
pub fn plot_rollouts(layout: &Layout, episodes: &[Episode], title: &str, path: &Path) -> anyhow::Result<()> {
    to_png(path, MAP_SIZE, |root| draw_rollouts(root, layout, episodes, title))
}

fn draw_rollouts(root: &Area, layout: &Layout, episodes: &[Episode], title: &str) -> anyhow::Result<()> {
    root.fill(&WHITE).map_err(plot_err)?;
    let (map, bar) = root.split_horizontally(MAP_SIZE.0 - 120);
    let mut chart = world_chart(&map, layout, title)?;
    for e in episodes {
        let traj = e.trajectory();
        let segments = traj.windows(2).zip(&e.steps).map(|(p, s)| {
            PathElement::new(vec![(p[0][0], p[0][1]), (p[1][0], p[1][1])], w_color(s.w_inf).stroke_width(2))
        });
        chart.draw_series(segments).map_err(plot_err)?;
    }
    let end = |e: &Episode| e.trajectory().last().map(|p| (p[0], p[1]));
    let crosses = episodes.iter().filter(|e| e.termination == Termination::Collision).filter_map(end);
    chart
        .draw_series(crosses.map(|p| Cross::new(p, 6, BLACK.stroke_width(2))))
        .map_err(plot_err)?
        .label("collision")
        .legend(|(x, y)| Cross::new((x + 10, y), 5, BLACK.stroke_width(2)));
    let failed = |e: &&Episode| !e.success() && e.termination != Termination::Collision;
    chart
        .draw_series(episodes.iter().filter(failed).filter_map(end).map(|p| Circle::new(p, 6, BLACK.stroke_width(2))))
        .map_err(plot_err)?
        .label("timeout / error")
        .legend(|(x, y)| Circle::new((x + 10, y), 5, BLACK.stroke_width(2)));
    let ok = episodes.iter().filter(|e| e.success()).count();
    chart
        .draw_series(std::iter::empty::<Circle<(f32, f32), i32>>())
        .map_err(plot_err)?
        .label(format!("success {ok}/{}", episodes.len()))
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], w_color(1.0).stroke_width(3)));
    legend(&mut chart, SeriesLabelPosition::UpperRight)?;
    mars_plots::draw_w_colorbar(&bar, &tick_label)
}

/// ODE steps K per env step along one episode, one line per policy (paper Fig. 1(f)).
pub fn plot_k_per_step(series: &[(String, Vec<usize>)], path: &Path) -> anyhow::Result<()> {
    to_png(path, LINE_SIZE, |root| draw_k_per_step(root, series))
}

fn draw_k_per_step(root: &Area, series: &[(String, Vec<usize>)]) -> anyhow::Result<()> {
    root.fill(&WHITE).map_err(plot_err)?;
    let steps = series.iter().map(|(_, k)| k.len()).max().unwrap_or(0).max(1);
    let k_max = series.iter().flat_map(|(_, k)| k).copied().max().unwrap_or(1);
    // Integer axes: steps and K are counts, and fractional ticks would suggest otherwise.
    let mut chart = ChartBuilder::on(root)
        .caption("ODE steps K per env step", (FONT, 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d(0..steps as i32, 0..(k_max as i32 + 1 + k_max as i32 / 10))
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("env step")
        .y_desc("K")
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 16))
        .light_line_style(WHITE)
        .draw()
        .map_err(plot_err)?;
    for (i, (name, ks)) in series.iter().enumerate() {
        let color = palette(i);
        // K is constant over a chunk, so draw it as a staircase rather than interpolating between steps.
        let pts = ks.iter().enumerate().flat_map(|(t, &k)| [(t as i32, k as i32), (t as i32 + 1, k as i32)]);
        chart
            .draw_series(LineSeries::new(pts, color.stroke_width(2)))
            .map_err(plot_err)?
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3)));
    }
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}

/// Training loss per epoch, one line per policy; log-scaled y when every value is positive (paper Fig. 1(e)).
pub fn plot_losses(series: &[(String, Vec<f32>)], path: &Path) -> anyhow::Result<()> {
    to_png(path, LINE_SIZE, |root| draw_losses(root, series))
}

fn draw_losses(root: &Area, series: &[(String, Vec<f32>)]) -> anyhow::Result<()> {
    root.fill(&WHITE).map_err(plot_err)?;
    let finite: Vec<f32> = series.iter().flat_map(|(_, v)| v).copied().filter(|v| v.is_finite()).collect();
    let lo = finite.iter().copied().fold(f32::INFINITY, f32::min);
    let hi = finite.iter().copied().fold(f32::NEG_INFINITY, f32::max);
    let epochs = series.iter().map(|(_, v)| v.len()).max().unwrap_or(0).max(2) as i32;
    if finite.is_empty() {
        return draw_loss_lines(root, series, 1..epochs, 0f32..1f32);
    }
    if lo > 0.0 {
        // Whole decades: plotters labels a log axis from the first power of ten inside the range, so a range
        // starting at 0.03 would show no labels below 0.1.
        let (lo, hi) = (10f32.powf(lo.log10().floor()), 10f32.powf(hi.log10().ceil()));
        let hi = if hi > lo { hi } else { lo * 10.0 };
        return draw_loss_lines(root, series, 1..epochs, (lo..hi).log_scale());
    }
    let pad = ((hi - lo) * 0.05).max(1e-6);
    draw_loss_lines(root, series, 1..epochs, (lo - pad)..(hi + pad))
}

fn draw_loss_lines<Y>(root: &Area, series: &[(String, Vec<f32>)], x: std::ops::Range<i32>, y: Y) -> anyhow::Result<()>
where
    Y: AsRangedCoord<Value = f32>,
    Y::CoordDescType: ValueFormatter<f32>,
{
    let mut chart = ChartBuilder::on(root)
        .caption("training loss", (FONT, 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(x, y)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .x_desc("epoch")
        .y_desc("loss")
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 16))
        .light_line_style(WHITE)
        .y_label_formatter(&|v| tick_label(*v))
        .draw()
        .map_err(plot_err)?;
    for (i, (name, losses)) in series.iter().enumerate() {
        let color = palette(i);
        let pts = losses.iter().enumerate().filter(|(_, v)| v.is_finite()).map(|(e, &v)| (e as i32 + 1, v));
        chart
            .draw_series(LineSeries::new(pts, color.stroke_width(2)))
            .map_err(plot_err)?
            .label(name.as_str())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3)));
    }
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mars_tasks::nav2d::eval::StepRecord;
    use mars_tasks::nav2d::expert::generate_demos;

    /// Draws into memory and returns the RGB pixels, so the test can look at them without an image decoder.
    fn render(size: (u32, u32), draw: impl FnOnce(&Area) -> anyhow::Result<()>) -> Vec<u8> {
        ensure_font().expect("font");
        let mut buf = vec![0u8; (size.0 * size.1 * 3) as usize];
        {
            let root = BitMapBackend::with_buffer(&mut buf, size).into_drawing_area();
            draw(&root).expect("draw");
            root.present().expect("present");
        }
        buf
    }

    /// Fraction of pixels that are not the white background.
    fn ink(buf: &[u8]) -> f64 {
        let px = buf.chunks_exact(3).filter(|p| p != &[255, 255, 255]).count();
        px as f64 / (buf.len() / 3) as f64
    }

    /// PNG signature and the IHDR width/height (bytes 16..24, big-endian).
    fn png_size(path: &Path) -> (u32, u32) {
        let bytes = std::fs::read(path).expect("png written");
        assert!(bytes.len() > 1000, "{} is suspiciously small", path.display());
        assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n");
        assert_eq!(&bytes[12..16], b"IHDR");
        let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]);
        (be(&bytes[16..20]), be(&bytes[20..24]))
    }

    /// A fresh directory per test (tests run in parallel and each removes its own). Set `MARS_PLOT_DIR` to
    /// keep the PNGs somewhere for a look.
    fn out_dir(test: &str) -> (std::path::PathBuf, bool) {
        let (dir, keep) = match std::env::var_os("MARS_PLOT_DIR") {
            Some(d) => (std::path::PathBuf::from(d).join(test), true),
            None => (std::env::temp_dir().join(format!("mars-plots-{}-{test}", std::process::id())), false),
        };
        std::fs::create_dir_all(&dir).expect("plot dir");
        (dir, keep)
    }

    fn clean(dir: &Path, keep: bool) {
        if !keep {
            std::fs::remove_dir_all(dir).ok();
        }
    }

    fn fake_episodes(layout: &Layout) -> Vec<Episode> {
        // Expert demos replayed as episodes with a w that rises along the way; one cut short as a collision.
        let demos = generate_demos(layout, 8, 3).expect("demos");
        demos
            .iter()
            .enumerate()
            .map(|(i, d)| {
                let n = d.observations.len();
                let mut steps: Vec<StepRecord> = d.observations[1..]
                    .iter()
                    .enumerate()
                    .map(|(t, o)| StepRecord { position: [o[0], o[1]], w_inf: t as f32 / n as f32, k: 1 + t / 10 })
                    .collect();
                let termination = if i == 0 {
                    steps.truncate(20);
                    Termination::Collision
                } else {
                    Termination::Success
                };
                let start = [d.rest_action[0], d.rest_action[1]];
                Episode { seed: i as u64, start, steps, calls: vec![], termination, mode: d.mode }
            })
            .collect()
    }

    /// Writes the PNG (right size?) and renders the same plot into memory (anything drawn?).
    fn check(
        dir: &Path,
        name: &str,
        size: (u32, u32),
        to_file: impl FnOnce(&Path) -> anyhow::Result<()>,
        to_buf: impl FnOnce(&Area) -> anyhow::Result<()>,
    ) {
        let path = dir.join(format!("{name}.png"));
        to_file(&path).expect(name);
        assert_eq!(png_size(&path), size, "{name}");
        let frac = ink(&render(size, to_buf));
        assert!(frac > 0.01 && frac < 0.9, "{name}: {frac} of pixels drawn");
    }

    #[test]
    fn all_plots_render_with_the_bundled_font() {
        let layout = Layout::default_four_passages();
        let demos = generate_demos(&layout, 40, 1).expect("demos");
        let episodes = fake_episodes(&layout);
        let ks = vec![("MARS".to_string(), episodes[1].k_per_step()), ("flow K=10".to_string(), vec![10; 50])];
        let losses = vec![
            ("MARS".to_string(), (0..30).map(|e| 1.0 / (1.0 + e as f32)).collect::<Vec<_>>()),
            ("flow".to_string(), (0..30).map(|e| 0.5 * (-0.1 * e as f32).exp()).collect()),
        ];
        let (dir, keep) = out_dir("all");
        check(&dir, "demos", MAP_SIZE, |p| plot_demos(&layout, &demos, p), |a| draw_demos(a, &layout, &demos));
        check(
            &dir,
            "rollouts",
            MAP_SIZE,
            |p| plot_rollouts(&layout, &episodes, "rollouts", p),
            |a| draw_rollouts(a, &layout, &episodes, "rollouts"),
        );
        check(&dir, "k", LINE_SIZE, |p| plot_k_per_step(&ks, p), |a| draw_k_per_step(a, &ks));
        check(&dir, "losses", LINE_SIZE, |p| plot_losses(&losses, p), |a| draw_losses(a, &losses));
        clean(&dir, keep);
    }

    #[test]
    fn degenerate_inputs_still_render() {
        let layout = Layout::default_four_passages();
        let (dir, keep) = out_dir("degenerate");
        plot_demos(&layout, &[], &dir.join("d.png")).expect("no demos");
        plot_rollouts(&layout, &[], "none", &dir.join("r.png")).expect("no episodes");
        plot_k_per_step(&[], &dir.join("k.png")).expect("no series");
        let bad = vec![("nan".to_string(), vec![f32::NAN, -1.0, 2.0])];
        plot_losses(&bad, &dir.join("l.png")).expect("non-positive loss -> linear axis");
        plot_losses(&[("empty".to_string(), vec![])], &dir.join("l2.png")).expect("empty");
        clean(&dir, keep);
    }

    #[test]
    fn w_colors_span_the_map() {
        assert_eq!(w_color(0.0), RGBColor(13, 8, 135));
        assert_eq!(w_color(1.0), RGBColor(235, 190, 20));
        assert_eq!(w_color(7.0), w_color(1.0));
        assert_eq!(w_color(f32::NAN), RGBColor(128, 128, 128));
    }
}
