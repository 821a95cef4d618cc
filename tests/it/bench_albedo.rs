//! `volrad bench albedo` on a generated 10×10×8 cloud: the albedo-scaled operator, the CSV,
//! the Jacobi counts against the spectral-radius prediction, albedo 1, and the PNG plots.

use std::path::{Path, PathBuf};

use formfactor::{ExactOptions, FormFactorMatrix, HierarchicalOperator, HierarchicalOptions};
use medium::CellValues;
use scene::Scene;
use solver::{Method, SolveControl, SolveOptions, TransportOperator};
use volrad::bench_albedo::{
    residual_plot_path, run_albedo_bench, write_outputs, AlbedoBenchOptions, AlbedoRun,
    AlbedoScaled, CSV_HEADER,
};

/// A 10×10×8 generated cloud; `sigma_t_scale` sets how much light stays inside.
fn scene_file(dir: &Path, method: &str, sigma_t_scale: f64) -> PathBuf {
    let text = format!(
        r#"
[volume]
generator = {{ kind = "cloud", seed = 3 }}
dims = [10, 10, 8]
sigma_t_scale = {sigma_t_scale}

[medium]
albedo = 0.9
phase = {{ kind = "isotropic" }}

[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.2]
irradiance = 1.0

[solve]
method = "{method}"
bins = 24

[[camera]]
name = "front"
eye = [5.0, 8.0, -20.0]
target = [5.0, 5.0, 4.0]
up = [0.0, 1.0, 0.0]
fov_y = 40.0
width = 40
height = 30
"#
    );
    let path = dir.join(format!("bench-{method}.toml"));
    std::fs::write(&path, text).unwrap();
    path
}

fn scene(dir: &Path, method: &str, sigma_t_scale: f64) -> Scene {
    Scene::from_file(&scene_file(dir, method, sigma_t_scale)).unwrap()
}

fn options(albedos: &[f64], methods: &[&str], sigma_scales: &[f64]) -> AlbedoBenchOptions {
    AlbedoBenchOptions {
        albedos: albedos.to_vec(),
        iterations: methods.iter().map(|m| m.parse().unwrap()).collect(),
        sigma_scales: sigma_scales.to_vec(),
        tolerance: 1e-5,
        max_iterations: 2000,
    }
}

fn quiet(_: &str) {}

fn runs_of<'a>(runs: &'a [AlbedoRun], method: &str) -> Vec<&'a AlbedoRun> {
    runs.iter().filter(|r| r.method == method).collect()
}

#[test]
fn scaled_operator_equals_operator_built_at_that_albedo() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scene(dir.path(), "zonal", 2.0);
    let mut unit = scene.medium.channels()[0].clone();
    unit.albedo = CellValues::Uniform(1.0);
    let mut at = unit.clone();
    at.albedo = CellValues::Uniform(0.7);
    let unit = scene.medium.clone().with_channel(0, unit).unwrap();
    let at = scene.medium.clone().with_channel(0, at).unwrap();
    let k1 = FormFactorMatrix::build(&unit, 0, &ExactOptions::default(), None).unwrap();
    let ka = FormFactorMatrix::build(&at, 0, &ExactOptions::default(), None).unwrap();
    let scaled = AlbedoScaled::new(&k1, 0.7);
    let x: Vec<f64> = (0..k1.len()).map(|i| 1.0 + (i % 7) as f64).collect();
    let (mut y_scaled, mut y_built) = (vec![0.0; x.len()], vec![0.0; x.len()]);
    scaled.apply(&x, &mut y_scaled);
    ka.apply(&x, &mut y_built);
    let err = y_scaled
        .iter()
        .zip(&y_built)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    let scale = y_built.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    // 1e-6: the medium stores the albedo as f32 (0.7 is not exact there).
    assert!(
        scale > 0.0 && err <= 1e-6 * scale,
        "max |aK1 x − Ka x| = {err} (scale {scale})"
    );
    // Rows scale too (Gauss–Seidel uses them).
    let rows = scaled.rows().expect("the exact zonal operator has rows");
    assert!((rows.row_dot(5, &x) - y_built[5]).abs() <= 1e-6 * scale);
}

