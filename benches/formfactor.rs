//! Form-factor benchmarks: exact CSR build and apply (against memory bandwidth), hierarchical
//! builds with links per cell on 16³, 32³, 64³ and the generated 64×64×48 cloud, and the issue's
//! target run: hierarchical form factors + Gauss–Seidel to 1e-5 on the cloud at albedo 0.99.
//!
//! `cargo bench --bench formfactor` (criterion part first, then the one-shot runs).

use std::time::Instant;

use criterion::{black_box, Criterion};
use formfactor::{ExactOptions, FormFactorMatrix, HierarchicalOperator, HierarchicalOptions};
use medium::{generators, CellValues, ChannelMedium, Grid, Interpolation, Medium, PhaseFunction};
use rayon::prelude::*;
use solver::{Method, SolveControl, SolveOptions, TransportOperator};
// Benchmarks run with the product's allocator, which the volrad crate sets.
use volrad as _;

/// Max's generated cloud scaled so its largest axis-parallel optical depth is `depth` (h = 1),
/// as for the built-in scene (grey, isotropic).
fn cloud_medium(dims: [usize; 3], depth: f64, albedo: f32) -> Medium {
    let grid = Grid::new(dims, 1.0).unwrap();
    let density = generators::cloud(dims, 7);
    let mut max_column: f64 = 0.0;
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            let s: f64 = (0..dims[0])
                .map(|i| density[grid.index(i, j, k)] as f64)
                .sum();
            max_column = max_column.max(s);
        }
    }
    for k in 0..dims[2] {
        for i in 0..dims[0] {
            let s: f64 = (0..dims[1])
                .map(|j| density[grid.index(i, j, k)] as f64)
                .sum();
            max_column = max_column.max(s);
        }
    }
    for j in 0..dims[1] {
        for i in 0..dims[0] {
            let s: f64 = (0..dims[2])
                .map(|k| density[grid.index(i, j, k)] as f64)
                .sum();
            max_column = max_column.max(s);
        }
    }
    let scale = depth / max_column;
    let channel = ChannelMedium {
        sigma_t: density.iter().map(|&d| (d as f64 * scale) as f32).collect(),
        albedo: CellValues::Uniform(albedo),
        emission: CellValues::Uniform(0.0),
    };
    Medium::new(
        grid,
        vec![channel],
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap()
}

fn peak_rss_mb() -> f64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines().find(|l| l.starts_with("VmHWM:")).and_then(|l| {
                l.split_whitespace()
                    .nth(1)
                    .and_then(|v| v.parse::<f64>().ok())
            })
        })
        .map_or(f64::NAN, |kb| kb / 1024.0)
}

fn criterion_part() {
    let mut c = Criterion::default().sample_size(10).configure_from_args();
    let cloud8 = cloud_medium([8, 8, 8], 10.0, 0.99);
    c.bench_function("exact build 8³ cloud", |b| {
        b.iter(|| FormFactorMatrix::build(&cloud8, 0, &ExactOptions::default(), None).unwrap())
    });
    let cloud16 = cloud_medium([16, 16, 16], 10.0, 0.99);
    c.bench_function("hierarchical build 16³ cloud", |b| {
        b.iter(|| {
            HierarchicalOperator::build(&cloud16, 0, &HierarchicalOptions::default()).unwrap()
        })
    });
    let exact16 = FormFactorMatrix::build(&cloud16, 0, &ExactOptions::default(), None).unwrap();
    let x = vec![1.0; cloud16.grid().cell_count()];
    let mut y = vec![0.0; x.len()];
    c.bench_function("exact apply 16³ cloud (own rayon CSR loop)", |b| {
        b.iter(|| exact16.apply(black_box(&x), &mut y))
    });
    c.bench_function("exact apply 16³ cloud (sprs serial product)", |b| {
        b.iter(|| {
            for (i, row) in exact16.matrix().outer_iterator().enumerate() {
                y[i] = exact16.albedo()[i] * row.dot(black_box(&x[..]));
            }
        })
    });
    c.final_summary();
}

