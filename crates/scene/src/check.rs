//! The scene file being validated ([`Ctx`]) and the checks of single values: numbers,
//! integers, vectors, colour channels, transfer tables, phase functions, lights and cameras.
//! Every failure names the file and the dotted key of the value.

use std::path::Path;
use std::sync::Arc;

use gather::{CameraSpec, Projection};
use glam::DVec3;
use medium::environment::SkySpec;
use medium::environment_map::EnvironmentMap;
use medium::transfer::{PiecewiseLinear, Transfer};
use medium::{Environment, Light, PhaseFunction};

use crate::raw::RawCamera;
use crate::SceneError;

/// The scene file being validated, for error messages.
/// One `[[light]]` entry: a light, or the environment (short-lived: the size gap between the
/// two does not matter).
#[allow(clippy::large_enum_variant)]
pub(crate) enum SceneLight {
    Light(Light),
    /// An environment and the directional lights it places: a sky's sun, a map's small bright
    /// sources.
    Environment(Environment, Vec<Light>),
}

pub(crate) struct Ctx<'a> {
    pub(crate) file: &'a Path,
    pub(crate) base_dir: &'a Path,
    /// The volume's data values given by the caller ([`crate::Scene::with_volume_data`]),
    /// taken once by `[volume]`'s check instead of a `file` or `generator`.
    pub(crate) supplied: std::cell::Cell<Option<medium::volume_io::VolumeData>>,
}

pub(crate) fn join(prefix: &str, key: &str) -> String {
    if prefix.is_empty() {
        key.to_string()
    } else {
        format!("{prefix}.{key}")
    }
}

fn type_name(v: &toml::Value) -> &'static str {
    match v {
        toml::Value::String(_) => "a string",
        toml::Value::Integer(_) => "an integer",
        toml::Value::Float(_) => "a number",
        toml::Value::Boolean(_) => "a boolean",
        toml::Value::Datetime(_) => "a date",
        toml::Value::Array(_) => "an array",
        toml::Value::Table(_) => "a table",
    }
}

/// Colour-channel values: one for grey, three for RGB.
pub(crate) type Channels<T> = Vec<T>;

