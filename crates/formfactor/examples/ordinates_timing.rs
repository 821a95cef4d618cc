//! Times the two halves of one discrete-ordinates application (scattering with the phase
//! matrix; the 96-bin transport sweep) and one Gauss–Seidel sweep on the generated cloud.
//! `cargo run --release -p formfactor --example ordinates_timing -- 64 64 48 [sigma_scale]`
//! (σ scale 4 is the benchmark's dense cloud, `ORDINATES_SIGMA_SCALE=4`; 0.4 its default). With `ORDINATES_SOLVE=1`
//! it runs the full Gauss–Seidel solve of `benches/ordinates.rs` instead (same cloud, light,
//! loop and stopping rule), without building the whole workspace. `ORDINATES_FLAT=1` sweeps
//! the scattered source uniform in each cell (without `OrdinatesOptions::linear_source`).

use std::time::Instant;

use formfactor::ordinates::{DirectionBins, OrdinatesOperator, OrdinatesOptions};
use glam::DVec3;
use medium::generators::cloud;
use medium::light_pass::LightPass;
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Light, Medium, PhaseFunction};
use solver::operator::TransportOperator;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let dim = |i: usize, d: usize| args.get(i).map_or(d, |v| v.parse().expect("grid size"));
    let dims = [dim(0, 64), dim(1, 64), dim(2, 48)];
    let scale: f32 = args.get(3).map_or(4.0, |v| v.parse().expect("σ scale"));
    let grid = Grid::new(dims, 1.0).unwrap();
    let channel = ChannelMedium {
        sigma_t: cloud(dims, 7).iter().map(|d| d * scale).collect(),
        albedo: CellValues::Uniform(0.99),
        emission: CellValues::Uniform(0.0),
    };
    let medium = Medium::new(
        grid,
        vec![channel],
        PhaseFunction::HenyeyGreenstein { g: 0.85 },
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let op = OrdinatesOperator::new(
        &medium,
        0,
        DirectionBins::max96(),
        OrdinatesOptions {
            linear_source: std::env::var("ORDINATES_FLAT").is_err(),
            ..Default::default()
        },
    )
    .unwrap();
    let len = op.len();
    let x: Vec<f64> = (0..len).map(|i| 1.0 + (i % 7) as f64 * 0.1).collect();
    let mut d = vec![0.0; len];
    let mut y = vec![0.0; len];
    let reps = 3;
    // Best of `reps` in process CPU seconds (user + system): less sensitive than wall time
    // to other jobs on a shared machine; with one thread it is the work itself.
    let best = |f: &mut dyn FnMut()| {
        (0..reps)
            .map(|_| {
                let (t, c) = (Instant::now(), cpu_seconds());
                f();
                (cpu_seconds() - c, t.elapsed().as_secs_f64())
            })
            .fold((f64::INFINITY, f64::INFINITY), |a, b| {
                (a.0.min(b.0), a.1.min(b.1))
            })
    };
    if std::env::var("ORDINATES_SOLVE").is_ok() {
        solve(&medium, &op);
        return;
    }
    if std::env::var("ORDINATES_ONLY_GS").is_ok() {
        // For a profiler: Gauss–Seidel sweeps only.
        let mut g = x.clone();
        for _ in 0..5 {
            op.sweep_in_place(&mut g, &x, 1.0);
        }
        return;
    }
    let scatter = best(&mut || op.scatter_density(&x, &mut d));
    let sweep = best(&mut || {
        op.transport(&d, &mut y);
    });
    let mut g = x.clone();
    let gs = best(&mut || {
        op.sweep_in_place(&mut g, &x, 1.0);
    });
    let check: f64 = y.iter().sum::<f64>() + g.iter().sum::<f64>();
    println!(
        "{dims:?} σ×{scale}: CPU (wall) seconds, best of {reps}: scatter {:.3} ({:.3}), \
         transport {:.3} ({:.3}), Gauss–Seidel sweep {:.3} ({:.3}); checksum {check:.6e}",
        scatter.0, scatter.1, sweep.0, sweep.1, gs.0, gs.1
    );
}

/// The Gauss–Seidel solve of `benches/ordinates.rs`: one oblique directional light, from
/// `g = E` until `‖Δg‖ / ‖E‖ < 1e-5`.
fn solve(medium: &Medium, op: &OrdinatesOperator) {
    let grid = medium.grid();
    let t0 = Instant::now();
    let lights = [Light::Directional {
        direction: DVec3::new(0.5, -1.0, 0.35).normalize(),
        irradiance: 1.0,
    }];
    let pass = LightPass::compute(medium, 0, &lights).unwrap();
    let external = op.first_bounce_density_from_pass(&pass).unwrap();
    let mut e = vec![0.0; op.len()];
    op.transport_external(&external, None, &mut e, None);
    let run = op.sweep_until_change(&e, 1e-5, 1000);
    let iterations = run.iterations;
    let secs = t0.elapsed().as_secs_f64();
    let balance = op.energy_balance(&run.solution, &external, None);
    // Per cell with medium and bin: e, g, the change's copy and the external density.
    let (n, m) = (op.state_cells().len(), op.bins().len());
    let state = 4 * n * m * 8 + op.scratch_bytes();
    println!(
        "{:?} Gauss–Seidel to 1e-5: {iterations} iterations, {secs:.1} s ({:.2} s/iteration), \
         energy imbalance {:.2e}, state {:.0} MB ({:.1} bytes per cell with medium per bin)",
        grid.dims,
        secs / iterations as f64,
        balance.relative_imbalance(),
        state as f64 / 1e6,
        state as f64 / (n * m) as f64
    );
}

/// User + system CPU time of this process from /proc/self/stat (Linux; 0 elsewhere).
fn cpu_seconds() -> f64 {
    let Ok(stat) = std::fs::read_to_string("/proc/self/stat") else {
        return 0.0;
    };
    // Fields after the parenthesised command name; utime and stime are fields 14 and 15.
    let rest = stat.rsplit_once(')').map_or("", |r| r.1);
    let f: Vec<f64> = rest
        .split_whitespace()
        .skip(11)
        .take(2)
        .filter_map(|v| v.parse().ok())
        .collect();
    f.iter().sum::<f64>() / 100.0
}
