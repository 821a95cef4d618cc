//! Golden solution files (`tests/data/solution-golden/`): small solutions written by this
//! volrad and committed, so that a change to the file's layout cannot pass unnoticed.
//!
//! - `golden_files_match_what_this_volrad_writes` solves the small scenes below and compares
//!   what it would write with the committed files; with `VOLRAD_BLESS=1` it rewrites them
//!   instead (after a deliberate layout change and a bump of `FORMAT_VERSION`, or when the
//!   solvers' numbers change on purpose).
//! - The `golden_*_decodes` tests read the committed files, check concrete fields, and check
//!   that decoding and encoding again gives the same bytes.

use std::path::{Path, PathBuf};

use glam::DVec3;
use medium::{CellValues, Interpolation, Light, PhaseFunction};
use scene::{OpticalModel, Projection, Scene, SolveMethod};
use serde_json::Value;
use solver::StopReason;
use volrad::engine::pipeline::solve_scene;
use volrad::engine::solution::container::FORMAT_VERSION;
use volrad::engine::solution::records::MetaRecord;
use volrad::engine::solution::{Container, ScatteredField, Solution};
use volrad::engine::SolveHooks;

/// A golden file and the scene it is solved from.
struct Case {
    file: &'static str,
    scene: &'static str,
    /// Relative tolerance on numbers when the fresh solve is not byte-identical to the
    /// golden file (another CPU: the light pass runs on AVX2 and FMA where the CPU has them,
    /// which moves last bits). `None`: the layout alone is compared (Monte Carlo, where a
    /// last bit can send a photon elsewhere).
    tolerance: Option<f64>,
}

/// Zonal (isotropic, one grey channel, a directional light, per-cell albedo).
const SMALL: Case = Case {
    file: "small.volrad",
    scene: r#"
[volume]
generator = { kind = "dipole" }
dims = [4, 3, 2]
sigma_t_scale = 1.6
cell_size = 0.5
# Written when `nearest` was the default; the golden file stores it.
interpolation = "nearest"

[medium]
albedo = { kind = "piecewise-linear", points = [[0.0, 0.6], [1.0, 0.95]] }
phase = "isotropic"

[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.2]
irradiance = 1.0

[background]
radiance = 0.25

[solve]
method = "zonal"
tolerance = 1e-6

[render]
exposure = 1.5
spp = 4

[[camera]]
name = "front"
eye = [1.0, 1.5, -8.0]
target = [1.0, 0.75, 0.5]
up = [0.0, 1.0, 0.0]
fov_y = 40.0
width = 16
height = 12
"#,
    tolerance: Some(1e-4),
};

/// Discrete ordinates with 6 bins (Henyey–Greenstein, three colour channels, a spot light,
/// emission, trilinear look, an orthographic camera).
const ORDINATES: Case = Case {
    file: "small-ordinates.volrad",
    scene: r#"
[volume]
generator = { kind = "dipole" }
dims = [3, 3, 2]
sigma_t_scale = [0.5, 0.7, 0.9]
interpolation = "trilinear"

[medium]
albedo = [0.9, 0.8, 0.7]
phase = { kind = "henyey-greenstein", g = 0.6 }
emission = 0.05

[[light]]
kind = "spot"
position = [1.5, 6.0, 1.0]
axis = [0.0, -1.0, 0.0]
half_angle_degrees = 30.0
intensity = 4.0

[solve]
method = "discrete-ordinates"
bins = 6
tolerance = 1e-6
# The solve the golden file was written with, before δ-M truncation became the default.
forward_peak_cone = 0

[[camera]]
name = "top"
projection = "orthographic"
ortho_height = 4.0
eye = [1.5, 10.0, 1.0]
target = [1.5, 1.5, 1.0]
up = [0.0, 0.0, 1.0]
width = 8
height = 8
"#,
    tolerance: Some(1e-4),
};

