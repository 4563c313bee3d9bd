//! Conditions an episode is seen under: what a real camera and a real venue do to the
//! images, each at a severity from 1 (slight) to 5 (harsh). Clean (no condition) is the
//! paper's render, bit for bit.
//!
//! A condition is part of an episode's definition: [`Conditions`] names which apply (written
//! into `dataset.json` and every evaluation file as its canonical text, e.g. `noise:3` or
//! `exposure:2,venue:4`), and [`Conditions::resolve`] draws everything random about them
//! from the episode's seed, so the same seed and conditions always give the same frames.
//!
//! Camera effects ([`camera`]) are applied to each camera's own full-resolution image before
//! YUYV packing, as a sensor and its signal processor would; the scene's light and the venue
//! ([`venue`]) change what is drawn.

pub mod camera;
pub mod venue;

use std::fmt;
use std::str::FromStr;

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;

pub use camera::{CameraEffects, CameraEffectsPlan};
pub use venue::{Occluder, StandingFigure, Sunlight, VenueLayout, VenueStyle};

/// One thing a real field does to the images.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Condition {
    /// Exposure and gain: a level off the right one, steps, and auto exposure hunting.
    Exposure,
    /// Flat light or a hazy lens: contrast reduced around mid-grey.
    Contrast,
    /// Sensor noise: shot and read noise in the raw image.
    Noise,
    /// White balance set for another colour temperature, drifting.
    WhiteBalance,
    /// Motion blur from the camera's own motion during the exposure, rolling-shutter skew.
    MotionBlur,
    /// Vignetting and a softer lens.
    Lens,
    /// A directional light with shadows of goals, robots and ball, and bright spots.
    Light,
    /// The venue: walls, their colours and features, objects and people beyond the field.
    Venue,
    /// A venue family never used in training (tiers of spectators, advertising boards).
    UnseenVenue,
    /// Robots standing around the field and on its edge (visual only).
    Robots,
}

impl Condition {
    pub const ALL: [Self; 10] = [
        Self::Exposure,
        Self::Contrast,
        Self::Noise,
        Self::WhiteBalance,
        Self::MotionBlur,
        Self::Lens,
        Self::Light,
        Self::Venue,
        Self::UnseenVenue,
        Self::Robots,
    ];
    pub const COUNT: usize = Self::ALL.len();

    pub fn name(self) -> &'static str {
        match self {
            Self::Exposure => "exposure",
            Self::Contrast => "contrast",
            Self::Noise => "noise",
            Self::WhiteBalance => "white-balance",
            Self::MotionBlur => "motion-blur",
            Self::Lens => "lens",
            Self::Light => "light",
            Self::Venue => "venue",
            Self::UnseenVenue => "unseen-venue",
            Self::Robots => "robots",
        }
    }

    fn index(self) -> usize {
        self as usize
    }

    /// Whether randomized training conditions may draw it (the unseen venue never is).
    pub fn in_training(self) -> bool {
        self != Self::UnseenVenue
    }
}

impl fmt::Display for Condition {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Condition {
    type Err = ConditionError;

    fn from_str(text: &str) -> Result<Self, Self::Err> {
        Self::ALL
            .into_iter()
            .find(|c| c.name() == text)
            .ok_or_else(|| ConditionError::UnknownCondition(text.to_owned()))
    }
}

/// How strong a condition is: 1 (slight) to 5 (harsh).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct Severity(u8);

impl Severity {
    pub const MAX: u8 = 5;

    pub fn new(level: u8) -> Result<Self, ConditionError> {
        if (1..=Self::MAX).contains(&level) {
            Ok(Self(level))
        } else {
            Err(ConditionError::Severity(level.to_string()))
        }
    }

    pub fn level(self) -> u8 {
        self.0
    }

    /// The entry of a five-entry table for this severity.
    pub fn pick<T: Copy>(self, table: [T; 5]) -> T {
        table[usize::from(self.0 - 1)]
    }
}

/// Bad condition text.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ConditionError {
    #[error(
        "unknown condition {0:?}: one of clean, randomized, exposure, contrast, noise, \
         white-balance, motion-blur, lens, light, venue, unseen-venue, robots"
    )]
    UnknownCondition(String),
    #[error("severity {0:?} is not one of 1, 2, 3, 4, 5")]
    Severity(String),
    #[error("condition {0:?} needs a severity: NAME:SEVERITY, e.g. noise:3")]
    MissingSeverity(String),
    #[error("condition {0} is named twice")]
    Repeated(Condition),
    #[error("venue and unseen-venue replace the same walls: name one of them")]
    TwoVenues,
}

/// Which conditions an episode runs under: each at most once with its severity, or a fresh
/// draw per episode from its seed (`randomized`, for training: never the unseen venue).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub struct Conditions {
    /// Severity of each condition, 0 where it is off.
    severities: [u8; Condition::COUNT],
    randomized: bool,
}

