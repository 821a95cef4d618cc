//! Iteration counts and times of every solve method on a synthetic zonal-shaped operator
//! (64×64×48 cells, 27-point coupling, reciprocal, column sums < 1), at albedo 0.99 and 0.999.
//!
//! `cargo bench --bench solve` prints a table per albedo (one timed solve per method, the
//! spectral radius and Jacobi's predicted count), then criterion timings at albedo 0.99.
//! `cargo bench --bench solve -- --table-only` skips criterion; `--methods=cg,coarse-gs` and
//! `--block=N` (aggregate edge in cells, default 6) select what runs.

use std::time::Instant;

use criterion::Criterion;
use rayon::prelude::*;
use solver::{
    predicted_iterations, solve, spectral_radius, Method, RowAccess, SolveControl, SolveOptions,
    TransportOperator,
};
// Benchmarks run with the product's allocator, which the volrad crate sets.
use volrad as _;

const NX: usize = 64;
const NY: usize = 64;
const NZ: usize = 48;
const TOLERANCE: f64 = 1e-5;

/// `K_ij = a · s_i · ω(j − i)`: `s_i = 1 − e^{−τ_i}` is the chance a cell intercepts light and
/// `ω` shares a cell's emission among itself and its 26 neighbours (∝ 1/d², self weight as a
/// face neighbour, Σ ω = 1). Column sums `Σ_i a s_i ω ≤ a`, less at the boundary (leakage);
/// reciprocity `K_ij / (a s_i) = K_ji / (a s_j)` gives the symmetrizer.
struct StencilZonal {
    albedo: f64,
    s: Vec<f64>,
    weights: Vec<f64>,
    aggregates: Vec<u32>,
    omega: [f64; 27],
}

impl StencilZonal {
    fn new(albedo: f64, block: usize) -> Self {
        let mut omega = [0.0; 27];
        for (k, w) in omega.iter_mut().enumerate() {
            let d = [k % 3, (k / 3) % 3, k / 9].map(|c| c as f64 - 1.0);
            let r2 = d.iter().map(|c| c * c).sum::<f64>();
            *w = 1.0 / r2.max(1.0);
        }
        let total: f64 = omega.iter().sum();
        omega.iter_mut().for_each(|w| *w /= total);
        let n = NX * NY * NZ;
        let s: Vec<f64> = (0..n)
            .map(|i| {
                let (x, y, z) = (i % NX, (i / NX) % NY, i / (NX * NY));
                let (fx, fy, fz) = (
                    x as f64 / NX as f64,
                    y as f64 / NY as f64,
                    z as f64 / NZ as f64,
                );
                // Optical thickness per cell 2..8, smoothly varying like a cloud.
                let tau =
                    5.0 + 3.0 * (6.0 * fx + 1.0).sin() * (5.0 * fy).cos() * (4.0 * fz + 0.5).sin();
                1.0 - (-tau).exp()
            })
            .collect();
        let weights = s.iter().map(|si| 1.0 / (albedo * si)).collect();
        let (bx, by) = (NX.div_ceil(block), NY.div_ceil(block));
        let aggregates = (0..n)
            .map(|i| {
                let (x, y, z) = (i % NX, (i / NX) % NY, i / (NX * NY));
                ((z / block * by + y / block) * bx + x / block) as u32
            })
            .collect();
        Self {
            albedo,
            s,
            weights,
            aggregates,
            omega,
        }
    }

    #[inline]
    fn visit_row(&self, i: usize, mut f: impl FnMut(usize, f64)) {
        let (x, y, z) = (i % NX, (i / NX) % NY, i / (NX * NY));
        let scale = self.albedo * self.s[i];
        for dz in 0..3 {
            let zz = z + dz;
            if zz == 0 || zz > NZ {
                continue;
            }
            for dy in 0..3 {
                let yy = y + dy;
                if yy == 0 || yy > NY {
                    continue;
                }
                for dx in 0..3 {
                    let xx = x + dx;
                    if xx == 0 || xx > NX {
                        continue;
                    }
                    let j = ((zz - 1) * NY + (yy - 1)) * NX + (xx - 1);
                    f(j, scale * self.omega[dz * 9 + dy * 3 + dx]);
                }
            }
        }
    }
}

impl TransportOperator for StencilZonal {
    fn len(&self) -> usize {
        self.s.len()
    }
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        y.par_chunks_mut(NX * NY).enumerate().for_each(|(z, slab)| {
            for (k, yi) in slab.iter_mut().enumerate() {
                *yi = self.row_dot(z * NX * NY + k, x);
            }
        });
    }
    fn rows(&self) -> Option<&dyn RowAccess> {
        Some(self)
    }
    fn symmetrizer(&self) -> Option<&[f64]> {
        Some(&self.weights)
    }
    fn coarse_aggregates(&self) -> Option<&[u32]> {
        Some(&self.aggregates)
    }
}

