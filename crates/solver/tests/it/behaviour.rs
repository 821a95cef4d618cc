//! Stopping behaviour: cancellation, divergence, singular systems, refused input, parsing,
//! the report's serialization, and the spectral-radius estimate.

use std::sync::atomic::Ordering;

use crate::common::*;
use solver::{
    predicted_iterations, solve, spectral_radius, DenseOperator, Method, Smoother, SolveControl,
    SolveError, SolveOptions, SolveReport, StopReason,
};

const ALL: [&str; 14] = [
    "jacobi",
    "gauss-seidel",
    "sor:1.5",
    "sor:0.8",
    "gmres:30",
    "gmres:5",
    "bicgstab",
    "cg",
    "two-level-cg",
    "two-level-cg:2",
    "coarse-cg",
    "coarse-gs",
    "coarse-jacobi",
    "coarse-sor:1.2",
];

fn opts(method: Method, tolerance: f64, max_iterations: usize) -> SolveOptions {
    SolveOptions {
        method,
        tolerance,
        max_iterations,
        record_history: true,
    }
}

#[test]
fn jacobi_rate_matches_power_iteration_spectral_radius() {
    for seed in 0..3 {
        let k = reciprocal(80, seed, 0.98, 1.0);
        let e = random_source(80, seed);
        let est = spectral_radius(&k, 10_000, 1e-12);
        assert!(
            est.converged && est.rho > 0.5 && est.rho < 0.98 + 1e-9,
            "{est:?}"
        );
        let (_, report) = solve(
            &k,
            &e,
            None,
            &opts(Method::Jacobi, 1e-12, 100_000),
            &SolveControl::new(),
        )
        .unwrap();
        assert!(report.converged);
        let h = &report.residual_history;
        let m = 20.min(h.len() / 2);
        let last = h.len() - 1;
        let rate = (h[last] / h[last - m]).powf(1.0 / m as f64);
        assert!(
            (rate / est.rho - 1.0).abs() < 0.05,
            "rate {rate} vs rho {}",
            est.rho
        );
        // The prediction from rho is the iteration count up to the start-up transient.
        let predicted = predicted_iterations(est.rho, 1e-12).unwrap() as f64;
        let measured = report.iterations as f64;
        assert!(
            (measured - predicted).abs() <= 0.2 * predicted + 5.0,
            "{measured} vs {predicted}"
        );
    }
}

#[test]
fn predicted_iterations_formula_and_limits() {
    assert_eq!(predicted_iterations(0.5, 1e-3), Some(10)); // 2^-10 < 1e-3 < 2^-9
    assert_eq!(predicted_iterations(0.1, 1e-5), Some(5));
    assert_eq!(predicted_iterations(1.0, 1e-5), None);
    assert_eq!(predicted_iterations(1.5, 1e-5), None);
    assert_eq!(predicted_iterations(f64::NAN, 1e-5), None);
}

#[test]
fn spectral_radius_of_a_known_matrix() {
    // Symmetric circulant with kernel (0.2, 0.5, 0.2): eigenvalues 0.5 + 0.4 cos(2πk/n), ρ = 0.9.
    let n = 30;
    let k = DenseOperator::from_fn(n, |i, j| match (i + n - j) % n {
        0 => 0.5,
        1 | 29 => 0.2,
        _ => 0.0,
    });
    let est = spectral_radius(&k, 1000, 1e-12);
    assert!(est.converged);
    assert!((est.rho - 0.9).abs() < 1e-9, "{est:?}");
}