impl Ctx<'_> {
    pub(crate) fn err(&self, key: impl Into<String>, message: impl Into<String>) -> SceneError {
        SceneError::Invalid {
            file: self.file.to_path_buf(),
            key: key.into(),
            message: message.into(),
        }
    }

    /// Deserialises a raw struct, naming the unknown or missing key serde reports.
    pub(crate) fn raw<T: serde::de::DeserializeOwned>(
        &self,
        value: toml::Value,
        prefix: &str,
    ) -> Result<T, SceneError> {
        if !value.is_table() {
            return Err(self.err(
                prefix,
                format!("expected a table, found {}", type_name(&value)),
            ));
        }
        value.try_into::<T>().map_err(|e| {
            let msg = e.message().to_string();
            let field = msg.split('`').nth(1).unwrap_or("");
            if msg.starts_with("unknown field") {
                let expected = msg.split_once(", expected").map_or("", |(_, rest)| rest);
                self.err(
                    join(prefix, field),
                    format!("unknown key (expected{expected})"),
                )
            } else if msg.starts_with("missing field") {
                self.err(join(prefix, field), "required key is missing")
            } else {
                self.err(prefix, msg)
            }
        })
    }

    pub(crate) fn number(&self, v: &toml::Value, key: &str) -> Result<f64, SceneError> {
        let x = match v {
            toml::Value::Float(x) => *x,
            toml::Value::Integer(i) => *i as f64,
            other => {
                return Err(self.err(
                    key,
                    format!("expected a number, found {}", type_name(other)),
                ))
            }
        };
        if !x.is_finite() {
            return Err(self.err(key, format!("{x} is not finite; expected a finite number")));
        }
        Ok(x)
    }

    pub(crate) fn non_negative(&self, v: &toml::Value, key: &str) -> Result<f64, SceneError> {
        let x = self.number(v, key)?;
        if x < 0.0 {
            return Err(self.err(key, format!("{x} is negative; expected a number ≥ 0")));
        }
        Ok(x)
    }

    pub(crate) fn positive(&self, v: &toml::Value, key: &str) -> Result<f64, SceneError> {
        let x = self.number(v, key)?;
        if x <= 0.0 {
            return Err(self.err(key, format!("{x}: expected a number > 0")));
        }
        Ok(x)
    }

    pub(crate) fn integer(&self, v: &toml::Value, key: &str, min: i64) -> Result<i64, SceneError> {
        match v {
            toml::Value::Integer(i) if *i >= min => Ok(*i),
            toml::Value::Integer(i) => {
                Err(self.err(key, format!("{i}: expected a whole number ≥ {min}")))
            }
            other => Err(self.err(
                key,
                format!("expected a whole number, found {}", type_name(other)),
            )),
        }
    }

    pub(crate) fn string<'v>(&self, v: &'v toml::Value, key: &str) -> Result<&'v str, SceneError> {
        v.as_str()
            .ok_or_else(|| self.err(key, format!("expected a string, found {}", type_name(v))))
    }

    pub(crate) fn array<'v>(
        &self,
        v: &'v toml::Value,
        key: &str,
        len: Option<usize>,
    ) -> Result<&'v [toml::Value], SceneError> {
        let a = v
            .as_array()
            .ok_or_else(|| self.err(key, format!("expected an array, found {}", type_name(v))))?;
        if let Some(n) = len {
            if a.len() != n {
                return Err(self.err(key, format!("expected {n} elements, found {}", a.len())));
            }
        }
        Ok(a)
    }

    pub(crate) fn vec3(&self, v: &toml::Value, key: &str) -> Result<DVec3, SceneError> {
        let a = self.array(v, key, Some(3))?;
        Ok(DVec3::new(
            self.number(&a[0], key)?,
            self.number(&a[1], key)?,
            self.number(&a[2], key)?,
        ))
    }

    pub(crate) fn dims(&self, v: &toml::Value, key: &str) -> Result<[usize; 3], SceneError> {
        let a = self.array(v, key, Some(3))?;
        let mut d = [0usize; 3];
        for (slot, x) in d.iter_mut().zip(a) {
            *slot = self.integer(x, key, 1)? as usize;
        }
        Ok(d)
    }

    /// A table with a `kind` and only the listed keys (used for nested `{ kind = ... }`).
    pub(crate) fn kind_table<'v>(
        &self,
        v: &'v toml::Value,
        key: &str,
        kinds: &[(&str, &[&str], &[&str])],
    ) -> Result<(&'v str, &'v toml::Table), SceneError> {
        let t = v
            .as_table()
            .ok_or_else(|| self.err(key, format!("expected a table, found {}", type_name(v))))?;
        let kind_value = t
            .get("kind")
            .ok_or_else(|| self.err(join(key, "kind"), "required key is missing"))?;
        let kind = self.string(kind_value, &join(key, "kind"))?;
        let names: Vec<&str> = kinds.iter().map(|k| k.0).collect();
        let Some((_, required, optional)) = kinds.iter().find(|k| k.0 == kind) else {
            return Err(self.err(
                join(key, "kind"),
                format!(
                    "unknown kind `{kind}` (expected one of: {})",
                    names.join(", ")
                ),
            ));
        };
        for k in t.keys() {
            if k != "kind" && !required.contains(&k.as_str()) && !optional.contains(&k.as_str()) {
                let mut allowed: Vec<&str> =
                    required.iter().chain(optional.iter()).copied().collect();
                allowed.insert(0, "kind");
                return Err(self.err(
                    join(key, k),
                    format!(
                        "unknown key for kind `{kind}` (expected one of: {})",
                        allowed.join(", ")
                    ),
                ));
            }
        }
        for r in *required {
            if !t.contains_key(*r) {
                return Err(self.err(
                    join(key, r),
                    format!("required key for kind `{kind}` is missing"),
                ));
            }
        }
        Ok((kind, t))
    }

    /// A number or an `[r, g, b]` triple, each checked with `check`.
    pub(crate) fn grey_or_rgb(
        &self,
        v: &toml::Value,
        key: &str,
        check: &dyn Fn(f64) -> Result<(), String>,
    ) -> Result<Channels<f64>, SceneError> {
        let values = match v {
            toml::Value::Array(_) => {
                let a = self
                    .array(v, key, Some(3))
                    .map_err(|_| self.err(key, "expected a number or an [r, g, b] triple"))?;
                a.iter()
                    .map(|x| self.number(x, key))
                    .collect::<Result<Vec<_>, _>>()?
            }
            _ => vec![self.number(v, key)?],
        };
        for &x in &values {
            check(x).map_err(|m| self.err(key, format!("{x}: {m}")))?;
        }
        Ok(values)
    }

    /// `points = [[x, y], ...]` (grey) or `[[x, r, g, b], ...]` (RGB).
    pub(crate) fn table_points(
        &self,
        v: &toml::Value,
        key: &str,
    ) -> Result<Channels<Vec<[f64; 2]>>, SceneError> {
        let rows = self.array(v, key, None)?;
        if rows.is_empty() {
            return Err(self.err(key, "expected at least one point [x, y]"));
        }
        let width = self.array(&rows[0], key, None)?.len();
        if width != 2 && width != 4 {
            return Err(self.err(
                key,
                "each point must be [x, y] (grey) or [x, r, g, b] (colour)",
            ));
        }
        let mut channels = vec![Vec::with_capacity(rows.len()); width - 1];
        for row in rows {
            let r = self.array(row, key, Some(width))?;
            let x = self.number(&r[0], key)?;
            for (c, y) in r[1..].iter().enumerate() {
                channels[c].push([x, self.number(y, key)?]);
            }
        }
        Ok(channels)
    }

    /// A table transfer (`piecewise-linear` or `preset`), per channel.
    pub(crate) fn table_transfer(
        &self,
        kind: &str,
        t: &toml::Table,
        key: &str,
    ) -> Result<Channels<PiecewiseLinear>, SceneError> {
        let scale = match t.get("scale") {
            Some(s) => self.non_negative(s, &join(key, "scale"))?,
            None => 1.0,
        };
        let tables = if kind == "preset" {
            let name_key = join(key, "name");
            let name = self.string(&t["name"], &name_key)?;
            vec![PiecewiseLinear::preset(name).map_err(|e| self.err(name_key, e.to_string()))?]
        } else {
            let points_key = join(key, "points");
            self.table_points(&t["points"], &points_key)?
                .into_iter()
                .map(|p| PiecewiseLinear::new(p).map_err(|e| self.err(&points_key, e.to_string())))
                .collect::<Result<Vec<_>, _>>()?
        };
        Ok(tables.into_iter().map(|t| t.scaled(scale)).collect())
    }

    /// `albedo` or `emission`: a number, `[r, g, b]`, or a transfer-function table.
    pub(crate) fn transfer(
        &self,
        v: &toml::Value,
        key: &str,
        range: (f64, f64),
        allow_particle: bool,
    ) -> Result<Channels<Transfer>, SceneError> {
        let (lo, hi) = range;
        let expected = if hi.is_finite() {
            format!("expected a value in [{lo}, {hi}]")
        } else {
            format!("expected a value ≥ {lo}")
        };
        let check = |x: f64| {
            if x >= lo && x <= hi {
                Ok(())
            } else {
                Err(expected.clone())
            }
        };
        if !v.is_table() {
            return Ok(self
                .grey_or_rgb(v, key, &check)?
                .into_iter()
                .map(|value| Transfer::Constant { value })
                .collect());
        }
        let mut kinds: Vec<(&str, &[&str], &[&str])> = vec![
            ("constant", &["value"], &[]),
            ("piecewise-linear", &["points"], &["scale"]),
            ("preset", &["name"], &["scale"]),
        ];
        if allow_particle {
            kinds.push(("particle", &["c"], &[]));
            // Blackbody emission is parsed by the [medium] section before it gets here; it is
            // listed so that a mistyped kind's message names it.
            kinds.push(("blackbody", &[], &["temperature", "grid", "scale"]));
        }
        let (kind, t) = self.kind_table(v, key, &kinds)?;
        match kind {
            "constant" => Ok(self
                .grey_or_rgb(&t["value"], &join(key, "value"), &check)?
                .into_iter()
                .map(|value| Transfer::Constant { value })
                .collect()),
            "particle" => Ok(self
                .grey_or_rgb(&t["c"], &join(key, "c"), &|x| {
                    if x >= 0.0 {
                        Ok(())
                    } else {
                        Err("expected a particle colour C ≥ 0".into())
                    }
                })?
                .into_iter()
                .map(|c| Transfer::Particle { c })
                .collect()),
            "blackbody" => Err(self.err(
                key,
                "blackbody emission is a whole emission, not a part of a transfer function",
            )),
            _ => {
                let tables = self.table_transfer(kind, t, key)?;
                for table in &tables {
                    let (tlo, thi) = table.range();
                    if tlo < lo || thi > hi {
                        return Err(self.err(
                            key,
                            format!("the table's values span [{tlo}, {thi}]; {expected}"),
                        ));
                    }
                }
                Ok(tables
                    .into_iter()
                    .map(|table| Transfer::Table { table })
                    .collect())
            }
        }
    }

    pub(crate) fn phase(&self, v: &toml::Value, key: &str) -> Result<PhaseFunction, SceneError> {
        if let Some(name) = v.as_str() {
            return match name {
                "isotropic" => Ok(PhaseFunction::Isotropic),
                "lambertian-sphere" => Ok(PhaseFunction::LambertianSphere),
                other => Err(self.err(
                    key,
                    format!(
                        "`{other}`: expected \"isotropic\", \"lambertian-sphere\", or a table such as {{ kind = \"henyey-greenstein\", g = 0.6 }}"
                    ),
                )),
            };
        }
        let (kind, t) = self.kind_table(
            v,
            key,
            &[
                ("isotropic", &[], &[]),
                ("henyey-greenstein", &["g"], &[]),
                ("lambertian-sphere", &[], &[]),
                ("two-lobe", &["r", "g1", "g2"], &[]),
            ],
        )?;
        let g = |name: &str| -> Result<f64, SceneError> {
            let k = join(key, name);
            let g = self.number(&t[name], &k)?;
            if g.abs() >= 1.0 {
                return Err(self.err(k, format!("{g}: expected |g| < 1")));
            }
            Ok(g)
        };
        Ok(match kind {
            "isotropic" => PhaseFunction::Isotropic,
            "lambertian-sphere" => PhaseFunction::LambertianSphere,
            "henyey-greenstein" => PhaseFunction::HenyeyGreenstein { g: g("g")? },
            _ => {
                let rk = join(key, "r");
                let r = self.number(&t["r"], &rk)?;
                if !(0.0..=1.0).contains(&r) {
                    return Err(self.err(rk, format!("{r}: expected a lobe weight in [0, 1]")));
                }
                PhaseFunction::TwoLobe {
                    r,
                    g1: g("g1")?,
                    g2: g("g2")?,
                }
            }
        })
    }

    /// `[[light]] kind = "environment"` with `file`: an equirectangular map (`.exr` or `.pfm`,
    /// linear RGB or grey) with `scale`, `up` and `rotation_degrees`.
    fn environment_map(&self, t: &toml::Table, key: &str) -> Result<SceneLight, SceneError> {
        let fk = join(key, "file");
        let Some(file) = t.get("file") else {
            return Err(self.err(
                key,
                "an environment needs `radiance` (uniform) or `file` (a map)",
            ));
        };
        if t.get("radiance").is_some() {
            return Err(self.err(
                join(key, "radiance"),
                "give `radiance` (uniform) or `file` (a map), not both",
            ));
        }
        let path = self.base_dir.join(self.string(file, &fk)?);
        let image =
            gather::image_io::read_image(&path).map_err(|e| self.err(&fk, e.to_string()))?;
        let scale = match t.get("scale") {
            Some(v) => self.non_negative(v, &join(key, "scale"))?,
            None => 1.0,
        };
        let up = match t.get("up") {
            Some(v) => self.vec3(v, &join(key, "up"))?,
            None => DVec3::Z,
        };
        let rotation = match t.get("rotation_degrees") {
            Some(v) => self.number(v, &join(key, "rotation_degrees"))?,
            None => 0.0,
        };
        let map = EnvironmentMap::from_interleaved(
            image.width as usize,
            image.height as usize,
            image.channels as usize,
            &image.pixels,
            up,
            rotation,
            scale,
        )
        .map_err(|e| {
            let param = match &e {
                medium::MediumError::Invalid { what, .. } => what.strip_prefix("environment "),
                _ => None,
            };
            match param {
                Some(p) if p != "map" => self.err(join(key, p), e.to_string()),
                _ => self.err(&fk, format!("{}: {e}", path.display())),
            }
        })?;
        // Its suns become lights, whose first bounce the render takes exactly.
        let (rest, sources) = map.split_bright_sources();
        let lights = sources
            .into_iter()
            .map(|s| Light::Directional {
                direction: -s.to_source,
                irradiance: s.irradiance,
            })
            .collect();
        Ok(SceneLight::Environment(
            Environment::map(Arc::new(rest)),
            lights,
        ))
    }

    pub(crate) fn light(&self, v: &toml::Value, key: &str) -> Result<SceneLight, SceneError> {
        let (kind, t) = self.kind_table(
            v,
            key,
            &[
                (
                    "environment",
                    &[],
                    &["radiance", "file", "scale", "up", "rotation_degrees"],
                ),
                (
                    "sky",
                    &["sun_elevation_degrees"],
                    &[
                        "sun_azimuth_degrees",
                        "turbidity",
                        "up",
                        "sun_irradiance",
                        "sky_fraction",
                        "ground_albedo",
                    ],
                ),
                ("directional", &["direction", "irradiance"], &[]),
                ("point", &["position", "intensity"], &[]),
                (
                    "spot",
                    &["position", "axis", "half_angle_degrees", "intensity"],
                    &[],
                ),
            ],
        )?;
        let nonzero = |name: &str| -> Result<DVec3, SceneError> {
            let k = join(key, name);
            let d = self.vec3(&t[name], &k)?;
            if d.length() < 1e-12 {
                return Err(self.err(k, format!("{d:?} is a zero vector; expected a direction")));
            }
            Ok(d.normalize())
        };
        let light = match kind {
            "environment" if t.get("file").is_some() || t.get("radiance").is_none() => {
                return self.environment_map(t, key);
            }
            "environment" => {
                for extra in ["scale", "up", "rotation_degrees"] {
                    if t.get(extra).is_some() {
                        return Err(self.err(
                            join(key, extra),
                            "belongs to an environment map (`file`), not a uniform `radiance`",
                        ));
                    }
                }
                let k = join(key, "radiance");
                let values = self.grey_or_rgb(&t["radiance"], &k, &|x| {
                    if x.is_finite() && x >= 0.0 {
                        Ok(())
                    } else {
                        Err("expected a finite radiance ≥ 0".into())
                    }
                })?;
                let rgb = [0, 1, 2].map(|c| values[c.min(values.len() - 1)]);
                return Environment::uniform_rgb(rgb)
                    .map(|e| SceneLight::Environment(e, Vec::new()))
                    .map_err(|e| self.err(k, e.to_string()));
            }
            "sky" => {
                let d = SkySpec::default();
                let num = |name: &str, default: f64| match t.get(name) {
                    Some(v) => self.number(v, &join(key, name)),
                    None => Ok(default),
                };
                let spec = SkySpec {
                    turbidity: num("turbidity", d.turbidity)?,
                    sun_elevation_degrees: num("sun_elevation_degrees", d.sun_elevation_degrees)?,
                    sun_azimuth_degrees: num("sun_azimuth_degrees", d.sun_azimuth_degrees)?,
                    up: match t.get("up") {
                        Some(_) => nonzero("up")?,
                        None => d.up,
                    },
                    sun_irradiance: num("sun_irradiance", d.sun_irradiance)?,
                    sky_fraction: num("sky_fraction", d.sky_fraction)?,
                    ground_albedo: num("ground_albedo", d.ground_albedo)?,
                };
                // The library names the parameter ("sky turbidity"): point at its key.
                return Environment::sky(spec)
                    .map(|e| SceneLight::Environment(e, Vec::new()))
                    .map_err(|e| {
                        let param = match &e {
                            medium::MediumError::Invalid { what, .. } => what.strip_prefix("sky "),
                            _ => None,
                        };
                        match param {
                            Some(p) => self.err(join(key, p), e.to_string()),
                            None => self.err(key, e.to_string()),
                        }
                    });
            }
            "directional" => Light::Directional {
                direction: nonzero("direction")?,
                irradiance: self.non_negative(&t["irradiance"], &join(key, "irradiance"))?,
            },
            "point" => Light::Point {
                position: self.vec3(&t["position"], &join(key, "position"))?,
                intensity: self.non_negative(&t["intensity"], &join(key, "intensity"))?,
            },
            _ => {
                let ak = join(key, "half_angle_degrees");
                let half = self.number(&t["half_angle_degrees"], &ak)?;
                if !(half > 0.0 && half <= 180.0) {
                    return Err(
                        self.err(ak, format!("{half}: expected an angle in (0, 180] degrees"))
                    );
                }
                Light::Spot {
                    position: self.vec3(&t["position"], &join(key, "position"))?,
                    axis: nonzero("axis")?,
                    half_angle: half.to_radians(),
                    intensity: self.non_negative(&t["intensity"], &join(key, "intensity"))?,
                }
            }
        };
        light
            .validated()
            .map(SceneLight::Light)
            .map_err(|e| self.err(key, e.to_string()))
    }

    pub(crate) fn camera(&self, v: toml::Value, key: &str) -> Result<CameraSpec, SceneError> {
        let raw: RawCamera = self.raw(v, key)?;
        let name = self.string(&raw.name, &join(key, "name"))?.to_string();
        if name.is_empty() {
            return Err(self.err(join(key, "name"), "expected a non-empty name"));
        }
        let eye = self.vec3(&raw.eye, &join(key, "eye"))?;
        let target = self.vec3(&raw.target, &join(key, "target"))?;
        let up = self.vec3(&raw.up, &join(key, "up"))?;
        let view = target - eye;
        if view.length() < 1e-12 {
            return Err(self.err(
                join(key, "target"),
                "equals `eye`; expected a distinct point to look at",
            ));
        }
        if up.length() < 1e-12 || view.normalize().cross(up.normalize()).length() < 1e-9 {
            return Err(self.err(
                join(key, "up"),
                format!("{up:?} is zero or parallel to the view direction; expected an up vector"),
            ));
        }
        let projection_name = match &raw.projection {
            Some(p) => self.string(p, &join(key, "projection"))?,
            None => "perspective",
        };
        let projection = match projection_name {
            "perspective" => {
                if raw.ortho_height.is_some() {
                    return Err(self.err(
                        join(key, "ortho_height"),
                        "only for projection = \"orthographic\"",
                    ));
                }
                let fk = join(key, "fov_y");
                let fov = raw.fov_y.as_ref().ok_or_else(|| {
                    self.err(
                        &fk,
                        "required key is missing (vertical field of view, degrees)",
                    )
                })?;
                let fov = self.number(fov, &fk)?;
                if !(fov > 0.0 && fov < 180.0) {
                    return Err(self.err(fk, format!("{fov}: expected degrees in (0, 180)")));
                }
                Projection::Perspective { fov_y_degrees: fov }
            }
            "orthographic" => {
                if raw.fov_y.is_some() {
                    return Err(
                        self.err(join(key, "fov_y"), "only for projection = \"perspective\"")
                    );
                }
                let hk = join(key, "ortho_height");
                let h = raw.ortho_height.as_ref().ok_or_else(|| {
                    self.err(&hk, "required key is missing (world-space image height)")
                })?;
                Projection::Orthographic {
                    height: self.positive(h, &hk)?,
                }
            }
            other => {
                return Err(self.err(
                    join(key, "projection"),
                    format!("unknown projection `{other}` (expected perspective or orthographic)"),
                ))
            }
        };
        let size = |v: &toml::Value, k: &str| -> Result<u32, SceneError> {
            let k = join(key, k);
            let n = self.integer(v, &k, 1)?;
            u32::try_from(n)
                .ok()
                .filter(|&n| n <= 65536)
                .ok_or_else(|| self.err(k, format!("{n}: expected at most 65536 pixels")))
        };
        Ok(CameraSpec {
            name,
            eye,
            target,
            up: up.normalize(),
            projection,
            width: size(&raw.width, "width")?,
            height: size(&raw.height, "height")?,
        })
    }
}

/// Broadcasts a grey list to `n` channels.
pub(crate) fn broadcast<T: Clone>(v: Vec<T>, n: usize) -> Vec<T> {
    if v.len() == n {
        v
    } else {
        vec![v[0].clone(); n]
    }
}
