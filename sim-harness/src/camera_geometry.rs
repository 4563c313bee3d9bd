//! Where the Nao's cameras sit and what they see: read from `config/nao_cameras.toml`, the one
//! place those numbers live.
//!
//! The file gives each camera's mounting with the head straight, and one fixed HeadPitch
//! for the whole run. The pitch turns both cameras about the head's pitch axis, as the
//! Nao's joint does, so a pitched head moves the cameras as well as tilting them. Nothing
//! reads ground truth to set it: it is configuration, the same for every episode.

use std::path::Path;

use dribble_controller::CameraPosition;
use serde::{Deserialize, Serialize};

const NAO_CAMERAS: &str = include_str!("../config/nao_cameras.toml");

/// One camera's mounting and intrinsics.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraMount {
    pub width: u32,
    pub height: u32,
    /// Ahead of the point between the feet, metres.
    pub forward_m: f32,
    /// Above the ground, metres.
    pub height_m: f32,
    /// Tilt of the optical axis below the horizon, degrees.
    pub pitch_down_deg: f32,
    pub horizontal_fov_deg: f32,
    pub vertical_fov_deg: f32,
}

impl CameraMount {
    /// Focal length in pixels along the image's x axis (from the horizontal field of view).
    pub fn fx(&self) -> f32 {
        self.width as f32 / 2.0 / (self.horizontal_fov_deg.to_radians() / 2.0).tan()
    }

    /// Focal length in pixels along the image's y axis (from the vertical field of view).
    pub fn fy(&self) -> f32 {
        self.height as f32 / 2.0 / (self.vertical_fov_deg.to_radians() / 2.0).tan()
    }
}

/// The Nao's HeadPitch joint range, degrees (positive looks down).
pub const HEAD_PITCH_RANGE_DEG: core::ops::RangeInclusive<f32> = -38.5..=29.5;

/// The head's pitch joint: where its axis lies and how far it is turned.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct HeadPitch {
    /// HeadPitch, degrees, positive down; within [`HEAD_PITCH_RANGE_DEG`].
    pub pitch_deg: f32,
    /// The pitch axis ahead of the point between the feet, metres.
    pub joint_forward_m: f32,
    /// The pitch axis above the ground, metres.
    pub joint_height_m: f32,
}

impl HeadPitch {
    /// `mount` (given with the head straight) after the head turns by `pitch_deg`: the
    /// camera's offset from the joint turns with it and its axis tilts by the same angle.
    fn apply(&self, mount: &CameraMount) -> CameraMount {
        let (sin, cos) = self.pitch_deg.to_radians().sin_cos();
        let dx = mount.forward_m - self.joint_forward_m;
        let dz = mount.height_m - self.joint_height_m;
        CameraMount {
            forward_m: self.joint_forward_m + dx * cos + dz * sin,
            height_m: self.joint_height_m - dx * sin + dz * cos,
            pitch_down_deg: mount.pitch_down_deg + self.pitch_deg,
            ..*mount
        }
    }
}

/// `nao_cameras.toml` as written: the mounts with the head straight, and the head.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
struct CameraFile {
    frame_rate_hz: f32,
    head: HeadPitch,
    top: CameraMount,
    bottom: CameraMount,
}

/// Both cameras and their timing.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct CameraGeometry {
    pub frame_rate_hz: f32,
    pub head: HeadPitch,
    /// The top camera with the head pitched by `head.pitch_deg`.
    pub top: CameraMount,
    /// The bottom camera with the head pitched by `head.pitch_deg`.
    pub bottom: CameraMount,
    /// Both mounts with the head straight, as the file gives them.
    #[serde(skip)]
    straight: [CameraMount; 2],
}

/// The camera configuration could not be used.
#[derive(Debug, thiserror::Error)]
pub enum CameraGeometryError {
    #[error("cannot read {path}: {source}")]
    Io {
        path: String,
        source: std::io::Error,
    },
    #[error("bad camera configuration {path}: {message}")]
    Invalid { path: String, message: String },
}

impl CameraGeometry {
    /// The Nao's cameras as `config/nao_cameras.toml` gives them (built into the binary).
    pub fn nao() -> Self {
        Self::parse(NAO_CAMERAS, "config/nao_cameras.toml")
            .unwrap_or_else(|error| panic!("the built-in camera configuration is broken: {error}"))
    }

    pub fn load(path: &Path) -> Result<Self, CameraGeometryError> {
        let text = std::fs::read_to_string(path).map_err(|source| CameraGeometryError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&text, &path.display().to_string())
    }

