//! The fixed top-down camera: the table, the goal's outline, the block and the pusher, rasterised with
//! tiny-skia into RGB8 (row-major, the image's top is the table's +y).

use tiny_skia::{Color, FillRule, Paint, PathBuilder, Pixmap, Rect, Stroke, Transform};

use super::{PushTConfig, PushTState};

/// A square view of the table.
pub struct Camera {
    pixmap: Pixmap,
    /// The table's x and y at the image's left and bottom edges, and the side it shows (m).
    origin: [f32; 2],
    span: f32,
}

impl Camera {
    /// `size` × `size` pixels over the square with lower-left corner `origin` and side `span` metres.
    pub fn new(size: u32, origin: [f32; 2], span: f32) -> Self {
        Self { pixmap: Pixmap::new(size, size).expect("a positive image size"), origin, span }
    }

    /// The default view of Push-T: 0.4 m of table around the block's way.
    pub fn push_t(size: u32) -> Self {
        Self::new(size, [0.16, -0.2], 0.4)
    }

    pub fn size(&self) -> u32 {
        self.pixmap.width()
    }

    /// Where table point (x, y) lies in the image: (column, row) in pixels, fractional (for drawing on frames).
    pub fn pixel(&self, x: f32, y: f32) -> [f32; 2] {
        let k = self.size() as f32 / self.span;
        [(x - self.origin[0]) * k, (self.origin[1] + self.span - y) * k]
    }

    /// The table → pixel transform, composed with a block pose (x, y, θ) for shapes in its frame.
    fn pose(&self, p: [f32; 3]) -> Transform {
        let k = self.size() as f32 / self.span;
        let (s, c) = p[2].sin_cos();
        let (tx, ty) = ((p[0] - self.origin[0]) * k, (self.origin[1] + self.span - p[1]) * k);
        // x' = k(c·x − s·y) + tx, y' = −k(s·x + c·y) + ty (the image's y runs down).
        Transform::from_row(k * c, -k * s, -k * s, -k * c, tx, ty)
    }

    /// Renders `s` (and the goal of `cfg`) into `rgb` (size × size × 3 bytes).
    pub fn render(&mut self, cfg: &PushTConfig, s: &PushTState, rgb: &mut [u8]) {
        self.pixmap.fill(Color::from_rgba8(226, 222, 210, 255));
        let t_shape = {
            let [bar_len, bar_t] = cfg.bar;
            let [stem_t, stem_len] = cfg.stem;
            let mut pb = PathBuilder::new();
            pb.push_rect(Rect::from_xywh(-bar_t / 2.0, -bar_len / 2.0, bar_t, bar_len).expect("bar"));
            pb.push_rect(Rect::from_xywh(bar_t / 2.0, -stem_t / 2.0, stem_len, stem_t).expect("stem"));
            pb.finish().expect("a T")
        };
        let mut paint = Paint { anti_alias: true, ..Paint::default() };
        paint.set_color_rgba8(90, 170, 90, 255);
        let stroke = Stroke { width: 2.0 * self.span / self.size() as f32, ..Stroke::default() };
        self.pixmap.stroke_path(&t_shape, &paint, &stroke, self.pose(cfg.goal), None);
        paint.set_color_rgba8(200, 60, 50, 255);
        self.pixmap.fill_path(&t_shape, &paint, FillRule::Winding, self.pose(s.block), None);
        paint.set_color_rgba8(40, 70, 200, 255);
        let pusher = PathBuilder::from_circle(0.0, 0.0, cfg.pusher_radius).expect("a circle");
        self.pixmap.fill_path(&pusher, &paint, FillRule::Winding, self.pose([s.pusher[0], s.pusher[1], 0.0]), None);
        for (o, px) in rgb.chunks_exact_mut(3).zip(self.pixmap.data().chunks_exact(4)) {
            o.copy_from_slice(&px[..3]);
        }
    }
}
