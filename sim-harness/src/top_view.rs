//! A top-down picture of the field, drawn on the CPU: lines, goals, the robot with its
//! cameras' view on the ground, the ball, and paths. For people, not for the robot.

use glam::Vec2;

use crate::camera_model::{CameraModel, Pixel};
use crate::field::FieldGeometry;
use crate::image_output::RgbImage;
use crate::pose::FieldPose;

pub const CARPET: [u8; 3] = [40, 120, 50];
pub const LINE: [u8; 3] = [235, 235, 235];
pub const GOAL: [u8; 3] = [250, 220, 40];
pub const ROBOT: [u8; 3] = [30, 60, 200];
pub const BALL: [u8; 3] = [250, 110, 20];

/// An RGB canvas that maps field coordinates to pixels.
#[derive(Clone, Debug)]
pub struct FieldCanvas {
    image: RgbImage,
    pixels_per_metre: f32,
    half_extent: Vec2,
}

impl FieldCanvas {
    /// A canvas showing the carpet of `field` at `pixels_per_metre`, with the lines and goals.
    pub fn new(field: &FieldGeometry, pixels_per_metre: f32) -> Self {
        let half_extent = Vec2::new(
            field.length / 2.0 + field.border,
            field.width / 2.0 + field.border,
        );
        let width = (2.0 * half_extent.x * pixels_per_metre).round() as u32;
        let height = (2.0 * half_extent.y * pixels_per_metre).round() as u32;
        let mut canvas = Self {
            image: RgbImage::filled(width, height, CARPET),
            pixels_per_metre,
            half_extent,
        };
        canvas.draw_field(field);
        canvas
    }

    fn draw_field(&mut self, field: &FieldGeometry) {
        let w = field.line_width.max(2.0 / self.pixels_per_metre);
        for line in field.line_polylines(96) {
            self.path(&line, w, LINE);
        }
        for side in [-1.0f32, 1.0] {
            let [(x, left), (_, right)] = field.goal_post_centres(side);
            self.line(Vec2::new(x, left), Vec2::new(x, right), 0.08, GOAL);
            for y in [left, right] {
                self.disc(Vec2::new(x, y), field.goal_post_diameter, GOAL);
            }
        }
    }

    /// The pixel of a field point.
    pub fn to_pixel(&self, point: Vec2) -> Vec2 {
        Vec2::new(
            (point.x + self.half_extent.x) * self.pixels_per_metre,
            (self.half_extent.y - point.y) * self.pixels_per_metre,
        )
    }

    fn put(&mut self, x: i64, y: i64, colour: [u8; 3]) {
        self.image.put(x, y, colour);
    }

    /// The picture drawn so far, to add labels to.
    pub fn image_mut(&mut self) -> &mut RgbImage {
        &mut self.image
    }

    /// A filled disc of `radius` metres.
    pub fn disc(&mut self, centre: Vec2, radius: f32, colour: [u8; 3]) {
        let c = self.to_pixel(centre);
        let r = (radius * self.pixels_per_metre).max(1.0);
        for y in (c.y - r).floor() as i64..=(c.y + r).ceil() as i64 {
            for x in (c.x - r).floor() as i64..=(c.x + r).ceil() as i64 {
                let d = Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - c;
                if d.length_squared() <= r * r {
                    self.put(x, y, colour);
                }
            }
        }
    }

    /// A line `width` metres wide.
    pub fn line(&mut self, a: Vec2, b: Vec2, width: f32, colour: [u8; 3]) {
        let (pa, pb) = (self.to_pixel(a), self.to_pixel(b));
        let r = (width * self.pixels_per_metre / 2.0).max(0.5);
        let steps = ((pb - pa).length() / 0.5).ceil().max(1.0) as usize;
        for i in 0..=steps {
            let p = pa + (pb - pa) * (i as f32 / steps as f32);
            for y in (p.y - r).floor() as i64..=(p.y + r).ceil() as i64 {
                for x in (p.x - r).floor() as i64..=(p.x + r).ceil() as i64 {
                    if (Vec2::new(x as f32 + 0.5, y as f32 + 0.5) - p).length_squared() <= r * r {
                        self.put(x, y, colour);
                    }
                }
            }
        }
    }

    /// A path through field points.
    pub fn path(&mut self, points: &[Vec2], width: f32, colour: [u8; 3]) {
        for pair in points.windows(2) {
            self.line(pair[0], pair[1], width, colour);
        }
    }

    /// The robot: a disc with a heading line.
    pub fn robot(&mut self, pose: FieldPose, colour: [u8; 3]) {
        let centre = Vec2::new(pose.x, pose.y);
        self.disc(centre, 0.15, colour);
        let heading = Vec2::new(pose.theta.cos(), pose.theta.sin());
        self.line(centre, centre + heading * 0.35, 0.05, colour);
    }

    /// The ground area a camera sees, outlined (the image border's rays where they meet the
    /// ground, out to `reach` metres).
    pub fn camera_view(&mut self, camera: &CameraModel, reach: f32, colour: [u8; 3]) {
        let (w, h) = (camera.width as f32, camera.height as f32);
        let border: Vec<Pixel> = (0..=16)
            .map(|i| Pixel {
                u: w * i as f32 / 16.0,
                v: h,
            })
            .chain((0..=16).map(|i| Pixel {
                u: w,
                v: h * (1.0 - i as f32 / 16.0),
            }))
            .chain((0..=16).map(|i| Pixel {
                u: w * (1.0 - i as f32 / 16.0),
                v: 0.0,
            }))
            .chain((0..=16).map(|i| Pixel {
                u: 0.0,
                v: h * i as f32 / 16.0,
            }))
            .collect();
        let origin = camera.position.truncate();
        let ground: Vec<Vec2> = border
            .iter()
            .map(|&pixel| match camera.ground_point(pixel) {
                Some(point) if (point - origin).length() <= reach => point,
                // Above the horizon or far away: cut the ray at `reach`.
                _ => {
                    let direction = camera.rotation
                        * glam::Vec3::new(1.0, (w / 2.0 - pixel.u) / camera.fx, 0.0);
                    origin + direction.truncate().normalize_or_zero() * reach
                }
            })
            .collect();
        let mut closed = ground.clone();
        if let Some(first) = ground.first() {
            closed.push(*first);
        }
        self.path(&closed, 0.02, colour);
    }

    pub fn into_image(self) -> RgbImage {
        self.image
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_centre_spot_is_the_image_centre_and_y_points_up() {
        let canvas = FieldCanvas::new(&FieldGeometry::SPL, 50.0);
        let image = canvas.clone().into_image();
        assert_eq!((image.width, image.height), (520, 370));
        assert_eq!(canvas.to_pixel(Vec2::ZERO), Vec2::new(260.0, 185.0));
        assert!(canvas.to_pixel(Vec2::new(0.0, 1.0)).y < 185.0);
    }
}