/// Blasi & Wuethrich's two-pass method (two-lobe phase: 12 × 24 direction bins, a point
/// light, the fewest photons allowed).
const TWO_PASS: Case = Case {
    file: "small-two-pass.volrad",
    scene: r#"
[volume]
generator = { kind = "dipole" }
dims = [3, 2, 2]
sigma_t_scale = 1.5
# Written when `nearest` was the default; the golden file stores it.
interpolation = "nearest"

[medium]
albedo = 0.8
phase = { kind = "two-lobe", r = 0.7, g1 = 0.6, g2 = -0.3 }

[[light]]
kind = "point"
position = [1.5, 5.0, 1.0]
intensity = 10.0

[solve]
method = "two-pass"
photons = 1000

[[camera]]
name = "front"
eye = [1.5, 1.0, -6.0]
target = [1.5, 1.0, 1.0]
up = [0.0, 1.0, 0.0]
fov_y = 45.0
width = 8
height = 6
"#,
    tolerance: None,
};

const CASES: [&Case; 3] = [&SMALL, &ORDINATES, &TWO_PASS];

fn golden_path(file: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data/solution-golden")
        .join(file)
}

/// The solution of `case` as this volrad writes it, with the solve times (the one thing a
/// solve does not repeat) set to zero.
fn generate(case: &Case) -> Vec<u8> {
    let label = Path::new("solution-golden").join(case.file.replace(".volrad", ".toml"));
    let scene = Scene::from_toml_str(case.scene, Path::new("."), &label).unwrap();
    let mut solution = solve_scene(&scene, &scene.solve, &SolveHooks::default()).unwrap();
    for ch in &mut solution.channels {
        if let Some(r) = &mut ch.report {
            r.seconds = 0.0;
            r.seconds_per_iteration = 0.0;
        }
    }
    solution.to_bytes()
}

fn decode(bytes: &[u8], what: &str) -> Container<'static, MetaRecord> {
    Container::<MetaRecord>::from_bytes(bytes, Path::new(what)).unwrap_or_else(|e| {
        panic!(
            "{e}\nThe golden file no longer decodes: the layout changed. If that is intended, \
             bump FORMAT_VERSION (src/solution/container.rs) and rewrite the golden files \
             with VOLRAD_BLESS=1 cargo test --test solution_file"
        )
    })
}

/// The metadata as JSON with the values that are not layout masked: every number, the scene
/// hash (a hash of the libraries' own encoding) and the writer's version.
fn shape(v: &Value) -> Value {
    match v {
        Value::Number(_) => Value::from(0),
        Value::Array(a) => Value::Array(a.iter().map(shape).collect()),
        Value::Object(o) => Value::Object(
            o.iter()
                .map(|(k, v)| match k.as_str() {
                    "scene_hash" | "volrad_version" => (k.clone(), Value::from("")),
                    _ => (k.clone(), shape(v)),
                })
                .collect(),
        ),
        other => other.clone(),
    }
}

fn close(a: f64, b: f64, tolerance: f64) -> bool {
    a == b || (a - b).abs() <= tolerance * a.abs().max(b.abs()) + 1e-30
}

/// Every number of `a` within `tolerance` of the same number of `b` (same shape assumed).
fn numbers_close(a: &Value, b: &Value, tolerance: f64, at: &str) -> Result<(), String> {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => {
            let (x, y) = (x.as_f64().unwrap(), y.as_f64().unwrap());
            if close(x, y, tolerance) {
                Ok(())
            } else {
                Err(format!("{at}: {x} here, {y} in the golden file"))
            }
        }
        (Value::Array(x), Value::Array(y)) => x
            .iter()
            .zip(y)
            .enumerate()
            .try_for_each(|(i, (x, y))| numbers_close(x, y, tolerance, &format!("{at}[{i}]"))),
        (Value::Object(x), Value::Object(y)) => x.iter().try_for_each(|(k, v)| {
            if k == "scene_hash" || k == "volrad_version" {
                return Ok(());
            }
            numbers_close(v, &y[k], tolerance, &format!("{at}.{k}"))
        }),
        _ => Ok(()),
    }
}