/// The seed stream of a condition's random draws, apart from the episode's placement.
const CONDITION_STREAM: u64 = 0x636f_6e64_6974_696f;

impl Conditions {
    /// The paper's clean render.
    pub const CLEAN: Self = Self {
        severities: [0; Condition::COUNT],
        randomized: false,
    };

    /// A fresh draw for every episode: training's mix.
    pub const RANDOMIZED: Self = Self {
        severities: [0; Condition::COUNT],
        randomized: true,
    };

    pub fn single(condition: Condition, severity: Severity) -> Self {
        let mut conditions = Self::CLEAN;
        conditions.severities[condition.index()] = severity.level();
        conditions
    }

    pub fn is_clean(&self) -> bool {
        !self.randomized && self.severities.iter().all(|&s| s == 0)
    }

    pub fn is_randomized(&self) -> bool {
        self.randomized
    }

    /// The conditions that apply, in [`Condition::ALL`]'s order (none when randomized: each
    /// episode draws its own, see [`Conditions::for_episode`]).
    pub fn active(&self) -> impl Iterator<Item = (Condition, Severity)> + '_ {
        Condition::ALL.into_iter().filter_map(|c| {
            let level = self.severities[c.index()];
            (level > 0).then_some((c, Severity(level)))
        })
    }

    pub fn severity(&self, condition: Condition) -> Option<Severity> {
        let level = self.severities[condition.index()];
        (level > 0).then_some(Severity(level))
    }

    /// The conditions of one episode: these, or for `randomized` a draw from `seed`: clean
    /// in one episode of five, otherwise one to three training conditions at severities 1-5
    /// (the harsher ones less often).
    pub fn for_episode(&self, seed: u64) -> Self {
        if !self.randomized {
            return *self;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(seed ^ CONDITION_STREAM ^ 0x7261_6e64);
        let mut drawn = Self::CLEAN;
        if rng.random_range(0..5) == 0 {
            return drawn;
        }
        let count = rng.random_range(1..=3);
        let pool: Vec<Condition> = Condition::ALL
            .into_iter()
            .filter(|c| c.in_training())
            .collect();
        for _ in 0..count {
            let condition = pool[rng.random_range(0..pool.len())];
            // Severities 1..5 with weights 3:3:3:2:1.
            let level = match rng.random_range(0..12) {
                0..=2 => 1,
                3..=5 => 2,
                6..=8 => 3,
                9..=10 => 4,
                _ => 5,
            };
            let slot = &mut drawn.severities[condition.index()];
            *slot = (*slot).max(level);
        }
        drawn
    }

    /// Everything random about these conditions for the episode of `seed`.
    pub fn resolve(&self, seed: u64) -> EpisodeLook {
        let conditions = self.for_episode(seed);
        let stream = |condition: Condition| {
            ChaCha8Rng::seed_from_u64(
                seed ^ CONDITION_STREAM ^ (condition.index() as u64 + 1) << 40,
            )
        };
        let camera = CameraEffectsPlan::draw(&conditions, seed, stream);
        let layout = VenueLayout::draw(&conditions, stream);
        EpisodeLook {
            conditions,
            seed,
            camera,
            layout,
        }
    }
}

impl fmt::Display for Conditions {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.randomized {
            return f.write_str("randomized");
        }
        let mut first = true;
        for (condition, severity) in self.active() {
            if !first {
                f.write_str(",")?;
            }
            write!(f, "{condition}:{}", severity.level())?;
            first = false;
        }
        if first {
            f.write_str("clean")?;
        }
        Ok(())
    }
}

impl FromStr for Conditions {
    type Err = ConditionError;

    /// `clean`, `randomized`, or `NAME:SEVERITY[,NAME:SEVERITY...]`.
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        match text.trim() {
            "clean" | "" => return Ok(Self::CLEAN),
            "randomized" => return Ok(Self::RANDOMIZED),
            _ => {}
        }
        let mut conditions = Self::CLEAN;
        for part in text.split(',') {
            let part = part.trim();
            let (name, level) = part
                .split_once(':')
                .ok_or_else(|| ConditionError::MissingSeverity(part.to_owned()))?;
            let condition: Condition = name.trim().parse()?;
            let level: u8 = level
                .trim()
                .parse()
                .map_err(|_| ConditionError::Severity(level.to_owned()))?;
            let severity = Severity::new(level)?;
            if conditions.severities[condition.index()] != 0 {
                return Err(ConditionError::Repeated(condition));
            }
            conditions.severities[condition.index()] = severity.level();
        }
        if conditions.severity(Condition::Venue).is_some()
            && conditions.severity(Condition::UnseenVenue).is_some()
        {
            return Err(ConditionError::TwoVenues);
        }
        Ok(conditions)
    }
}

