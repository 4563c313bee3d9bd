//! A moving test pattern for both cameras: frames for timing checks on the robot, tests and
//! benchmarks when no camera or simulator is at hand.

use crate::frame::CameraFrame;
use crate::units::Timestamp;

/// A vertical luma gradient with a bright disc that circles the image once every
/// `orbit_seconds`, chroma neutral. Deterministic: the same time gives the same image.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TestPattern {
    pub orbit_seconds: f32,
}

impl Default for TestPattern {
    fn default() -> Self {
        Self { orbit_seconds: 4.0 }
    }
}

impl TestPattern {
    /// Paints the pattern as seen at `time` into `frame` and stamps it with `sequence`.
    pub fn paint<const W: usize, const H: usize>(
        &self,
        frame: &mut CameraFrame<W, H>,
        sequence: u64,
        time: Timestamp,
    ) {
        let seconds = time.as_nanos() as f64 / 1e9;
        let angle = (seconds / f64::from(self.orbit_seconds) * core::f64::consts::TAU) as f32;
        let (width, height) = (W as f32, H as f32);
        let centre = (
            width * (0.5 + 0.3 * angle.cos()),
            height * (0.5 + 0.3 * angle.sin()),
        );
        let radius_squared = (height * 0.1) * (height * 0.1);
        for (y, row) in frame.rows_mut().iter_mut().enumerate() {
            let gradient = (y * 160 / H) as u8 + 40;
            let dy = y as f32 - centre.1;
            for (x, pixel) in row.iter_mut().enumerate() {
                let dx = x as f32 - centre.0;
                let in_disc = dx * dx + dy * dy <= radius_squared;
                *pixel = [if in_disc { 250 } else { gradient }, 128];
            }
        }
        frame.restamp(sequence, time);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::frame::BottomFrame;

    #[test]
    fn the_disc_moves_and_the_frame_is_stamped() {
        let pattern = TestPattern::default();
        let mut early = BottomFrame::new_boxed();
        let mut late = BottomFrame::new_boxed();
        pattern.paint(&mut early, 3, Timestamp::ZERO);
        pattern.paint(&mut late, 4, Timestamp::from_nanos(1_000_000_000));
        assert_eq!(early.header().sequence, 3);
        assert!(BottomFrame::check_header(late.header()).is_ok());
        assert_ne!(early.as_bytes(), late.as_bytes());
        // At time zero the disc sits right of the centre.
        assert_eq!(early.luma(256, 120), 250);
        assert_ne!(late.luma(256, 120), 250);
    }
}