#[test]
fn golden_files_match_what_this_volrad_writes() {
    let bless = std::env::var("VOLRAD_BLESS").is_ok_and(|v| v == "1");
    for case in CASES {
        let fresh = generate(case);
        let path = golden_path(case.file);
        if bless {
            std::fs::create_dir_all(path.parent().unwrap()).unwrap();
            std::fs::write(&path, &fresh).unwrap();
            eprintln!("wrote {} ({} bytes)", path.display(), fresh.len());
            continue;
        }
        let golden = std::fs::read(&path).unwrap_or_else(|e| {
            panic!(
                "{}: {e}; write it with VOLRAD_BLESS=1 cargo test --test solution_file",
                path.display()
            )
        });
        if fresh == golden {
            continue;
        }
        // Not the same bytes: the layout must still be the same, and (unless Monte Carlo)
        // the numbers close.
        let (f, g) = (decode(&fresh, "fresh"), decode(&golden, case.file));
        let (fj, gj) = (
            serde_json::to_value(&f.meta).unwrap(),
            serde_json::to_value(&g.meta).unwrap(),
        );
        assert_eq!(
            shape(&fj),
            shape(&gj),
            "{}: the metadata's layout differs from the golden file's. If the change is \
             intended, bump FORMAT_VERSION and rewrite with VOLRAD_BLESS=1",
            case.file
        );
        let names = |c: &Container<'static, MetaRecord>| {
            c.arrays
                .iter()
                .map(|(n, v)| (n.clone(), v.len()))
                .collect::<Vec<_>>()
        };
        assert_eq!(
            names(&f),
            names(&g),
            "{}: the arrays differ from the golden file's (names, order or lengths). If the \
             change is intended, bump FORMAT_VERSION and rewrite with VOLRAD_BLESS=1",
            case.file
        );
        if let Some(tolerance) = case.tolerance {
            let numbers = numbers_close(&fj, &gj, tolerance, "meta").and_then(|()| {
                f.arrays
                    .iter()
                    .zip(&g.arrays)
                    .try_for_each(|((n, x), (_, y))| {
                        match x
                            .iter()
                            .zip(y.iter())
                            .position(|(a, b)| !close(*a as f64, *b as f64, tolerance))
                        {
                            Some(i) => Err(format!("{n}[{i}]: {} here, {} golden", x[i], y[i])),
                            None => Ok(()),
                        }
                    })
            });
            if let Err(e) = numbers {
                panic!(
                    "{}: same layout, other numbers ({e}). If the solvers changed on purpose, \
                     rewrite with VOLRAD_BLESS=1",
                    case.file
                );
            }
        }
        eprintln!(
            "note: {}: same layout as the golden file, numbers differ in the last bits \
             (another CPU or build)",
            case.file
        );
    }
}

/// Reads a committed golden file and checks that decoding then encoding again gives its
/// bytes, both for the container of records and for the whole [`Solution`] (the writer's
/// version aside, which the encoder always sets to its own).
fn read_golden(file: &str) -> Solution {
    let path = golden_path(file);
    let golden = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    // The ordinates' file (170 kB) holds 3 kB of binned light per wide-lit cell (format 14):
    // its small grid emits nearly everywhere, so most of its cells are lit from all sides.
    assert!(
        golden.len() < 200_000,
        "{file}: {} bytes, keep golden files small",
        golden.len()
    );
    assert_eq!(
        u32::from_le_bytes(golden[8..12].try_into().unwrap()),
        FORMAT_VERSION
    );
    let records = decode(&golden, file);
    assert_eq!(
        records.to_bytes().unwrap(),
        golden,
        "{file}: the records do not encode back to the same bytes"
    );

    let solution = Solution::from_bytes(&golden, &path).unwrap();
    let again = solution.to_bytes();
    let mut again_records = decode(&again, "re-encoded");
    again_records.meta.volrad_version = records.meta.volrad_version.clone();
    assert_eq!(
        again_records.to_bytes().unwrap(),
        golden,
        "{file}: the solution does not encode back to the same bytes"
    );
    assert_eq!(Solution::from_bytes(&again, &path).unwrap(), solution);
    solution
}

