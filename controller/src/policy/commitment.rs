//! Commitment to one command hypothesis of a modal CNN: a margin before switching.
//!
//! The modal CNN (`models/dribble_models/networks.py`, `ModalCNN`) answers several commands
//! and one choice logit per command; its graph takes the command with the largest logit,
//! afresh at every frame. Where two hypotheses are nearly equal (which side to search, which
//! way to circle the ball) that choice can flip from one frame to the next, and the robot
//! dithers between them. [`HypothesisCommitment`] keeps the hypothesis it chose until
//! another's logit beats the held one's by `switch_margin`: hysteresis, with the held index
//! the one piece of state carried from step to step, forgotten at an episode's start.
//!
//! Our own because it is six lines of arithmetic on the network's outputs; it allocates
//! nothing.

use super::{PolicyError, PolicyOutput};

/// Which hypothesis a modal CNN's commands come from, and when to change it.
#[derive(Clone, Debug, PartialEq)]
pub struct HypothesisCommitment {
    count: usize,
    switch_margin: f32,
    held: Option<usize>,
    switches: u64,
}

impl HypothesisCommitment {
    /// For a network of `count` hypotheses; `switch_margin` in logits (0: the largest logit
    /// at every frame).
    pub fn new(count: usize, switch_margin: f32) -> Self {
        Self {
            count,
            switch_margin,
            held: None,
            switches: 0,
        }
    }

    /// The command of the hypothesis chosen for this frame, from the network's `commands`
    /// (`count` rows of forward, left, turn) and `logits` (one per hypothesis).
    ///
    /// The first frame takes the largest logit (the first of equal ones). Later frames keep
    /// the held hypothesis unless another's logit exceeds its own by more than the margin,
    /// or its own is NaN. A NaN logit is never chosen; when every logit is NaN the step has
    /// no command (an error: the tick publishes a stop).
    pub fn choose(
        &mut self,
        commands: &[f32],
        logits: &[f32],
    ) -> Result<PolicyOutput, PolicyError> {
        if commands.len() != self.count * 3 || logits.len() != self.count {
            return Err(PolicyError::Engine(
                "the hypotheses outputs do not hold the manifest's count",
            ));
        }
        let mut best: Option<(usize, f32)> = None;
        for (index, &logit) in logits.iter().enumerate() {
            if !logit.is_nan() && best.is_none_or(|(_, largest)| logit > largest) {
                best = Some((index, logit));
            }
        }
        let Some((best, largest)) = best else {
            self.held = None;
            return Err(PolicyError::Engine("every hypothesis logit is NaN"));
        };
        let chosen = match self.held {
            Some(held)
                if !logits[held].is_nan() && largest <= logits[held] + self.switch_margin =>
            {
                held
            }
            _ => best,
        };
        if self.held.is_some_and(|held| held != chosen) {
            self.switches += 1;
        }
        self.held = Some(chosen);
        let command = &commands[chosen * 3..chosen * 3 + 3];
        Ok(PolicyOutput {
            forward: command[0],
            left: command[1],
            turn: command[2],
        })
    }

    /// The hypothesis the last frame took, if any frame has been chosen since the reset.
    pub fn held(&self) -> Option<usize> {
        self.held
    }

    /// The margin another hypothesis's logit must beat the held one's by.
    pub fn switch_margin(&self) -> f32 {
        self.switch_margin
    }

    /// How many hypotheses the network answers.
    pub fn count(&self) -> usize {
        self.count
    }

    /// How often the held hypothesis changed since the policy was loaded.
    pub fn switches(&self) -> u64 {
        self.switches
    }

    /// Forgets the held hypothesis (an episode's start).
    pub fn reset(&mut self) {
        self.held = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const COMMANDS: [f32; 6] = [0.1, 0.0, 1.0, 0.2, 0.0, -1.0];

    fn turn(commitment: &mut HypothesisCommitment, logits: [f32; 2]) -> f32 {
        commitment
            .choose(&COMMANDS, &logits)
            .expect("a command")
            .turn
    }

    #[test]
    fn without_a_margin_it_takes_the_largest_logit_at_every_frame() {
        let mut commitment = HypothesisCommitment::new(2, 0.0);
        assert_eq!(turn(&mut commitment, [0.3, 0.2]), 1.0);
        assert_eq!(turn(&mut commitment, [0.2, 0.3]), -1.0);
        assert_eq!(turn(&mut commitment, [0.3, 0.2]), 1.0);
        assert_eq!(commitment.switches(), 2);
    }

    #[test]
    fn with_a_margin_it_holds_its_hypothesis_until_another_beats_it_by_more() {
        let mut commitment = HypothesisCommitment::new(2, 1.0);
        assert_eq!(
            turn(&mut commitment, [0.0, -0.5]),
            1.0,
            "first frame: largest"
        );
        assert_eq!(commitment.held(), Some(0));
        for logits in [[0.0, 0.9], [0.0, 1.0], [-2.0, -1.0]] {
            assert_eq!(turn(&mut commitment, logits), 1.0, "{logits:?}: held");
        }
        assert_eq!(turn(&mut commitment, [0.0, 1.01]), -1.0, "beaten by more");
        assert_eq!(commitment.held(), Some(1));
        assert_eq!(
            turn(&mut commitment, [0.5, 0.0]),
            -1.0,
            "now the other is held"
        );
        assert_eq!(commitment.switches(), 1);
    }

    #[test]
    fn a_reset_forgets_the_held_hypothesis() {
        let mut commitment = HypothesisCommitment::new(2, 10.0);
        assert_eq!(turn(&mut commitment, [1.0, 0.0]), 1.0);
        assert_eq!(turn(&mut commitment, [0.0, 5.0]), 1.0);
        commitment.reset();
        assert_eq!(commitment.held(), None);
        assert_eq!(turn(&mut commitment, [0.0, 5.0]), -1.0);
        assert_eq!(commitment.switches(), 0, "a reset is no switch");
    }

    #[test]
    fn nan_logits_are_never_chosen_and_all_nan_is_no_command() {
        let mut commitment = HypothesisCommitment::new(2, 10.0);
        assert_eq!(turn(&mut commitment, [f32::NAN, 0.0]), -1.0);
        assert_eq!(
            turn(&mut commitment, [5.0, f32::NAN]),
            1.0,
            "the held one is NaN"
        );
        assert!(commitment.choose(&COMMANDS, &[f32::NAN; 2]).is_err());
        assert_eq!(commitment.held(), None);
        assert_eq!(turn(&mut commitment, [0.0, 0.0]), 1.0, "equal: the first");
    }

    #[test]
    fn outputs_of_another_size_are_an_error_not_a_panic() {
        let mut commitment = HypothesisCommitment::new(3, 0.0);
        assert!(commitment.choose(&COMMANDS, &[0.0, 1.0]).is_err());
        assert!(commitment.choose(&[0.0; 9], &[0.0, 1.0]).is_err());
        assert!(commitment.choose(&[0.0; 9], &[0.0, 1.0, 2.0]).is_ok());
    }
}