#[test]
fn scaled_sweeps_without_rows_reach_the_jacobi_solution() {
    // The hierarchical operator has no rows: Gauss–Seidel and SOR go through its own sweep
    // with the shifted source and relaxation. A wrong shift converges to a different g.
    let dir = tempfile::tempdir().unwrap();
    let scene = scene(dir.path(), "zonal-hierarchical", 2.0);
    let mut unit = scene.medium.channels()[0].clone();
    unit.albedo = CellValues::Uniform(1.0);
    let unit = scene.medium.clone().with_channel(0, unit).unwrap();
    let k1 = HierarchicalOperator::build(&unit, 0, &HierarchicalOptions::default()).unwrap();
    assert!(k1.rows().is_none());
    let op = AlbedoScaled::new(&k1, 0.8);
    let source: Vec<f64> = (0..op.len()).map(|i| (i % 5) as f64 * 0.1 + 0.05).collect();
    let solve = |method: Method| {
        let options = SolveOptions {
            method,
            tolerance: 1e-9,
            max_iterations: 5000,
            record_history: false,
        };
        let (g, report) =
            solver::solve(&op, &source, None, &options, &SolveControl::new()).unwrap();
        assert!(report.converged, "{method}: {report:?}");
        g
    };
    let jacobi = solve(Method::Jacobi);
    let norm = jacobi.iter().map(|v| v * v).sum::<f64>().sqrt();
    for method in [Method::GaussSeidel, Method::Sor { omega: 1.3 }] {
        let g = solve(method);
        let diff = g
            .iter()
            .zip(&jacobi)
            .map(|(a, b)| (a - b).powi(2))
            .sum::<f64>()
            .sqrt();
        assert!(
            diff <= 1e-6 * norm,
            "{method}: ‖g − g_jacobi‖ / ‖g‖ = {}",
            diff / norm
        );
    }
}

#[test]
fn csv_has_a_row_per_combination_and_plots_are_pngs() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scene(dir.path(), "zonal", 2.0);
    let albedos = [0.5, 0.9, 1.0];
    let methods = ["jacobi", "gauss-seidel", "gmres:30"];
    let scales = [0.5, 1.0];
    let runs = run_albedo_bench(&scene, &options(&albedos, &methods, &scales), &mut quiet).unwrap();
    let out = dir.path().join("out");
    write_outputs(&out, &runs, "test", 1e-5).unwrap();

    let csv = std::fs::read_to_string(out.join("albedo.csv")).unwrap();
    let mut lines = csv.lines();
    assert_eq!(lines.next().unwrap(), CSV_HEADER);
    let columns = CSV_HEADER.split(',').count();
    assert_eq!(columns, 10);
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len(), albedos.len() * methods.len() * scales.len());
    for &a in &albedos {
        for m in methods {
            for &s in &scales {
                let n = rows
                    .iter()
                    .filter(|r| {
                        r[0].parse::<f64>().unwrap() == a
                            && r[2] == m
                            && r[1].parse::<f64>().unwrap() == s
                    })
                    .count();
                assert_eq!(n, 1, "albedo {a}, method {m}, σ-scale {s}");
            }
        }
    }
    for r in &rows {
        assert_eq!(r.len(), columns, "{r:?}");
        let iterations: usize = r[3].parse().unwrap();
        let converged: bool = r[4].parse().unwrap();
        let residual: f64 = r[5].parse().unwrap();
        assert!(iterations > 0);
        assert_eq!(converged, residual <= 1e-5, "{r:?}");
    }

    for path in [out.join("albedo.png")]
        .into_iter()
        .chain(albedos.iter().map(|&a| residual_plot_path(&out, a)))
    {
        let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        assert!(
            bytes.starts_with(b"\x89PNG\r\n\x1a\n"),
            "{}",
            path.display()
        );
        let img = image::load_from_memory(&bytes).unwrap().to_rgb8();
        assert_eq!(img.dimensions(), (960, 640));
        // Something beyond the white background was drawn (lines, labels).
        let dark = img
            .pixels()
            .filter(|p| p.0.iter().all(|&c| c < 100))
            .count();
        assert!(dark > 1000, "{}: {dark} dark pixels", path.display());
    }
}

#[test]
fn jacobi_counts_grow_with_albedo_and_match_the_spectral_prediction() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scene(dir.path(), "zonal", 4.0);
    let albedos = [0.3, 0.6, 0.8, 0.9, 0.95, 0.99, 1.0];
    let runs =
        run_albedo_bench(&scene, &options(&albedos, &["jacobi"], &[1.0]), &mut quiet).unwrap();
    let jacobi = runs_of(&runs, "jacobi");
    assert_eq!(jacobi.len(), albedos.len());
    for pair in jacobi.windows(2) {
        assert!(pair[0].albedo < pair[1].albedo);
        assert!(
            pair[0].iterations <= pair[1].iterations,
            "a={} needs {} iterations, a={} only {}",
            pair[0].albedo,
            pair[0].iterations,
            pair[1].albedo,
            pair[1].iterations
        );
        assert!(pair[0].spectral_radius < pair[1].spectral_radius);
    }
    assert!(jacobi.last().unwrap().iterations > jacobi[0].iterations + 5);
    for r in &jacobi {
        assert!(r.converged, "a={}: {r:?}", r.albedo);
        let predicted = r
            .predicted_jacobi_iterations
            .expect("ρ < 1 in a leaky cloud") as f64;
        let measured = r.iterations as f64;
        assert!(
            (predicted - measured).abs() <= (0.05 * measured).max(2.0),
            "a={}: ρ={} predicts {predicted}, measured {measured}",
            r.albedo,
            r.spectral_radius
        );
    }
}

