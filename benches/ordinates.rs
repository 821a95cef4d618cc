//! Discrete-ordinates speed: the generated 64×64×48 cloud (Max's cloud, seed 7,
//! σt = 0.4 × density), 96 bins, Henyey–Greenstein g = 0.85, albedo 0.99, one oblique
//! directional light. Criterion times one application of `K` (scatter + 96-bin sweep) on the
//! 64×64×48 and on Max's 24×24×18 size; then a full Gauss–Seidel solve to a relative change
//! of 1e-5 runs once on each size and prints iterations, time and state memory.
//! Run with `cargo bench --bench ordinates` (`ORDINATES_SOLVE=0` skips the full solves;
//! `ORDINATES_SIGMA_SCALE=4` makes the cloud ten times denser).

use std::time::Instant;

use criterion::Criterion;
use formfactor::ordinates::{DirectionBins, OrdinatesOperator, OrdinatesOptions};
use glam::DVec3;
use medium::generators::cloud;
use medium::light_pass::LightPass;
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Light, Medium, PhaseFunction};
use solver::operator::TransportOperator;
// Benchmarks run with the product's allocator, which the volrad crate sets.
use volrad as _;

const SIGMA_T_SCALE: f32 = 0.4;
const TOLERANCE: f64 = 1e-5;

/// `ORDINATES_SIGMA_SCALE` overrides the σt scale (a denser cloud needs more iterations).
fn sigma_t_scale() -> f32 {
    std::env::var("ORDINATES_SIGMA_SCALE")
        .map_or(SIGMA_T_SCALE, |v| v.parse().unwrap_or(SIGMA_T_SCALE))
}

struct Case {
    medium: Medium,
    op: OrdinatesOperator,
    external: Vec<f64>,
}

fn case(dims: [usize; 3]) -> Case {
    let grid = Grid::new(dims, 1.0).unwrap();
    let channel = ChannelMedium {
        sigma_t: cloud(dims, 7).iter().map(|d| d * sigma_t_scale()).collect(),
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
    let t0 = Instant::now();
    let op = OrdinatesOperator::new(
        &medium,
        0,
        DirectionBins::max96(),
        OrdinatesOptions::default(),
    )
    .unwrap();
    let lights = [Light::Directional {
        direction: DVec3::new(0.5, -1.0, 0.35).normalize(),
        irradiance: 1.0,
    }];
    let pass = LightPass::compute(&medium, 0, &lights).unwrap();
    let external = op.first_bounce_density_from_pass(&pass).unwrap();
    eprintln!(
        "{dims:?}: operator + light pass + first-bounce density built in {:.2} s",
        t0.elapsed().as_secs_f64()
    );
    Case {
        medium,
        op,
        external,
    }
}

/// Gauss–Seidel (block over bins) from `g = E` until `‖Δg‖ / ‖E‖ < TOLERANCE`.
fn solve(c: &Case) {
    let t0 = Instant::now();
    let mut e = vec![0.0; c.op.len()];
    c.op.transport_external(&c.external, None, &mut e, None);
    let run = c.op.sweep_until_change(&e, TOLERANCE, 1000);
    let (iterations, change) = (run.iterations, run.final_change);
    let secs = t0.elapsed().as_secs_f64();
    let balance = c.op.energy_balance(&run.solution, &c.external, None);
    let (grid, channel) = (c.medium.grid(), &c.medium.channels()[0]);
    let n = grid.cell_count();
    let m = c.op.bins().len();
    // State: g, E, the previous iterate and the external density (f64 each, per cell with
    // medium and bin), plus the operator's scratch (density and per-piece sweep output).
    let state = 4 * c.op.len() * 8 + c.op.scratch_bytes();
    eprintln!(
        "{:?} Gauss–Seidel to {TOLERANCE:e}: {iterations} iterations, {secs:.1} s \
         ({:.2} s/iteration), final change {change:.2e}, energy imbalance {:.2e}, \
         state {:.0} MB ({:.1} bytes per cell per bin), mean σt {:.3}, max σt {:.3}, \
         cells with σt > 0: {:.1} %",
        grid.dims,
        secs / iterations as f64,
        balance.relative_imbalance(),
        state as f64 / 1e6,
        state as f64 / (n * m) as f64,
        channel.sigma_t.iter().map(|&s| s as f64).sum::<f64>() / n as f64,
        channel.max_sigma_t(),
        100.0 * channel.sigma_t.iter().filter(|&&s| s > 0.0).count() as f64 / n as f64,
    );
}

fn main() {
    let mut criterion = Criterion::default().configure_from_args().sample_size(10);
    for dims in [[24, 24, 18], [64, 64, 48]] {
        let c = case(dims);
        let x = c.external.clone();
        let mut y = vec![0.0; c.op.len()];
        let name = format!("ordinates_apply_96bins_{}x{}x{}", dims[0], dims[1], dims[2]);
        criterion.bench_function(&name, |b| b.iter(|| c.op.apply(&x, &mut y)));
        if std::env::var("ORDINATES_SOLVE").map_or(true, |v| v != "0") {
            solve(&c);
        }
    }
    criterion.final_summary();
}
