//! A small hand-written policy for tests, benchmarks and timing checks on the robot.

use super::{Policy, PolicyError, PolicyInput, PolicyOutput};

/// Turns toward the brighter half of the top image and walks faster the brighter the
/// bottom image is. It plays no soccer; it reads every thumbnail pixel, is deterministic and
/// allocation-free, and carries state between steps (a smoothed turn) so that `reset`
/// matters, which makes it a stand-in for a learned policy wherever the pipeline around the
/// policy is under test.
#[derive(Clone, Debug, Default)]
pub struct BrightnessPolicy {
    smoothed_turn: f32,
}

/// Weight of the newest turn in the smoothed turn.
const TURN_SMOOTHING: f32 = 0.5;

impl Policy for BrightnessPolicy {
    fn step(&mut self, input: PolicyInput<'_>) -> Result<PolicyOutput, PolicyError> {
        let (mut left_sum, mut right_sum) = (0u32, 0u32);
        for row in input.top.rows() {
            let (left, right) = row.split_at(row.len() / 2);
            left_sum += left.iter().map(|&p| u32::from(p)).sum::<u32>();
            right_sum += right.iter().map(|&p| u32::from(p)).sum::<u32>();
        }
        let half_pixels = (input.top.as_bytes().len() / 2) as f32;
        let turn = (left_sum as f32 - right_sum as f32) / (half_pixels * 255.0);
        self.smoothed_turn += TURN_SMOOTHING * (turn - self.smoothed_turn);

        let bottom = input.bottom.as_bytes();
        let bottom_sum: u32 = bottom.iter().map(|&p| u32::from(p)).sum();
        let brightness = bottom_sum as f32 / (bottom.len() as f32 * 255.0);
        Ok(PolicyOutput {
            forward: 2.0 * brightness - 1.0,
            left: 0.0,
            turn: self.smoothed_turn,
        })
    }

    fn reset(&mut self) {
        self.smoothed_turn = 0.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::thumbnail::{BottomThumbnail, TopThumbnail};

    #[test]
    fn turns_toward_the_brighter_side_and_reset_forgets_the_smoothing() {
        let mut top = TopThumbnail::black();
        for row in top.as_bytes_mut().chunks_exact_mut(160) {
            row[..80].fill(255);
        }
        let mut bottom = BottomThumbnail::black();
        bottom.as_bytes_mut().fill(255);
        let mut policy = BrightnessPolicy::default();
        let input = PolicyInput::at_rest(&top, &bottom);
        let first = policy.step(input).expect("step");
        let second = policy.step(input).expect("step");
        assert_eq!(first.forward, 1.0);
        assert_eq!(first.turn, 0.5, "half way to a full left turn");
        assert_eq!(second.turn, 0.75);
        policy.reset();
        assert_eq!(policy.step(input).expect("step"), first);
    }
}
