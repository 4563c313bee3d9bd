//! How many samples each pixel of the cameras' images is drawn with.
//!
//! Four is the paper's render and every shipped result's: lines far away thin out instead
//! of vanishing, and every policy here was trained on such frames. One sample draws a clean
//! camera pair in about two fifths of the CPU time on lavapipe (no resolve, a quarter of the
//! depth and colour writes), at the price of frames that differ along object edges; it is a
//! setting beside the default for work where episodes an hour count more than the last bit
//! of a frame, and every file a run writes names it.

use std::fmt;
use std::str::FromStr;

/// Samples a pixel of the cameras' images.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Multisampling {
    /// Four samples a pixel, resolved by the driver: the frames every shipped result saw.
    #[default]
    Four,
    /// One sample a pixel, drawn straight into the image that is packed into YUYV.
    One,
}

impl Multisampling {
    /// The sample count the pipelines and targets are built with.
    pub fn samples(self) -> u32 {
        match self {
            Self::Four => 4,
            Self::One => 1,
        }
    }

    /// Whether these are the default frames (what files leave unnamed).
    pub fn is_default(self) -> bool {
        self == Self::Four
    }
}

impl fmt::Display for Multisampling {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.samples())
    }
}

/// A sample count other than 4 or 1 (lavapipe refuses 2; nothing here needs 8).
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
#[error("camera samples must be 4 (the default, every shipped result's frames) or 1, not {0:?}")]
pub struct MultisamplingError(String);

impl FromStr for Multisampling {
    type Err = MultisamplingError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text.trim() {
            "4" => Ok(Self::Four),
            "1" => Ok(Self::One),
            other => Err(MultisamplingError(other.to_owned())),
        }
    }
}

impl TryFrom<u32> for Multisampling {
    type Error = MultisamplingError;

    fn try_from(samples: u32) -> Result<Self, Self::Error> {
        match samples {
            4 => Ok(Self::Four),
            1 => Ok(Self::One),
            other => Err(MultisamplingError(other.to_string())),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_read_back_as_written_and_others_are_refused() {
        for setting in [Multisampling::Four, Multisampling::One] {
            assert_eq!(setting.to_string().parse::<Multisampling>(), Ok(setting));
            assert_eq!(Multisampling::try_from(setting.samples()), Ok(setting));
        }
        assert_eq!(Multisampling::default(), Multisampling::Four);
        assert!(Multisampling::Four.is_default() && !Multisampling::One.is_default());
        for bad in ["2", "8", "", "four", "-1"] {
            let error = bad.parse::<Multisampling>().expect_err(bad);
            assert!(error.to_string().contains("4 (the default"), "{error}");
        }
    }
}
