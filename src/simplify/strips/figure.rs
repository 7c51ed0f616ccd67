//! The progressive-strips paper's Fig. 4 redone: indices sent to the GPU against the level
//! while a mesh refines from its base to the full mesh, for a triangle-list progressive mesh,
//! the unfiltered strip, STSS and DTFS. Drawn with `embedded-graphics` into an `image`
//! buffer written as PNG, like the bench plot (linear axes here).

use super::measure::LevelIndices;
use crate::bench::plot::Canvas;
use crate::error::{Error, Result};
use embedded_graphics::mono_font::{ascii::FONT_6X10, MonoTextStyle};
use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::{Line, PrimitiveStyle, Rectangle};
use embedded_graphics::text::{Alignment, Text};
use std::path::Path;

const W: i32 = 900;
const H: i32 = 600;
const LEFT: i32 = 80;
const RIGHT: i32 = 30;
const TOP: i32 = 50;
const BOTTOM: i32 = 70;

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
    let mut c = Canvas(image::RgbImage::from_pixel(
        W as u32,
        H as u32,
        image::Rgb([255, 255, 255]),
    ));
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
    let text = MonoTextStyle::new(&FONT_6X10, Rgb888::BLACK);
    let thin = |col| PrimitiveStyle::with_stroke(col, 1);
    let grey = Rgb888::new(215, 215, 215);
    let mut x = 0.0;
    while x <= xtop {
        let p = px(x);
        let _ = Line::new(Point::new(p, TOP), Point::new(p, H - BOTTOM))
            .into_styled(thin(grey))
            .draw(&mut c);
        let _ = Text::with_alignment(
            &label(x),
            Point::new(p, H - BOTTOM + 16),
            text,
            Alignment::Center,
        )
        .draw(&mut c);
        x += xs;
    }
    let mut y = 0.0;
    while y <= ytop {
        let p = py(y);
        let _ = Line::new(Point::new(LEFT, p), Point::new(W - RIGHT, p))
            .into_styled(thin(grey))
            .draw(&mut c);
        let _ = Text::with_alignment(
            &label(y),
            Point::new(LEFT - 6, p + 3),
            text,
            Alignment::Right,
        )
        .draw(&mut c);
        y += ys;
    }
    let _ = Rectangle::with_corners(Point::new(LEFT, TOP), Point::new(W - RIGHT, H - BOTTOM))
        .into_styled(thin(Rgb888::BLACK))
        .draw(&mut c);
    let _ = Text::with_alignment(
        "level (vertex splits applied to the base mesh)",
        Point::new((LEFT + W - RIGHT) / 2, H - 24),
        text,
        Alignment::Center,
    )
    .draw(&mut c);
    let _ = Text::new("indices sent to the GPU", Point::new(8, TOP - 10), text).draw(&mut c);
    let title = format!("Fig. 4 redone on {name}: indices per level, restarts counted");
    let _ =
        Text::with_alignment(&title, Point::new(W / 2, 22), text, Alignment::Center).draw(&mut c);
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
        let _ = Text::new(what, p + Point::new(28, 3), text).draw(&mut c);
    }
    let mut png = Vec::new();
    c.0.write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
        .map_err(|e| Error::Internal(format!("png: {e}")))?;
    Ok(png)
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
