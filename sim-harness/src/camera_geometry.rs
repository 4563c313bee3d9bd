//! Where the Nao's cameras sit and what they see: read from `config/nao_cameras.toml`, the one
//! place those numbers live.

use std::path::Path;

use dribble_controller::CameraPosition;
use serde::Deserialize;

const NAO_CAMERAS: &str = include_str!("../config/nao_cameras.toml");

/// One camera's mounting and intrinsics.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
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

/// Both cameras and their timing.
#[derive(Clone, Copy, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CameraGeometry {
    pub frame_rate_hz: f32,
    pub top: CameraMount,
    pub bottom: CameraMount,
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
        let geometry: Self = toml::from_str(text).map_err(|e| invalid(e.to_string()))?;
        for (name, mount, size) in [
            ("top", geometry.top, (640, 480)),
            ("bottom", geometry.bottom, (320, 240)),
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
        if geometry.frame_rate_hz.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
            return Err(invalid("frame_rate_hz must be positive".into()));
        }
        Ok(geometry)
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
        assert_eq!(geometry.bottom.pitch_down_deg, 39.7);
        // 61 degrees across 640 pixels.
        assert!(
            (geometry.top.fx() - 543.3).abs() < 0.5,
            "{}",
            geometry.top.fx()
        );
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
