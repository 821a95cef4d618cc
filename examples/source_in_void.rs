//! Kobayashi's source-in-a-void benchmark (problem 1: Kobayashi, Sugimura & Nagaya 2001, "3D
//! radiation transport benchmark problems and results for simple geometries with void
//! region"), unfolded: the paper's 100 cm octant with reflecting planes at 0 is the octant of a
//! 200 cm cube with vacuum boundaries, which is what volrad solves. A 20 cm source cube
//! (σt = 0.1 /cm, 1 particle /cm³/s, isotropic: emission 1/4π) inside a 100 cm near-void
//! (σt = 1e-4 /cm) inside a shield (σt = 0.1 /cm); case i a pure absorber, case ii half
//! scattering (σs = σt / 2, isotropic). 60³ cells of 10/3 cm: the detector points of lines 1A
//! (5, 5 + 10 i, 5), 1B (5 + 10 i, 5 + 10 i, 5 + 10 i) and 1C (5 + 10 i, 55, 5) are cell
//! centres.
//!
//! ```text
//! cargo run --release --example source_in_void -- [--case i|ii] [--method M] [--dims N]
//!     [--histories N]
//! ```
//! Prints, per line and point, the scalar flux of the solve method (`volrad export --field
//! fluence`) and a reference computed here independently: for case i the exact uncollided
//! flux's mean over the detector's cell (3³ Gauss points, each with chords through the source
//! along 200,000 directions, optical depth through the three nested boxes in closed form; a
//! cell's value is its mean, and the point value differs by up to about 1 %); for case ii an analog Monte Carlo of `--histories` particles
//! (default 10⁷) scoring track length in each detector cell, with its standard error. Also the
//! solve's time, the process's peak memory and the peak and time `volrad info` predicts, and
//! the emitter pass's estimated rays per cell; with `TIME_PASS=1` the pass is run again alone
//! after the solve and its report (rays, seconds) printed.

use std::f64::consts::PI;
use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use glam::DVec3;
use medium::emitter_pass::cell_gauss_points;
use medium::{CellValues, ChannelMedium, Interpolation, Medium};
use rayon::prelude::*;
use scene::Scene;
use volrad::engine::budget::{human_bytes, solve_peak, Occupancy};
use volrad::engine::methods::fluence;
use volrad::engine::pipeline::solve_scene;
use volrad::engine::timing::solve_time;
use volrad::engine::SolveHooks;

const SIDE_CM: f64 = 200.0;
const SOURCE_HALF: f64 = 10.0;
const VOID_HALF: f64 = 50.0;
const SIGMA: f64 = 0.1;
const SIGMA_VOID: f64 = 1e-4;

/// σt at a point measured from the centre of the 200 cm cube.
fn sigma_at(p: DVec3) -> f64 {
    let m = p.abs().max_element();
    if !(SOURCE_HALF..VOID_HALF).contains(&m) {
        SIGMA
    } else {
        SIGMA_VOID
    }
}

/// Optical depth between `a` and `b` (centred coordinates) through the nested boxes, by the
/// ray's crossings of the planes ±10 and ±50 (σt is constant between crossings).
fn optical_depth(a: DVec3, b: DVec3) -> f64 {
    let d = b - a;
    let mut ts = vec![0.0, 1.0];
    for axis in 0..3 {
        if d[axis] != 0.0 {
            for plane in [-VOID_HALF, -SOURCE_HALF, SOURCE_HALF, VOID_HALF] {
                let t = (plane - a[axis]) / d[axis];
                if t > 0.0 && t < 1.0 {
                    ts.push(t);
                }
            }
        }
    }
    ts.sort_by(f64::total_cmp);
    let len = d.length();
    ts.windows(2)
        .map(|w| sigma_at(a + d * (0.5 * (w[0] + w[1]))) * (w[1] - w[0]) * len)
        .sum()
}

