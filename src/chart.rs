//! Line charts for the figures terratile draws (the bench's Table 1 plot, the progressive
//! strips' Fig. 4): drawn with `embedded-graphics` (lines, markers and its built-in bitmap
//! font, so no system font is needed) into an `image` buffer encoded as PNG. A [`Frame`]
//! holds a chart's layout and draws what every chart has: grid lines with their labels, the
//! plot's border, the axis names and the title; each figure draws its own series.

use crate::error::{Error, Result};
use embedded_graphics::mono_font::{ascii::FONT_6X10, MonoTextStyle};
use embedded_graphics::pixelcolor::Rgb888;
use embedded_graphics::prelude::*;
use embedded_graphics::primitives::{Line, PrimitiveStyle, Rectangle};
use embedded_graphics::text::{Alignment, Text};

/// An `image` buffer as an embedded-graphics target.
pub(crate) struct Canvas(pub(crate) image::RgbImage);

impl Canvas {
    /// The PNG file of the picture.
    pub(crate) fn png(&self) -> Result<Vec<u8>> {
        let mut png = Vec::new();
        self.0
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .map_err(|e| Error::Internal(format!("png: {e}")))?;
        Ok(png)
    }
}

impl OriginDimensions for Canvas {
    fn size(&self) -> Size {
        Size::new(self.0.width(), self.0.height())
    }
}

impl DrawTarget for Canvas {
    type Color = Rgb888;
    type Error = std::convert::Infallible;

    fn draw_iter<I: IntoIterator<Item = Pixel<Rgb888>>>(
        &mut self,
        pixels: I,
    ) -> std::result::Result<(), Self::Error> {
        let (w, h) = (self.0.width() as i32, self.0.height() as i32);
        for Pixel(p, c) in pixels {
            if p.x >= 0 && p.y >= 0 && p.x < w && p.y < h {
                self.0
                    .put_pixel(p.x as u32, p.y as u32, image::Rgb([c.r(), c.g(), c.b()]));
            }
        }
        Ok(())
    }
}

/// The black 6 × 10 bitmap font every label is set in.
pub(crate) const TEXT: MonoTextStyle<'static, Rgb888> =
    MonoTextStyle::new(&FONT_6X10, Rgb888::BLACK);

/// A chart's layout in pixels: the picture's size and the margins around the plot area.
pub(crate) struct Frame {
    /// Width of the picture.
    pub w: i32,
    /// Height of the picture.
    pub h: i32,
    /// Margin left of the plot area (the y labels).
    pub left: i32,
    /// Margin right of it.
    pub right: i32,
    /// Margin above it (the title, the y axis name).
    pub top: i32,
    /// Margin below it (the x labels and axis name).
    pub bottom: i32,
}

/// A grid line: its position along the axis in pixels, and its label.
pub(crate) type Tick = (i32, String);

impl Frame {
    /// A white picture of the frame's size.
    pub(crate) fn canvas(&self) -> Canvas {
        Canvas(image::RgbImage::from_pixel(
            self.w as u32,
            self.h as u32,
            image::Rgb([255, 255, 255]),
        ))
    }

    /// Draws the grid lines at `x` and `y` in `grid` with their labels (below the plot area
    /// and left of it), the plot area's border, the axis names `x_name` (centred below)
    /// and `y_name` (above the y labels) and `title` (centred at the top).
    pub(crate) fn draw(
        &self,
        c: &mut Canvas,
        grid: Rgb888,
        [x, y]: [&[Tick]; 2],
        [x_name, y_name]: [&str; 2],
        title: &str,
    ) {
        let (left, right, top, bottom) = (
            self.left,
            self.w - self.right,
            self.top,
            self.h - self.bottom,
        );
        let thin = |col| PrimitiveStyle::with_stroke(col, 1);
        for (p, label) in x {
            let _ = Line::new(Point::new(*p, top), Point::new(*p, bottom))
                .into_styled(thin(grid))
                .draw(c);
            let at = Point::new(*p, bottom + 16);
            let _ = Text::with_alignment(label, at, TEXT, Alignment::Center).draw(c);
        }
        for (p, label) in y {
            let _ = Line::new(Point::new(left, *p), Point::new(right, *p))
                .into_styled(thin(grid))
                .draw(c);
            let at = Point::new(left - 6, p + 3);
            let _ = Text::with_alignment(label, at, TEXT, Alignment::Right).draw(c);
        }
        let _ = Rectangle::with_corners(Point::new(left, top), Point::new(right, bottom))
            .into_styled(thin(Rgb888::BLACK))
            .draw(c);
        let at = Point::new((left + right) / 2, self.h - 24);
        let _ = Text::with_alignment(x_name, at, TEXT, Alignment::Center).draw(c);
        let _ = Text::new(y_name, Point::new(8, top - 10), TEXT).draw(c);
        let at = Point::new(self.w / 2, 22);
        let _ = Text::with_alignment(title, at, TEXT, Alignment::Center).draw(c);
    }
}
