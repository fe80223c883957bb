//! PNG plots of a daemon run: latency percentile distributions, K requested vs used, joint-space episodes.
//!
//! Text uses mars-plots' bundled font (no fontconfig or system fonts on the robot computer).

use std::ops::Range;
use std::path::Path;

use anyhow::ensure;
use mars_plots::{Area, FONT, legend, palette, plot_err as err, to_png, w_color};
use plotters::prelude::*;

use mars_ipc::MAX_JOINTS;

use crate::report::latency::{Channel, K_MAX, Totals};

pub const LATENCY_SIZE: (u32, u32) = (1000, 600);
pub const K_SIZE: (u32, u32) = (900, 520);
pub const EPISODES_SIZE: (u32, u32) = (1000, 700);

/// One episode of the HIL demo, sampled at the policy rate.
#[derive(Debug, Clone, Default)]
pub struct EpisodeTrace {
    /// The grasp mode the episode ended in, if known.
    pub mode: Option<usize>,
    pub success: bool,
    /// Joint positions (rad), one per policy call; the arm's joints first, the rest of the frame's capacity 0.
    pub q: Vec<[f64; MAX_JOINTS]>,
    /// ‖w‖∞ of the chunk each call produced (same length as `q`).
    pub w_inf: Vec<f32>,
    /// A camera task's first frame the policy used and the newest frame kept (the scene as the episode ended;
    /// RGB8; empty without a camera).
    pub first_frame: Vec<u8>,
    pub last_frame: Vec<u8>,
}

impl EpisodeTrace {
    /// Keeps `rgb` as the episode's first frame, or else as its newest (the buffers are reused across episodes).
    pub fn keep_frame(&mut self, rgb: &[u8]) {
        let slot = if self.first_frame.is_empty() { &mut self.first_frame } else { &mut self.last_frame };
        slot.clear();
        slot.extend_from_slice(rgb);
    }
}

/// Latency against percentile, one line per time channel, on the HdrHistogram "1/(1−q)" axis: equal
/// distances per added nine (90%, 99%, 99.9%, ...), which is where control-loop tails live.
pub fn plot_latency(totals: &Totals, path: &Path) -> anyhow::Result<()> {
    to_png(path, LATENCY_SIZE, |root| draw_latency(root, totals))
}

fn draw_latency(root: &Area, totals: &Totals) -> anyhow::Result<()> {
    let series: Vec<(Channel, Vec<(f64, f64)>)> = Channel::ALL
        .into_iter()
        .filter(|c| c.is_time())
        .filter_map(|c| totals.histogram(c).filter(|h| !h.is_empty()).map(|h| (c, h)))
        .map(|(c, h)| {
            // The last quantile is 1, whose 1/(1−q) is infinite: cap q at 1 − 1/count, the resolution of the data.
            let q_max = 1.0 - 1.0 / h.len().max(2) as f64;
            let pts = h
                .iter_quantiles(5)
                .map(|v| {
                    (1.0 / (1.0 - v.quantile_iterated_to().min(q_max)), (v.value_iterated_to() as f64 / 1e3).max(1e-3))
                })
                .collect();
            (c, pts)
        })
        .collect();
    let all = || series.iter().flat_map(|(_, p)| p);
    let x_hi = all().map(|p| p.0).fold(1e4, f64::max);
    let (y_lo, y_hi) = all().fold((f64::INFINITY, 0f64), |(lo, hi), p| (lo.min(p.1), hi.max(p.1)));
    let (y_lo, y_hi) = if series.is_empty() { (1.0, 1000.0) } else { decades(y_lo, y_hi) };
    let title = if series.is_empty() { "latency: no samples" } else { "latency by percentile" };
    let mut chart = ChartBuilder::on(root)
        .caption(title, (FONT, 22))
        .margin(15)
        .margin_right(30)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d((1.0..decades(1.0, x_hi).1).log_scale(), (y_lo..y_hi).log_scale())
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("percentile")
        .y_desc("latency (µs)")
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 16))
        .x_label_formatter(&|x| percentile_label(*x))
        .y_label_formatter(&|y| short(*y))
        .draw()
        .map_err(err)?;
    for (i, (c, pts)) in series.iter().enumerate() {
        let color = palette(i);
        chart
            .draw_series(LineSeries::new(pts.iter().copied(), color.stroke_width(2)))
            .map_err(err)?
            .label(c.tag())
            .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], color.stroke_width(3)));
    }
    if series.is_empty() {
        return Ok(());
    }
    legend(&mut chart, SeriesLabelPosition::UpperLeft)
}