impl RowAccess for StencilZonal {
    fn row_dot(&self, row: usize, x: &[f64]) -> f64 {
        let mut s = 0.0;
        self.visit_row(row, |j, v| s += v * x[j]);
        s
    }
    fn for_each_in_row(&self, row: usize, visit: &mut dyn FnMut(usize, f64)) -> bool {
        self.visit_row(row, visit);
        true
    }
}

/// `--methods=a,b,…` restricts the methods; `--block=N` sets the aggregate edge (default 6).
fn arg(name: &str) -> Option<String> {
    std::env::args().find_map(|a| a.strip_prefix(&format!("--{name}=")).map(str::to_string))
}

fn block() -> usize {
    arg("block").and_then(|b| b.parse().ok()).unwrap_or(6)
}

fn methods() -> Vec<Method> {
    if let Some(list) = arg("methods") {
        return list
            .split(',')
            .map(|m| m.parse().expect("valid method"))
            .collect();
    }
    [
        "jacobi",
        "gauss-seidel",
        "sor:1.6",
        "gmres:30",
        "bicgstab",
        "cg",
        "coarse-cg",
        "coarse-jacobi",
        "coarse-gs",
    ]
    .iter()
    .map(|m| m.parse().expect("valid method"))
    .collect()
}

fn options(method: Method) -> SolveOptions {
    SolveOptions {
        method,
        tolerance: TOLERANCE,
        max_iterations: 20_000,
        record_history: false,
    }
}

fn table(albedo: f64) {
    let op = StencilZonal::new(albedo, block());
    let source: Vec<f64> = op.s.iter().map(|s| 0.1 * s).collect();
    let t = Instant::now();
    let est = spectral_radius(&op, 5000, 1e-7);
    println!(
        "\nalbedo {albedo}: {} unknowns, rho(K) = {:.6} ({} power steps, {:.2} s), Jacobi predicted {:?} iterations to {TOLERANCE:e}",
        op.len(),
        est.rho,
        est.iterations,
        t.elapsed().as_secs_f64(),
        predicted_iterations(est.rho, TOLERANCE)
    );
    println!(
        "{:<14} {:>6} {:>9} {:>10} {:>9} {:>10} {:>7}",
        "method", "iters", "converged", "residual", "seconds", "s/iter", "K-apps"
    );
    let mut rows = Vec::new();
    for m in methods() {
        let (_, r) = solve(&op, &source, None, &options(m), &SolveControl::new()).expect("solve");
        println!(
            "{:<14} {:>6} {:>9} {:>10.2e} {:>9.3} {:>10.2e} {:>7}",
            r.method,
            r.iterations,
            r.converged,
            r.final_residual,
            r.seconds,
            r.seconds_per_iteration,
            r.operator_applications + r.operator_sweeps
        );
        rows.push(r);
    }
    let Some(jacobi) = rows.iter().find(|r| r.method == "jacobi") else {
        return;
    };
    if let Some(best) = rows
        .iter()
        .filter(|r| r.converged)
        .min_by(|a, b| a.seconds.total_cmp(&b.seconds))
    {
        println!(
            "fastest: {} with {} iterations ({:.3} s) vs Jacobi's {} ({:.3} s): {:.1}× fewer iterations, {:.1}× less time",
            best.method,
            best.iterations,
            best.seconds,
            jacobi.iterations,
            jacobi.seconds,
            jacobi.iterations as f64 / best.iterations.max(1) as f64,
            jacobi.seconds / best.seconds
        );
    }
}

fn main() {
    let table_only = std::env::args().any(|a| a == "--table-only");
    for albedo in [0.99, 0.999] {
        table(albedo);
    }
    if table_only {
        return;
    }
    // Criterion refuses arguments it does not know: parse its own only without ours.
    let ours = std::env::args().any(|a| a.starts_with("--methods=") || a.starts_with("--block="));
    let mut criterion = Criterion::default();
    if !ours {
        criterion = criterion.configure_from_args();
    }
    let mut criterion = criterion
        .sample_size(10)
        .warm_up_time(std::time::Duration::from_secs(1));
    let op = StencilZonal::new(0.99, block());
    let source: Vec<f64> = op.s.iter().map(|s| 0.1 * s).collect();
    for m in methods() {
        let name = format!("solve/albedo0.99/{m}");
        criterion.bench_function(&name, |b| {
            b.iter(|| solve(&op, &source, None, &options(m), &SolveControl::new()).expect("solve"))
        });
    }
    criterion.final_summary();
}
