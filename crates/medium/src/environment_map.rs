//! An environment map: the light arriving from every direction at infinity as an image — an
//! equirectangular (latitude–longitude) panorama of linear RGB radiance, as HDR sky captures
//! are stored.
//!
//! Orientation (docs/scene-format.md): row 0 is the zenith (`up`), the last row the nadir,
//! rows equally spaced in the polar angle; columns equally spaced in azimuth, counter-clockwise
//! about `up` (seen from above), column `x`'s centre at azimuth `rotation + 360° (x + ½)/width`
//! from the same horizontal reference axis as the sky's (the projection of +x, of +y when `up`
//! is along x). Lookups are bilinear between texel centres, wrapping in azimuth.
//!
//! Small bright sources (a sun disc) are split off as directional lights by the scene
//! ([`EnvironmentMap::split_bright_sources`]), whose first bounce renders take exactly.
//! The solvers integrate an environment over a few hundred directions; sampling a detailed map
//! at so few points would alias (a small bright source would be missed or counted many times),
//! so they take each direction bin's mean over the texels in it
//! ([`EnvironmentMap::for_each_sample`] gives them the texels, split finely enough, with
//! their solid angles). Renders and the Monte Carlo methods look the map up directly.

use std::f64::consts::PI;

use glam::DVec3;

use crate::MediumError;

/// Most texels a map may hold (a 16k × 8k panorama).
pub const MAX_TEXELS: usize = 1 << 27;

/// A texel is a small bright source, split off as a light by
/// [`EnvironmentMap::split_bright_sources`], when its luminance is over this many times the
/// map's mean (a sun in a sky capture is 10⁴–10⁵ times).
pub const BRIGHT_SOURCE_RATIO: f64 = 100.0;

/// Bright texels within this angle (degrees) of a source's first texel join it (a sun disc
/// spans half a degree).
pub const BRIGHT_SOURCE_RADIUS_DEGREES: f64 = 2.0;

/// Most bright sources split off one map; the rest stay in the map.
pub const MAX_BRIGHT_SOURCES: usize = 8;

/// A small bright source split off a map: the light it sends, as a directional light's.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BrightSource {
    /// The unit vector toward the source (its texels' power-weighted mean direction).
    pub to_source: DVec3,
    /// Its irradiance on a plane facing it (the grey part of its texels' radiance × solid
    /// angle, summed).
    pub irradiance: f64,
}

/// Largest angular size of the pieces [`EnvironmentMap::for_each_sample`] splits texels into
/// (degrees): small next to a direction bin, so each piece lies in one.
const SAMPLE_DEGREES: f64 = 1.0;

/// An equirectangular environment map (see the module doc), checked and ready to look up.
///
/// # Invariants
/// `width × height` texels, each finite and ≥ 0 per channel; `scale` finite and ≥ 0; `up` a
/// unit vector; `rotation_degrees` finite (checked by [`EnvironmentMap::new`]).
#[derive(Clone, Debug, PartialEq)]
pub struct EnvironmentMap {
    width: usize,
    height: usize,
    texels: Vec<[f32; 3]>,
    up: DVec3,
    rotation_degrees: f64,
    scale: f64,
    /// The horizontal frame: azimuth 0 of column space (the reference axis turned by the
    /// rotation) and `up × e1`.
    e1: DVec3,
    e2: DVec3,
    /// The largest radiance per channel (times `scale`).
    max_rgb: [f64; 3],
}

