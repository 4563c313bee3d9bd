//! Pictures drawn with `plotters` into an RGB buffer and written as PNG (the `png` crate, as
//! the rest of the project's images). Labels use DejaVu Sans from the `dejavu` crate,
//! registered once as plotters' `sans-serif`, so no system font is needed.
//!
//! plotters 0.3.7 draws `ab_glyph` text without each glyph's left side bearing, which opens
//! gaps after narrow glyphs ("1 0000"); its axis labels are short enough to live with that,
//! but titles and legends are drawn as [`Label`]s, laid out by `ab_glyph` itself.

use std::path::Path;
use std::sync::OnceLock;

use ab_glyph::{Font as _, FontRef, PxScale, ScaleFont as _, point};
use anyhow::{Context, anyhow};
use dribble_sim::image_output::RgbImage;
use plotters::coord::Shift;
use plotters::element::{Drawable, PointCollection};
use plotters::prelude::{BitMapBackend, Color, DrawingArea, IntoDrawingArea, RGBColor};
use plotters::style::FontStyle;
use plotters_backend::{BackendColor, BackendCoord, DrawingBackend, DrawingErrorKind};

/// The font family every label names.
pub const FONT: &str = "sans-serif";

/// Registers the embedded fonts with plotters (once per process).
fn register_fonts() -> anyhow::Result<()> {
    static REGISTERED: OnceLock<Result<(), String>> = OnceLock::new();
    REGISTERED
        .get_or_init(|| {
            for (style, name, bytes) in [
                (FontStyle::Normal, "regular", dejavu::sans::regular()),
                (FontStyle::Bold, "bold", dejavu::sans::bold()),
            ] {
                plotters::style::register_font(FONT, style, bytes)
                    .map_err(|_| format!("the embedded DejaVu Sans ({name}) does not parse"))?;
            }
            Ok(())
        })
        .clone()
        .map_err(|message| anyhow!(message))
}

/// Draws a `width` x `height` picture with `draw` and writes it to `path` as PNG.
pub fn draw_png(
    path: &Path,
    (width, height): (u32, u32),
    draw: impl FnOnce(&DrawingArea<BitMapBackend<'_>, Shift>) -> anyhow::Result<()>,
) -> anyhow::Result<()> {
    register_fonts()?;
    let mut pixels = vec![255u8; width as usize * height as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (width, height)).into_drawing_area();
        draw(&root)?;
        root.present()
            .with_context(|| format!("drawing {}", path.display()))?;
    }
    RgbImage {
        width,
        height,
        pixels,
    }
    .save_png(path)?;
    Ok(())
}

/// A line of text in DejaVu Sans with its top-left corner at a pixel, laid out with kerning
/// and side bearings and drawn anti-aliased over what is there.
#[derive(Clone, Debug)]
pub struct Label {
    text: String,
    corner: BackendCoord,
    size_px: f32,
    colour: RGBColor,
    bold: bool,
}

impl Label {
    pub fn new(
        text: impl Into<String>,
        corner: (i32, i32),
        size_px: f32,
        colour: RGBColor,
    ) -> Self {
        Self {
            text: text.into(),
            corner,
            size_px,
            colour,
            bold: false,
        }
    }

    pub fn bold(self) -> Self {
        Self { bold: true, ..self }
    }
}

impl<'a> PointCollection<'a, BackendCoord> for &'a Label {
    type Point = &'a BackendCoord;
    type IntoIter = std::iter::Once<&'a BackendCoord>;

    fn point_iter(self) -> Self::IntoIter {
        std::iter::once(&self.corner)
    }
}

impl<DB: DrawingBackend> Drawable<DB> for Label {
    fn draw<I: Iterator<Item = BackendCoord>>(
        &self,
        mut points: I,
        backend: &mut DB,
        _: (u32, u32),
    ) -> Result<(), DrawingErrorKind<DB::ErrorType>> {
        let Some((left, top)) = points.next() else {
            return Ok(());
        };
        let bytes = if self.bold {
            dejavu::sans::bold()
        } else {
            dejavu::sans::regular()
        };
        // The embedded font parses (register_fonts checked it before anything is drawn).
        let Ok(font) = FontRef::try_from_slice(bytes) else {
            return Ok(());
        };
        let scale = PxScale::from(self.size_px);
        let scaled = font.as_scaled(scale);
        let baseline = top as f32 + scaled.ascent();
        let mut x = left as f32;
        let mut previous = None;
        for c in self.text.chars() {
            let id = scaled.glyph_id(c);
            if let Some(previous) = previous {
                x += scaled.kern(previous, id);
            }
            previous = Some(id);
            let glyph = id.with_scale_and_position(scale, point(x, baseline));
            x += scaled.h_advance(id);
            let Some(outline) = font.outline_glyph(glyph) else {
                continue; // a space
            };
            let bounds = outline.px_bounds();
            let mut pixels = Vec::new();
            outline.draw(|gx, gy, coverage| pixels.push((gx, gy, coverage)));
            for (gx, gy, coverage) in pixels {
                let colour = BackendColor {
                    alpha: f64::from(coverage.clamp(0.0, 1.0)),
                    rgb: self.colour.rgb(),
                };
                let at = (
                    bounds.min.x as i32 + gx as i32,
                    bounds.min.y as i32 + gy as i32,
                );
                backend.draw_pixel(at, colour)?;
            }
        }
        Ok(())
    }
}