#[test]
fn cancellation_before_and_during_a_solve_is_reported() {
    let k = reciprocal(60, 1, 0.999, 1.0);
    let e = random_source(60, 1);
    let control = SolveControl::new();
    control.cancel();
    for name in ALL {
        let m: Method = name.parse().unwrap();
        let (g, r) = solve(&k, &e, None, &opts(m, 1e-14, 100_000), &control).unwrap();
        assert_eq!(r.stop_reason, StopReason::Cancelled, "{name}");
        assert!(r.cancelled && !r.converged, "{name}");
        assert!(r.iterations <= 1, "{name}: {}", r.iterations);
        assert_eq!(g.len(), 60);
    }
    // Cancelled from the progress callback (as another thread would) after 5 iterations.
    for name in ALL {
        let control = SolveControl::new();
        let flag = control.flag();
        let control = control.with_progress(move |it, _| {
            if it >= 5 {
                flag.store(true, Ordering::Relaxed);
            }
        });
        let m: Method = name.parse().unwrap();
        let (_, r) = solve(&k, &e, None, &opts(m, 1e-14, 100_000), &control).unwrap();
        assert_eq!(r.stop_reason, StopReason::Cancelled, "{name}");
        assert!(
            r.iterations >= 5 && r.iterations <= 6,
            "{name}: {}",
            r.iterations
        );
        assert!(r.final_residual.is_finite() && r.final_residual > 1e-14);
    }
}

#[test]
fn non_contractive_operator_is_reported_not_looped() {
    // Column sums up to 2: energy is created, ρ > 1.
    let k = reciprocal(50, 4, 2.0, 1.0);
    let e = random_source(50, 4);
    assert!(spectral_radius(&k, 1000, 1e-10).rho > 1.1);
    for name in ["jacobi", "gauss-seidel", "sor:1.5", "coarse-jacobi"] {
        let m: Method = name.parse().unwrap();
        let (_, r) = solve(&k, &e, None, &opts(m, 1e-8, 100_000), &SolveControl::new()).unwrap();
        assert!(!r.converged, "{name}");
        assert!(
            matches!(r.stop_reason, StopReason::Diverged | StopReason::Stagnated),
            "{name}: {:?}",
            r.stop_reason
        );
        assert!(r.iterations < 2000, "{name}: {}", r.iterations);
    }
    // Krylov methods may legitimately solve the (non-physical) system; either way the report
    // is honest about the true residual.
    for name in ALL {
        let m: Method = name.parse().unwrap();
        let (_, r) = solve(&k, &e, None, &opts(m, 1e-8, 3000), &SolveControl::new()).unwrap();
        assert_eq!(r.converged, r.final_residual <= 1e-8, "{name}: {r:?}");
        assert_eq!(
            r.converged,
            r.stop_reason == StopReason::Converged,
            "{name}"
        );
    }
}

/// Symmetric doubly stochastic circulant: ρ = 1 exactly, null space of `I − K` = constants.
fn conservative(n: usize) -> DenseOperator {
    DenseOperator::from_fn(n, |i, j| match (i + n - j) % n {
        0 => 0.4,
        1 => 0.3,
        d if d == n - 1 => 0.3,
        _ => 0.0,
    })
    .with_symmetrizer(vec![1.0; n])
}

#[test]
fn at_spectral_radius_one_every_method_converges_or_says_it_did_not() {
    let n = 40;
    let k = conservative(n);
    assert!((spectral_radius(&k, 5000, 1e-13).rho - 1.0).abs() < 1e-6);
    // Consistent: E orthogonal to the constants.
    let mut e = random_source(n, 9);
    let mean = e.iter().sum::<f64>() / n as f64;
    e.iter_mut().for_each(|v| *v -= mean);
    for name in ALL {
        let m: Method = name.parse().unwrap();
        let (g, r) = solve(&k, &e, None, &opts(m, 1e-9, 20_000), &SolveControl::new()).unwrap();
        assert!(g.iter().all(|v| v.is_finite()), "{name}");
        assert_eq!(r.converged, r.final_residual <= 1e-9, "{name}: {r:?}");
        assert_eq!(
            r.converged,
            r.stop_reason == StopReason::Converged,
            "{name}"
        );
        if !r.converged {
            assert!(r.iterations <= 20_000);
        }
    }
    // Jacobi converges here (other eigenvalues lie in (−0.2, 1)).
    let (_, r) = solve(
        &k,
        &e,
        None,
        &opts(Method::Jacobi, 1e-9, 20_000),
        &SolveControl::new(),
    )
    .unwrap();
    assert!(r.converged);
    // Inconsistent (E has a constant part): no solution exists, and no method may claim one.
    let e: Vec<f64> = e.iter().map(|v| v + 0.1).collect();
    for name in ALL {
        let m: Method = name.parse().unwrap();
        let (_, r) = solve(&k, &e, None, &opts(m, 1e-9, 20_000), &SolveControl::new()).unwrap();
        assert!(!r.converged, "{name}: {r:?}");
        assert!(r.final_residual > 1e-3, "{name}");
        assert_ne!(r.stop_reason, StopReason::Converged);
    }
}