impl EnvironmentMap {
    /// A map of `width × height` texels (row 0 the zenith, x fastest) of linear RGB radiance,
    /// multiplied by `scale`, turned by `rotation_degrees` about `up`.
    pub fn new(
        width: usize,
        height: usize,
        texels: Vec<[f32; 3]>,
        up: DVec3,
        rotation_degrees: f64,
        scale: f64,
    ) -> Result<Self, MediumError> {
        let bad = |what: &'static str, message: String| Err(MediumError::invalid(what, message));
        if width == 0 || height == 0 {
            return bad(
                "environment map",
                format!("{width} × {height} texels: both must be at least 1"),
            );
        }
        let count = width.checked_mul(height).filter(|&n| n <= MAX_TEXELS);
        if count.is_none() {
            return bad(
                "environment map",
                format!("{width} × {height} texels: at most {MAX_TEXELS}"),
            );
        }
        if texels.len() != width * height {
            return bad(
                "environment map",
                format!("{} texels for a {width} × {height} map", texels.len()),
            );
        }
        if let Some((i, t)) = texels
            .iter()
            .enumerate()
            .find(|(_, t)| t.iter().any(|v| !(v.is_finite() && *v >= 0.0)))
        {
            return bad(
                "environment map",
                format!(
                    "texel ({}, {}) is {t:?}: radiance must be finite and ≥ 0",
                    i % width,
                    i / width
                ),
            );
        }
        if !(scale.is_finite() && scale >= 0.0) {
            return bad(
                "environment scale",
                format!("{scale} must be finite and ≥ 0"),
            );
        }
        if !rotation_degrees.is_finite() {
            return bad(
                "environment rotation_degrees",
                format!("{rotation_degrees} must be finite"),
            );
        }
        let len = up.length();
        if !(len.is_finite() && len > 1e-12) {
            return bad("environment up", format!("{up:?} has no direction"));
        }
        let up = up / len;
        let (r1, r2) = crate::environment::horizontal_frame(up);
        let turn = rotation_degrees.to_radians();
        let e1 = r1 * turn.cos() + r2 * turn.sin();
        let e2 = up.cross(e1);
        let max_rgb = max_rgb(&texels, scale);
        Ok(EnvironmentMap {
            width,
            height,
            texels,
            up,
            rotation_degrees,
            scale,
            e1,
            e2,
            max_rgb,
        })
    }

    /// [`new`](Self::new) from `width × height` pixels of `channels` interleaved values
    /// (1: grey, 3: RGB), as image files and the solution file hold them.
    pub fn from_interleaved(
        width: usize,
        height: usize,
        channels: usize,
        values: &[f32],
        up: DVec3,
        rotation_degrees: f64,
        scale: f64,
    ) -> Result<Self, MediumError> {
        let texels = match channels {
            1 => values.iter().map(|&v| [v; 3]).collect(),
            3 => values.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
            n => {
                return Err(MediumError::invalid(
                    "environment map",
                    format!("{n} channels: expected 1 (grey) or 3 (RGB)"),
                ))
            }
        };
        Self::new(width, height, texels, up, rotation_degrees, scale)
    }

    /// The unit direction toward polar angle `theta` from `up` and azimuth `phi` (map space).
    fn direction(&self, theta: f64, phi: f64) -> DVec3 {
        let (s, c) = theta.sin_cos();
        self.up * c + (self.e1 * phi.cos() + self.e2 * phi.sin()) * s
    }

    /// Calls `f(from, solid_angle, rgb)` for pieces of every non-black texel (each split into
    /// pieces of at most about a degree, so each lies in one of a solver's direction bins):
    /// the unit direction toward the piece's centre, its exact solid angle and the texel's
    /// radiance. The solid angles add up to 4π over all texels, so `Σ rgb Ω` is the map's
    /// irradiance integral exactly.
    pub fn for_each_sample(&self, mut f: impl FnMut(DVec3, f64, [f64; 3])) {
        let (dtheta, dphi) = (PI / self.height as f64, 2.0 * PI / self.width as f64);
        let split = |angle: f64| (angle.to_degrees() / SAMPLE_DEGREES).ceil().max(1.0) as usize;
        let (sy, sx) = (split(dtheta), split(dphi));
        for y in 0..self.height {
            for sub_y in 0..sy {
                let t0 = dtheta * (y as f64 + sub_y as f64 / sy as f64);
                let t1 = t0 + dtheta / sy as f64;
                let band = (t0.cos() - t1.cos()) * dphi / sx as f64;
                let theta = 0.5 * (t0 + t1);
                for x in 0..self.width {
                    let t = self.texels[y * self.width + x];
                    if t == [0.0; 3] {
                        continue;
                    }
                    let rgb = t.map(|v| v as f64 * self.scale);
                    for sub_x in 0..sx {
                        let phi = dphi * (x as f64 + (sub_x as f64 + 0.5) / sx as f64);
                        f(self.direction(theta, phi), band, rgb);
                    }
                }
            }
        }
    }

