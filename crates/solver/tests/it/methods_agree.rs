//! Every method reaches the direct solution on random contractive systems.

use crate::common::*;
use solver::{
    solve, DenseOperator, Method, Smoother, SolveControl, SolveOptions, StopReason,
    TransportOperator,
};

fn options(method: Method, tolerance: f64) -> SolveOptions {
    SolveOptions {
        method,
        tolerance,
        max_iterations: 5000,
        record_history: true,
    }
}

#[track_caller]
fn check_method(op: &dyn TransportOperator, e: &[f64], exact: &[f64], method: Method) {
    let tol = 1e-10;
    let (g, report) = solve(op, e, None, &options(method, tol), &SolveControl::new()).unwrap();
    assert!(report.converged, "{method}: {report:?}");
    assert_eq!(report.stop_reason, StopReason::Converged);
    assert!(
        report.final_residual <= tol,
        "{method}: {}",
        report.final_residual
    );
    // Error ≤ ‖(I − K)⁻¹‖ · residual; the systems here have ‖(I − K)⁻¹‖ ≲ 50.
    let err = rel_diff(&g, exact);
    assert!(err < 1e-7, "{method}: relative error {err:e}");
    assert_eq!(report.method, method.to_string());
    // One history entry per iteration plus the initial residual.
    assert_eq!(
        report.residual_history.len(),
        report.iterations + 1,
        "{method}"
    );
}

#[test]
fn all_methods_reach_the_direct_solution_on_reciprocal_systems() {
    let methods = [
        Method::Jacobi,
        Method::GaussSeidel,
        Method::Sor { omega: 1.3 },
        Method::Gmres { restart: 10 },
        Method::BiCgStab,
        Method::ConjugateGradient,
        Method::TwoLevelCg { smoothing: 0 },
        Method::TwoLevelCg { smoothing: 2 },
        Method::CoarseCorrected {
            inner: Smoother::GaussSeidel,
        },
        Method::CoarseCorrected {
            inner: Smoother::Jacobi,
        },
        Method::CoarseCorrected {
            inner: Smoother::Sor { omega: 1.2 },
        },
    ];
    for seed in 0..3 {
        let k = reciprocal(70, seed, 0.97, 1.0);
        assert!(k.symmetry_defect().unwrap() < 1e-12);
        assert!(k.max_column_sum() <= 0.97 + 1e-12);
        let e = random_source(70, seed);
        let exact = direct_solve(&k, &e);
        for m in methods {
            check_method(&k, &e, &exact, m);
        }
        // Operator-supplied aggregates take the place of the contiguous default.
        let k = k.with_aggregates((0..70).map(|i| (i % 7) as u32).collect());
        for m in [
            Method::CoarseCorrected {
                inner: Smoother::GaussSeidel,
            },
            Method::TwoLevelCg { smoothing: 1 },
        ] {
            check_method(&k, &e, &exact, m);
        }
    }
}

#[test]
fn general_methods_reach_the_direct_solution_on_nonsymmetric_dominant_systems() {
    let methods = [
        Method::Jacobi,
        Method::GaussSeidel,
        Method::Sor { omega: 0.9 },
        Method::Gmres { restart: 20 },
        Method::BiCgStab,
        Method::CoarseCorrected {
            inner: Smoother::GaussSeidel,
        },
    ];
    for seed in 10..13 {
        let k = dominant(60, seed, 0.9);
        let e = random_source(60, seed);
        let exact = direct_solve(&k, &e);
        for m in methods {
            check_method(&k, &e, &exact, m);
        }
    }
}

#[test]
fn coarse_correction_probed_through_apply_only_matches() {
    let k = reciprocal(50, 7, 0.99, 1.0);
    let e = random_source(50, 7);
    let exact = direct_solve(&k, &e);
    let hidden = ApplyOnly(&k);
    let (g, report) = solve(
        &hidden,
        &e,
        None,
        &options(
            Method::CoarseCorrected {
                inner: Smoother::Jacobi,
            },
            1e-10,
        ),
        &SolveControl::new(),
    )
    .unwrap();
    assert!(report.converged);
    assert!(rel_diff(&g, &exact) < 1e-7);
    // Probing costs one application per default aggregate on top of two per cycle.
    assert_eq!(
        report.operator_applications,
        solver::PROBED_DEFAULT_AGGREGATES + 2 * report.iterations + 1
    );
}