#[test]
fn bad_input_is_refused() {
    let k = reciprocal(20, 2, 0.9, 1.0);
    let e = random_source(20, 2);
    let c = SolveControl::new();
    let o = opts(Method::Jacobi, 1e-8, 100);
    assert!(matches!(
        solve(&k, &e[..19], None, &o, &c),
        Err(SolveError::WrongLength {
            what: "source",
            len: 19,
            expected: 20
        })
    ));
    assert!(matches!(
        solve(&k, &e, Some(&[0.0; 21]), &o, &c),
        Err(SolveError::WrongLength {
            what: "initial guess",
            len: 21,
            ..
        })
    ));
    let mut bad = e.clone();
    bad[7] = f64::NAN;
    assert!(matches!(
        solve(&k, &bad, None, &o, &c),
        Err(SolveError::NonFinite {
            what: "source",
            index: 7,
            ..
        })
    ));
    assert!(matches!(
        solve(&k, &e, None, &opts(Method::Jacobi, 0.0, 10), &c),
        Err(SolveError::InvalidOptions(_))
    ));
    assert!(matches!(
        solve(
            &k,
            &e,
            None,
            &opts(Method::Sor { omega: 2.0 }, 1e-8, 10),
            &c
        ),
        Err(SolveError::InvalidOptions(_))
    ));
    // Methods the operator cannot support are refused, not silently replaced.
    let general = dominant(20, 3, 0.8);
    let err = solve(
        &general,
        &e,
        None,
        &opts(Method::ConjugateGradient, 1e-8, 100),
        &c,
    )
    .unwrap_err();
    assert!(matches!(err, SolveError::Unsupported { .. }));
    assert!(err.to_string().contains("symmetrizer"));
    let hidden = ApplyOnly(&k);
    for m in ["gauss-seidel", "sor:1.2", "coarse-gs"] {
        let err = solve(&hidden, &e, None, &opts(m.parse().unwrap(), 1e-8, 100), &c).unwrap_err();
        assert!(matches!(err, SolveError::Unsupported { .. }), "{m}: {err}");
    }
    // Diffusion-synthetic acceleration needs the operator's geometry; a matrix has none.
    let err = solve(&k, &e, None, &opts(Method::DsaCg, 1e-8, 100), &c).unwrap_err();
    assert!(err.to_string().contains("diffusion"), "{err}");
    // Broken operator data.
    let k_bad_w = reciprocal(20, 2, 0.9, 1.0).with_symmetrizer(vec![-1.0; 20]);
    assert!(matches!(
        solve(
            &k_bad_w,
            &e,
            None,
            &opts(Method::ConjugateGradient, 1e-8, 100),
            &c
        ),
        Err(SolveError::InvalidOperatorData {
            what: "symmetrizer",
            ..
        })
    ));
    let k_bad_a = reciprocal(20, 2, 0.9, 1.0).with_aggregates([0, 2].repeat(10));
    assert!(matches!(
        solve(
            &k_bad_a,
            &e,
            None,
            &opts("coarse-gs".parse().unwrap(), 1e-8, 100),
            &c
        ),
        Err(SolveError::InvalidOperatorData {
            what: "coarse aggregates",
            ..
        })
    ));
}

