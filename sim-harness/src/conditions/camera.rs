//! What a camera and its signal processor do to each frame: exposure and gain (a level,
//! steps, auto exposure hunting), sensor noise (shot and read noise in the raw image),
//! white balance drift, motion blur and rolling-shutter skew from the camera's own rotation,
//! vignetting and a softer lens, and contrast.
//!
//! [`CameraEffectsPlan`] is drawn once per episode; [`CameraEffectsPlan::frame`] gives the
//! per-frame [`CameraEffects`] the renderer's effects shader (`camera_effects.wgsl`) applies
//! to the camera's full-resolution image before YUYV packing, so the YUYV chroma and the
//! controller's 4x4 thumbnails average the noise as they would on the robot.
//!
//! Severity 3 of each condition is at least: 0.7 EV either way, contrast halved, noise of
//! 20/255 per full-resolution pixel at mid-grey, a 30 ms exposure (at the robot's 1 rad/s
//! turn, 30 mrad of smear), white balance off by 1000 K.

use bytemuck::{Pod, Zeroable};
use glam::{Quat, Vec3};
use rand::RngExt;
use rand_chacha::ChaCha8Rng;

use super::{Condition, Conditions};

/// Display values are linear light to this power (the renderer's flat colours are display
/// values; the sensor works in linear light).
pub const GAMMA: f32 = 2.2;
/// Exposure steps and white balance drift are drawn over this long (the 90 s time limit
/// and some room).
const TIMELINE_S: f32 = 120.0;
/// The colour temperature the cameras' white balance is set for, kelvin.
const BALANCED_K: f32 = 5500.0;
/// At most this many samples a pixel for blur and lens softness.
pub const MAX_SAMPLES: u32 = 16;

/// Exposure and gain over an episode.
#[derive(Clone, Debug, PartialEq)]
pub struct ExposurePlan {
    /// The constant error of the exposure, EV (positive: brighter).
    pub level_ev: f32,
    /// Steps of the exposure (light switched, a cloud, auto exposure reacting): times in
    /// seconds and the offset from the level that holds after each, EV.
    pub steps: Vec<(f32, f32)>,
    /// Amplitude of auto exposure hunting after each step, EV.
    pub hunt_ev: f32,
}

impl ExposurePlan {
    /// Hunting: an oscillation of this period that dies out with this time constant.
    const HUNT_PERIOD_S: f32 = 0.133;
    const HUNT_DECAY_S: f32 = 0.25;

    /// The exposure error at `time_s`, EV.
    pub fn ev_at(&self, time_s: f32) -> f32 {
        let mut ev = self.level_ev;
        let mut last_step: Option<f32> = None;
        for &(at, offset) in &self.steps {
            if at > time_s {
                break;
            }
            ev = self.level_ev + offset;
            last_step = Some(at);
        }
        if let Some(at) = last_step {
            let since = time_s - at;
            ev += self.hunt_ev
                * (-since / Self::HUNT_DECAY_S).exp()
                * (core::f32::consts::TAU * since / Self::HUNT_PERIOD_S).sin();
        }
        ev
    }
}

/// White balance set for the wrong colour temperature, drifting slowly.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WhiteBalancePlan {
    /// The light's colour temperature minus the one the camera balances for, kelvin.
    pub shift_k: f32,
    /// A slow drift around it: amplitude (a share of the shift) and period.
    pub drift: f32,
    pub drift_period_s: f32,
    pub drift_phase: f32,
}

impl WhiteBalancePlan {
    /// Per-channel gains (linear, green 1) at `time_s`: the colour cast of light at
    /// `BALANCED_K + shift` seen by a camera balanced for `BALANCED_K`.
    pub fn gains_at(&self, time_s: f32) -> [f32; 3] {
        let wobble = 1.0
            + self.drift
                * (core::f32::consts::TAU * time_s / self.drift_period_s + self.drift_phase).sin();
        let light = blackbody_rgb(BALANCED_K + self.shift_k * wobble);
        let balanced = blackbody_rgb(BALANCED_K);
        let gains = [0, 1, 2].map(|c| light[c] / balanced[c]);
        gains.map(|g| g / gains[1])
    }
}

