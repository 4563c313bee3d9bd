//! A moving test pattern for both cameras: frames for timing checks on the robot, tests and
//! benchmarks when no camera or simulator is at hand.

use core::time::Duration;

use crate::frame::{BottomFrame, CameraFrame, TopFrame};
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

/// Which cameras' frames [`PatternCameras::poll`] painted.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DueFrames {
    pub top: bool,
    pub bottom: bool,
}

/// Both cameras painting the test pattern on the robot's schedule, as a camera driver
/// delivers them: the top camera every `period` from `start`, the bottom one half a period
/// later, each frame numbered from 0 and stamped with the time it was due. The frames live
/// here (allocated once); a caller publishes or feeds the ones a poll says are new.
#[derive(Debug)]
pub struct PatternCameras {
    pattern: TestPattern,
    period: Duration,
    top: Box<TopFrame>,
    bottom: Box<BottomFrame>,
    /// The next frame of each camera: its sequence number and when it is due.
    next_top: (u64, Timestamp),
    next_bottom: (u64, Timestamp),
}

impl PatternCameras {
    pub fn new(pattern: TestPattern, period: Duration, start: Timestamp) -> Self {
        Self {
            pattern,
            period,
            top: TopFrame::new_boxed(),
            bottom: BottomFrame::new_boxed(),
            next_top: (0, start),
            next_bottom: (0, start + period / 2),
        }
    }

    /// Paints every frame due at `now` (at most one per camera; a late poll skips none of
    /// the numbers, only the frames in between) and says which.
    pub fn poll(&mut self, now: Timestamp) -> DueFrames {
        let mut due = DueFrames::default();
        if now >= self.next_top.1 {
            let (sequence, time) = self.next_top;
            self.pattern.paint(&mut self.top, sequence, time);
            self.next_top = (sequence + 1, time + self.period);
            due.top = true;
        }
        if now >= self.next_bottom.1 {
            let (sequence, time) = self.next_bottom;
            self.pattern.paint(&mut self.bottom, sequence, time);
            self.next_bottom = (sequence + 1, time + self.period);
            due.bottom = true;
        }
        due
    }

    /// When the next frame of either camera is due.
    pub fn next_due(&self) -> Timestamp {
        self.next_top.1.min(self.next_bottom.1)
    }

    /// Numbers the next frames from 0 again, as a restarted camera driver does.
    pub fn restart_numbering(&mut self) {
        (self.next_top.0, self.next_bottom.0) = (0, 0);
    }

    /// The newest top frame painted.
    pub fn top(&self) -> &TopFrame {
        &self.top
    }

    /// The newest bottom frame painted.
    pub fn bottom(&self) -> &BottomFrame {
        &self.bottom
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_cameras_fire_a_period_apart_the_bottom_half_a_period_after_the_top() {
        let period = Duration::from_millis(30);
        let mut cameras = PatternCameras::new(TestPattern::default(), period, Timestamp::ZERO);
        let at = |ms: u64| Timestamp::from_nanos(ms * 1_000_000);
        assert_eq!(
            cameras.poll(at(0)),
            DueFrames {
                top: true,
                bottom: false
            }
        );
        assert_eq!(cameras.next_due(), at(15));
        assert_eq!(
            cameras.poll(at(15)),
            DueFrames {
                top: false,
                bottom: true
            }
        );
        assert_eq!(cameras.poll(at(20)), DueFrames::default());
        assert_eq!(
            cameras.poll(at(31)),
            DueFrames {
                top: true,
                bottom: false
            }
        );
        assert_eq!(cameras.top().header().sequence, 1);
        assert_eq!(cameras.top().header().timestamp_ns, 30_000_000);
        cameras.restart_numbering();
        assert_eq!(
            cameras.poll(at(45)),
            DueFrames {
                top: false,
                bottom: true
            }
        );
        assert_eq!(cameras.bottom().header().sequence, 0);
    }

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
