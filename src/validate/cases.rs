//! What a validation run covers: the scene variants (`--vary albedo=…`, a cartesian product
//! written into each scene's TOML before it is checked) and the views (an orbit around each
//! scene's first camera).

use std::path::{Path, PathBuf};

use anyhow::{bail, Context, Result};
use medium::Interpolation;
use scene::{CameraSpec, Scene};

/// A scene key `--vary` can sweep.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VaryKey {
    /// `[medium] albedo`, a number in [0, 1].
    Albedo,
    /// The Henyey–Greenstein `g` of `[medium] phase` (0 writes `isotropic`).
    G,
    /// A factor on `[volume] sigma_t_scale` (which defaults to 1).
    SigmaTFactor,
    /// `[solve] bins` (discrete ordinates).
    Bins,
    /// `[solve] forward_peak_cone` in degrees (discrete ordinates; 0: no truncation).
    ForwardPeakCone,
    /// `[solve] transport_refinement` (transport cells per data cell side; the methods with
    /// a transport grid).
    TransportRefinement,
}

impl VaryKey {
    const ALL: [(VaryKey, &'static str); 6] = [
        (VaryKey::Albedo, "albedo"),
        (VaryKey::G, "g"),
        (VaryKey::SigmaTFactor, "sigma-t-factor"),
        (VaryKey::Bins, "bins"),
        (VaryKey::ForwardPeakCone, "forward-peak-cone"),
        (VaryKey::TransportRefinement, "transport-refinement"),
    ];

    pub fn name(self) -> &'static str {
        Self::ALL
            .iter()
            .find(|(k, _)| *k == self)
            .map_or("?", |(_, n)| n)
    }

    /// Whether the key changes what is seen (the medium), not only how it is solved: cases
    /// that differ only in keys that do not share one path-traced reference.
    pub fn changes_the_medium(self) -> bool {
        matches!(self, VaryKey::Albedo | VaryKey::G | VaryKey::SigmaTFactor)
    }

    /// The short tag in case names (`a0.9`, `g0.85`, `s4`).
    fn tag(self) -> &'static str {
        match self {
            VaryKey::Albedo => "a",
            VaryKey::G => "g",
            VaryKey::SigmaTFactor => "s",
            VaryKey::Bins => "b",
            VaryKey::ForwardPeakCone => "cone",
            VaryKey::TransportRefinement => "r",
        }
    }
}

/// One `--vary KEY=v1,v2,…`.
#[derive(Clone, Debug, PartialEq)]
pub struct Variation {
    pub key: VaryKey,
    pub values: Vec<f64>,
}

/// Parses `KEY=v1,v2,…` (keys: [`VaryKey`]'s names). The values' ranges are the scene
/// checker's: [`scene_cases`] refuses a variant it does not take, naming the key, before any
/// work.
pub fn parse_variation(spec: &str) -> Result<Variation> {
    let keys = VaryKey::ALL.map(|(_, n)| n).join(", ");
    let Some((key, values)) = spec.split_once('=') else {
        bail!("--vary {spec}: expected KEY=v1,v2,… (keys: {keys})");
    };
    let key = key.trim();
    let Some(&(key, _)) = VaryKey::ALL.iter().find(|(_, n)| *n == key) else {
        bail!("--vary {spec}: unknown key `{key}` (expected one of {keys})");
    };
    let mut parsed = Vec::new();
    for v in values.split(',') {
        let x: f64 = v
            .trim()
            .parse()
            .with_context(|| format!("--vary {spec}: `{}` is not a number", v.trim()))?;
        if !x.is_finite() {
            bail!("--vary {spec}: `{}` is not a finite number", v.trim());
        }
        if !parsed.contains(&x) {
            parsed.push(x);
        }
    }
    if parsed.is_empty() {
        bail!("--vary {spec}: no value");
    }
    Ok(Variation {
        key,
        values: parsed,
    })
}