/// Everything about an episode's cameras that the conditions change.
#[derive(Clone, Debug, PartialEq)]
pub struct CameraEffectsPlan {
    pub seed: u64,
    pub exposure: Option<ExposurePlan>,
    /// Contrast around mid-grey (1: unchanged).
    pub contrast: f32,
    /// Noise at mid-grey in display units (20/255 at severity 3); 0: none.
    pub noise_mid_grey: f32,
    pub white_balance: Option<WhiteBalancePlan>,
    /// Exposure time and rolling-shutter readout time, seconds (0: instantaneous).
    pub exposure_s: f32,
    pub readout_s: f32,
    /// Brightness lost at the image corners (0: none), and the lens's blur, standard
    /// deviation in full-resolution pixels.
    pub vignetting: f32,
    pub softness_px: f32,
}

impl CameraEffectsPlan {
    /// No effect at all: the clean render.
    pub fn none(seed: u64) -> Self {
        Self {
            seed,
            exposure: None,
            contrast: 1.0,
            noise_mid_grey: 0.0,
            white_balance: None,
            exposure_s: 0.0,
            readout_s: 0.0,
            vignetting: 0.0,
            softness_px: 0.0,
        }
    }

    pub fn is_none(&self) -> bool {
        *self == Self::none(self.seed)
    }

    pub(super) fn draw(
        conditions: &Conditions,
        seed: u64,
        stream: impl Fn(Condition) -> ChaCha8Rng,
    ) -> Self {
        let mut plan = Self::none(seed);
        if let Some(severity) = conditions.severity(Condition::Exposure) {
            let mut rng = stream(Condition::Exposure);
            let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let level_ev = sign * severity.pick([0.25, 0.45, 0.7, 1.0, 1.4]);
            let step_ev = severity.pick([0.0, 0.25, 0.4, 0.6, 0.8]);
            let mean_gap_s = severity.pick([f32::INFINITY, 8.0, 5.0, 3.5, 2.5]);
            let mut steps = Vec::new();
            if step_ev > 0.0 {
                let mut at = 0.0;
                loop {
                    // Exponential gaps, at least a second apart.
                    let u: f32 = rng.random_range(0.0..1.0);
                    at += 1.0 + (mean_gap_s - 1.0) * -(1.0 - u).ln();
                    if at > TIMELINE_S {
                        break;
                    }
                    let offset = if rng.random_bool(0.5) {
                        step_ev
                    } else {
                        -step_ev
                    };
                    steps.push((at, offset));
                }
            }
            plan.exposure = Some(ExposurePlan {
                level_ev,
                steps,
                hunt_ev: severity.pick([0.0, 0.15, 0.3, 0.4, 0.5]),
            });
        }
        if let Some(severity) = conditions.severity(Condition::Contrast) {
            plan.contrast = severity.pick([0.85, 0.7, 0.5, 0.4, 0.3]);
        }
        if let Some(severity) = conditions.severity(Condition::Noise) {
            plan.noise_mid_grey = severity.pick([5.0, 10.0, 20.0, 30.0, 45.0]) / 255.0;
        }
        if let Some(severity) = conditions.severity(Condition::WhiteBalance) {
            let mut rng = stream(Condition::WhiteBalance);
            let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            plan.white_balance = Some(WhiteBalancePlan {
                shift_k: sign * severity.pick([250.0, 500.0, 1000.0, 1500.0, 2200.0]),
                drift: severity.pick([0.1, 0.2, 0.25, 0.3, 0.35]),
                drift_period_s: rng.random_range(10.0..30.0),
                drift_phase: rng.random_range(0.0..core::f32::consts::TAU),
            });
        }
        if let Some(severity) = conditions.severity(Condition::MotionBlur) {
            plan.exposure_s = severity.pick([0.010, 0.020, 0.030, 0.040, 0.050]);
            plan.readout_s = severity.pick([0.010, 0.020, 0.030, 0.033, 0.033]);
        }
        if let Some(severity) = conditions.severity(Condition::Lens) {
            plan.vignetting = severity.pick([0.1, 0.2, 0.35, 0.5, 0.65]);
            plan.softness_px = severity.pick([0.5, 0.8, 1.2, 1.6, 2.2]);
        }
        plan
    }