    pub fn width(&self) -> usize {
        self.width
    }

    pub fn height(&self) -> usize {
        self.height
    }

    /// The texels as given (before `scale`), row 0 the zenith.
    pub fn texels(&self) -> &[[f32; 3]] {
        &self.texels
    }

    pub fn up(&self) -> DVec3 {
        self.up
    }

    pub fn rotation_degrees(&self) -> f64 {
        self.rotation_degrees
    }

    pub fn scale(&self) -> f64 {
        self.scale
    }

    /// The largest radiance per channel.
    pub fn max_rgb(&self) -> [f64; 3] {
        self.max_rgb
    }

    /// The radiance of every texel (times `scale`), when all are the same: the map is then a
    /// uniform environment, and the solvers treat it as one (which keeps the white furnace
    /// exact).
    pub fn uniform_rgb(&self) -> Option<[f64; 3]> {
        let first = self.texels[0];
        self.texels
            .iter()
            .all(|t| *t == first)
            .then(|| first.map(|v| v as f64 * self.scale))
    }

    /// Whether any texel's channels differ.
    pub fn is_coloured(&self) -> bool {
        self.texels.iter().any(|t| t[0] != t[1] || t[1] != t[2])
    }

    /// The map without its small bright sources, and those sources as directional lights: every
    /// texel brighter (luminance) than [`BRIGHT_SOURCE_RATIO`] times the map's mean, grouped
    /// into sources of texels within [`BRIGHT_SOURCE_RADIUS_DEGREES`] of each source's
    /// brightest (at most [`MAX_BRIGHT_SOURCES`]). A source takes the grey part of its texels,
    /// the least of their three channels, which leaves the rest of their colour (≥ 0) in the
    /// map: no light is lost or counted twice, and a white sun leaves nothing. A light's first
    /// bounce is exact in the render, where a map's is spread over a solver's direction bin,
    /// which is why a sun disc should be a light.
    pub fn split_bright_sources(mut self) -> (EnvironmentMap, Vec<BrightSource>) {
        let mut texels = std::mem::take(&mut self.texels);
        let (dtheta, dphi) = (PI / self.height as f64, 2.0 * PI / self.width as f64);
        let solid_angle = |y: usize| (dtheta * y as f64).cos() - (dtheta * (y + 1) as f64).cos();
        let lum = |t: &[f32; 3]| crate::environment::luminance(&t.map(|v| v as f64));
        let mut mean = 0.0;
        for (i, t) in texels.iter().enumerate() {
            mean += lum(t) * solid_angle(i / self.width) * dphi;
        }
        mean /= 4.0 * PI;
        let threshold = BRIGHT_SOURCE_RATIO * mean;
        let mut bright: Vec<usize> = (0..texels.len())
            .filter(|&i| mean > 0.0 && lum(&texels[i]) > threshold)
            .collect();
        // Brightest first: each source starts at its brightest texel.
        bright.sort_by(|&a, &b| lum(&texels[b]).total_cmp(&lum(&texels[a])));
        let centre = |i: usize| {
            let (x, y) = (i % self.width, i / self.width);
            self.direction(dtheta * (y as f64 + 0.5), dphi * (x as f64 + 0.5))
        };
        let cos_radius = BRIGHT_SOURCE_RADIUS_DEGREES.to_radians().cos();
        let mut seeds: Vec<DVec3> = Vec::new();
        let mut sums: Vec<(DVec3, f64)> = Vec::new();
        for i in bright {
            let d = centre(i);
            let k = match seeds.iter().position(|s| s.dot(d) >= cos_radius) {
                Some(k) => k,
                None if seeds.len() < MAX_BRIGHT_SOURCES => {
                    seeds.push(d);
                    sums.push((DVec3::ZERO, 0.0));
                    seeds.len() - 1
                }
                None => continue,
            };
            let grey = texels[i].iter().copied().fold(f32::INFINITY, f32::min);
            let power = grey as f64 * self.scale * solid_angle(i / self.width) * dphi;
            sums[k].0 += d * power;
            sums[k].1 += power;
            for v in &mut texels[i] {
                *v -= grey;
            }
        }
        let sources = sums
            .into_iter()
            .filter(|(_, e)| *e > 0.0)
            .map(|(d, e)| BrightSource {
                to_source: d.normalize(),
                irradiance: e,
            })
            .collect();
        self.max_rgb = max_rgb(&texels, self.scale);
        self.texels = texels;
        (self, sources)
    }