/// One scene of the run: a scene file as it is, or with the variation's values written in.
pub struct SceneCase {
    /// Unique name in the report and image files (`cloud24-isotropic_a0.9_g0.6`).
    pub name: String,
    pub path: PathBuf,
    /// `albedo 0.9, g 0.6` for a variant; empty for the scene as written.
    pub variant: String,
    /// The scene file and the variation values that change the medium: cases with the same
    /// key see the same light, so one path-traced reference serves them all.
    pub reference_key: String,
    pub scene: Scene,
}

/// The scene as validation sees it: with the piecewise-constant (`nearest`) medium the solvers
/// discretise and the path tracer traces, whatever `[volume] interpolation` says, so that the
/// renders and the reference see the same medium (`trilinear`, the default, is a render look;
/// docs/physics.md).
fn as_validated(mut scene: Scene) -> Scene {
    if scene.medium.interpolation() != Interpolation::Nearest {
        scene.medium = scene
            .medium
            .clone()
            .with_interpolation(Interpolation::Nearest);
    }
    scene
}

/// The scene at `path` once per combination of the variations (once as written when there
/// are none), each with the `nearest` medium ([`as_validated`]). Every combination is checked
/// here, before any work.
pub fn scene_cases(
    path: &Path,
    base_name: &str,
    variations: &[Variation],
) -> Result<Vec<SceneCase>> {
    if variations.is_empty() {
        return Ok(vec![SceneCase {
            name: base_name.to_string(),
            path: path.to_path_buf(),
            variant: String::new(),
            reference_key: path.display().to_string(),
            scene: as_validated(Scene::from_file(path)?),
        }]);
    }
    let text = medium::regular_file::read_to_string(path)
        .with_context(|| format!("reading the scene {}", path.display()))?;
    let table: toml::Table = text
        .parse()
        .with_context(|| format!("{}: not valid TOML", path.display()))?;
    let base_dir = Scene::base_dir(path);
    let mut cases = Vec::new();
    for combination in combinations(variations) {
        let mut edited = table.clone();
        let mut name = base_name.to_string();
        let mut variant = Vec::new();
        let mut reference_key = path.display().to_string();
        for &(key, value) in &combination {
            if key.changes_the_medium() {
                reference_key.push_str(&format!(" {}={value}", key.name()));
            }
            apply(&mut edited, key, value)
                .with_context(|| format!("{}: --vary {}", path.display(), key.name()))?;
            name.push_str(&format!("_{}{value}", key.tag()));
            variant.push(format!("{} {value}", key.name()));
        }
        let edited_text = toml::to_string(&edited)?;
        let scene = Scene::from_toml_str(&edited_text, base_dir, path)
            .with_context(|| format!("{} with {}", path.display(), variant.join(", ")))?;
        cases.push(SceneCase {
            name,
            path: path.to_path_buf(),
            variant: variant.join(", "),
            reference_key,
            scene: as_validated(scene),
        });
    }
    Ok(cases)
}

/// The cartesian product of the variations' values, in the order given.
fn combinations(variations: &[Variation]) -> Vec<Vec<(VaryKey, f64)>> {
    let mut out: Vec<Vec<(VaryKey, f64)>> = vec![Vec::new()];
    for v in variations {
        out = out
            .into_iter()
            .flat_map(|prefix| {
                v.values.iter().map(move |&x| {
                    let mut c = prefix.clone();
                    c.push((v.key, x));
                    c
                })
            })
            .collect();
    }
    out
}

fn section<'t>(table: &'t mut toml::Table, name: &str) -> Result<&'t mut toml::Table> {
    table
        .entry(name)
        .or_insert_with(|| toml::Value::Table(toml::Table::new()))
        .as_table_mut()
        .with_context(|| format!("[{name}] is not a table"))
}

