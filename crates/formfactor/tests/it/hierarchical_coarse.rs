//! The hierarchical operator's Galerkin coarse matrix (formed from its links, for the solver's
//! two-level methods) against the same matrix probed with one application per aggregate.

use formfactor::{HierarchicalOperator, HierarchicalOptions, NearQuadrature};
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Medium, PhaseFunction};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use solver::TransportOperator;

/// A noisy ellipsoidal blob (peak σt = `peak`) with empty corners.
fn cloud(dims: [usize; 3], peak: f64, seed: u64) -> Vec<f32> {
    let mut rng = Pcg64::seed_from_u64(seed);
    let mut out = Vec::new();
    for k in 0..dims[2] {
        for j in 0..dims[1] {
            for i in 0..dims[0] {
                let d2: f64 = [i, j, k]
                    .iter()
                    .zip(dims)
                    .map(|(&x, d)| ((x as f64 + 0.5) / (d as f64 / 2.0) - 1.0).powi(2))
                    .sum();
                let noise = 0.5 + rng.random::<f64>();
                out.push((peak * (1.0 - d2).max(0.0) * noise) as f32);
            }
        }
    }
    out
}

/// The grey, isotropic one-channel medium of `channel` on `grid`.
fn grey(grid: Grid, channel: ChannelMedium) -> Medium {
    Medium::new(
        grid,
        vec![channel],
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap()
}

#[test]
fn coarse_operator_from_links_equals_the_probed_galerkin_matrix() {
    // 20×20×18 cells: 8-cell aggregates clipped at the far faces (3×3×3 = 27 aggregates).
    let dims = [20, 20, 18];
    let grid = Grid::new(dims, 1.0).unwrap();
    let channel = ChannelMedium {
        sigma_t: cloud(dims, 0.8, 11),
        albedo: CellValues::Uniform(0.9),
        emission: CellValues::Uniform(0.0),
    };
    let op = HierarchicalOperator::build(
        &grey(grid, channel),
        0,
        &HierarchicalOptions {
            near: NearQuadrature {
                radius: 2,
                points_per_axis: 2,
                directions: 32,
            },
            ..Default::default()
        },
    )
    .unwrap();
    assert!(op.link_count() > 0, "the test needs far-field links");
    let aggs = op.coarse_aggregates().expect("aggregates").to_vec();
    let nc = *aggs.iter().max().unwrap() as usize + 1;
    assert_eq!(nc, 27);
    let w = op.symmetrizer().expect("weights").to_vec();
    for weights in [None, Some(&w[..])] {
        let kc = op
            .coarse_operator(&aggs, nc, weights)
            .expect("coarse operator");
        let n = op.len();
        let mut probed = vec![0.0; nc * nc];
        let (mut x, mut y) = (vec![0.0; n], vec![0.0; n]);
        for d in 0..nc {
            for (xi, &a) in x.iter_mut().zip(&aggs) {
                *xi = f64::from(u8::from(a as usize == d));
            }
            op.apply(&x, &mut y);
            for (i, &a) in aggs.iter().enumerate() {
                probed[a as usize * nc + d] += weights.map_or(1.0, |w| w[i]) * y[i];
            }
        }
        let scale = probed.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        assert!(scale > 0.0);
        for (k, (a, b)) in kc.iter().zip(&probed).enumerate() {
            assert!(
                (a - b).abs() <= 1e-9 * scale,
                "entry ({}, {}): links give {a}, probing {b}",
                k / nc,
                k % nc
            );
        }
        if weights.is_some() {
            // W K is symmetric by reciprocity, so its Galerkin matrix is too.
            for c in 0..nc {
                for d in 0..c {
                    let (cd, dc) = (kc[c * nc + d], kc[d * nc + c]);
                    assert!((cd - dc).abs() <= 1e-6 * scale, "({c},{d}): {cd} vs {dc}");
                }
            }
        }
    }
}

fn small_cloud_operator(dims: [usize; 3], peak: f64, albedo: f32) -> HierarchicalOperator {
    let grid = Grid::new(dims, 1.0).unwrap();
    let channel = ChannelMedium {
        sigma_t: cloud(dims, peak, 5),
        albedo: CellValues::Uniform(albedo),
        emission: CellValues::Uniform(0.0),
    };
    HierarchicalOperator::build(
        &grey(grid, channel),
        0,
        &HierarchicalOptions {
            near: NearQuadrature {
                radius: 2,
                points_per_axis: 2,
                directions: 32,
            },
            ..Default::default()
        },
    )
    .unwrap()
}

fn solve_with(
    op: &HierarchicalOperator,
    e: &[f64],
    method: &str,
    tolerance: f64,
) -> (Vec<f64>, solver::SolveReport) {
    let options = solver::SolveOptions {
        method: method.parse().unwrap(),
        tolerance,
        max_iterations: 5000,
        record_history: false,
    };
    solver::solve(op, e, None, &options, &solver::SolveControl::new()).unwrap()
}

#[test]
fn dsa_cg_reaches_the_jacobi_solution_in_fewer_iterations_than_cg() {
    // Optically thick (σt up to 3 per cell): the regime where diffusion is accurate.
    let op = small_cloud_operator([16, 16, 14], 3.0, 0.999);
    let e: Vec<f64> = (0..op.len()).map(|i| (i % 7) as f64 * 0.1).collect();
    let (g_j, jacobi) = solve_with(&op, &e, "jacobi", 1e-9);
    let (g_gs, gs) = solve_with(&op, &e, "gauss-seidel", 1e-9);
    let (g_d, dsa) = solve_with(&op, &e, "dsa-cg", 1e-9);
    let (_, cg) = solve_with(&op, &e, "cg", 1e-9);
    for r in [&jacobi, &gs, &dsa, &cg] {
        assert!(r.converged, "{r:?}");
    }
    let rel = |a: &[f64], b: &[f64]| {
        let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
        (num / b.iter().map(|y| y * y).sum::<f64>()).sqrt()
    };
    assert!(rel(&g_d, &g_j) < 1e-6, "{}", rel(&g_d, &g_j));
    assert!(rel(&g_d, &g_gs) < 1e-6, "{}", rel(&g_d, &g_gs));
    assert!(
        2 * dsa.iterations <= cg.iterations,
        "dsa-cg {} vs cg {} (jacobi {})",
        dsa.iterations,
        cg.iterations,
        jacobi.iterations
    );
}

#[test]
fn dsa_cg_converges_at_albedo_one() {
    let op = small_cloud_operator([12, 12, 10], 2.0, 1.0);
    let e: Vec<f64> = (0..op.len()).map(|i| (i % 5) as f64).collect();
    let (g, r) = solve_with(&op, &e, "dsa-cg", 1e-8);
    assert!(g.iter().all(|v| v.is_finite()));
    // The cloud leaks at its edges, so a = 1 still has a solution: it must be found.
    assert!(r.converged && r.final_residual <= 1e-8, "{r:?}");
}

#[test]
fn dsa_cg_on_a_thin_cloud_matches_cg_and_jacobi_in_far_fewer_iterations() {
    // The sample cloud's regime: optically thin cells (σt·h ≤ 0.6), albedo 0.999, where the
    // light escapes at the edges and diffusion is only a rough model of transport.
    let op = small_cloud_operator([20, 20, 16], 0.6, 0.999);
    let e: Vec<f64> = (0..op.len()).map(|i| 1.0 + (i % 3) as f64).collect();
    let (g_j, jacobi) = solve_with(&op, &e, "jacobi", 1e-9);
    let (g_c, cg) = solve_with(&op, &e, "cg", 1e-9);
    let (g_d, dsa) = solve_with(&op, &e, "dsa-cg", 1e-9);
    for r in [&jacobi, &cg, &dsa] {
        assert!(r.converged, "{r:?}");
    }
    let rel = |a: &[f64], b: &[f64]| {
        let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
        (num / b.iter().map(|y| y * y).sum::<f64>()).sqrt()
    };
    assert!(rel(&g_d, &g_j) < 1e-6, "{}", rel(&g_d, &g_j));
    assert!(rel(&g_d, &g_c) < 1e-6, "{}", rel(&g_d, &g_c));
    eprintln!(
        "jacobi {}, cg {}, dsa-cg {}",
        jacobi.iterations, cg.iterations, dsa.iterations
    );
    assert!(
        5 * dsa.iterations <= jacobi.iterations && dsa.iterations < cg.iterations,
        "dsa-cg {} vs cg {} and jacobi {}",
        dsa.iterations,
        cg.iterations,
        jacobi.iterations
    );
}

#[test]
fn multigrid_v_cycles_reduce_the_clouds_diffusion_residual() {
    // The hierarchical operator's own diffusion matrix: harmonic-mean faces between cells of
    // very different σt, vacuum faces towards empty cells, albedo 0.999 (almost no absorption).
    let op = small_cloud_operator([24, 24, 20], 0.6, 0.999);
    let d = op
        .diffusion()
        .expect("the hierarchical operator has a diffusion approximation");
    let n = op.len();
    let mut mg = solver::DiffusionMultigrid::new(&d).unwrap();
    let levels = mg.level_sizes();
    assert!(levels.len() >= 2, "{levels:?}");
    let r: Vec<f64> = (0..n)
        .map(|i| {
            if d.row_ptr()[i + 1] > d.row_ptr()[i] {
                ((i * 13) % 7) as f64 - 3.0
            } else {
                0.0
            }
        })
        .collect();
    let residual = |y: &[f64]| -> f64 {
        (0..n)
            .map(|i| {
                let mut ay = (d.sigma_t()[i] - d.sigma_s()[i]) * y[i];
                for p in d.row_ptr()[i]..d.row_ptr()[i + 1] {
                    ay += d.val()[p] * y[d.col()[p] as usize];
                }
                (r[i] - ay).powi(2)
            })
            .sum::<f64>()
            .sqrt()
    };
    let r0 = residual(&vec![0.0; n]);
    let mut y = vec![0.0; n];
    for cycles in [1, 2, 4] {
        mg.solve(&r, &mut y, cycles);
        let factor = (residual(&y) / r0).powf(1.0 / cycles as f64);
        eprintln!("levels {levels:?}: {cycles} V-cycles, {factor:.3} per cycle");
        assert!(factor < 0.45, "{cycles} V-cycles: {factor} per cycle");
    }
    let iterations = mg.solve_pcg(&r, &mut y, 1e-8, 100);
    assert!(residual(&y) <= 1e-8 * r0 * 1.0001, "{}", residual(&y) / r0);
    assert!(
        iterations <= 30,
        "multigrid PCG needed {iterations} iterations"
    );
}
