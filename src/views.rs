//! Views from the command line: which camera a render uses (a scene camera, overridden by
//! `--eye`, `--target`, …), orbits around the volume, and the output path of each view.

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use glam::DVec3;
use scene::{CameraSpec, Projection};

use crate::cli::ViewArgs;

/// The camera to use: the scene's (by name, or its first), with command-line overrides.
pub fn choose_camera(
    cameras: &[CameraSpec],
    name: Option<&str>,
    view: &ViewArgs,
    grid_center: DVec3,
) -> Result<CameraSpec> {
    let base = match name {
        Some(n) => cameras
            .iter()
            .find(|c| c.name == n)
            .cloned()
            .with_context(|| {
                let known: Vec<&str> = cameras.iter().map(|c| c.name.as_str()).collect();
                format!(
                    "no camera named `{n}` (the scene has: {})",
                    known.join(", ")
                )
            })?,
        None => match cameras.first() {
            Some(c) => c.clone(),
            None if view.eye.is_some() => CameraSpec {
                name: "command-line".into(),
                eye: DVec3::ZERO,
                target: grid_center,
                up: DVec3::Z,
                projection: Projection::Perspective {
                    fov_y_degrees: 40.0,
                },
                width: 512,
                height: 384,
            },
            None => bail!("no camera: the scene has none; give --eye (and --target, --fov)"),
        },
    };
    Ok(apply_view(base, view))
}

/// Command-line camera overrides on top of a scene camera.
pub fn apply_view(mut cam: CameraSpec, view: &ViewArgs) -> CameraSpec {
    if let Some(e) = view.eye {
        cam.eye = DVec3::from(e);
        cam.name = "command-line".into();
    }
    if let Some(t) = view.target {
        cam.target = DVec3::from(t);
    }
    if let Some(u) = view.up {
        cam.up = DVec3::from(u);
    }
    if let Some(f) = view.fov {
        cam.projection = Projection::Perspective { fov_y_degrees: f };
    }
    if let Some(w) = view.width {
        cam.width = w;
    }
    if let Some(h) = view.height {
        cam.height = h;
    }
    cam
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