    /// The effects on one frame of the camera at `rotation` (camera to field), given the
    /// camera's rotation a frame earlier (`previous`, `dt_s` before), for the frame of
    /// `sequence` of camera `camera_index` taken at `time_s`.
    #[allow(clippy::too_many_arguments)]
    pub fn frame(
        &self,
        camera_index: u32,
        sequence: u64,
        time_s: f32,
        rotation: Quat,
        previous: Option<(Quat, f32)>,
        size: (u32, u32),
        focal_px: (f32, f32),
    ) -> CameraEffects {
        let gain = self
            .exposure
            .as_ref()
            .map_or(1.0, |plan| 2f32.powf(plan.ev_at(time_s)));
        let white_balance = self
            .white_balance
            .map_or([1.0; 3], |plan| plan.gains_at(time_s));
        // Angular velocity in the camera frame, from the rotation a frame ago.
        let omega = match previous {
            Some((before, dt_s))
                if dt_s > 0.0 && (self.exposure_s > 0.0 || self.readout_s > 0.0) =>
            {
                let delta = rotation * before.inverse();
                let (axis, mut angle) = delta.to_axis_angle();
                if angle > core::f32::consts::PI {
                    angle -= core::f32::consts::TAU;
                }
                rotation.inverse() * (axis * (angle / dt_s))
            }
            _ => Vec3::ZERO,
        };
        // Samples: one per pixel of smear, eight or more where the lens is soft.
        let smear_px =
            omega.length() * (self.exposure_s + self.readout_s) * focal_px.0.max(focal_px.1);
        let mut samples = (smear_px.ceil() as u32).clamp(1, MAX_SAMPLES);
        if self.softness_px > 0.0 {
            samples = samples.max(8);
        }
        // Raw noise: read noise a quarter of the variance at mid-grey, shot noise the rest.
        let mid_linear = 0.5f32.powf(GAMMA);
        let slope = mid_linear.powf(1.0 / GAMMA - 1.0) / GAMMA;
        let sigma_linear = self.noise_mid_grey / slope;
        let read = 0.5 * sigma_linear;
        let shot = 0.75 * sigma_linear * sigma_linear / mid_linear;
        let noise_seed = splitmix(self.seed ^ (u64::from(camera_index) << 56) ^ sequence);
        CameraEffects {
            gain_contrast_noise: [gain, self.contrast, read * read, shot],
            white_balance: [white_balance[0], white_balance[1], white_balance[2], 0.0],
            omega_exposure: [omega.x, omega.y, omega.z, self.exposure_s],
            readout_vignetting_softness_samples: [
                self.readout_s,
                self.vignetting,
                self.softness_px,
                samples as f32,
            ],
            intrinsics: [focal_px.0, focal_px.1, size.0 as f32, size.1 as f32],
            seed: [noise_seed as u32, (noise_seed >> 32) as u32, 0, 0],
        }
    }
}

/// One frame's effects, laid out as the effects shader's uniform.
#[repr(C)]
#[derive(Clone, Copy, Debug, PartialEq, Pod, Zeroable)]
pub struct CameraEffects {
    /// Exposure gain (linear), contrast, read noise variance and shot noise factor (linear).
    pub gain_contrast_noise: [f32; 4],
    /// White balance gains, red, green, blue (linear).
    pub white_balance: [f32; 4],
    /// Angular velocity in the camera frame (rad/s; x optical axis, y left, z up) and the
    /// exposure time (s).
    pub omega_exposure: [f32; 4],
    /// Readout time (s), vignetting, lens softness (px), samples per pixel.
    pub readout_vignetting_softness_samples: [f32; 4],
    /// fx, fy (px), width, height.
    pub intrinsics: [f32; 4],
    /// The frame's noise seed.
    pub seed: [u32; 4],
}

/// The colour of a black body at `kelvin` in linear RGB (Tanner Helland's fit of the CIE
/// data in display values, linearised), good to a few percent between 1000 K and 12000 K.
pub fn blackbody_rgb(kelvin: f32) -> [f32; 3] {
    let t = kelvin.clamp(1000.0, 40_000.0) / 100.0;
    let red = if t <= 66.0 {
        255.0
    } else {
        329.698_73 * (t - 60.0).powf(-0.133_204_76)
    };
    let green = if t <= 66.0 {
        99.470_8 * t.ln() - 161.119_57
    } else {
        288.122_16 * (t - 60.0).powf(-0.075_514_846)
    };
    let blue = if t >= 66.0 {
        255.0
    } else if t <= 19.0 {
        0.0
    } else {
        138.517_73 * (t - 10.0).ln() - 305.044_8
    };
    [red, green, blue].map(|c: f32| (c.clamp(1.0, 255.0) / 255.0).powf(GAMMA))
}

