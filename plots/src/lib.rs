//! What every plot of the project shares, so the trainer's figures (`mars-policy`) and marsd's run report
//! (`mars-runtime`) look alike and neither needs the other: the bundled font (no fontconfig or system fonts on
//! the robot computer), PNG output, the series palette, the colour map of ‖w‖∞ and its colour bar, legends.
//!
//! ```
//! use mars_plots::{palette, w_color};
//! assert_eq!(palette(0), palette(10), "the palette repeats after its 10 colours");
//! assert_eq!(w_color(f32::NAN), plotters::style::RGBColor(128, 128, 128));
//! assert_eq!(w_color(2.0), w_color(1.0), "out of range clamps");
//! ```

use std::path::Path;
use std::sync::OnceLock;

use anyhow::anyhow;
use plotters::coord::{CoordTranslate, Shift};
use plotters::prelude::*;
use plotters::style::register_font;

const FONT_BYTES: &[u8] = include_bytes!("../../assets/DejaVuSansMono.ttf");
/// The family every label asks for; [`ensure_font`] maps it to the bundled font.
pub const FONT: &str = "sans-serif";

/// A PNG's drawing area.
pub type Area<'a> = DrawingArea<BitMapBackend<'a>, Shift>;

/// Registers the bundled font once. plotters' default label styles ask for "sans-serif", so that name (and
/// the other generic families, in case a style asks for them) all map to the bundled font.
pub fn ensure_font() -> anyhow::Result<()> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            for family in ["sans-serif", "serif", "monospace"] {
                register_font(family, FontStyle::Normal, FONT_BYTES)
                    .map_err(|_| "the bundled font assets/DejaVuSansMono.ttf is not a valid font".to_string())?;
            }
            Ok(())
        })
        .clone()
        .map_err(|e| anyhow!(e))
}

/// Renders with `draw` on white into a PNG at `path`.
pub fn to_png(path: &Path, size: (u32, u32), draw: impl FnOnce(&Area) -> anyhow::Result<()>) -> anyhow::Result<()> {
    ensure_font()?;
    let root = BitMapBackend::new(path, size).into_drawing_area();
    root.fill(&WHITE).map_err(plot_err)?;
    draw(&root).map_err(|e| e.context(format!("drawing {}", path.display())))?;
    root.present().map_err(|e| anyhow!("writing {}: {e}", path.display()))
}

/// A plotters error as an `anyhow` one.
pub fn plot_err<E: std::error::Error + Send + Sync>(e: DrawingAreaErrorKind<E>) -> anyhow::Error {
    anyhow!("plotting failed: {e}")
}

/// Distinct colours for modes / series (Tableau 10).
pub fn palette(i: usize) -> RGBColor {
    const P: [(u8, u8, u8); 10] = [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
    ];
    let (r, g, b) = P[i % P.len()];
    RGBColor(r, g, b)
}

/// Colour for ‖w‖∞ ∈ [0, 1]: the plasma colormap, stopped short of its pale yellow end so w = 1 stays
/// visible on white. Out-of-range values clamp; NaN is grey.
pub fn w_color(w: f32) -> RGBColor {
    const STOPS: [(f32, f32, f32); 5] =
        [(13.0, 8.0, 135.0), (126.0, 3.0, 168.0), (204.0, 71.0, 120.0), (240.0, 130.0, 60.0), (235.0, 190.0, 20.0)];
    if w.is_nan() {
        return RGBColor(128, 128, 128);
    }
    let x = w.clamp(0.0, 1.0) * (STOPS.len() - 1) as f32;
    let i = (x.floor() as usize).min(STOPS.len() - 2);
    let t = x - i as f32;
    let (a, b) = (STOPS[i], STOPS[i + 1]);
    let mix = |u: f32, v: f32| (u + t * (v - u)).round() as u8;
    RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2))
}

/// The series' legend at `position`, on a translucent white box.
pub fn legend<'a, 'b: 'a, CT: CoordTranslate>(
    chart: &mut ChartContext<'a, BitMapBackend<'b>, CT>,
    position: SeriesLabelPosition,
) -> anyhow::Result<()> {
    chart
        .configure_series_labels()
        .position(position)
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK)
        .label_font((FONT, 14))
        .draw()
        .map_err(plot_err)
}

/// A vertical 0..1 bar of [`w_color`] filling `area`, its ticks written by `tick`.
pub fn draw_w_colorbar(area: &Area, tick: &dyn Fn(f32) -> String) -> anyhow::Result<()> {
    // The title is drawn by hand above the bar: as a chart caption it collides with the top tick label.
    area.draw(&Text::new("‖w‖∞", (25, 12), (FONT, 18).into_font())).map_err(plot_err)?;
    let mut chart = ChartBuilder::on(area)
        .margin_top(45)
        .margin_bottom(55)
        .margin_left(10)
        .margin_right(35)
        .y_label_area_size(40)
        .build_cartesian_2d(0f32..1f32, 0f32..1f32)
        .map_err(plot_err)?;
    chart
        .configure_mesh()
        .disable_mesh()
        .disable_x_axis()
        .y_labels(6)
        .y_label_formatter(&|v| tick(*v))
        .label_style((FONT, 14))
        .draw()
        .map_err(plot_err)?;
    let n = 100;
    chart
        .draw_series((0..n).map(|i| {
            let (lo, hi) = (i as f32 / n as f32, (i + 1) as f32 / n as f32);
            Rectangle::new([(0.0, lo), (1.0, hi)], w_color((lo + hi) / 2.0).filled())
        }))
        .map_err(plot_err)?;
    Ok(())
}
