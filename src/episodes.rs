//! Which episodes a command runs: `train`, `test`, or a range of seeds.

use std::ops::Range;
use std::str::FromStr;

use dribble_sim::episode::{TEST_SEEDS, TRAINING_SEEDS};

/// A set of episode seeds, as given on the command line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Episodes(pub Range<u64>);

impl FromStr for Episodes {
    type Err = String;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text {
            "train" => Ok(Self(TRAINING_SEEDS)),
            "test" => Ok(Self(TEST_SEEDS)),
            _ => {
                let (start, end) = text.split_once("..").ok_or_else(|| {
                    format!("expected train, test or a seed range like 0..10, got {text:?}")
                })?;
                let parse = |s: &str| {
                    s.trim()
                        .parse::<u64>()
                        .map_err(|e| format!("bad seed {s:?} in {text:?}: {e}"))
                };
                let range = parse(start)?..parse(end)?;
                if range.is_empty() {
                    return Err(format!("the seed range {text:?} is empty"));
                }
                Ok(Self(range))
            }
        }
    }
}

/// An episode's time limit from the command line: simulated seconds, finite and positive
/// (NaN, infinite, zero or negative limits would make an episode end at once or never).
pub fn time_limit(text: &str) -> Result<f32, String> {
    match text.trim().parse::<f32>() {
        Ok(seconds) if seconds.is_finite() && seconds > 0.0 => Ok(seconds),
        _ => Err(format!(
            "{text:?} is not a time limit: a positive, finite number of simulated seconds"
        )),
    }
}

/// `--driver teacher`: a scripted teacher drives, not a policy. `expert`, the word of the
/// first datasets and scripts, means the same.
pub const TEACHER_DRIVER: &str = "teacher";

/// Whether a `--driver` names the scripted teacher rather than a policy's `policy.toml`.
pub fn is_teacher_driver(driver: &str) -> bool {
    driver == TEACHER_DRIVER || driver == "expert"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_time_limit_is_a_positive_finite_number_of_seconds() {
        assert_eq!(time_limit("90"), Ok(90.0));
        assert_eq!(time_limit(" 0.5"), Ok(0.5));
        for bad in ["NaN", "nan", "inf", "-inf", "0", "-1", "1e39", "", "ninety"] {
            assert!(time_limit(bad).is_err(), "{bad:?} accepted");
        }
    }

    #[test]
    fn parses_names_and_ranges() {
        assert_eq!("test".parse(), Ok(Episodes(10_000..10_020)));
        assert_eq!("train".parse(), Ok(Episodes(0..100)));
        assert_eq!("5..8".parse(), Ok(Episodes(5..8)));
        assert!("8..5".parse::<Episodes>().is_err());
        assert!("ten".parse::<Episodes>().is_err());
    }

    #[test]
    fn teacher_and_the_older_expert_name_the_scripted_driver() {
        assert!(super::is_teacher_driver("teacher") && super::is_teacher_driver("expert"));
        assert!(!super::is_teacher_driver("models/policy/cnn/policy.toml"));
    }
}