fn splitmix(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::conditions::Severity;

    fn plan(text: &str, seed: u64) -> CameraEffectsPlan {
        text.parse::<Conditions>()
            .expect("parses")
            .resolve(seed)
            .camera
    }

    #[test]
    fn severity_three_is_at_least_what_the_issue_asks() {
        let exposure = plan("exposure:3", 1).exposure.expect("exposure");
        assert!(exposure.level_ev.abs() >= 0.7);
        assert!(plan("contrast:3", 1).contrast <= 0.5);
        assert!(plan("noise:3", 1).noise_mid_grey >= 20.0 / 255.0);
        assert!(plan("motion-blur:3", 1).exposure_s >= 0.030);
        let balance = plan("white-balance:3", 1).white_balance.expect("balance");
        assert!(balance.shift_k.abs() >= 1000.0);
    }

    #[test]
    fn harsher_severities_go_further() {
        for condition in [
            Condition::Exposure,
            Condition::Contrast,
            Condition::Noise,
            Condition::WhiteBalance,
            Condition::MotionBlur,
            Condition::Lens,
        ] {
            let strength = |level: u8| {
                let conditions = Conditions::single(condition, Severity::new(level).expect("1-5"));
                let p = conditions.resolve(7).camera;
                p.exposure.map_or(0.0, |e| e.level_ev.abs())
                    + (1.0 - p.contrast)
                    + p.noise_mid_grey
                    + p.white_balance.map_or(0.0, |w| w.shift_k.abs())
                    + p.exposure_s
                    + p.vignetting
            };
            for level in 1..5 {
                assert!(strength(level + 1) > strength(level), "{condition} {level}");
            }
        }
    }

    #[test]
    fn exposure_steps_and_hunts_around_its_level() {
        let exposure = plan("exposure:4", 3).exposure.expect("exposure");
        assert!(!exposure.steps.is_empty());
        let (at, offset) = exposure.steps[0];
        assert!((exposure.ev_at(at - 0.01) - exposure.level_ev).abs() < 1e-6);
        // Hunting: just after the step the error swings past the new level and settles.
        let settled = exposure.level_ev + offset;
        let swings: Vec<f32> = (1..8)
            .map(|k| exposure.ev_at(at + k as f32 / 30.0))
            .collect();
        assert!(
            swings.iter().any(|&ev| (ev - settled).abs() > 0.05),
            "{swings:?}"
        );
        assert!((exposure.ev_at(at + 0.99) - settled).abs() < 0.01);
    }

    #[test]
    fn warmer_light_reddens_and_keeps_green() {
        let warm = WhiteBalancePlan {
            shift_k: -1000.0,
            drift: 0.0,
            drift_period_s: 10.0,
            drift_phase: 0.0,
        }
        .gains_at(0.0);
        assert!((warm[1] - 1.0).abs() < 1e-6);
        assert!(warm[0] > 1.05 && warm[2] < 0.9, "{warm:?}");
    }

    #[test]
    fn a_turning_camera_gets_its_angular_velocity_and_more_samples() {
        let p = plan("motion-blur:3", 1);
        let before = Quat::from_rotation_z(0.0);
        let now = Quat::from_rotation_z(1.0 / 30.0);
        let effects = p.frame(
            0,
            5,
            0.2,
            now,
            Some((before, 1.0 / 30.0)),
            (640, 480),
            (550.0, 550.0),
        );
        let omega = effects.omega_exposure;
        // A turn about the field's z is about the camera's z (camera level here).
        assert!(
            (omega[2] - 1.0).abs() < 1e-3 && omega[0].abs() < 1e-4,
            "{omega:?}"
        );
        assert!(effects.readout_vignetting_softness_samples[3] >= 16.0);
        let still = p.frame(
            0,
            5,
            0.2,
            now,
            Some((now, 1.0 / 30.0)),
            (640, 480),
            (550.0, 550.0),
        );
        assert_eq!(still.readout_vignetting_softness_samples[3], 1.0);
    }

    #[test]
    fn noise_seeds_differ_by_frame_and_camera_and_repeat() {
        let p = plan("noise:3", 9);
        let frame = |camera, sequence| {
            p.frame(
                camera,
                sequence,
                0.0,
                Quat::IDENTITY,
                None,
                (640, 480),
                (1.0, 1.0),
            )
            .seed
        };
        assert_eq!(frame(0, 1), frame(0, 1));
        assert_ne!(frame(0, 1), frame(0, 2));
        assert_ne!(frame(0, 1), frame(1, 1));
    }
}