/// Whole decades around [lo, hi], so a log axis has labelled ends.
fn decades(lo: f64, hi: f64) -> (f64, f64) {
    let lo = 10f64.powf(lo.max(1e-9).log10().floor());
    let hi = 10f64.powf(hi.max(lo).log10().ceil());
    (lo, if hi > lo { hi } else { lo * 10.0 })
}

/// x = 1/(1−q) as a percentile: 10 → "90%", 1000 → "99.9%"; only decades are labelled (one more nine each).
fn percentile_label(x: f64) -> String {
    if (x.log10() - x.log10().round()).abs() > 1e-6 {
        return String::new();
    }
    let p = 100.0 * (1.0 - 1.0 / x);
    let s = format!("{p:.4}");
    format!("{}%", s.trim_end_matches('0').trim_end_matches('.'))
}

fn short(v: f64) -> String {
    // Tick values computed as sums can miss zero by rounding error (1e-16): that is zero.
    if v.abs() < 1e-9 {
        "0".into()
    } else if (1e-3..1e5).contains(&v.abs()) {
        let s = format!("{v:.3}");
        s.trim_end_matches('0').trim_end_matches('.').to_string()
    } else {
        format!("{v:.0e}")
    }
}

/// How often each K was requested and used, as grouped bars per K: the deadline cap shows as used bars
/// shifted left of requested ones.
pub fn plot_k(totals: &Totals, path: &Path) -> anyhow::Result<()> {
    to_png(path, K_SIZE, |root| draw_k(root, totals))
}

fn draw_k(root: &Area, totals: &Totals) -> anyhow::Result<()> {
    let counts = |c: Channel| -> Vec<u64> {
        let h = totals.histogram(c);
        (0..=K_MAX).map(|k| h.map_or(0, |h| h.count_at(k))).collect()
    };
    let (req, used) = (counts(Channel::KRequested), counts(Channel::KUsed));
    let k_hi = (1..=K_MAX as usize).rev().find(|&k| req[k] + used[k] > 0).unwrap_or(1).max(4);
    let y_hi = req.iter().chain(&used).copied().max().unwrap_or(0).max(10) as f64 * 1.1;
    let mut chart = ChartBuilder::on(root)
        .caption("ODE steps K: requested vs used", (FONT, 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(70)
        .build_cartesian_2d(0.5..k_hi as f64 + 0.5, 0.0..y_hi)
        .map_err(err)?;
    chart
        .configure_mesh()
        .x_desc("K")
        .y_desc("policy calls")
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 16))
        .x_labels(k_hi.min(16))
        .x_label_formatter(&|x| if x.fract().abs() < 1e-9 { format!("{x:.0}") } else { String::new() })
        .y_label_formatter(&|y| short(*y))
        .light_line_style(WHITE)
        .draw()
        .map_err(err)?;
    for (i, (name, c, side)) in [("requested", &req, -0.4), ("used", &used, 0.0)].into_iter().enumerate() {
        let color = palette(i);
        let bars = (1..=k_hi).filter(|&k| c[k] > 0).map(move |k| {
            let x = k as f64 + side;
            Rectangle::new([(x, 0.0), (x + 0.4, c[k] as f64)], color.filled())
        });
        chart
            .draw_series(bars)
            .map_err(err)?
            .label(format!("{name} ({} calls)", c.iter().sum::<u64>()))
            .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 15, y + 5)], color.filled()));
    }
    legend(&mut chart, SeriesLabelPosition::UpperRight)
}