/// The exact uncollided scalar flux of case i at `x` (centred): `∫ S/4π · e^{−τ} ds dω` over
/// chords through the source cube, along a Fibonacci lattice of directions. Within the source
/// σt is uniform, so each chord's integral is closed form once the depth to its entry is known.
fn exact_uncollided(x: DVec3, n: usize) -> f64 {
    let golden = PI * (3.0 - 5f64.sqrt());
    let mut sum = 0.0;
    for i in 0..n {
        let z = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
        let r = (1.0 - z * z).sqrt();
        let phi = golden * i as f64;
        let d = DVec3::new(r * phi.cos(), r * phi.sin(), z);
        let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
        for a in 0..3 {
            let (mut ta, mut tb) = ((-SOURCE_HALF - x[a]) / d[a], (SOURCE_HALF - x[a]) / d[a]);
            if ta > tb {
                std::mem::swap(&mut ta, &mut tb);
            }
            t0 = t0.max(ta);
            t1 = t1.min(tb);
        }
        if t1 <= t0 {
            continue;
        }
        let tau_in = optical_depth(x, x + d * t0);
        sum += (-tau_in).exp() * (1.0 - (-SIGMA * (t1 - t0)).exp()) / SIGMA;
    }
    sum / (4.0 * PI) * 4.0 * PI / n as f64
}

/// The mean of [`exact_uncollided`] over the cell of side `h` centred at `x`, at its 3³
/// Gauss–Legendre points (`cell_gauss_points`): what a cell's value is (and what the Monte Carlo of case ii
/// tallies); the point value differs from it by up to about 1 % here.
fn exact_uncollided_cell_mean(x: DVec3, h: f64) -> f64 {
    cell_gauss_points(h)
        .map(|(offset, w)| w * exact_uncollided(x + offset, 200_000))
        .sum()
}

/// splitmix64: a small, good generator for the Monte Carlo reference (one stream per batch).
struct SplitMix(u64);

impl SplitMix {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
    }

    fn direction(&mut self) -> DVec3 {
        let z = 1.0 - 2.0 * self.next_f64();
        let r = (1.0 - z * z).max(0.0).sqrt();
        let phi = 2.0 * PI * self.next_f64();
        DVec3::new(r * phi.cos(), r * phi.sin(), z)
    }
}

/// Case ii's reference: `histories` particles from the source (uniform point, isotropic),
/// flown analogously through the cells (scatter with probability σs/σt, isotropically), each
/// scoring its track length in the `detectors` cells. Returns each detector's flux (source
/// 1 /cm³/s) and its standard error, from 64 independent batches.
fn monte_carlo_flux(
    medium: &Medium,
    detectors: &[usize],
    histories: u64,
    albedo: f64,
) -> Vec<(f64, f64)> {
    let grid = medium.grid();
    let sigma_t = &medium.channels()[0].sigma_t;
    let centre = DVec3::splat(0.5 * SIDE_CM);
    // A cell may be a point of several lines: each distinct cell has one slot.
    let mut slot = vec![usize::MAX; grid.cell_count()];
    let mut cells: Vec<usize> = Vec::new();
    for &d in detectors {
        if slot[d] == usize::MAX {
            slot[d] = cells.len();
            cells.push(d);
        }
    }
    let batches = 64u64;
    let per_batch = histories.div_ceil(batches);
    let tallies: Vec<Vec<f64>> = (0..batches)
        .into_par_iter()
        .map(|b| {
            let mut rng = SplitMix(0x5eed ^ (b + 1).wrapping_mul(0x9e37_79b9));
            let mut tally = vec![0.0; cells.len()];
            for _ in 0..per_batch {
                let mut x = centre
                    + (DVec3::new(rng.next_f64(), rng.next_f64(), rng.next_f64()) - 0.5)
                        * (2.0 * SOURCE_HALF);
                let mut dir = rng.direction();
                loop {
                    let mut remaining = -(1.0 - rng.next_f64()).ln();
                    let ray = medium::traversal::Ray {
                        origin: x,
                        direction: dir,
                    };
                    let mut collided = None;
                    for s in grid.traverse(&ray, 0.0, f64::INFINITY) {
                        let sigma = sigma_t[s.cell] as f64;
                        let l = s.length();
                        let used = if sigma * l >= remaining {
                            collided = Some(s.t_enter + remaining / sigma);
                            remaining / sigma
                        } else {
                            remaining -= sigma * l;
                            l
                        };
                        if slot[s.cell] != usize::MAX {
                            tally[slot[s.cell]] += used;
                        }
                        if collided.is_some() {
                            break;
                        }
                    }
                    let Some(t) = collided else { break };
                    if rng.next_f64() >= albedo {
                        break;
                    }
                    x = ray.at(t);
                    dir = rng.direction();
                }
            }
            tally
        })
        .collect();
    // Flux = track length per volume per history × the source's 20³ cm³ at 1 /cm³/s.
    let scale = (2.0 * SOURCE_HALF).powi(3) / (per_batch as f64 * grid.cell_volume());
    detectors
        .iter()
        .map(|&d| {
            let k = slot[d];
            let values: Vec<f64> = tallies.iter().map(|t| t[k] * scale).collect();
            let mean = values.iter().sum::<f64>() / batches as f64;
            let var = values.iter().map(|v| (v - mean).powi(2)).sum::<f64>()
                / ((batches - 1) * batches) as f64;
            (mean, var.sqrt())
        })
        .collect()
}