fn bandwidth_part() {
    let cloud = cloud_medium([16, 16, 16], 10.0, 0.99);
    let exact = FormFactorMatrix::build(&cloud, 0, &ExactOptions::default(), None).unwrap();
    let x = vec![1.0; cloud.grid().cell_count()];
    let mut y = vec![0.0; x.len()];
    let reps = 20;
    let t = Instant::now();
    for _ in 0..reps {
        exact.apply(&x, &mut y);
    }
    let apply_s = t.elapsed().as_secs_f64() / reps as f64;
    let bytes = exact.report().entries as f64 * 16.0;
    let big = vec![1.0f64; 1 << 25];
    let t = Instant::now();
    let mut s = 0.0;
    for _ in 0..5 {
        s += big.par_iter().sum::<f64>();
    }
    let stream = 5.0 * big.len() as f64 * 8.0 / t.elapsed().as_secs_f64();
    black_box(s);
    println!(
        "exact 16³ cloud: {} nonzeros, build {:.2} s, apply {:.2} ms = {:.1} GB/s of matrix; parallel read bandwidth {:.1} GB/s",
        exact.report().entries,
        exact.report().seconds,
        apply_s * 1e3,
        bytes / apply_s / 1e9,
        stream / 1e9
    );
}

fn hierarchical_part() {
    let options = HierarchicalOptions::default();
    for dims in [[16, 16, 16], [32, 32, 32], [64, 64, 64], [64, 64, 48]] {
        let cloud = cloud_medium(dims, 10.0, 0.99);
        let op = HierarchicalOperator::build(&cloud, 0, &options).unwrap();
        let r = op.report();
        println!(
            "hierarchical {dims:?}: build {:.2} s, {} active of {} cells, links {} ({:.1}/active cell, per level {:?}), near {} ({:.1}/active cell), operator {:.0} MB, max raw column sum {:.6}, {} cells scaled (min d {:.6})",
            r.seconds,
            r.active_cells,
            cloud.grid().cell_count(),
            op.link_count(),
            op.link_count() as f64 / r.active_cells as f64,
            op.links_per_level(),
            op.near_entries(),
            op.near_entries() as f64 / r.active_cells as f64,
            op.memory_bytes() as f64 / 1e6,
            r.max_column_sum_raw,
            r.cells_scaled,
            r.min_scale
        );
    }
}

fn target_part() {
    // The target: 64×64×48 cloud, albedo 0.99, hierarchical + Gauss–Seidel to 1e-5.
    let start = Instant::now();
    let cloud = cloud_medium([64, 64, 48], 10.0, 0.99);
    let op = HierarchicalOperator::build(&cloud, 0, &HierarchicalOptions::default()).unwrap();
    let built = start.elapsed().as_secs_f64();
    // Unshadowed unit irradiance: E_i = a σt_i / 4π.
    let source: Vec<f64> = cloud.channels()[0]
        .sigma_t
        .iter()
        .map(|&s| 0.99 * s as f64 / (4.0 * std::f64::consts::PI))
        .collect();
    for method in [Method::GaussSeidel, Method::Jacobi] {
        let options = SolveOptions {
            method,
            tolerance: 1e-5,
            max_iterations: 5000,
            record_history: false,
        };
        let t = Instant::now();
        match solver::solve(&op, &source, None, &options, &SolveControl::new()) {
            Ok((g, report)) => println!(
                "target 64×64×48 cloud a=0.99 {}: build {built:.2} s + solve {:.2} s ({} iterations, converged {}, residual {:.2e}) = {:.2} s total; peak RSS {:.0} MB; mean g {:.4e}",
                report.method,
                t.elapsed().as_secs_f64(),
                report.iterations,
                report.converged,
                report.final_residual,
                built + t.elapsed().as_secs_f64(),
                peak_rss_mb(),
                g.iter().sum::<f64>() / g.len() as f64
            ),
            Err(e) => println!("target solve {method:?} failed: {e}"),
        }
    }
    let _ = op.len();
}

fn main() {
    let only_quick = std::env::args().any(|a| a == "--quick");
    criterion_part();
    bandwidth_part();
    hierarchical_part();
    if !only_quick {
        target_part();
    }
}