/// Episodes in the plane of two joints, each step coloured by its chunk's ‖w‖∞, starts as black dots and
/// ends as circles in the colour of the episode's grasp mode: the two modes show as two branches.
pub fn plot_episodes(
    traces: &[EpisodeTrace],
    mode_names: &[String],
    joint_x: usize,
    joint_y: usize,
    path: &Path,
) -> anyhow::Result<()> {
    ensure!(joint_x < MAX_JOINTS && joint_y < MAX_JOINTS, "joints are 0..{MAX_JOINTS}, not ({joint_x}, {joint_y})");
    to_png(path, EPISODES_SIZE, |root| draw_episodes(root, traces, mode_names, joint_x, joint_y))
}

fn draw_episodes(
    root: &Area,
    traces: &[EpisodeTrace],
    mode_names: &[String],
    jx: usize,
    jy: usize,
) -> anyhow::Result<()> {
    let (map, bar) = root.split_horizontally(EPISODES_SIZE.0 - 110);
    let xy = |q: &[f64; MAX_JOINTS]| (q[jx], q[jy]);
    let pts = || traces.iter().flat_map(|t| t.q.iter().map(xy)).filter(|p| p.0.is_finite() && p.1.is_finite());
    let span = |v: Vec<f64>| -> Range<f64> {
        let (lo, hi) = v.iter().fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &x| (a.min(x), b.max(x)));
        if lo > hi {
            return -1.0..1.0;
        }
        let pad = ((hi - lo) * 0.06).max(0.05);
        (lo - pad)..(hi + pad)
    };
    let (xr, yr) = (span(pts().map(|p| p.0).collect()), span(pts().map(|p| p.1).collect()));
    let mut chart = ChartBuilder::on(&map)
        .caption(format!("{} episodes in the (q{jx}, q{jy}) plane", traces.len()), (FONT, 22))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(60)
        .build_cartesian_2d(xr, yr)
        .map_err(err)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .x_desc(format!("q{jx} (rad)"))
        .y_desc(format!("q{jy} (rad)"))
        .label_style((FONT, 15))
        .axis_desc_style((FONT, 16))
        .x_label_formatter(&|v| short(*v))
        .y_label_formatter(&|v| short(*v))
        .draw()
        .map_err(err)?;
    for t in traces {
        let segments = t.q.windows(2).enumerate().map(|(i, w)| {
            let color = w_color(t.w_inf.get(i).copied().unwrap_or(f32::NAN));
            PathElement::new(vec![xy(&w[0]), xy(&w[1])], color.stroke_width(2))
        });
        chart.draw_series(segments).map_err(err)?;
    }
    chart
        .draw_series(traces.iter().filter_map(|t| t.q.first()).map(|q| Circle::new(xy(q), 4, BLACK.filled())))
        .map_err(err)?;
    let n_modes = traces.iter().filter_map(|t| t.mode).map(|m| m + 1).max().unwrap_or(0);
    for mode in (0..n_modes).map(Some).chain([None]) {
        let ends: Vec<_> = traces.iter().filter(|t| t.mode == mode).filter_map(|t| t.q.last().map(xy)).collect();
        if ends.is_empty() {
            continue;
        }
        let color = mode.map_or(RGBColor(128, 128, 128), palette);
        let name = match mode {
            Some(m) => mode_names.get(m).cloned().unwrap_or_else(|| format!("mode {m}")),
            None => "no grasp".to_string(),
        };
        chart
            .draw_series(ends.iter().map(|&p| Circle::new(p, 7, color.stroke_width(3))))
            .map_err(err)?
            .label(format!("{name} ({})", ends.len()))
            .legend(move |(x, y)| Circle::new((x + 10, y), 6, color.stroke_width(3)));
    }
    let (x, y) = (chart.x_range(), chart.y_range());
    legend(&mut chart, emptiest_corner(pts(), x, y))?;
    mars_plots::draw_w_colorbar(&bar, &|v| short(f64::from(v)))
}