/// An episode's conditions with their random draws made: what the renderer draws and what a
/// teacher that sees as a detector must look past.
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeLook {
    /// The conditions of this episode (a randomized run's draw for its seed).
    pub conditions: Conditions,
    pub seed: u64,
    pub camera: CameraEffectsPlan,
    pub layout: VenueLayout,
}

impl EpisodeLook {
    /// The paper's clean look.
    pub fn clean() -> Self {
        Conditions::CLEAN.resolve(0)
    }

    pub fn is_clean(&self) -> bool {
        self.conditions.is_clean()
    }

    /// The same episode seen by a clean camera in clean light: no camera effect and no
    /// light condition; the venue and the robots standing about kept as drawn. What the
    /// twin drops is only what the camera and the light do to the picture of the scene: the
    /// venue stays, since the robot sees it (a twin in the paper's arena would show walls
    /// the robot cannot see, and a clean-trained policy reads its side of the field from
    /// them), and so do the robots, which hide the ball. `dribble record --clean-twin`.
    pub fn clean_twin(&self) -> Self {
        let mut kept = Conditions::CLEAN;
        for condition in Self::TWIN_KEEPS {
            if let Some(severity) = self.conditions.severity(condition) {
                kept.severities[condition.index()] = severity.level();
            }
        }
        kept.resolve(self.seed)
    }

    /// The conditions a clean twin keeps: what stands in the scene, not what the camera or
    /// the light do to its picture.
    pub const TWIN_KEEPS: [Condition; 3] =
        [Condition::Venue, Condition::UnseenVenue, Condition::Robots];
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_clean_twin_keeps_the_venue_and_the_robots_and_drops_camera_and_light() {
        let look: Conditions = "noise:3,light:4,venue:5,robots:3".parse().expect("valid");
        let look = look.resolve(77);
        let twin = look.clean_twin();
        assert_eq!(twin.conditions.to_string(), "venue:5,robots:3");
        assert_eq!(twin.seed, 77);
        assert!(look.layout.sunlight.is_some());
        let mut unlit = look.layout.clone();
        unlit.sunlight = None;
        assert_eq!(
            twin.layout, unlit,
            "the same walls, features, people and robots"
        );
        assert_eq!(twin.camera, Conditions::CLEAN.resolve(77).camera);
        let clean: Conditions = "contrast:3".parse().expect("valid");
        assert!(clean.resolve(5).clean_twin().is_clean());
    }

    #[test]
    fn text_round_trips_and_is_canonical() {
        for text in [
            "clean",
            "randomized",
            "noise:3",
            "exposure:2,venue:4,robots:5",
        ] {
            let parsed: Conditions = text.parse().expect("parses");
            assert_eq!(parsed.to_string(), text);
        }
        let reordered: Conditions = "robots:5, exposure:2".parse().expect("parses");
        assert_eq!(reordered.to_string(), "exposure:2,robots:5");
    }

    #[test]
    fn bad_text_is_refused_with_a_reason() {
        assert_eq!(
            "fog:3".parse::<Conditions>(),
            Err(ConditionError::UnknownCondition("fog".into()))
        );
        assert_eq!(
            "noise".parse::<Conditions>(),
            Err(ConditionError::MissingSeverity("noise".into()))
        );
        assert_eq!(
            "noise:6".parse::<Conditions>(),
            Err(ConditionError::Severity("6".into()))
        );
        assert_eq!(
            "noise:0".parse::<Conditions>(),
            Err(ConditionError::Severity("0".into()))
        );
        assert_eq!(
            "noise:1,noise:2".parse::<Conditions>(),
            Err(ConditionError::Repeated(Condition::Noise))
        );
        assert_eq!(
            "venue:1,unseen-venue:2".parse::<Conditions>(),
            Err(ConditionError::TwoVenues)
        );
    }

    #[test]
    fn randomized_draws_follow_the_seed_and_never_the_unseen_venue() {
        let mut clean = 0;
        for seed in 0..500 {
            let drawn = Conditions::RANDOMIZED.for_episode(seed);
            assert_eq!(drawn, Conditions::RANDOMIZED.for_episode(seed));
            assert!(drawn.severity(Condition::UnseenVenue).is_none());
            assert!(!drawn.is_randomized());
            clean += usize::from(drawn.is_clean());
        }
        // One in five clean, within sampling error.
        assert!((60..=140).contains(&clean), "{clean} clean of 500");
    }

    #[test]
    fn the_same_seed_resolves_to_the_same_look() {
        let conditions: Conditions = "light:3,venue:3,robots:3,exposure:3".parse().expect("ok");
        assert_eq!(conditions.resolve(30_001), conditions.resolve(30_001));
        assert_ne!(conditions.resolve(30_001), conditions.resolve(30_002));
    }
}