fn apply(table: &mut toml::Table, key: VaryKey, value: f64) -> Result<()> {
    // A fractional count stays a float, which the scene checker refuses by name.
    let count = |value: f64| {
        if value.fract() == 0.0 {
            toml::Value::Integer(value as i64)
        } else {
            toml::Value::Float(value)
        }
    };
    match key {
        VaryKey::Bins => {
            section(table, "solve")?.insert("bins".into(), count(value));
        }
        VaryKey::TransportRefinement => {
            section(table, "solve")?.insert("transport_refinement".into(), count(value));
        }
        VaryKey::ForwardPeakCone => {
            section(table, "solve")?.insert("forward_peak_cone".into(), toml::Value::Float(value));
        }
        VaryKey::Albedo => {
            section(table, "medium")?.insert("albedo".into(), toml::Value::Float(value));
        }
        VaryKey::G => {
            let mut phase = toml::Table::new();
            if value == 0.0 {
                phase.insert("kind".into(), "isotropic".into());
            } else {
                phase.insert("kind".into(), "henyey-greenstein".into());
                phase.insert("g".into(), toml::Value::Float(value));
            }
            section(table, "medium")?.insert("phase".into(), toml::Value::Table(phase));
        }
        VaryKey::SigmaTFactor => {
            let volume = section(table, "volume")?;
            let scale = match volume.get("sigma_t_scale") {
                None => 1.0,
                Some(toml::Value::Float(x)) => *x,
                Some(toml::Value::Integer(i)) => *i as f64,
                Some(other) => bail!("[volume] sigma_t_scale is {other}, not a number"),
            };
            volume.insert("sigma_t_scale".into(), toml::Value::Float(scale * value));
        }
    }
    Ok(())
}

/// `views` cameras around `spec`'s target ([`orbit_cameras`](crate::views::orbit_cameras):
/// the same distance and elevation, turned about the camera's up axis in equal steps), so the
/// light falls from every side. The first is `spec` itself; the others are named by their
/// turn (`front+090`).
pub fn orbit(spec: &CameraSpec, views: usize) -> Vec<CameraSpec> {
    let n = views.max(1);
    crate::views::orbit_cameras(spec, n as u32)
        .into_iter()
        .enumerate()
        .map(|(k, camera)| {
            if k == 0 {
                spec.clone()
            } else {
                CameraSpec {
                    name: format!("{}+{:03.0}", spec.name, orbit_degrees(k, n)),
                    ..camera
                }
            }
        })
        .collect()
}

/// The turn of an orbit view about the first, in degrees (0 for the scene's own camera).
pub fn orbit_degrees(index: usize, views: usize) -> f64 {
    360.0 * index as f64 / views.max(1) as f64
}

#[cfg(test)]
mod tests {
    use super::*;
    use gather::Projection;
    use glam::DVec3;

    #[test]
    fn variations_parse_and_refuse_unknown_keys_and_non_numbers() {
        let v = parse_variation("g=0, 0.6,0.85,0.6").unwrap();
        assert_eq!(v.key, VaryKey::G);
        assert_eq!(v.values, vec![0.0, 0.6, 0.85]);
        for (bad, needle) in [
            ("density=2", "`density`"),
            ("albedo", "KEY="),
            ("albedo=x", "`x`"),
            ("albedo=inf", "finite"),
        ] {
            let e = parse_variation(bad).unwrap_err();
            assert!(format!("{e:#}").contains(needle), "{bad}: {e:#}");
        }
    }

    #[test]
    fn combinations_are_the_cartesian_product() {
        let c = combinations(&[
            parse_variation("albedo=0.5,0.9").unwrap(),
            parse_variation("g=0,0.6,0.85").unwrap(),
        ]);
        assert_eq!(c.len(), 6);
        assert_eq!(c[0], vec![(VaryKey::Albedo, 0.5), (VaryKey::G, 0.0)]);
        assert_eq!(c[5], vec![(VaryKey::Albedo, 0.9), (VaryKey::G, 0.85)]);
    }