/// The corner of the plot with the fewest points in it, for the legend (episodes end in corners too).
fn emptiest_corner(pts: impl Iterator<Item = (f64, f64)>, x: Range<f64>, y: Range<f64>) -> SeriesLabelPosition {
    let mut n = [0usize; 4]; // upper left, upper right, lower left, lower right
    for (px, py) in pts {
        let (fx, fy) = ((px - x.start) / (x.end - x.start), (py - y.start) / (y.end - y.start));
        let (left, right, up, low) = (fx < 0.35, fx > 0.65, fy > 0.7, fy < 0.3);
        for (i, hit) in [left && up, right && up, left && low, right && low].into_iter().enumerate() {
            n[i] += hit as usize;
        }
    }
    use SeriesLabelPosition::*;
    // Ties go to the first: upper right, where legends usually are.
    let corners = [(n[1], UpperRight), (n[0], UpperLeft), (n[3], LowerRight), (n[2], LowerLeft)];
    corners.into_iter().min_by_key(|c| c.0).map_or(UpperRight, |c| c.1)
}

/// Push-T's camera strip: one row per episode (the last `rows` kept), the first frame the policy saw and the
/// scene as the episode ended, both scaled up, with the flange's path over the second, each policy step a dot coloured by ‖w‖∞ of
/// the chunk then executing (`w_color`, as in the episodes plot), the start black. `xy` maps a trace's joints to
/// the table, `pixel` a table point to the camera's (column, row); `size` is the camera's side in pixels.
pub fn plot_camera_strip(
    traces: &[EpisodeTrace],
    mode_names: &[String],
    size: u32,
    xy: impl Fn(&[f64; MAX_JOINTS]) -> [f64; 2],
    pixel: impl Fn([f64; 2]) -> [f32; 2],
    path: &Path,
    rows: usize,
) -> anyhow::Result<()> {
    let shown: Vec<&EpisodeTrace> = traces.iter().filter(|t| !t.first_frame.is_empty()).collect();
    let shown = &shown[shown.len().saturating_sub(rows)..];
    ensure!(!shown.is_empty(), "no episode kept a camera frame");
    let scale = (256 / size).max(1);
    let side = size * scale;
    let (label_w, gap) = (150u32, 8u32);
    let width = label_w + 2 * side + 3 * gap;
    let height = shown.len() as u32 * (side + gap) + gap;
    to_png(path, (width, height), |root| {
        for (row, t) in shown.iter().enumerate() {
            let top = gap + row as u32 * (side + gap);
            let mode = t.mode.and_then(|m| mode_names.get(m)).map_or("no mode", |s| s.as_str());
            let outcome = if t.success { "success" } else { "failure" };
            for (i, line) in [mode, outcome].iter().enumerate() {
                let at = (8, top as i32 + 8 + 22 * i as i32);
                root.draw(&Text::new(line.to_string(), at, (FONT, 18).into_font())).map_err(err)?;
            }
            let last = if t.last_frame.is_empty() { &t.first_frame } else { &t.last_frame };
            for (col, frame) in [&t.first_frame, last].into_iter().enumerate() {
                let left = label_w + gap + col as u32 * (side + gap);
                for (i, px) in frame.chunks_exact(3).enumerate() {
                    let (u, v) = (i as u32 % size, i as u32 / size);
                    let c = RGBColor(px[0], px[1], px[2]);
                    for dy in 0..scale {
                        for dx in 0..scale {
                            let at = ((left + u * scale + dx) as i32, (top + v * scale + dy) as i32);
                            root.draw_pixel(at, &c).map_err(err)?;
                        }
                    }
                }
                if col == 1 {
                    for (i, q) in t.q.iter().enumerate() {
                        let [pu, pv] = pixel(xy(q));
                        let at = (left as i32 + (pu * scale as f32) as i32, top as i32 + (pv * scale as f32) as i32);
                        let color = if i == 0 { BLACK } else { w_color(t.w_inf.get(i).copied().unwrap_or(f32::NAN)) };
                        root.draw(&Circle::new(at, 3, color.filled())).map_err(err)?;
                    }
                }
            }
        }
        Ok(())
    })
}
