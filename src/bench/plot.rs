//! The plot of `bench table1 --plot FILE.png`: time against points, log–log, for the grid
//! pipeline and the Delaunay build measured here and for the paper's pipeline (its Delaunay:
//! a line at "more than 12 hours"). Drawn on a `chart::Frame` (grid, labels, border, axis
//! names, title); the series, markers and legend are drawn here.

use super::table1::{Table1, PAPER, PAPER_DELAUNAY_S};
use crate::chart::{Frame, Tick, TEXT};
use crate::error::Result;
use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::{Circle, Line, PrimitiveStyle, Rectangle, Triangle};
use embedded_graphics::text::Text;
use std::path::Path;

use crate::chart::Canvas;

const FRAME: Frame = Frame {
    w: 900,
    h: 620,
    left: 90,
    right: 30,
    top: 50,
    bottom: 70,
};

/// Log-scale axis mapping from [lo, hi] (decades) to pixels [a, b].
struct Axis {
    lo: f64,
    hi: f64,
    a: i32,
    b: i32,
}

impl Axis {
    fn px(&self, v: f64) -> i32 {
        let t = (v.log10() - self.lo) / (self.hi - self.lo);
        (self.a as f64 + t * (self.b - self.a) as f64).round() as i32
    }

    /// A grid line at each decade, labelled by `label`.
    fn decades(&self, label: fn(f64) -> String) -> Vec<Tick> {
        ((self.lo as i32)..=(self.hi as i32))
            .map(|d| (self.px(10f64.powi(d)), label(10f64.powi(d))))
            .collect()
    }
}

fn label_points(v: f64) -> String {
    match v {
        v if v >= 1e6 => format!("{}M", v / 1e6),
        v if v >= 1e3 => format!("{}k", v / 1e3),
        v => format!("{v}"),
    }
}

fn label_seconds(v: f64) -> String {
    match v {
        v if v >= 3600.0 => format!("{}h", (v / 3600.0 * 10.0).round() / 10.0),
        v if v >= 1.0 => format!("{v} s"),
        v => format!("{} ms", v * 1e3),
    }
}

/// Draws `t` as a PNG at `path`.
pub fn plot_table1(t: &Table1, path: &Path) -> Result<()> {
    let mut c = FRAME.canvas();
    let ours: Vec<(f64, f64, f64)> = t
        .rows
        .iter()
        .map(|r| (r.points as f64, r.grid_s, r.delaunay_s))
        .collect();
    let (xa, ya) = axes(&ours);
    let title = format!(
        "Table 1 on {} (log-log)",
        Path::new(&t.file)
            .file_name()
            .map_or("?".into(), |f| f.to_string_lossy())
    );
    let ticks = [&xa.decades(label_points)[..], &ya.decades(label_seconds)];
    FRAME.draw(&mut c, GREY, ticks, ["points", "seconds"], &title);

    let grid: Vec<(f64, f64)> = ours.iter().map(|o| (o.0, o.1)).collect();
    let tin: Vec<(f64, f64)> = ours.iter().map(|o| (o.0, o.2)).collect();
    let paper: Vec<(f64, f64)> = PAPER.iter().map(|p| (p.0 as f64, p.1)).collect();
    draw_series(&mut c, &xa, &ya, &paper, GREEN, 2);
    draw_series(&mut c, &xa, &ya, &grid, BLUE, 0);
    draw_series(&mut c, &xa, &ya, &tin, RED, 1);
    // The paper's Delaunay: "more than 12 hours", dashed.
    let y = ya.px(PAPER_DELAUNAY_S);
    let (left, right) = (FRAME.left, FRAME.w - FRAME.right);
    let mut x = left;
    while x < right {
        let _ = Line::new(Point::new(x, y), Point::new((x + 8).min(right), y))
            .into_styled(PrimitiveStyle::with_stroke(GREEN, 2))
            .draw(&mut c);
        x += 14;
    }
    draw_legend(&mut c);
    crate::fsutil::write_bytes_atomic(path, &c.png()?)
}

const BLUE: Rgb888 = Rgb888::new(30, 90, 200);
const RED: Rgb888 = Rgb888::new(200, 40, 40);
const GREEN: Rgb888 = Rgb888::new(40, 140, 60);
const GREY: Rgb888 = Rgb888::new(210, 210, 210);

/// The axes spanning whole decades around our rows `ours` (points, grid s, Delaunay s), the
/// paper's rows and its Delaunay line (with room above it).
fn axes(ours: &[(f64, f64, f64)]) -> (Axis, Axis) {
    let xs = ours
        .iter()
        .map(|o| o.0)
        .chain(PAPER.iter().map(|p| p.0 as f64));
    let (xmin, xmax) = xs.fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let ys = ours
        .iter()
        .flat_map(|o| [o.1, o.2])
        .chain([PAPER_DELAUNAY_S])
        .chain(PAPER.iter().map(|p| p.1));
    let (ymin, ymax) = ys.fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let xa = Axis {
        lo: xmin.log10().floor(),
        hi: xmax.log10().ceil(),
        a: FRAME.left,
        b: FRAME.w - FRAME.right,
    };
    let ya = Axis {
        lo: ymin.log10().floor(),
        hi: (ymax * 2.0).log10().ceil(),
        a: FRAME.h - FRAME.bottom,
        b: FRAME.top,
    };
    (xa, ya)
}

/// A marker at `q`: 0 a disc, 1 a square, anything else a triangle.
fn draw_marker(c: &mut Canvas, q: Point, col: Rgb888, marker: u8) {
    let fill = PrimitiveStyle::with_fill(col);
    let _ = match marker {
        0 => Circle::with_center(q, 9).into_styled(fill).draw(c),
        1 => Rectangle::with_center(q, Size::new(8, 8))
            .into_styled(fill)
            .draw(c),
        _ => Triangle::new(
            q + Point::new(0, -5),
            q + Point::new(-5, 4),
            q + Point::new(5, 4),
        )
        .into_styled(fill)
        .draw(c),
    };
}

/// A series of (points, seconds): a polyline with a marker at each point.
fn draw_series(c: &mut Canvas, xa: &Axis, ya: &Axis, pts: &[(f64, f64)], col: Rgb888, marker: u8) {
    let p: Vec<Point> = pts
        .iter()
        .map(|&(x, y)| Point::new(xa.px(x), ya.px(y)))
        .collect();
    for w in p.windows(2) {
        let _ = Line::new(w[0], w[1])
            .into_styled(PrimitiveStyle::with_stroke(col, 2))
            .draw(c);
    }
    for q in &p {
        draw_marker(c, *q, col, marker);
    }
}

/// The legend, in the lower right corner.
fn draw_legend(c: &mut Canvas) {
    let entries = [
        (BLUE, 0u8, "terratile grid pipeline (this machine)"),
        (RED, 1, "spade Delaunay build (this machine)"),
        (GREEN, 2, "paper's grid pipeline (Pentium IV)"),
        (GREEN, 3, "paper's Delaunay: more than 12 h"),
    ];
    for (k, (col, marker, name)) in entries.iter().enumerate() {
        let p = Point::new(
            FRAME.w - FRAME.right - 280,
            FRAME.h - FRAME.bottom - 70 + 16 * k as i32,
        );
        if *marker == 3 {
            let _ = Line::new(p + Point::new(-8, 0), p + Point::new(8, 0))
                .into_styled(PrimitiveStyle::with_stroke(*col, 2))
                .draw(c);
        } else {
            draw_marker(c, p, *col, *marker);
        }
        let _ = Text::new(name, p + Point::new(14, 3), TEXT).draw(c);
    }
}