    /// Radiance (linear RGB) arriving from unit direction `from` (pointing at the sky).
    pub fn rgb_from(&self, from: DVec3) -> [f64; 3] {
        let cos_theta = from.dot(self.up).clamp(-1.0, 1.0);
        let theta = cos_theta.acos();
        let phi = from
            .dot(self.e2)
            .atan2(from.dot(self.e1))
            .rem_euclid(2.0 * PI);
        let u = phi / (2.0 * PI) * self.width as f64 - 0.5;
        let v = (theta / PI * self.height as f64 - 0.5).clamp(0.0, (self.height - 1) as f64);
        let x0 = u.floor();
        let fx = u - x0;
        let x0 = (x0 as i64).rem_euclid(self.width as i64) as usize;
        let x1 = (x0 + 1) % self.width;
        let y0 = (v.floor() as usize).min(self.height - 1);
        let y1 = (y0 + 1).min(self.height - 1);
        let fy = v - y0 as f64;
        let texel = |x: usize, y: usize| self.texels[y * self.width + x];
        let mut rgb = [0.0; 3];
        for (k, c) in rgb.iter_mut().enumerate() {
            let top = (1.0 - fx) * texel(x0, y0)[k] as f64 + fx * texel(x1, y0)[k] as f64;
            let bottom = (1.0 - fx) * texel(x0, y1)[k] as f64 + fx * texel(x1, y1)[k] as f64;
            *c = self.scale * ((1.0 - fy) * top + fy * bottom);
        }
        rgb
    }
}

/// The largest radiance per channel of `texels` times `scale`.
fn max_rgb(texels: &[[f32; 3]], scale: f64) -> [f64; 3] {
    let mut max = [0.0f64; 3];
    for t in texels {
        for (m, v) in max.iter_mut().zip(t) {
            *m = m.max(*v as f64 * scale);
        }
    }
    max
}

#[cfg(test)]
mod tests {
    use super::*;

    fn map(width: usize, height: usize, f: impl Fn(usize, usize) -> f32) -> EnvironmentMap {
        let texels = (0..width * height)
            .map(|i| [f(i % width, i / width); 3])
            .collect();
        EnvironmentMap::new(width, height, texels, DVec3::Z, 0.0, 1.0).unwrap()
    }

    #[test]
    fn rows_run_from_the_zenith_and_columns_counter_clockwise_from_x() {
        // Upper half 2, lower half 0.
        let m = map(8, 4, |_, y| if y < 2 { 2.0 } else { 0.0 });
        assert_eq!(m.rgb_from(DVec3::Z)[0], 2.0);
        assert_eq!(m.rgb_from(-DVec3::Z)[0], 0.0);
        // Column x centred at azimuth 90° (x + ½): only column 1 (at 135°) is bright.
        let m = map(4, 2, |x, _| if x == 1 { 1.0 } else { 0.0 });
        let at = |deg: f64| {
            let a = deg.to_radians();
            m.rgb_from(DVec3::new(a.cos(), a.sin(), 0.0))[0]
        };
        assert!((at(135.0) - 1.0).abs() < 1e-12, "{}", at(135.0));
        assert!(at(315.0).abs() < 1e-12);
        // Half way between column centres 1 and 2: the mean.
        assert!((at(180.0) - 0.5).abs() < 1e-12);
        // A rotation of 90° turns the map counter-clockwise: the bright column moves to 225°.
        let turned = EnvironmentMap::new(4, 2, m.texels().to_vec(), DVec3::Z, 90.0, 1.0).unwrap();
        let a = 225f64.to_radians();
        assert!((turned.rgb_from(DVec3::new(a.cos(), a.sin(), 0.0))[0] - 1.0).abs() < 1e-12);
    }