#[test]
fn golden_small_decodes() {
    let s = read_golden(SMALL.file);
    assert_eq!(s.method, SolveMethod::Zonal);
    assert_eq!(s.scene_origin, "solution-golden/small.toml");
    assert_eq!(s.medium.grid().dims, [4, 3, 2]);
    assert_eq!(s.medium.grid().cell_size, 0.5);
    assert_eq!(s.medium.phase(), PhaseFunction::Isotropic);
    assert_eq!(s.medium.interpolation(), Interpolation::Nearest);
    assert_eq!(s.background, 0.25);
    assert_eq!(s.render.model, OpticalModel::Scattering);
    assert_eq!((s.render.exposure, s.render.spp), (Some(1.5), 4));
    assert_eq!(s.cameras.len(), 1);
    assert_eq!(s.cameras[0].name, "front");
    assert_eq!(s.cameras[0].eye, DVec3::new(1.0, 1.5, -8.0));
    assert_eq!(
        s.cameras[0].projection,
        Projection::Perspective {
            fov_y_degrees: 40.0
        }
    );
    assert_eq!((s.cameras[0].width, s.cameras[0].height), (16, 12));
    assert!(s.bins.is_none());

    assert_eq!(s.lights.len(), 1);
    let Light::Directional {
        direction,
        irradiance,
    } = s.lights[0]
    else {
        panic!("{:?}", s.lights[0]);
    };
    assert!((direction - DVec3::new(0.3, -1.0, 0.2).normalize()).length() < 1e-15);
    assert_eq!(irradiance, 1.0);

    let cells = 24;
    assert_eq!(s.medium.channels().len(), 1);
    let m = &s.medium.channels()[0];
    assert_eq!(m.sigma_t.len(), cells);
    assert_eq!(m.sigma_t[..4], SMALL_SIGMA_T);
    let CellValues::PerCell(albedo) = &m.albedo else {
        panic!("albedo {:?}", m.albedo);
    };
    assert_eq!(albedo[..4], SMALL_ALBEDO);
    assert_eq!(m.emission, CellValues::Uniform(0.0));
    assert_eq!(s.medium.data().map(<[f32]>::len), Some(cells));

    let ch = &s.channels[0];
    assert_eq!(ch.light_pass.fields.len(), 1);
    assert_eq!(ch.light_pass.fields[0].light, s.lights[0]);
    assert_eq!(
        ch.light_pass.fields[0].cell_irradiance[..4],
        SMALL_IRRADIANCE
    );
    assert_eq!(
        ch.light_pass.fields[0].corner_optical_depth.len(),
        5 * 4 * 3
    );
    let ScatteredField::Isotropic {
        source,
        higher_order,
    } = &ch.scattered
    else {
        panic!("{:?}", ch.scattered);
    };
    assert_eq!(source[..4], SMALL_SOURCE);
    assert_eq!(higher_order.len(), cells);
    let report = ch.report.as_ref().unwrap();
    assert_eq!(report.method, "cg");
    assert!(report.converged);
    assert_eq!(report.stop_reason, StopReason::Converged);
    assert!(report.final_residual <= 1e-6);
    assert_eq!(report.seconds, 0.0);
}

