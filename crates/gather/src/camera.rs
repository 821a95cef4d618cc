//! Cameras: perspective (eye, target, up, vertical field of view) and orthographic.
//!
//! Image coordinates are continuous: pixel `(i, j)` covers `[i, i+1] × [j, j+1]`, `(0, 0)` is the
//! top-left corner of the image, x grows to the right and y grows downwards. So the centre of
//! the top-left pixel is `ray(0.5, 0.5)`.

use glam::DVec3;
use medium::traversal::Ray;
use serde::{Deserialize, Serialize};

use crate::GatherError;

/// The projection of a camera as a scene states it (degrees, world-space heights); a
/// [`Camera`] turns it into a [`CameraProjection`].
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Projection {
    Perspective {
        fov_y_degrees: f64,
    },
    /// Orthographic with the given world-space image height.
    Orthographic {
        height: f64,
    },
}

/// A camera as a scene or a request states it: unchecked; [`Camera::from_spec`] validates it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CameraSpec {
    pub name: String,
    pub eye: DVec3,
    pub target: DVec3,
    pub up: DVec3,
    pub projection: Projection,
    pub width: u32,
    pub height: u32,
}

/// How rays leave the camera.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CameraProjection {
    /// Rays from the eye; `tan_half_fov_y` is `tan(fov_y / 2)`.
    Perspective { tan_half_fov_y: f64 },
    /// Parallel rays along the view direction from the plane through the eye; `height` is the
    /// world-space height of the image.
    Orthographic { height: f64 },
}

/// A validated camera with an orthonormal frame.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub name: String,
    pub width: u32,
    pub height: u32,
    pub eye: DVec3,
    /// Unit view direction (eye towards target).
    pub forward: DVec3,
    /// Unit vector to the image's right.
    pub right: DVec3,
    /// Unit vector to the image's top (the given `up` made orthogonal to `forward`).
    pub up: DVec3,
    pub projection: CameraProjection,
}

impl Camera {
    /// Builds a camera from a scene's `[[camera]]` entry, refusing degenerate ones.
    pub fn from_spec(spec: &CameraSpec) -> Result<Camera, GatherError> {
        Camera::new(
            &spec.name,
            spec.eye,
            spec.target,
            spec.up,
            spec.projection,
            spec.width,
            spec.height,
        )
    }

    /// A perspective camera; `fov_y_degrees` is the full vertical field of view.
    pub fn perspective(
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        fov_y_degrees: f64,
        width: u32,
        height: u32,
    ) -> Result<Camera, GatherError> {
        Camera::new(
            "perspective",
            eye,
            target,
            up,
            Projection::Perspective { fov_y_degrees },
            width,
            height,
        )
    }

    /// An orthographic camera whose image is `view_height` world units tall.
    pub fn orthographic(
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        view_height: f64,
        width: u32,
        height: u32,
    ) -> Result<Camera, GatherError> {
        Camera::new(
            "orthographic",
            eye,
            target,
            up,
            Projection::Orthographic {
                height: view_height,
            },
            width,
            height,
        )
    }

    fn new(
        name: &str,
        eye: DVec3,
        target: DVec3,
        up: DVec3,
        projection: Projection,
        width: u32,
        height: u32,
    ) -> Result<Camera, GatherError> {
        let err = |m: String| GatherError::camera(name, m);
        if width == 0 || height == 0 {
            return Err(err(format!(
                "image size {width}×{height} must be at least 1×1"
            )));
        }
        if !(eye.is_finite() && target.is_finite() && up.is_finite()) {
            return Err(err("eye, target and up must be finite".into()));
        }
        let view = target - eye;
        let distance = view.length();
        if !(distance > 1e-12 * (1.0 + eye.length())) {
            return Err(err(format!(
                "eye {eye} and target {target} coincide: no view direction"
            )));
        }
        let forward = view / distance;
        if !(up.length() > 0.0) {
            return Err(err("up vector is zero".into()));
        }
        let side = forward.cross(up.normalize());
        // sin of the angle between up and the view direction; below ~1e-6 rad the frame is
        // numerically meaningless.
        if side.length() < 1e-6 {
            return Err(err(format!(
                "up {up} is parallel to the view direction {forward}"
            )));
        }
        let right = side.normalize();
        let true_up = right.cross(forward);
        let projection = match projection {
            Projection::Perspective { fov_y_degrees } => {
                if !(fov_y_degrees > 0.0 && fov_y_degrees < 180.0) {
                    return Err(err(format!(
                        "fov_y {fov_y_degrees}° must lie strictly between 0 and 180"
                    )));
                }
                CameraProjection::Perspective {
                    tan_half_fov_y: (0.5 * fov_y_degrees.to_radians()).tan(),
                }
            }
            Projection::Orthographic { height: h } => {
                if !(h.is_finite() && h > 0.0) {
                    return Err(err(format!(
                        "orthographic image height {h} must be finite and positive"
                    )));
                }
                CameraProjection::Orthographic { height: h }
            }
        };
        Ok(Camera {
            name: name.to_string(),
            width,
            height,
            eye,
            forward,
            right,
            up: true_up,
            projection,
        })
    }