    #[test]
    fn samples_cover_the_sphere_and_find_each_texel() {
        // One bright texel: its samples carry its radiance over its exact solid angle, and
        // point where a lookup finds it.
        let m = map(64, 32, |x, y| if (x, y) == (10, 7) { 5.0 } else { 1.0 });
        let (mut omega, mut power, mut bright) = (0.0, 0.0, 0.0);
        m.for_each_sample(|from, o, rgb| {
            omega += o;
            power += o * rgb[0];
            if rgb[0] == 5.0 {
                bright += o;
                assert!(m.rgb_from(from)[0] > 1.0, "{from}");
            }
        });
        let (t0, t1) = (7.0 * PI / 32.0, 8.0 * PI / 32.0);
        let texel = (t0.cos() - t1.cos()) * 2.0 * PI / 64.0;
        assert!((omega - 4.0 * PI).abs() < 1e-9, "{omega}");
        assert!((bright - texel).abs() < 1e-12, "{bright} vs {texel}");
        assert!((power - (4.0 * PI + 4.0 * texel)).abs() < 1e-9);
    }

    #[test]
    fn a_bright_texel_becomes_a_light_of_its_power() {
        // A grey sky of 0.2 with one warm texel of (3000, 2000, 1000) and its dimmer
        // neighbour: one source, the grey part (1000 and 500) of both; their colour stays.
        let (w, h, x, y) = (1024, 512, 300, 100);
        let m = map(w, h, |_, _| 0.2);
        let mut texels = m.texels().to_vec();
        texels[y * w + x] = [3000.0, 2000.0, 1000.0];
        texels[y * w + x + 1] = [500.0; 3];
        let m = EnvironmentMap::new(w, h, texels, DVec3::Z, 0.0, 2.0).unwrap();
        let (rest, sources) = m.split_bright_sources();
        assert_eq!(sources.len(), 1, "{sources:?}");
        let (yf, wf, hf) = (y as f64, w as f64, h as f64);
        let band = ((PI * yf / hf).cos() - (PI * (yf + 1.0) / hf).cos()) * 2.0 * PI / wf;
        let want = 2.0 * 1500.0 * band;
        assert!(
            (sources[0].irradiance - want).abs() < 1e-9 * want,
            "{sources:?} vs {want}"
        );
        assert_eq!(rest.texels()[y * w + x], [2000.0, 1000.0, 0.0]);
        assert_eq!(rest.texels()[y * w + x + 1], [0.0; 3]);
        assert_eq!(rest.texels()[0], [0.2; 3]);
        assert_eq!(rest.max_rgb()[0], 4000.0);
        // Toward the two texels' power-weighted centre: between their azimuths.
        let d = sources[0].to_source;
        let phi = d.y.atan2(d.x).to_degrees();
        let column = |c: f64| c * 360.0 / wf;
        assert!(phi > column(300.5) && phi < column(301.5), "{phi}");
        // A smooth map keeps everything.
        let (same, none) = map(16, 8, |x, y| 1.0 + (x + y) as f32).split_bright_sources();
        assert!(
            none.is_empty() && same.texels() == map(16, 8, |x, y| 1.0 + (x + y) as f32).texels()
        );
    }

    #[test]
    fn bad_maps_are_refused_naming_the_texel() {
        let e = EnvironmentMap::new(2, 1, vec![[0.0; 3], [f32::NAN; 3]], DVec3::Z, 0.0, 1.0)
            .unwrap_err()
            .to_string();
        assert!(e.contains("texel (1, 0)"), "{e}");
        assert!(EnvironmentMap::new(2, 2, vec![[0.0; 3]; 3], DVec3::Z, 0.0, 1.0).is_err());
        assert!(EnvironmentMap::new(0, 2, vec![], DVec3::Z, 0.0, 1.0).is_err());
        assert!(EnvironmentMap::new(1, 1, vec![[1.0; 3]], DVec3::ZERO, 0.0, 1.0).is_err());
        assert!(EnvironmentMap::new(1, 1, vec![[1.0; 3]], DVec3::Z, 0.0, -1.0).is_err());
    }
}