#[test]
fn starting_from_the_solution_takes_no_iterations() {
    let k = reciprocal(40, 3, 0.9, 1.0);
    let e = random_source(40, 3);
    let exact = direct_solve(&k, &e);
    for m in [
        Method::Jacobi,
        Method::GaussSeidel,
        Method::Gmres { restart: 5 },
        Method::BiCgStab,
        Method::ConjugateGradient,
    ] {
        let (_, report) = solve(
            &k,
            &e,
            Some(&exact),
            &options(m, 1e-9),
            &SolveControl::new(),
        )
        .unwrap();
        assert!(
            report.converged && report.iterations == 0,
            "{m}: {report:?}"
        );
    }
}

const BLOCK: usize = 4;

#[test]
fn acceleration_pays_on_a_thick_chain_at_albedo_0999() {
    // 2000 thick cells in a row: leakage only at the ends, Jacobi needs ~10⁴+ iterations.
    let chain = Chain::new(2000, 1, 0.999, 0.999).with_blocks(BLOCK);
    let e = vec![1.0; 2000];
    let run = |m: Method| {
        let o = SolveOptions {
            method: m,
            tolerance: 1e-8,
            max_iterations: 200_000,
            record_history: false,
        };
        solve(&chain, &e, None, &o, &SolveControl::new()).unwrap()
    };
    let (g_j, jacobi) = run(Method::Jacobi);
    assert!(jacobi.converged, "{jacobi:?}");
    for m in [
        Method::ConjugateGradient,
        Method::Gmres { restart: 50 },
        Method::CoarseCg,
        Method::TwoLevelCg { smoothing: 0 },
        Method::TwoLevelCg { smoothing: 1 },
        Method::CoarseCorrected {
            inner: Smoother::GaussSeidel,
        },
    ] {
        let (g, r) = run(m);
        assert!(r.converged, "{m}: {r:?}");
        assert!(
            r.iterations * 10 <= jacobi.iterations,
            "{m}: {} iterations vs Jacobi's {}",
            r.iterations,
            jacobi.iterations
        );
        assert!(rel_diff(&g, &g_j) < 1e-5, "{m}");
    }
}

#[test]
fn parallel_kernels_are_deterministic() {
    // Longer than several reduction chunks, so the parallel paths run.
    let chain = Chain::new(40_000, 2, 0.99, 0.95);
    let e = random_source(40_000, 2);
    for m in [Method::Jacobi, Method::BiCgStab, Method::ConjugateGradient] {
        let o = options(m, 1e-8);
        let (a, ra) = solve(&chain, &e, None, &o, &SolveControl::new()).unwrap();
        let (b, rb) = solve(&chain, &e, None, &o, &SolveControl::new()).unwrap();
        assert!(ra.converged);
        assert_eq!(ra.residual_history, rb.residual_history, "{m}");
        assert!(
            a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits()),
            "{m}"
        );
    }
}

/// An operator with its own sweep and no rows (like a discrete-ordinates transport sweep).
struct SweepOnly<'a>(&'a DenseOperator);

impl TransportOperator for SweepOnly<'_> {
    fn len(&self) -> usize {
        self.0.len()
    }
    fn apply(&self, x: &[f64], y: &mut [f64]) {
        self.0.apply(x, y)
    }
    fn sweep_in_place(&self, g: &mut [f64], source: &[f64], omega: f64) -> bool {
        // Backward order, to differ from the row default.
        for i in (0..g.len()).rev() {
            let kg: f64 = (0..g.len()).map(|j| self.0.entry(i, j) * g[j]).sum();
            g[i] = (1.0 - omega) * g[i] + omega * (source[i] + kg);
        }
        true
    }
}

#[test]
fn sweep_only_operators_support_gauss_seidel_and_sor() {
    let k = reciprocal(50, 21, 0.98, 1.0);
    let e = random_source(50, 21);
    let exact = direct_solve(&k, &e);
    let op = SweepOnly(&k);
    for m in [
        Method::GaussSeidel,
        Method::Sor { omega: 1.4 },
        Method::CoarseCorrected {
            inner: Smoother::GaussSeidel,
        },
    ] {
        check_method(&op, &e, &exact, m);
    }
}