#[test]
fn methods_parse_and_print() {
    for name in ALL {
        let m: Method = name.parse().unwrap();
        assert_eq!(m.to_string().parse::<Method>().unwrap(), m);
    }
    assert_eq!(
        "sor:1.5".parse::<Method>().unwrap(),
        Method::Sor { omega: 1.5 }
    );
    assert_eq!(
        "GMRES".parse::<Method>().unwrap(),
        Method::Gmres { restart: 30 }
    );
    assert_eq!(
        "coarse-gs".parse::<Method>().unwrap(),
        Method::CoarseCorrected {
            inner: Smoother::GaussSeidel
        }
    );
    for bad in [
        "",
        "sor",
        "sor:2.5",
        "sor:x",
        "gmres:0",
        "gmres:100000000",
        "jacobi:3",
        "multigrid",
        "coarse-bicgstab",
        "two-level-cg:x",
        "dsa-cg:2",
        "two-level-cg:9",
    ] {
        let err = bad.parse::<Method>().unwrap_err();
        assert!(err.to_string().contains("expected one of"), "{bad}: {err}");
    }
    // The largest restart parses; one built in code beyond it is refused by the solve, not
    // allowed to allocate its basis (which would abort the process).
    assert_eq!(
        format!("gmres:{}", solver::MAX_GMRES_RESTART).parse::<Method>(),
        Ok(Method::Gmres {
            restart: solver::MAX_GMRES_RESTART
        })
    );
    let k = reciprocal(30, 5, 0.9, 1.0);
    let e = random_source(30, 5);
    let huge = opts(
        Method::Gmres {
            restart: usize::MAX / 16,
        },
        1e-8,
        10,
    );
    assert!(matches!(
        solve(&k, &e, None, &huge, &SolveControl::new()),
        Err(solver::SolveError::InvalidOptions(_))
    ));
    // A restart longer than the problem converges as GMRES(n) does.
    let (_, r) = solve(
        &k,
        &e,
        None,
        &opts(Method::Gmres { restart: 1000 }, 1e-10, 200),
        &SolveControl::new(),
    )
    .unwrap();
    assert!(r.converged, "{r:?}");
}

#[test]
fn report_round_trips_through_serde() {
    let k = reciprocal(30, 5, 0.9, 1.0);
    let e = random_source(30, 5);
    let (_, r) = solve(
        &k,
        &e,
        None,
        &opts(Method::BiCgStab, 1e-10, 100),
        &SolveControl::new(),
    )
    .unwrap();
    let text = serde_json::to_string(&r).unwrap();
    let back: SolveReport = serde_json::from_str(&text).unwrap();
    // serde_json's float parsing is not bit-exact; the stored file format (bincode) is.
    assert_eq!(back.method, r.method);
    assert_eq!(
        (back.iterations, back.converged, back.stop_reason),
        (r.iterations, r.converged, r.stop_reason)
    );
    assert_eq!(back.operator_applications, r.operator_applications);
    assert_eq!(back.residual_history.len(), r.residual_history.len());
    for (a, b) in back.residual_history.iter().zip(&r.residual_history) {
        assert!((a - b).abs() <= 1e-15 * b.abs());
    }
    assert!(r.converged && r.operator_applications >= 2 * r.iterations);
    assert!(r.seconds >= 0.0 && r.seconds_per_iteration >= 0.0);
}

#[test]
fn zero_source_gives_zero_solution() {
    let k = reciprocal(25, 6, 0.9, 1.0);
    for name in ALL {
        let m: Method = name.parse().unwrap();
        let (g, r) = solve(
            &k,
            &[0.0; 25],
            None,
            &opts(m, 1e-10, 100),
            &SolveControl::new(),
        )
        .unwrap();
        assert!(r.converged && r.iterations == 0, "{name}");
        assert!(g.iter().all(|&v| v == 0.0));
    }
}
