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
//! ```
//! Prints, per line and point, the scalar flux of the solve method (`volrad export --field
//! fluence`) and, for case i, the exact uncollided flux integrated here independently (chords
//! through the source along 200,000 directions, optical depth through the three nested boxes in
//! closed form), with the solve's time and the process's peak memory.

use std::f64::consts::PI;
use std::path::Path;
use std::time::Instant;

use anyhow::{bail, Context, Result};
use glam::DVec3;
use medium::{CellValues, ChannelMedium, Interpolation, Medium};
use scene::Scene;
use volrad::engine::methods::fluence;
use volrad::engine::pipeline::solve_scene;
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
fn exact_uncollided(x: DVec3) -> f64 {
    let n = 200_000;
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

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let (mut case, mut method, mut dims) = ("i".to_string(), "discrete-ordinates".to_string(), 60);
    let mut it = args.iter();
    while let Some(a) = it.next() {
        let mut value = || it.next().with_context(|| format!("{a} needs a value"));
        match a.as_str() {
            "--case" => case = value()?.clone(),
            "--method" => method = value()?.clone(),
            "--dims" => dims = value()?.parse().context("--dims")?,
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
    println!(
        "Kobayashi problem 1, case {case}, {method}, {dims}³ cells: solve {seconds:.1} s, peak \
         resident {} MiB",
        peak.parse::<f64>()
            .map_or(peak.clone(), |k| format!("{:.0}", k / 1024.0))
    );
    println!("| line | point (cm) | flux | exact uncollided | error |");
    println!("|---|---|---|---|---|");
    let mut worst: f64 = 0.0;
    for (line, points) in [
        (
            "1A",
            (0..10)
                .map(|i| [5.0, 5.0 + 10.0 * i as f64, 5.0])
                .collect::<Vec<_>>(),
        ),
        ("1B", (0..10).map(|i| [5.0 + 10.0 * i as f64; 3]).collect()),
        (
            "1C",
            (0..10)
                .map(|i| [5.0 + 10.0 * i as f64, 55.0, 5.0])
                .collect(),
        ),
    ] {
        for p in points {
            let x = DVec3::from(p);
            let cell = grid
                .cell_at(centre + x)
                .context("a detector point outside the grid")?;
            let value = flux[cell];
            if albedo == 0.0 {
                let exact = exact_uncollided(x);
                let err = value / exact - 1.0;
                worst = worst.max(err.abs());
                println!(
                    "| {line} | {p:?} | {value:.5e} | {exact:.5e} | {:+.2} % |",
                    err * 100.0
                );
            } else {
                println!("| {line} | {p:?} | {value:.5e} | | |");
            }
        }
    }
    if albedo == 0.0 {
        println!("worst error {:.2} %", worst * 100.0);
    }
    Ok(())
}