    /// Width over height.
    #[inline]
    pub fn aspect(&self) -> f64 {
        self.width as f64 / self.height as f64
    }

    /// A rectangle of pixels `[x0, x1) × [y0, y1)` outside which no ray of this camera meets
    /// the box `[lo, hi]` (conservative: the bounds of the corners' projections, one pixel
    /// wider). The whole image when the box reaches behind a perspective eye.
    pub fn pixel_bounds(&self, lo: DVec3, hi: DVec3) -> [u32; 4] {
        let whole = [0, 0, self.width, self.height];
        let (mut min, mut max) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for c in 0..8 {
            let corner = DVec3::new(
                if c & 1 == 0 { lo.x } else { hi.x },
                if c & 2 == 0 { lo.y } else { hi.y },
                if c & 4 == 0 { lo.z } else { hi.z },
            );
            let v = corner - self.eye;
            // Image-plane coordinates in [-1, 1] at the image edges.
            let (sx, sy) = match self.projection {
                CameraProjection::Perspective { tan_half_fov_y } => {
                    let depth = v.dot(self.forward);
                    if !(depth > 1e-9 * (1.0 + v.length())) {
                        return whole;
                    }
                    let scale = 1.0 / (depth * tan_half_fov_y);
                    (
                        v.dot(self.right) * scale / self.aspect(),
                        v.dot(self.up) * scale,
                    )
                }
                CameraProjection::Orthographic { height } => {
                    let half = 0.5 * height;
                    (
                        v.dot(self.right) / (half * self.aspect()),
                        v.dot(self.up) / half,
                    )
                }
            };
            let p = [
                (sx + 1.0) * 0.5 * self.width as f64,
                (1.0 - sy) * 0.5 * self.height as f64,
            ];
            for a in 0..2 {
                min[a] = min[a].min(p[a]);
                max[a] = max[a].max(p[a]);
            }
        }
        if !(min[0].is_finite() && min[1].is_finite() && max[0].is_finite() && max[1].is_finite()) {
            return whole;
        }
        let span = |lo: f64, hi: f64, n: u32| {
            let a = (lo.floor() - 1.0).clamp(0.0, n as f64) as u32;
            let b = (hi.ceil() + 1.0).clamp(0.0, n as f64) as u32;
            (a, b.max(a))
        };
        let (x0, x1) = span(min[0], max[0], self.width);
        let (y0, y1) = span(min[1], max[1], self.height);
        [x0, y0, x1, y1]
    }

    /// The ray through continuous image point `(px, py)` (pixels; `(0, 0)` top-left corner,
    /// `(width, height)` bottom-right). Its direction has unit length.
    #[inline]
    pub fn ray(&self, px: f64, py: f64) -> Ray {
        // Image-plane coordinates in [-1, 1] (x right, y up).
        let sx = 2.0 * px / self.width as f64 - 1.0;
        let sy = 1.0 - 2.0 * py / self.height as f64;
        match self.projection {
            CameraProjection::Perspective { tan_half_fov_y } => {
                let dir = self.forward
                    + self.right * (sx * tan_half_fov_y * self.aspect())
                    + self.up * (sy * tan_half_fov_y);
                Ray::new(self.eye, dir)
            }
            CameraProjection::Orthographic { height } => {
                let half = 0.5 * height;
                let origin =
                    self.eye + self.right * (sx * half * self.aspect()) + self.up * (sy * half);
                Ray {
                    origin,
                    direction: self.forward,
                }
            }
        }
    }
}