    /// The path tracer traces the piecewise-constant medium, so validation renders it too:
    /// a scene that does not say (`trilinear`, the default) or says `trilinear` is validated
    /// as `nearest`, as written and in every variant; nothing else of the medium changes.
    #[test]
    fn cases_use_the_nearest_medium_the_path_tracer_traces() {
        let dir = tempfile::tempdir().unwrap();
        let text = |line: &str| {
            format!(
                "[volume]\ngenerator = {{ kind = \"cloud\", seed = 5 }}\ndims = [6, 6, 4]\n{line}\n\
                 [medium]\nalbedo = 0.9\n\
                 [[light]]\nkind = \"directional\"\ndirection = [0.0, -1.0, 0.0]\nirradiance = 1.0\n\
                 [[camera]]\nname = \"front\"\neye = [3.0, 3.0, -9.0]\ntarget = [3.0, 3.0, 2.0]\n\
                 up = [0.0, 1.0, 0.0]\nfov_y = 40.0\nwidth = 8\nheight = 8\n"
            )
        };
        let nearest_path = dir.path().join("nearest.toml");
        std::fs::write(&nearest_path, text("interpolation = \"nearest\"")).unwrap();
        let nearest = Scene::from_file(&nearest_path).unwrap().medium;
        assert_eq!(nearest.interpolation(), Interpolation::Nearest);
        for line in ["", "interpolation = \"trilinear\""] {
            let path = dir.path().join("scene.toml");
            std::fs::write(&path, text(line)).unwrap();
            assert_eq!(
                Scene::from_file(&path).unwrap().medium.interpolation(),
                Interpolation::Trilinear
            );
            let cases = scene_cases(&path, "s", &[]).unwrap();
            assert_eq!(cases[0].scene.medium, nearest, "{line:?}");
            let varied = scene_cases(&path, "s", &[parse_variation("g=0,0.6").unwrap()]).unwrap();
            assert_eq!(varied.len(), 2);
            for case in &varied {
                assert_eq!(case.scene.medium.interpolation(), Interpolation::Nearest);
            }
        }
    }

    /// `--vary transport-refinement=1,2` writes `[solve] transport_refinement` (whole cells
    /// and the split grid, compared in one run), and a count the scene does not take is
    /// refused naming the key before any work.
    #[test]
    fn transport_refinement_is_varied_and_checked() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("scene.toml");
        std::fs::write(
            &path,
            "[volume]\ngenerator = { kind = \"cloud\", seed = 5 }\ndims = [6, 6, 4]\n\
             [medium]\nalbedo = 0.9\n\
             [[light]]\nkind = \"directional\"\ndirection = [0.0, -1.0, 0.0]\nirradiance = 1.0\n\
             [[camera]]\nname = \"front\"\neye = [3.0, 3.0, -9.0]\ntarget = [3.0, 3.0, 2.0]\n\
             up = [0.0, 1.0, 0.0]\nfov_y = 40.0\nwidth = 8\nheight = 8\n",
        )
        .unwrap();
        let cases = scene_cases(
            &path,
            "s",
            &[parse_variation("transport-refinement=1,2").unwrap()],
        )
        .unwrap();
        let refinements: Vec<_> = cases
            .iter()
            .map(|c| (c.name.as_str(), c.scene.solve.transport_refinement))
            .collect();
        assert_eq!(
            refinements,
            [
                ("s_r1", scene::TransportRefinement::Fixed(1)),
                ("s_r2", scene::TransportRefinement::Fixed(2))
            ]
        );
        let bad = [parse_variation("transport-refinement=9").unwrap()];
        let err = format!("{:#}", scene_cases(&path, "s", &bad).err().unwrap());
        assert!(err.contains("solve.transport_refinement"), "{err}");
    }

    #[test]
    fn orbit_starts_at_the_scene_camera_and_names_views_by_their_turn() {
        let spec = CameraSpec {
            name: "front".into(),
            eye: DVec3::new(10.0, -20.0, 15.0),
            target: DVec3::new(10.0, 10.0, 5.0),
            up: DVec3::Z,
            projection: Projection::Perspective {
                fov_y_degrees: 40.0,
            },
            width: 32,
            height: 24,
        };
        let views = orbit(&spec, 8);
        let names: Vec<&str> = views.iter().map(|v| v.name.as_str()).collect();
        assert_eq!(names[..3], ["front", "front+045", "front+090"]);
        assert_eq!(views[0], spec);
        // Half way round, the eye is opposite: back-lit where the first was front-lit.
        let (d0, back) = (spec.eye - spec.target, views[4].eye - spec.target);
        assert!((back.x + d0.x).abs() < 1e-9 && (back.y + d0.y).abs() < 1e-9);
        assert!((back.z - d0.z).abs() < 1e-9);
    }
}