fn main() -> Result<()> {
    // The solve's own log (phases, the emitter pass, the operator's size) with RUST_LOG=info.
    tracing_subscriber::fmt()
        .with_env_filter(tracing_subscriber::EnvFilter::from_default_env())
        .with_writer(std::io::stderr)
        .init();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mut case, mut method, mut dims) = ("i".to_string(), "discrete-ordinates".to_string(), 60);
    let mut histories: u64 = 10_000_000;
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--case" => case = value()?.clone(),
            "--method" => method = value()?.clone(),
            "--dims" => dims = value()?.parse().context("--dims")?,
            "--histories" => histories = value()?.parse().context("--histories")?,
            other => bail!("unknown argument {other}"),
        }
    }
    let albedo = match case.as_str() {
        "i" => 0.0,
        "ii" => 0.5,
        other => bail!("--case {other}: i or ii"),
    };
    if dims % 20 != 0 {
        bail!("--dims {dims}: a multiple of 20 puts the detector points at cell centres");
    }
    let h = SIDE_CM / dims as f64;
    let text = format!(
        "[volume]\ngenerator = {{ kind = \"cloud\", seed = 1 }}\ndims = [{dims}, {dims}, {dims}]\n\
         cell_size = {h}\ninterpolation = \"nearest\"\n[medium]\nalbedo = {albedo}\nemission = 1.0\n\
         [solve]\nmethod = \"{method}\"\n"
    );
    let mut scene = Scene::from_toml_str(&text, Path::new("."), Path::new("kobayashi-1.toml"))?;
    let grid = *scene.medium.grid();
    let centre = DVec3::splat(0.5 * SIDE_CM);
    let (mut sigma_t, mut emission) = (Vec::new(), Vec::new());
    for c in 0..grid.cell_count() {
        let p = grid.cell_center(c) - centre;
        sigma_t.push(sigma_at(p) as f32);
        let inside = p.abs().max_element() < SOURCE_HALF;
        emission.push(if inside {
            (1.0 / (4.0 * PI)) as f32
        } else {
            0.0
        });
    }
    scene.medium = Medium::new(
        grid,
        vec![ChannelMedium {
            sigma_t,
            albedo: CellValues::Uniform(albedo),
            emission: CellValues::PerCell(emission),
        }],
        scene.medium.phase(),
        Interpolation::Nearest,
        None,
    )?;
    let start = Instant::now();
    let solution = solve_scene(&scene, &scene.solve, &SolveHooks::default())?;
    let seconds = start.elapsed().as_secs_f64();
    let flux = fluence(&solution, 0)?;
    let peak = std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("VmHWM:"))
                .map(|l| l.split_whitespace().nth(1).unwrap_or("?").to_string())
        })
        .unwrap_or_else(|| "?".into());
    let occupancy = Occupancy::of(&scene.medium);
    if std::env::var("TIME_PASS").is_ok() {
        let pass =
            medium::emitter_pass::EmitterPass::compute(&scene.medium, 0, &Default::default())?;
        println!("pass: {:?}", pass.report());
    }
    for plan in volrad::engine::methods::emitter_pass_plans(&scene, &scene.solve) {
        println!(
            "emitter pass: {:.0} rays per cell (estimated), {}",
            plan.rays_per_cell,
            if plan.runs { "run" } else { "not run" }
        );
    }
    let predicted = solve_peak(&scene, &scene.solve, &occupancy).total();
    let predicted_time = solve_time(
        &scene,
        &scene.solve,
        &occupancy,
        rayon::current_num_threads(),
    );
    println!(
        "Kobayashi problem 1, case {case}, {method}, {dims}³ cells: solve {seconds:.1} s, peak \
         resident {} MiB (`volrad info` predicts {} and {})",
        peak.parse::<f64>()
            .map_or(peak.clone(), |k| format!("{:.0}", k / 1024.0)),
        human_bytes(predicted),
        predicted_time
    );
    let lines: Vec<(&str, Vec<[f64; 3]>)> = vec![
        (
            "1A",
            (0..10).map(|i| [5.0, 5.0 + 10.0 * i as f64, 5.0]).collect(),
        ),
        ("1B", (0..10).map(|i| [5.0 + 10.0 * i as f64; 3]).collect()),
        (
            "1C",
            (0..10)
                .map(|i| [5.0 + 10.0 * i as f64, 55.0, 5.0])
                .collect(),
        ),
    ];
    let points: Vec<(&str, [f64; 3], usize)> = lines
        .iter()
        .flat_map(|(line, ps)| ps.iter().map(move |p| (*line, *p)))
        .map(|(line, p)| {
            grid.cell_at(centre + DVec3::from(p))
                .map(|cell| (line, p, cell))
                .context("a detector point outside the grid")
        })
        .collect::<Result<_>>()?;
    let reference: Vec<(f64, f64)> = if albedo == 0.0 {
        points
            .par_iter()
            .map(|(_, p, _)| {
                (
                    exact_uncollided_cell_mean(DVec3::from(*p), grid.cell_size),
                    0.0,
                )
            })
            .collect()
    } else {
        let cells: Vec<usize> = points.iter().map(|(_, _, c)| *c).collect();
        let start = Instant::now();
        let r = monte_carlo_flux(&scene.medium, &cells, histories, albedo as f64);
        println!(
            "Monte Carlo reference: {histories} histories, {:.1} s",
            start.elapsed().as_secs_f64()
        );
        r
    };
    let what = if albedo == 0.0 {
        "exact uncollided, the cell's mean"
    } else {
        "Monte Carlo ± 1 s.e."
    };
    println!("| line | point (cm) | flux | {what} | error |");
    println!("|---|---|---|---|---|");
    let mut worst: f64 = 0.0;
    for ((line, p, cell), (want, se)) in points.iter().zip(&reference) {
        let value = flux[*cell];
        let err = value / want - 1.0;
        worst = worst.max(err.abs());
        let reference = if *se > 0.0 {
            format!("{want:.5e} ± {:.1} %", 100.0 * se / want)
        } else {
            format!("{want:.5e}")
        };
        println!(
            "| {line} | {p:?} | {value:.5e} | {reference} | {:+.2} % |",
            err * 100.0
        );
    }
    println!("worst error {:.2} %", worst * 100.0);
    Ok(())
}
