//! The progressive-strips paper's Fig. 4 redone: indices sent to the GPU against the level
//! while a mesh refines from its base to the full mesh, for a triangle-list progressive mesh,
//! the unfiltered strip, STSS and DTFS. Drawn on a `chart::Frame`, like the bench plot
//! (linear axes here).

use super::measure::LevelIndices;
use crate::chart::{Frame, Tick, TEXT};
use crate::error::Result;
use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::{Line, PrimitiveStyle};
use embedded_graphics::text::Text;
use std::path::Path;

const FRAME: Frame = Frame {
    w: 900,
    h: 600,
    left: 80,
    right: 30,
    top: 50,
    bottom: 70,
};
const W: i32 = FRAME.w;
const H: i32 = FRAME.h;
const LEFT: i32 = FRAME.left;
const RIGHT: i32 = FRAME.right;
const TOP: i32 = FRAME.top;
const BOTTOM: i32 = FRAME.bottom;

/// The series: name, colour, and the value of a row.
type Series = (&'static str, Rgb888, fn(&LevelIndices) -> usize);

const SERIES: [Series; 4] = [
    (
        "triangle-list progressive mesh (PM)",
        Rgb888::new(40, 140, 60),
        |r| r.list,
    ),
    (
        "strip, unfiltered (PSnf)",
        Rgb888::new(120, 120, 120),
        |r| r.unfiltered,
    ),
    ("strip, STSS (PSstss)", Rgb888::new(30, 90, 200), |r| r.stss),
    ("strip, DTFS (PSdtfs)", Rgb888::new(200, 40, 40), |r| r.dtfs),
];

/// A round step of about a fifth of `max` (1, 2 or 5 times a power of ten).
fn step(max: f64) -> f64 {
    let raw = (max / 5.0).max(1.0);
    let p = 10f64.powf(raw.log10().floor());
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|k| k * p)
        .find(|&s| s >= raw)
        .unwrap_or(10.0 * p)
}

fn label(v: f64) -> String {
    if v >= 1e3 && v % 1e3 == 0.0 {
        format!("{}k", v / 1e3)
    } else {
        format!("{v}")
    }
}

/// The colour of the fifth series: DTFS on the strip in the paper's order.
const PAPER: Rgb888 = Rgb888::new(230, 140, 20);

/// Draws `rows` (ascending levels) of mesh `name` as Fig. 4 into a PNG's bytes; `paper`
/// (may be empty): the same levels with the full mesh stripified on its own (the paper's
/// order), whose DTFS curve is drawn too.
pub fn fig4_png(rows: &[LevelIndices], paper: &[LevelIndices], name: &str) -> Result<Vec<u8>> {
    let mut c = FRAME.canvas();
    let xmax = rows.iter().map(|r| r.level).max().unwrap_or(0).max(1) as f64;
    let ymax = rows
        .iter()
        .flat_map(|r| SERIES.map(|s| (s.2)(r)))
        .chain(paper.iter().map(|r| r.dtfs))
        .max()
        .unwrap_or(0)
        .max(1) as f64;
    let (xs, ys) = (step(xmax), step(ymax));
    // The x axis ends at the last level (the full mesh), not at the next round tick: the
    // data fill the plot's width. The y axis rounds up, above the highest series.
    let (xtop, ytop) = (xmax, (ymax / ys).ceil() * ys);
    let px = |l: f64| LEFT + ((l / xtop) * (W - LEFT - RIGHT) as f64).round() as i32;
    let py = |v: f64| H - BOTTOM - ((v / ytop) * (H - TOP - BOTTOM) as f64).round() as i32;
    let ticks = |top: f64, step: f64, at: &dyn Fn(f64) -> i32| -> Vec<Tick> {
        let mut v = 0.0;
        let mut out = Vec::new();
        while v <= top {
            out.push((at(v), label(v)));
            v += step;
        }
        out
    };
    let (xticks, yticks) = (ticks(xtop, xs, &px), ticks(ytop, ys, &py));
    FRAME.draw(
        &mut c,
        Rgb888::new(215, 215, 215),
        [&xticks, &yticks],
        [
            "level (vertex splits applied to the base mesh)",
            "indices sent to the GPU",
        ],
        &format!("Fig. 4 redone on {name}: indices per level, restarts counted"),
    );
    let paper_series: Series = (
        "strip, DTFS, the full mesh stripified on its own (paper's order)",
        PAPER,
        |r| r.dtfs,
    );
    let all = SERIES
        .iter()
        .map(|s| (s, rows))
        .chain((!paper.is_empty()).then_some((&paper_series, paper)));
    for (k, ((what, col, value), rows)) in all.enumerate() {
        let pts: Vec<Point> = rows
            .iter()
            .map(|r| Point::new(px(r.level as f64), py(value(r) as f64)))
            .collect();
        for w in pts.windows(2) {
            let _ = Line::new(w[0], w[1])
                .into_styled(PrimitiveStyle::with_stroke(*col, 2))
                .draw(&mut c);
        }
        // The legend, upper left.
        let p = Point::new(LEFT + 20, TOP + 20 + 16 * k as i32);
        let _ = Line::new(p, p + Point::new(20, 0))
            .into_styled(PrimitiveStyle::with_stroke(*col, 2))
            .draw(&mut c);
        let _ = Text::new(what, p + Point::new(28, 3), TEXT).draw(&mut c);
    }
    c.png()
}

/// [`fig4_png`] written to `path` atomically.
pub fn write_fig4(
    rows: &[LevelIndices],
    paper: &[LevelIndices],
    name: &str,
    path: &Path,
) -> Result<()> {
    crate::fsutil::write_bytes_atomic(path, &fig4_png(rows, paper, name)?)
}