#[test]
fn albedo_one_every_method_converges_or_says_it_did_not() {
    let dir = tempfile::tempdir().unwrap();
    let scene = scene(dir.path(), "zonal", 4.0);
    let methods = [
        "jacobi",
        "gauss-seidel",
        "sor:1.5",
        "gmres:30",
        "bicgstab",
        "cg",
        "coarse-cg",
        "coarse-gs",
    ];
    let mut capped = options(&[1.0], &methods, &[1.0]);
    // Five iterations are too few for Jacobi here: it must report that, not claim success.
    capped.max_iterations = 5;
    let runs = run_albedo_bench(&scene, &capped, &mut quiet).unwrap();
    let jacobi = runs_of(&runs, "jacobi")[0];
    assert!(!jacobi.converged && jacobi.iterations == 5, "{jacobi:?}");
    assert!(jacobi.final_residual > 1e-5);

    let runs = run_albedo_bench(&scene, &options(&[1.0], &methods, &[1.0]), &mut quiet).unwrap();
    assert_eq!(runs.len(), methods.len());
    for r in &runs {
        assert!(r.iterations <= 2000, "{r:?}");
        assert_eq!(r.converged, r.final_residual <= 1e-5, "{r:?}");
        assert!(r.final_residual.is_finite() || !r.converged);
    }
}

#[test]
fn per_cell_albedo_and_bad_albedos_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let mut scene = scene(dir.path(), "zonal", 1.0);
    let cells = scene.medium.grid().cell_count();
    let opts = options(&[0.5], &["jacobi"], &[1.0]);
    for bad in [0.0, -0.1, 1.5, f64::NAN] {
        let mut o = opts.clone();
        o.albedos = vec![bad];
        assert!(
            run_albedo_bench(&scene, &o, &mut quiet).is_err(),
            "albedo {bad}"
        );
    }
    let mut o = opts.clone();
    o.iterations = Vec::new();
    assert!(run_albedo_bench(&scene, &o, &mut quiet).is_err());
    assert!("newton".parse::<solver::Method>().is_err());
    let mut channel = scene.medium.channels()[0].clone();
    channel.albedo = CellValues::PerCell((0..cells).map(|i| 0.5 + 0.4 * (i % 2) as f32).collect());
    scene.medium = scene.medium.clone().with_channel(0, channel).unwrap();
    let err = run_albedo_bench(&scene, &opts, &mut quiet)
        .unwrap_err()
        .to_string();
    assert!(err.contains("per-cell albedo"), "{err}");
}

/// The bench iterates the operator a solve iterates: on the scene's transport grid when it
/// is coarser (`transport_scale = 2`: the Jacobi solve of the scene and the bench's run at the
/// scene's albedo take the same iterations), and a scene whose solve would not fit in memory
/// is refused before any operator is built.
#[test]
fn the_bench_iterates_the_solves_operator_and_checks_memory_first() {
    let dir = tempfile::tempdir().unwrap();
    let path = scene_file(dir.path(), "zonal", 2.0);
    let text = std::fs::read_to_string(&path).unwrap().replace(
        "bins = 24",
        "bins = 24\ntransport_scale = 2\niteration = \"jacobi\"",
    );
    std::fs::write(&path, text).unwrap();
    let scene = Scene::from_file(&path).unwrap();
    let runs = run_albedo_bench(&scene, &options(&[0.9], &["jacobi"], &[1.0]), &mut quiet).unwrap();
    let solution = volrad::engine::pipeline::solve_scene(
        &scene,
        &scene.solve,
        &volrad::engine::SolveHooks::default(),
    )
    .unwrap();
    assert_eq!(solution.transport.transport().dims, [5, 5, 4]);
    let report = solution.channels[0].report.as_ref().unwrap();
    assert_eq!(runs[0].iterations, report.iterations);

    let out = crate::fixtures::volrad(&[
        "--max-memory",
        "1M",
        "bench",
        "albedo",
        crate::fixtures::s(&path),
        "--albedo",
        "0.9",
        "-o",
        crate::fixtures::s(&dir.path().join("out")),
    ]);
    let err = crate::fixtures::stderr(&out);
    assert!(
        !out.status.success() && err.contains("needs about"),
        "{err}"
    );
    assert!(!dir.path().join("out").exists(), "nothing written");
}