#[test]
fn golden_ordinates_decodes() {
    let s = read_golden(ORDINATES.file);
    assert_eq!(s.method, SolveMethod::DiscreteOrdinates);
    assert_eq!(s.medium.grid().dims, [3, 3, 2]);
    assert_eq!(s.medium.phase(), PhaseFunction::HenyeyGreenstein { g: 0.6 });
    assert_eq!(s.medium.interpolation(), Interpolation::Trilinear);
    assert_eq!(s.medium.channels().len(), 3);
    assert_eq!(s.medium.channels()[1].albedo, CellValues::Uniform(0.8));
    assert_eq!(s.medium.channels()[2].emission, CellValues::Uniform(0.05));
    assert_eq!(
        s.cameras[0].projection,
        Projection::Orthographic { height: 4.0 }
    );
    let Light::Spot {
        position,
        axis,
        half_angle,
        intensity,
    } = s.lights[0]
    else {
        panic!("{:?}", s.lights[0]);
    };
    assert_eq!(position, DVec3::new(1.5, 6.0, 1.0));
    assert_eq!(axis, DVec3::new(0.0, -1.0, 0.0));
    assert!((half_angle - 30f64.to_radians()).abs() < 1e-15);
    assert_eq!(intensity, 4.0);

    let bins = s.bins.as_ref().unwrap();
    assert_eq!(bins.face_resolution, 1);
    assert_eq!(bins.directions.len(), 6);
    let total: f64 = bins.solid_angles.iter().sum();
    assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-12);

    let cells = 18;
    for ch in &s.channels {
        let ScatteredField::Binned {
            fluence,
            higher_order,
        } = &ch.scattered
        else {
            panic!("{:?}", ch.scattered);
        };
        // The bins' fluence per cell (format 12), and the higher orders of every cell here
        // (all of them scatter) in rows of 6 bins.
        assert_eq!(fluence.len(), cells);
        assert!(fluence.iter().all(|&f| f > 0.0));
        assert_eq!(
            (
                higher_order.cells(),
                higher_order.kept_cells(),
                higher_order.width()
            ),
            (cells, cells, 6)
        );
        assert_eq!(ch.report.as_ref().unwrap().method, "gauss-seidel");
    }
    let ScatteredField::Binned { fluence, .. } = &s.channels[2].scattered else {
        unreachable!()
    };
    assert_eq!(fluence[..4], ORDINATES_FLUENCE_2);
    // An emitting channel stores its emitter pass (format 7).
    let emitted = s.channels[2].emitted_fluence.as_ref().unwrap();
    assert_eq!(emitted.len(), cells);
    assert!(emitted.iter().all(|&v| v > 0.0));
    // And its first scattering for the render to draw by direction (format 11; format 13:
    // the incident light as a cone and a rest): σs φ, the cone's weight and cosine, and the
    // unit axis per cell.
    let beam = s.channels[2].emitted_beam.as_ref().unwrap();
    assert_eq!(beam.shapes.len(), 6 * cells);
    for v in beam.shapes.chunks(6) {
        let axis = (v[3] * v[3] + v[4] * v[4] + v[5] * v[5]).sqrt();
        assert!(v[0] > 0.0 && (0.0..=1.0).contains(&v[1]), "{v:?}");
        assert!((-1.0..=1.0).contains(&v[2]), "{v:?}");
        assert!(axis == 0.0 || (axis - 1.0).abs() < 1e-5, "{v:?}");
    }
    // The widest-lit cells' light in 192 direction bins (format 14): per bin a share and the
    // mean direction times it; the shares of a row sum to 1.
    assert_eq!(beam.binned.cells(), cells);
    assert!(beam.binned.kept_cells() > 0);
    for (cell, row) in beam.binned.kept_rows() {
        assert_eq!(row.len(), 4 * 192);
        let shares: f32 = row.iter().step_by(4).sum();
        assert!((shares - 1.0).abs() < 1e-4, "cell {cell}: {shares}");
        for bin in row.chunks(4) {
            let m = (bin[1] * bin[1] + bin[2] * bin[2] + bin[3] * bin[3]).sqrt();
            assert!(
                bin[0] >= 0.0 && m <= bin[0] * 1.0001,
                "cell {cell}: {bin:?}"
            );
        }
    }
    // Every channel emits here; each has its own.
    assert!(s.channels.iter().all(|c| c
        .emitted_beam
        .as_ref()
        .is_some_and(|b| b.shapes.len() == 6 * cells)));
}

#[test]
fn golden_two_pass_decodes() {
    let s = read_golden(TWO_PASS.file);
    assert_eq!(s.method, SolveMethod::TwoPass);
    assert_eq!(
        s.medium.phase(),
        PhaseFunction::TwoLobe {
            r: 0.7,
            g1: 0.6,
            g2: -0.3
        }
    );
    assert_eq!(
        s.lights[0],
        Light::Point {
            position: DVec3::new(1.5, 5.0, 1.0),
            intensity: 10.0
        }
    );
    let ch = &s.channels[0];
    assert!(ch.report.is_none());
    let ScatteredField::TwoPass(t) = &ch.scattered else {
        panic!("{:?}", ch.scattered);
    };
    assert_eq!(t.grid, *s.medium.grid());
    assert_eq!(t.storage_factor, 1);
    assert_eq!(t.optical_dims, [3, 2, 2]);
    assert_eq!((t.bins.n_theta, t.bins.n_phi), (12, 24));
    assert_eq!(t.voxel_source.len(), 12 * 288);
    assert_eq!(t.cell_share.len(), 12);
    assert_eq!(t.energy.photons, 1000);
    assert!(!t.include_first_bounce);
    assert_eq!(t.energy.interactions, TWO_PASS_INTERACTIONS);
    assert_eq!(t.max_source, TWO_PASS_MAX_SOURCE);
    // The field is stored as arrays, not in the metadata, whose size is bounded
    // (MAX_METADATA_BYTES): a 48×48×36 two-pass solution's 96 MB field once failed to write.
    let bytes = std::fs::read(golden_path(TWO_PASS.file)).unwrap();
    let container = decode(&bytes, TWO_PASS.file);
    let names: Vec<&str> = container.arrays.iter().map(|(n, _)| n.as_str()).collect();
    assert!(
        names.contains(&"two_pass/0/voxel_source") && names.contains(&"two_pass/0/cell_share"),
        "{names:?}"
    );
    let metadata_len = u64::from_le_bytes(bytes[24..32].try_into().unwrap());
    assert!(metadata_len < 4096, "metadata of {metadata_len} bytes");
}

