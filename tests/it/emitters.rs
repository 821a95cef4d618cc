//! Light from within the medium: emitting cells through every method. The emitters'
//! uncollided light is traced to every cell (the emitter pass), so a small source seen across
//! a near-empty region shows no ray effects, and `fluence` counts it in every method.

use std::path::Path;

use glam::DVec3;
use medium::emitter_pass::uniform_box_cell_fluence;
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Medium};
use rayon::prelude::*;

use crate::fixtures::{masked_error, path_traced};
use scene::Scene;
use volrad::engine::methods::fluence;
use volrad::engine::pipeline::{render_view, solve_scene};
use volrad::engine::SolveHooks;

const ISOTROPIC: &str = r#"{ kind = "isotropic" }"#;
const FORWARD: &str = r#"{ kind = "henyey-greenstein", g = 0.6 }"#;

/// A scene of `n³` unit cells whose central `side³` cube emits 2, with uniform albedo, solved
/// by `method`; σt is uniform (`Some`) or the generated cloud's (`None`, 0 at the grid's edge).
/// Returns it and the cube's `[lo, hi)` cell range.
fn emitting_cube(
    n: usize,
    side: usize,
    sigma_t: Option<f32>,
    albedo: f32,
    phase: &str,
    method: &str,
) -> (Scene, [usize; 2]) {
    let text = format!(
        r#"
[volume]
generator = {{ kind = "cloud", seed = 1 }}
dims = [{n}, {n}, {n}]
sigma_t_scale = 0.6
interpolation = "nearest"

[medium]
albedo = {albedo}
phase = {phase}
# Replaced below by the emitting cube.
emission = 1.0

[solve]
method = "{method}"
bins = 96

[[camera]]
name = "side"
eye = [{c}, {far}, {c}]
target = [{c}, {c}, {c}]
up = [0.0, 0.0, 1.0]
fov_y = 30.0
width = 64
height = 64
"#,
        c = n as f64 / 2.0,
        far = -2.5 * n as f64,
    );
    let mut scene =
        Scene::from_toml_str(&text, Path::new("."), Path::new("emitters-test.toml")).unwrap();
    let grid = *scene.medium.grid();
    let (lo, hi) = ((n - side) / 2, (n - side) / 2 + side);
    let emission = (0..grid.cell_count())
        .map(|c| {
            if grid.coords(c).iter().all(|&v| v >= lo && v < hi) {
                2.0
            } else {
                0.0
            }
        })
        .collect();
    scene.medium = Medium::new(
        grid,
        vec![ChannelMedium {
            sigma_t: match sigma_t {
                Some(s) => vec![s; grid.cell_count()],
                None => scene.medium.channels()[0].sigma_t.clone(),
            },
            albedo: CellValues::Uniform(albedo),
            emission: CellValues::PerCell(emission),
        }],
        scene.medium.phase(),
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    (scene, [lo, hi])
}

/// The exact mean uncollided fluence of cell `c` of the emitting cube (2 per unit length) in
/// uniform σt (a cell's value is its mean; at the cube's corners the centre's is 10 % above).
fn exact_fluence(grid: &Grid, c: usize, lo: f64, hi: f64, sigma: f64) -> f64 {
    let (lo, hi) = (DVec3::splat(lo), DVec3::splat(hi));
    uniform_box_cell_fluence(
        grid.cell_min(c),
        grid.cell_size,
        [lo, hi],
        sigma,
        2.0,
        20_000,
    )
}

/// Max's emission in a non-scattering medium: a uniformly emitting cube in vacuum and in a
/// pure absorber. Every method's exported fluence is the exact uncollided fluence within 1 %
/// at every cell of an octant (the cube is symmetric) and on the line through its middle. The
/// code before the emitter pass exported 0 in the zonal methods here and carried the light of
/// discrete ordinates on 96 directions (ray effects).
#[test]
fn an_emitting_cube_in_vacuum_and_in_an_absorber_has_the_exact_fluence_in_every_method() {
    let n = 16;
    for sigma in [0.0f32, 0.3] {
        let (scene, [lo, hi]) = emitting_cube(n, 4, Some(sigma), 0.0, ISOTROPIC, "none");
        let grid = *scene.medium.grid();
        let cells: Vec<usize> = (0..grid.cell_count())
            .filter(|&c| {
                let [i, j, k] = grid.coords(c);
                (i >= n / 2 && j >= n / 2 && k >= n / 2) || (j == n / 2 && k == n / 2)
            })
            .collect();
        let wanted: Vec<f64> = cells
            .par_iter()
            .map(|&c| exact_fluence(&grid, c, lo as f64, hi as f64, sigma as f64))
            .collect();
        for method in [
            "zonal",
            "zonal-hierarchical",
            "discrete-ordinates",
            "two-pass",
            "none",
        ] {
            let (scene, _) = emitting_cube(n, 4, Some(sigma), 0.0, ISOTROPIC, method);
            let solution = solve_scene(&scene, &scene.solve, &SolveHooks::default()).unwrap();
            let phi = fluence(&solution, 0).unwrap();
            let mut worst = (0.0f64, [0usize; 3]);
            for (&c, &want) in cells.iter().zip(&wanted) {
                let err = (phi[c] - want).abs() / want;
                if err > worst.0 {
                    worst = (err, grid.coords(c));
                }
            }
            eprintln!(
                "emitting cube, σt = {sigma}, {method}: worst cell {:.2} % at {:?}",
                worst.0 * 100.0,
                worst.1
            );
            assert!(
                worst.0 < 0.01,
                "{method}, σt = {sigma}: fluence off by {:.2} % at cell {:?}",
                worst.0 * 100.0,
                worst.1
            );
        }
    }
}

/// With scattering (albedo 0.9, σt·h ≤ 0.6), a view of a cube emitting inside a cloud,
/// rendered from a stored solution (16 samples per pixel: the cube's edges are sharp), agrees
/// with the path tracer, which samples emission as a source: isotropic in zonal-hierarchical,
/// discrete ordinates and two-pass, g = 0.6 in discrete ordinates (whose first collision
/// then has a direction: a cone and a rest about the pass's flux vector, drawn by the render in
/// the view's own direction) and two-pass. Measured: RMS 0.7 %, 0.9 % and 1.1 %
/// (zonal-hierarchical, discrete ordinates, two-pass at g = 0), 1.3 % and 2.3 % (discrete
/// ordinates and two-pass at g = 0.6; discrete ordinates 2.1 % with the first collision a
/// Henyey–Greenstein lobe of its mean cosine, 5.1 % as a beam and an isotropic rest stored in
/// the bins, and 5–8 % whatever the bins); image means −2.2 … +1.2 %.
/// Two-pass sent no photons from emitting cells before, and missed 45 % of this image.
#[test]
fn a_source_inside_a_scattering_medium_matches_the_path_tracer() {
    for (phase, methods) in [
        (
            ISOTROPIC,
            &["zonal-hierarchical", "discrete-ordinates", "two-pass"][..],
        ),
        (FORWARD, &["discrete-ordinates", "two-pass"][..]),
    ] {
        let (scene, _) = emitting_cube(16, 4, None, 0.9, phase, methods[0]);
        let traced = path_traced(&scene, 0, 1024);
        let peak = traced.mean.pixels.iter().fold(0.0f32, |a, &b| a.max(b)) as f64;
        // Discrete ordinates forward-scattering also at 216 bins: the emitters' first
        // collision, drawn in the view's direction, does not depend on the bins (stored in
        // them it was 5.1 % at 96 bins and 6.2 % at 216).
        let runs = methods.iter().flat_map(|&m| {
            let more = (m == "discrete-ordinates" && phase == FORWARD).then_some((m, Some(216)));
            [(m, None)].into_iter().chain(more)
        });
        for (method, bins) in runs {
            let method = &method;
            let (mut scene, _) = emitting_cube(16, 4, None, 0.9, phase, method);
            if let Some(b) = bins {
                scene.solve.bins = scene::BinCount::Fixed(b);
            }
            let solution = solve_scene(&scene, &scene.solve, &SolveHooks::default()).unwrap();
            let image = render_view(&solution, &scene.cameras[0], Some(16)).unwrap();
            let (rms, mean, count) = masked_error(&image, 0, &traced, |_, r| r > 1e-3 * peak);
            assert!(count > 200);
            let bins_text = match (*method, bins) {
                ("discrete-ordinates", b) => format!(" ({} bins)", b.unwrap_or(96)),
                _ => String::new(),
            };
            eprintln!(
                "emitting cube in a cloud, {phase}, {method}{bins_text}: RMS {:.2} %, mean {:+.2} %",
                rms * 100.0,
                mean * 100.0
            );
            // Every method draws the solved source as the cell's σs times the in-scattered
            // radiance interpolated between centres: 0.7–1.1 % (3.7–4.0 % with it constant
            // per cell). At g = 0.6, #23's 3 %.
            let rms_bound = match phase {
                FORWARD => 0.03,
                _ => 0.025,
            };
            // Two-pass at g = 0.6 is 2 % dark (its own bias).
            let mean_bound = if method == &"two-pass" && phase == FORWARD {
                0.03
            } else {
                0.02
            };
            assert!(
                rms < rms_bound && mean.abs() < mean_bound,
                "{phase}, {method}: RMS {:.2} %, image mean {:+.2} % against the path tracer",
                rms * 100.0,
                mean * 100.0
            );
        }
    }
}

/// A cloud that emits throughout (the fire sample) is an extended, smooth source: its pass
/// would trace thousands of rays per cell (17× the solve), so the solve carries the emission
/// through its operator and says so in `volrad info`; discrete ordinates' exported fluence then
/// counts the emission once, from the bins: without scattering it is the uncollided fluence
/// (the pass's, computed here) to within the bins' angular error, not twice it.
#[test]
fn an_extended_emitting_region_is_carried_by_the_operator() {
    let path = crate::fixtures::root().join("data/fire-scattering.toml");
    let o = crate::fixtures::volrad(&["info", crate::fixtures::s(&path)]);
    assert!(o.status.success());
    let info = String::from_utf8_lossy(&o.stdout);
    assert!(info.contains("carried by the operator"), "{info}");

    let text = std::fs::read_to_string(&path)
        .unwrap()
        .replace("albedo = 0.6", "albedo = 0.0")
        .replace(
            "method = \"zonal-hierarchical\"",
            "method = \"discrete-ordinates\"",
        );
    let scene = Scene::from_toml_str(&text, &crate::fixtures::root().join("data"), &path).unwrap();
    let solution = solve_scene(&scene, &scene.solve, &SolveHooks::default()).unwrap();
    assert!(solution
        .channels
        .iter()
        .all(|c| c.emitted_fluence.is_none()));
    let phi = fluence(&solution, 0).unwrap();
    let exact = medium::emitter_pass::EmitterPass::compute(
        &scene.medium,
        0,
        &medium::emitter_pass::EmitterPassOptions::default(),
    )
    .unwrap();
    let (sum, sum_exact): (f64, f64) = (phi.iter().sum(), exact.fluence().iter().sum());
    assert!(
        (sum / sum_exact - 1.0).abs() < 0.05,
        "total fluence {sum} (ordinates) against {sum_exact} (the emitter pass)"
    );
}

/// The zonal methods' fluence where nothing scatters (the empty space around a glowing,
/// scattering cloud) is the light of every cell's solved source traced there, not only the
/// uncollided light: it agrees with discrete ordinates (which carry all light in their bins)
/// inside the cloud and outside it. (Before, the zonal export counted only the uncollided
/// light outside: 43 % of the ordinates' there.)
#[test]
fn zonal_fluence_outside_the_scattering_cells_counts_the_scattered_light() {
    let path = crate::fixtures::root().join("data/fire-scattering.toml");
    let scene = Scene::from_file(&path).unwrap();
    let mut totals = Vec::new();
    for (method, iteration) in [
        ("zonal-hierarchical", "dsa-cg"),
        ("discrete-ordinates", "gauss-seidel"),
    ] {
        let mut settings = scene.solve.clone();
        settings.method = method.parse().unwrap();
        settings.iteration = iteration.parse().unwrap();
        let solution = solve_scene(&scene, &settings, &SolveHooks::default()).unwrap();
        let phi = fluence(&solution, 0).unwrap();
        let sigma_t = &scene.medium.channels()[0].sigma_t;
        let (mut cloud, mut empty) = (0.0, 0.0);
        for (f, s) in phi.iter().zip(sigma_t) {
            if *s > 0.0 {
                cloud += f;
            } else {
                empty += f;
            }
        }
        totals.push((cloud, empty));
    }
    let (zonal, ordinates) = (totals[0], totals[1]);
    for (what, a, b) in [
        ("cloud", zonal.0, ordinates.0),
        ("empty space", zonal.1, ordinates.1),
    ] {
        eprintln!(
            "fire sample, {what}: zonal / ordinates total fluence {:.4}",
            a / b
        );
        assert!(
            (a / b - 1.0).abs() < 0.05,
            "{what}: zonal {a} against ordinates {b}"
        );
    }
}

/// Analog Monte Carlo of `scene`'s emission: `histories` particles born uniformly in the
/// emitting cells (in proportion to their emission) with isotropic directions, flown with
/// exact free paths through the piecewise-constant medium, scattered with probability equal
/// to the albedo by the phase function; each scores its track length in every cell. Returns
/// per cell the scalar flux (emission `e` radiates `4π e` per unit volume) and its standard
/// error, from 32 independent batches.
fn analog_fluence(scene: &Scene, histories: u64) -> Vec<(f64, f64)> {
    use rand::Rng;
    let medium = &scene.medium;
    let grid = *medium.grid();
    let ch = &medium.channels()[0];
    let phase = medium.phase();
    let emitting: Vec<(usize, f64)> = (0..grid.cell_count())
        .map(|c| (c, ch.emission.get(c) as f64))
        .filter(|&(_, e)| e > 0.0)
        .collect();
    let total: f64 = emitting.iter().map(|&(_, e)| e).sum();
    let mut cumulative = Vec::with_capacity(emitting.len());
    let mut acc = 0.0;
    for &(_, e) in &emitting {
        acc += e / total;
        cumulative.push(acc);
    }
    let batches = 32u64;
    let per_batch = histories.div_ceil(batches);
    let tallies: Vec<Vec<f64>> = (0..batches)
        .into_par_iter()
        .map(|b| {
            let mut rng = montecarlo::rng::stream(23, 7, b);
            let mut tally = vec![0.0; grid.cell_count()];
            for _ in 0..per_batch {
                let u: f64 = rng.random();
                let k = cumulative
                    .partition_point(|&c| c < u)
                    .min(emitting.len() - 1);
                let corner = grid.cell_center(emitting[k].0) - DVec3::splat(0.5 * grid.cell_size);
                let offset = DVec3::new(rng.random(), rng.random(), rng.random());
                let mut x = corner + offset * grid.cell_size;
                let mut dir = medium::PhaseFunction::Isotropic.sample(DVec3::Z, &mut rng);
                loop {
                    let mut remaining = -(1.0 - rng.random::<f64>()).ln();
                    let ray = medium::traversal::Ray::new(x, dir);
                    let mut collided = None;
                    for s in grid.traverse(&ray, 0.0, f64::INFINITY) {
                        let sigma = ch.sigma_t[s.cell] as f64;
                        let l = s.length();
                        if sigma * l >= remaining {
                            tally[s.cell] += remaining / sigma;
                            collided = Some(s.t_enter + remaining / sigma);
                            break;
                        }
                        remaining -= sigma * l;
                        tally[s.cell] += l;
                    }
                    let Some(t) = collided else { break };
                    if rng.random::<f64>() >= ch.albedo.get(0) as f64 {
                        break;
                    }
                    x = ray.at(t);
                    dir = phase.sample(dir, &mut rng);
                }
            }
            tally
        })
        .collect();
    // Flux = track length per cell volume per particle × the source power 4π Σ e V (unit
    // volumes cancel).
    let scale = 4.0 * std::f64::consts::PI * total / per_batch as f64;
    (0..grid.cell_count())
        .map(|c| {
            let values: Vec<f64> = tallies.iter().map(|t| t[c] * scale).collect();
            let mean = values.iter().sum::<f64>() / batches as f64;
            let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>()
                / ((batches - 1) * batches) as f64;
            (mean, var.sqrt())
        })
        .collect()
}

const FORWARD_PEAKED: &str = r#"{ kind = "henyey-greenstein", g = 0.85 }"#;

/// #23's scattering cases for a cube emitting inside the cloud: phase function, albedo and
/// the methods that solve it (zonal-hierarchical is isotropic only).
const SCATTERING_CASES: [(&str, f32, &[&str]); 4] = [
    (
        ISOTROPIC,
        0.5,
        &["zonal-hierarchical", "discrete-ordinates", "two-pass"],
    ),
    (
        ISOTROPIC,
        0.99,
        &["zonal-hierarchical", "discrete-ordinates", "two-pass"],
    ),
    (FORWARD_PEAKED, 0.5, &["discrete-ordinates", "two-pass"]),
    (FORWARD_PEAKED, 0.99, &["discrete-ordinates", "two-pass"]),
];

/// Of the cells above 10⁻⁴ of the reference's peak that `select` picks: how many, the median
/// of `value / reference`, the share within 3 % plus three standard errors of the reference,
/// and the worst relative error.
fn flux_agreement(
    phi: &[f64],
    reference: &[(f64, f64)],
    select: impl Fn(usize) -> bool,
) -> (usize, f64, f64, f64) {
    let peak = reference.iter().map(|r| r.0).fold(0.0, f64::max);
    let (mut ratios, mut within, mut worst) = (Vec::new(), 0usize, 0.0f64);
    for (c, (&value, &(r, se))) in phi.iter().zip(reference).enumerate() {
        if r <= 1e-4 * peak || !select(c) {
            continue;
        }
        ratios.push(value / r);
        within += usize::from((value - r).abs() <= 0.03 * r + 3.0 * se);
        worst = worst.max((value - r).abs() / r);
    }
    ratios.sort_by(f64::total_cmp);
    let n = ratios.len();
    (
        n,
        ratios.get(n / 2).copied().unwrap_or(f64::NAN),
        within as f64 / n.max(1) as f64,
        worst,
    )
}

/// #23's per-cell measure: the scalar flux (`fluence`, all light) of every cell above 10⁻⁴ of
/// the peak against an analog Monte Carlo of the emission (4 × 10⁶ particles; a cell agrees
/// within 3 % plus three of its standard errors), for a cube emitting inside a cloud at albedo
/// 0.5 and 0.99, isotropic and g = 0.85. Printed per method for the scattering cells and the
/// empty ones; asserted where the methods hold today (docs/validation.md, *Light from emitting
/// cells*, has the table): in the scattering cells every method's median ratio is within 3 %
/// of 1 (two-pass's `fluence` had no scattered light before: medians 0.49–0.73), and 98 % of
/// all cells agree for zonal-hierarchical and for every method with isotropic scattering.
#[test]
fn every_cells_scalar_flux_against_an_analog_monte_carlo() {
    for (phase, albedo, methods) in SCATTERING_CASES {
        let (scene, _) = emitting_cube(16, 4, None, albedo, phase, methods[0]);
        let reference = analog_fluence(&scene, 4_000_000);
        let sigma_t = &scene.medium.channels()[0].sigma_t;
        for method in methods {
            let (scene, _) = emitting_cube(16, 4, None, albedo, phase, method);
            let solution = solve_scene(&scene, &scene.solve, &SolveHooks::default()).unwrap();
            let phi = fluence(&solution, 0).unwrap();
            let inside = flux_agreement(&phi, &reference, |c| sigma_t[c] > 0.0);
            let outside = flux_agreement(&phi, &reference, |c| sigma_t[c] == 0.0);
            eprintln!(
                "scalar flux, {phase}, albedo {albedo}, {method}: scattering cells ({}) median \
                 {:.3}, {:.0} % within, worst {:.1} %; empty cells ({}) median {:.3}, {:.0} % \
                 within, worst {:.1} %",
                inside.0,
                inside.1,
                inside.2 * 100.0,
                inside.3 * 100.0,
                outside.0,
                outside.1,
                outside.2 * 100.0,
                outside.3 * 100.0
            );
            assert!(inside.0 > 400 && outside.0 > 3000);
            assert!(
                (inside.1 - 1.0).abs() < 0.03,
                "{method}, albedo {albedo}: median ratio {:.3} in the scattering cells",
                inside.1
            );
            // Where the flux is every cell's source traced to the cell (the zonal methods; the
            // others with isotropic scattering) and each cell's uncollided light is its mean,
            // nearly every cell agrees: 87 %, 73 % and 61 % of the scattering cells did at
            // albedo 0.5 with centre values and the bins' and tallies' own flux.
            if *method == "discrete-ordinates" && phase == FORWARD_PEAKED {
                // The bins' own flux at g = 0.85, the emitters' first collision a cone and an
                // isotropic rest with the pass's three moments: 100 % and 99 % of the
                // scattering cells at albedo 0.5 and 0.99, 100 % and 94 % of the empty ones
                // (100 %, 94 %; 98 %, 85 % with a Henyey–Greenstein lobe of the mean cosine; 85
                // % and 63 % of the scattering cells with a beam and an isotropic rest).
                let share = if albedo < 0.9 { 0.98 } else { 0.92 };
                assert!(
                    inside.2 >= share && outside.2 >= share,
                    "{method}, albedo {albedo}: {:.1} % of the scattering cells and {:.1} % of \
                     the empty ones within 3 %",
                    inside.2 * 100.0,
                    outside.2 * 100.0
                );
            }
            if *method == "zonal-hierarchical" || phase == ISOTROPIC {
                assert!(
                    inside.2 >= 0.98 && outside.2 >= 0.98,
                    "{method}, albedo {albedo}: {:.1} % of the scattering cells and {:.1} % of \
                     the empty ones within 3 %",
                    inside.2 * 100.0,
                    outside.2 * 100.0
                );
            }
        }
    }
}

/// How a rendered view agrees with the path tracer over the pixels above 10⁻⁴ of the image's
/// peak (chosen by the render: choosing by the reference's own noisy values would keep the
/// pixels where it happens to be low): the pixels, the share within 3 % plus three standard
/// errors, and per band of brightness (bright: above 10⁻² of the peak; dim: below) the ratio
/// of the band's summed radiance to the reference's with its standard error. A single dim
/// pixel's reference is 20–60 % uncertain even at hundreds of paths and skewed (its median
/// lies below its mean), so the bands' sums, not the pixels' median, say whether a method is
/// biased there.
struct PixelAgreement {
    count: usize,
    within: f64,
    bright: (f64, f64),
    dim: (f64, f64),
}

fn pixel_agreement(
    image: &gather::Image,
    traced: &montecarlo::path_trace::PathTraced,
) -> PixelAgreement {
    let n = image.channels as usize;
    let peak = (0..traced.mean.pixels.len())
        .map(|i| image.pixels[n * i] as f64)
        .fold(0.0, f64::max);
    let (mut count, mut within) = (0usize, 0usize);
    // Per band: Σ value, Σ reference, Σ variance.
    let mut bands = [(0.0, 0.0, 0.0); 2];
    for (_, x, r, e) in crate::fixtures::pixels_against(image, 0, traced) {
        if x <= 1e-4 * peak {
            continue;
        }
        count += 1;
        within += usize::from((x - r).abs() <= 0.03 * r + 3.0 * e);
        let band = &mut bands[usize::from(x < 1e-2 * peak)];
        band.0 += x;
        band.1 += r;
        band.2 += e * e;
    }
    let ratio = |(x, r, v): (f64, f64, f64)| (x / r, x * v.sqrt() / (r * r));
    PixelAgreement {
        count,
        within: within as f64 / count.max(1) as f64,
        bright: ratio(bands[0]),
        dim: ratio(bands[1]),
    }
}

/// #23's per-pixel measure: two views (the side and from above) of the cube emitting inside
/// the cloud at albedo 0.5 and 0.99, isotropic and g = 0.85, rendered from each method's
/// stored solution (16 samples per pixel) against the path tracer with emission as a source
/// (1024 paths per pixel, with next-event estimation toward the emitting cells), over the
/// pixels above 10⁻⁴ of the peak ([`pixel_agreement`]). Printed per method and
/// view (docs/validation.md, *Light from emitting cells*, has the table); asserted where the
/// methods hold today (below).
#[test]
fn two_views_of_an_emitting_cube_pixel_by_pixel() {
    for (phase, albedo, methods) in SCATTERING_CASES {
        let (scene, _) = emitting_cube(16, 4, None, albedo, phase, methods[0]);
        let side = scene.cameras[0].clone();
        let mut above = side.clone();
        above.name = "above".into();
        above.eye = DVec3::new(8.0, 8.0 - 10.0, 8.0 + 38.0);
        above.up = DVec3::Y;
        let views = [side, above];
        let traced: Vec<_> = views
            .iter()
            .map(|v| {
                let options = montecarlo::PathTraceOptions {
                    spp: 1024,
                    emitter_sampling: true,
                    ..Default::default()
                };
                crate::fixtures::path_traced_with(&scene, v, 0, &options)
            })
            .collect();
        for method in methods {
            let (scene, _) = emitting_cube(16, 4, None, albedo, phase, method);
            let solution = solve_scene(&scene, &scene.solve, &SolveHooks::default()).unwrap();
            for (view, reference) in views.iter().zip(&traced) {
                let image = render_view(&solution, view, Some(16)).unwrap();
                let a = pixel_agreement(&image, reference);
                eprintln!(
                    "pixels, {phase}, albedo {albedo}, {method}, {}: {} pixels, {:.1} % within; \
                     bright {:.3} ± {:.3}, dim {:.3} ± {:.3}",
                    view.name,
                    a.count,
                    a.within * 100.0,
                    a.bright.0,
                    a.bright.1,
                    a.dim.0,
                    a.dim.1
                );
                assert!(a.count > 300);
                // With isotropic scattering every method agrees with the reference in each band
                // (within 3 % plus three standard errors; measured −0.3 … +1.4 % bright, 0 …
                // +7 % dim) and in most pixels (87–96 %; the rest are dim ones whose reference
                // is 10–30 % uncertain). At g = 0.85 discrete ordinates are within 2 % in the
                // bright pixels (−4.9 … +5.4 % with the emitters' first collision a
                // Henyey–Greenstein lobe of its mean cosine, which scatters a nearby emitter's
                // light 2–3× too strongly forward) and −7 … +4 % in the dim ones (−18 … 0 %
                // while the render interpolated the cells beside the cube with the cube's
                // own); two-pass 2–4 % and −2 … +25 %.
                let (bright_bound, dim_bound, share) = match (phase == ISOTROPIC, *method) {
                    (true, _) => (0.03, 0.03, 0.8),
                    (false, "discrete-ordinates") => (0.03, 0.1, 0.75),
                    (false, _) => (0.05, 0.25, 0.6),
                };
                let agrees =
                    |(ratio, se): (f64, f64), bound: f64| (ratio - 1.0).abs() < bound + 3.0 * se;
                assert!(
                    agrees(a.bright, bright_bound) && agrees(a.dim, dim_bound) && a.within > share,
                    "{phase}, albedo {albedo}, {method}, {}: bright {:.3} ± {:.3}, dim {:.3} ± \
                     {:.3}, {:.1} % of pixels within 3 %",
                    view.name,
                    a.bright.0,
                    a.bright.1,
                    a.dim.0,
                    a.dim.1,
                    a.within * 100.0
                );
            }
        }
    }
}

/// The emitters' light at g = 0.85 (discrete ordinates, albedo 0.5) split by order, over five
/// views around the cube emitting inside the cloud: the first scattering (the solution rendered
/// without its higher orders, less the emission, which the albedo-0 solve renders) against the
/// path tracer's single scattering (`max_depth = 1`), and the higher orders (the rest) against
/// the path tracer's. Per band of brightness as [`pixel_agreement`] takes them (bright: above
/// 10⁻² of the render's peak; dim: 10⁻⁴ … 10⁻²). Measured: the first scattering within 2.5 %
/// in the bright bands (the bright pixels of [`two_views_of_an_emitting_cube_pixel_by_pixel`]
/// were −4.9 … +5.4 % off with a Henyey–Greenstein lobe of its mean cosine) and −8 … +1 %
/// in the dim ones (−8 … −34 % while the render interpolated the cells beside the cube with
/// the cube's own: docs/validation.md, *Two views, pixel by pixel*), the higher orders within
/// −7 … +8 %.
#[test]
fn the_emitters_first_scattering_and_the_higher_orders_apart() {
    use volrad::engine::solution::{CellRows, ScatteredField};
    let phase = SCATTERING_CASES[3].0;
    let (scene, _) = emitting_cube(16, 4, None, 0.5, phase, "discrete-ordinates");
    let (dark, _) = emitting_cube(16, 4, None, 0.0, phase, "discrete-ordinates");
    let solution = solve_scene(&scene, &scene.solve, &SolveHooks::default()).unwrap();
    let emission = solve_scene(&dark, &dark.solve, &SolveHooks::default()).unwrap();
    let mut first = solution.clone();
    for ch in &mut first.channels {
        if let ScatteredField::Binned { higher_order, .. } = &mut ch.scattered {
            let (cells, width) = (higher_order.cells(), higher_order.width());
            *higher_order = CellRows::from_dense(cells, width, |_| 0.0).unwrap();
        }
    }
    let side = scene.cameras[0].clone();
    let centre = DVec3::splat(8.0);
    for (name, dir, up) in [
        ("side", DVec3::new(0.0, -1.0, 0.0), DVec3::Z),
        ("above", DVec3::new(0.0, -10.0, 38.0), DVec3::Y),
        ("top", DVec3::Z, DVec3::Y),
        ("below", DVec3::new(0.0, -10.0, -38.0), DVec3::Y),
        ("corner", DVec3::new(1.0, -1.0, 0.0), DVec3::Z),
    ] {
        let mut view = side.clone();
        view.name = name.into();
        view.eye = centre + dir.normalize() * 40.0;
        view.up = up;
        let traced = |max_depth| {
            let options = montecarlo::PathTraceOptions {
                spp: 2048,
                emitter_sampling: true,
                max_depth,
                ..Default::default()
            };
            crate::fixtures::path_traced_with(&scene, &view, 0, &options)
        };
        let (single, all) = (traced(Some(1)), traced(None));
        let full = render_view(&solution, &view, Some(16)).unwrap();
        let once = render_view(&first, &view, Some(16)).unwrap();
        let glow = render_view(&emission, &view, Some(16)).unwrap();
        let peak = full.pixels.iter().fold(0.0f32, |a, &b| a.max(b)) as f64;
        // Per band: Σ first (volrad, reference), Σ higher (volrad, reference).
        let mut bands = [[0.0f64; 4]; 2];
        for (i, &x) in full.pixels.iter().enumerate() {
            let x = x as f64;
            if x <= 1e-4 * peak {
                continue;
            }
            let (x1, x0) = (once.pixels[i] as f64, glow.pixels[i] as f64);
            let (r1, r) = (single.mean.pixels[i] as f64, all.mean.pixels[i] as f64);
            let band = &mut bands[usize::from(x < 1e-2 * peak)];
            band[0] += x1 - x0;
            band[1] += r1 - x0;
            band[2] += x - x1;
            band[3] += r - r1;
        }
        let [bright, dim] = bands.map(|b| (b[0] / b[1], b[2] / b[3]));
        eprintln!(
            "orders, {name}: first scattering {:.3} bright, {:.3} dim; higher orders {:.3} \
             bright, {:.3} dim",
            bright.0, dim.0, bright.1, dim.1
        );
        assert!(
            (bright.0 - 1.0).abs() < 0.03,
            "{name}: the bright band's first scattering {:.3}",
            bright.0
        );
        assert!(
            (dim.0 - 1.0).abs() < 0.15,
            "{name}: the dim band's first scattering {:.3}",
            dim.0
        );
        assert!(
            (bright.1 - 1.0).abs() < 0.1 && (dim.1 - 1.0).abs() < 0.1,
            "{name}: the higher orders {:.3} bright, {:.3} dim",
            bright.1,
            dim.1
        );
    }
}
