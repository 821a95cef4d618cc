//! Views: which camera a render uses (a scene camera by name, overridden by the command
//! line's `--eye`, `--target`, … or the service's query), orbits around the volume, and the
//! output path of each view.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use glam::DVec3;
use medium::Grid;
use scene::{CameraSpec, Projection};

use crate::cli::ViewArgs;

/// What a request (command-line flags or HTTP query) says about the camera: a scene camera
/// by name, and overrides of its parts. The command line and the service read their own
/// syntax into this and share [`CameraRequest::camera`], so both have the same defaults.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct CameraRequest {
    pub name: Option<String>,
    pub eye: Option<DVec3>,
    pub target: Option<DVec3>,
    pub up: Option<DVec3>,
    pub fov_y_degrees: Option<f64>,
    pub width: Option<u32>,
    pub height: Option<u32>,
}

impl CameraRequest {
    /// This request with every part `other` gives replaced by `other`'s (the name too).
    pub fn merge(&mut self, other: &CameraRequest) {
        if other.name.is_some() {
            self.name.clone_from(&other.name);
        }
        self.eye = other.eye.or(self.eye);
        self.target = other.target.or(self.target);
        self.up = other.up.or(self.up);
        self.fov_y_degrees = other.fov_y_degrees.or(self.fov_y_degrees);
        self.width = other.width.or(self.width);
        self.height = other.height.or(self.height);
    }

    /// The overrides of the command line's view flags.
    pub fn from_args(name: Option<&str>, view: &ViewArgs) -> CameraRequest {
        CameraRequest {
            name: name.map(str::to_string),
            eye: view.eye.map(DVec3::from),
            target: view.target.map(DVec3::from),
            up: view.up.map(DVec3::from),
            fov_y_degrees: view.fov,
            width: view.width,
            height: view.height,
        }
    }

    /// The camera to use: the named scene camera, else the scene's first, else one looking at
    /// the volume's centre from in front (−y) at 2.5 times its largest extent (up +z, 40°,
    /// 512×384); then the overrides. The result is checked as a render would check it.
    pub fn camera(&self, cameras: &[CameraSpec], grid: &Grid) -> Result<CameraSpec> {
        let extent = DVec3::new(
            grid.dims[0] as f64,
            grid.dims[1] as f64,
            grid.dims[2] as f64,
        ) * grid.cell_size;
        let center = extent * 0.5;
        let mut cam = match &self.name {
            Some(n) => cameras
                .iter()
                .find(|c| &c.name == n)
                .cloned()
                .with_context(|| {
                    let known: Vec<&str> = cameras.iter().map(|c| c.name.as_str()).collect();
                    format!(
                        "no camera named `{n}` (the scene has: {})",
                        if known.is_empty() {
                            "none".to_string()
                        } else {
                            known.join(", ")
                        }
                    )
                })?,
            None => cameras.first().cloned().unwrap_or(CameraSpec {
                name: "default".into(),
                eye: center + DVec3::new(0.0, -2.5 * extent.max_element(), 0.0),
                target: center,
                up: DVec3::Z,
                projection: Projection::Perspective {
                    fov_y_degrees: 40.0,
                },
                width: 512,
                height: 384,
            }),
        };
        self.apply(&mut cam);
        gather::Camera::from_spec(&cam).map_err(|e| {
            let hint = if self.eye.is_some() || self.target.is_some() {
                " (give an up vector across the view direction)"
            } else {
                ""
            };
            anyhow::anyhow!("camera `{}`: {e}{hint}", cam.name)
        })?;
        Ok(cam)
    }

    /// The overrides on top of `cam`; a new eye makes it a camera of its own.
    pub fn apply(&self, cam: &mut CameraSpec) {
        if let Some(e) = self.eye {
            cam.eye = e;
            cam.name = "custom".into();
        }
        if let Some(t) = self.target {
            cam.target = t;
        }
        if let Some(u) = self.up {
            cam.up = u;
        }
        if let Some(f) = self.fov_y_degrees {
            cam.projection = Projection::Perspective { fov_y_degrees: f };
        }
        if let Some(w) = self.width {
            cam.width = w;
        }
        if let Some(h) = self.height {
            cam.height = h;
        }
    }
}

/// `n` cameras on a horizontal circle (about the camera's up axis) around its target, keeping
/// the base camera's distance and elevation.
pub fn orbit_cameras(base: &CameraSpec, n: u32) -> Vec<CameraSpec> {
    let up = base.up.normalize();
    let offset = base.eye - base.target;
    let along = up * offset.dot(up);
    let radial = offset - along;
    (0..n)
        .map(|i| {
            let angle = std::f64::consts::TAU * i as f64 / n as f64;
            let rotated = glam::DQuat::from_axis_angle(up, angle) * radial;
            CameraSpec {
                name: format!("{}_{i:03}", base.name),
                eye: base.target + along + rotated,
                ..base.clone()
            }
        })
        .collect()
}

/// Output paths for several views: `DIR/NAME.png` when `-o` names a folder, else
/// `STEM_NAME.EXT` beside it (an orbit's names are `CAMERA_000`, `CAMERA_001`, …).
pub fn view_outputs(out: &Path, names: &[String], into_directory: bool) -> Vec<PathBuf> {
    names
        .iter()
        .map(|n| {
            if into_directory {
                out.join(format!("{n}.png"))
            } else {
                let stem = out
                    .file_stem()
                    .map(|s| s.to_string_lossy().into_owned())
                    .unwrap_or_default();
                let ext = out
                    .extension()
                    .map(|e| e.to_string_lossy().into_owned())
                    .unwrap_or_else(|| "png".into());
                out.with_file_name(format!("{stem}_{n}.{ext}"))
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn orbit_keeps_distance_and_height() {
        let base = CameraSpec {
            name: "front".into(),
            eye: DVec3::new(10.0, -20.0, 15.0),
            target: DVec3::new(10.0, 10.0, 5.0),
            up: DVec3::Z,
            projection: Projection::Perspective {
                fov_y_degrees: 40.0,
            },
            width: 8,
            height: 8,
        };
        let cams = orbit_cameras(&base, 4);
        assert_eq!(cams.len(), 4);
        let d0 = (base.eye - base.target).length();
        for c in &cams {
            assert!(((c.eye - c.target).length() - d0).abs() < 1e-9);
            assert!((c.eye.z - base.eye.z).abs() < 1e-9);
        }
        assert!((cams[0].eye - base.eye).length() < 1e-9);
        assert!((cams[2].eye - DVec3::new(10.0, 40.0, 15.0)).length() < 1e-9);
    }
}