    pub fn parse(text: &str, path: &str) -> Result<Self, CameraGeometryError> {
        let invalid = |message: String| CameraGeometryError::Invalid {
            path: path.to_owned(),
            message,
        };
        let file: CameraFile = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
        for (name, mount, size) in [
            ("top", file.top, (640, 480)),
            ("bottom", file.bottom, (320, 240)),
        ] {
            if (mount.width, mount.height) != size {
                return Err(invalid(format!(
                    "the {name} camera must be {}x{} (the frame contract), found {}x{}",
                    size.0, size.1, mount.width, mount.height
                )));
            }
            let fovs_ok = [mount.horizontal_fov_deg, mount.vertical_fov_deg]
                .iter()
                .all(|f| f.is_finite() && *f > 1.0 && *f < 170.0);
            if !fovs_ok || mount.height_m.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
                return Err(invalid(format!(
                    "the {name} camera's field of view or height is not sensible"
                )));
            }
        }
        if file.frame_rate_hz.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return Err(invalid("frame_rate_hz must be positive".into()));
        }
        let straight = Self {
            frame_rate_hz: file.frame_rate_hz,
            head: HeadPitch {
                pitch_deg: 0.0,
                ..file.head
            },
            top: file.top,
            bottom: file.bottom,
            straight: [file.top, file.bottom],
        };
        straight
            .with_head_pitch(file.head.pitch_deg)
            .map_err(|e| invalid(e.to_string()))
    }

    /// The same cameras with the head pitched by `pitch_deg` instead.
    pub fn with_head_pitch(&self, pitch_deg: f32) -> Result<Self, CameraGeometryError> {
        if !HEAD_PITCH_RANGE_DEG.contains(&pitch_deg) {
            return Err(CameraGeometryError::Invalid {
                path: "head".into(),
                message: format!(
                    "head pitch {pitch_deg} deg is outside the Nao's HeadPitch range {:.1}..{:.1} deg",
                    HEAD_PITCH_RANGE_DEG.start(),
                    HEAD_PITCH_RANGE_DEG.end()
                ),
            });
        }
        let head = HeadPitch {
            pitch_deg,
            ..self.head
        };
        Ok(Self {
            head,
            top: head.apply(&self.straight[0]),
            bottom: head.apply(&self.straight[1]),
            ..*self
        })
    }

    pub fn mount(&self, camera: CameraPosition) -> &CameraMount {
        match camera {
            CameraPosition::Top => &self.top,
            CameraPosition::Bottom => &self.bottom,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_built_in_configuration_is_the_design_documents() {
        let geometry = CameraGeometry::nao();
        assert_eq!((geometry.top.width, geometry.top.height), (640, 480));
        let straight = geometry.with_head_pitch(0.0).expect("in range");
        assert_eq!(straight.bottom.pitch_down_deg, 39.7);
        assert!(HEAD_PITCH_RANGE_DEG.contains(&geometry.head.pitch_deg));
        // 61 degrees across 640 pixels.
        assert!(
            (geometry.top.fx() - 543.3).abs() < 0.5,
            "{}",
            geometry.top.fx()
        );
    }

    #[test]
    fn pitching_the_head_turns_both_cameras_about_its_joint() {
        let straight = CameraGeometry::nao()
            .with_head_pitch(0.0)
            .expect("in range");
        let pitched = straight.with_head_pitch(20.0).expect("in range");
        let head = straight.head;
        for (before, after) in [
            (straight.top, pitched.top),
            (straight.bottom, pitched.bottom),
        ] {
            assert!((after.pitch_down_deg - before.pitch_down_deg - 20.0).abs() < 1e-4);
            // The distance to the joint is kept; looking down moves the camera down.
            let reach = |m: &CameraMount| {
                (m.forward_m - head.joint_forward_m).hypot(m.height_m - head.joint_height_m)
            };
            assert!((reach(&after) - reach(&before)).abs() < 1e-5);
            assert!(after.height_m < before.height_m);
        }
        let error = straight
            .with_head_pitch(35.0)
            .expect_err("past the joint's limit");
        assert!(error.to_string().contains("HeadPitch range"), "{error}");
    }

    #[test]
    fn a_camera_of_the_wrong_size_is_refused() {
        let text = NAO_CAMERAS.replace("width = 320", "width = 640");
        let error = CameraGeometry::parse(&text, "x.toml").expect_err("wrong size");
        assert!(
            error
                .to_string()
                .contains("the bottom camera must be 320x240"),
            "{error}"
        );
    }
}