// Values read from the committed golden files (exact: they are what the files hold).
const SMALL_SIGMA_T: [f32; 4] = [0.66302073, 1.6, 1.6, 0.66302073];
const SMALL_ALBEDO: [f32; 4] = [0.74503577, 0.95, 0.95, 0.74503577];
const SMALL_IRRADIANCE: [f32; 4] = [0.6758711, 0.34533805, 0.27765468, 0.44522983];
const SMALL_SOURCE: [f32; 4] = [0.035039145, 0.081582904, 0.06898902, 0.024120944];
const ORDINATES_FLUENCE_2: [f32; 4] = [0.1997151, 0.2691873, 0.19978654, 0.25200474];
const TWO_PASS_INTERACTIONS: u64 = 42;
const TWO_PASS_MAX_SOURCE: f64 = 0.09003358334302902;

/// A solution file that is a FIFO, a directory or a device is refused at once, naming the path
/// and what it is; reading a FIFO would otherwise block forever (the reads run on a thread the
/// test stops waiting for).
#[cfg(unix)]
#[test]
fn a_solution_that_is_a_fifo_or_a_directory_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("fifo.volrad");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(made.success());
    let folder = dir.path().join("folder.volrad");
    std::fs::create_dir(&folder).unwrap();
    let cases = vec![
        (fifo, "is a FIFO, not a regular file"),
        (folder, "is a directory, not a regular file"),
        (
            PathBuf::from("/dev/null"),
            "is a character device, not a regular file",
        ),
    ];
    let count = cases.len();
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        for (path, what) in cases {
            let result = Solution::read(&path).map(|_| ());
            let _ = tx.send((path, what, result));
        }
    });
    for _ in 0..count {
        let (path, what, result) = rx
            .recv_timeout(std::time::Duration::from_secs(10))
            .expect("refused at once, not blocked reading a FIFO");
        let err = result.expect_err("not a solution");
        assert_eq!(err.to_string(), format!("{}: {what}", path.display()));
        // As the command line prints it (the whole chain): once, not twice.
        assert_eq!(
            format!("{:#}", anyhow::Error::new(err)),
            format!("{}: {what}", path.display())
        );
    }
}

/// First views of one solution rendered at once from several threads (as the service's
/// requests and its background preparation do) all finish and agree: the shared render
/// caches are built once, and no thread waits on a cache that its own stack is building.
#[test]
fn concurrent_first_views_of_one_solution_finish_and_agree() {
    let golden = std::fs::read(golden_path(ORDINATES.file)).unwrap();
    for _ in 0..20 {
        let solution = std::sync::Arc::new(
            Solution::from_bytes(&golden, &golden_path(ORDINATES.file)).unwrap(),
        );
        let (sender, receiver) = std::sync::mpsc::channel();
        for _ in 0..6 {
            let (solution, sender) = (solution.clone(), sender.clone());
            std::thread::spawn(move || {
                let image =
                    volrad::engine::pipeline::render_view(&solution, &solution.cameras[0], None)
                        .map(|image| image.pixels);
                let _ = sender.send(image);
            });
        }
        let images: Vec<Vec<f32>> = (0..6)
            .map(|_| {
                receiver
                    .recv_timeout(std::time::Duration::from_secs(60))
                    .expect("a first view did not finish within a minute")
                    .unwrap()
            })
            .collect();
        assert!(images[0].iter().any(|&v| v > 0.0));
        assert!(images.iter().all(|image| *image == images[0]));
    }
}
