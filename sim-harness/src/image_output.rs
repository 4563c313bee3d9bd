//! Pictures for people: camera frames as RGB, thumbnails as grayscale, written as PNG.

use std::fs::File;
use std::io::BufWriter;
use std::path::Path;

use dribble_controller::{CameraFrame, Thumbnail};

/// The image could not be written.
#[derive(Debug, thiserror::Error)]
#[error("cannot write {path}: {message}")]
pub struct ImageError {
    pub path: String,
    pub message: String,
}

/// An RGB image, row-major, three bytes per pixel.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<u8>,
}

impl RgbImage {
    /// A blank image of one colour.
    pub fn filled(width: u32, height: u32, colour: [u8; 3]) -> Self {
        Self {
            width,
            height,
            pixels: colour
                .iter()
                .copied()
                .cycle()
                .take(width as usize * height as usize * 3)
                .collect(),
        }
    }

    /// Sets one pixel; a point outside the image is ignored.
    pub fn put(&mut self, x: i64, y: i64, colour: [u8; 3]) {
        if x < 0 || y < 0 || x >= i64::from(self.width) || y >= i64::from(self.height) {
            return;
        }
        let i = ((y as usize) * self.width as usize + x as usize) * 3;
        self.pixels[i..i + 3].copy_from_slice(&colour);
    }

    pub fn save_png(&self, path: &Path) -> Result<(), ImageError> {
        write_png(
            path,
            self.width,
            self.height,
            png::ColorType::Rgb,
            &self.pixels,
        )
    }
}

/// A YUYV frame converted back to RGB (BT.601, full range), as a person would see it.
pub fn frame_to_rgb<const W: usize, const H: usize>(frame: &CameraFrame<W, H>) -> RgbImage {
    let mut pixels = Vec::with_capacity(W * H * 3);
    for row in frame.rows() {
        for pair in row.chunks_exact(2) {
            let (u, v) = (f32::from(pair[0][1]) - 128.0, f32::from(pair[1][1]) - 128.0);
            for pixel in pair {
                let y = f32::from(pixel[0]);
                let rgb = [
                    y + 1.402 * v,
                    y - 0.344_136 * u - 0.714_136 * v,
                    y + 1.772 * u,
                ];
                pixels.extend(rgb.map(|c| c.round().clamp(0.0, 255.0) as u8));
            }
        }
    }
    RgbImage {
        width: W as u32,
        height: H as u32,
        pixels,
    }
}

/// Writes a thumbnail as an 8-bit grayscale PNG, scaled up `scale` times so it can be seen.
pub fn save_thumbnail<const W: usize, const H: usize>(
    thumbnail: &Thumbnail<W, H>,
    scale: usize,
    path: &Path,
) -> Result<(), ImageError> {
    let scale = scale.max(1);
    let mut pixels = Vec::with_capacity(W * H * scale * scale);
    for row in thumbnail.rows() {
        let wide: Vec<u8> = row
            .iter()
            .flat_map(|&p| std::iter::repeat_n(p, scale))
            .collect();
        for _ in 0..scale {
            pixels.extend_from_slice(&wide);
        }
    }
    write_png(
        path,
        (W * scale) as u32,
        (H * scale) as u32,
        png::ColorType::Grayscale,
        &pixels,
    )
}

fn write_png(
    path: &Path,
    width: u32,
    height: u32,
    colour: png::ColorType,
    pixels: &[u8],
) -> Result<(), ImageError> {
    let error = |message: String| ImageError {
        path: path.display().to_string(),
        message,
    };
    let file = File::create(path).map_err(|e| error(e.to_string()))?;
    let mut encoder = png::Encoder::new(BufWriter::new(file), width, height);
    encoder.set_color(colour);
    encoder.set_depth(png::BitDepth::Eight);
    let mut writer = encoder.write_header().map_err(|e| error(e.to_string()))?;
    writer
        .write_image_data(pixels)
        .map_err(|e| error(e.to_string()))?;
    writer.finish().map_err(|e| error(e.to_string()))
}

#[cfg(test)]
mod tests {
    use super::*;
    use dribble_controller::BottomFrame;

    #[test]
    fn grey_yuyv_becomes_grey_rgb() {
        let mut frame = BottomFrame::new_boxed();
        for pixel in frame.rows_mut().as_flattened_mut() {
            *pixel = [100, 128];
        }
        let rgb = frame_to_rgb(&frame);
        assert_eq!(rgb.pixels.len(), 320 * 240 * 3);
        assert!(rgb.pixels.iter().all(|&c| c == 100));
    }
}
