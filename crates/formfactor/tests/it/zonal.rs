//! Physics of the exact zonal operator: energy (column sums), reciprocity, the self term
//! against an independent quadrature, thresholding and bad input (the source term is the
//! light pass's: crates/medium/tests/light_pass.rs).

use formfactor::{ExactOptions, FormFactorError, FormFactorMatrix, NearQuadrature};
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Medium, PhaseFunction};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use solver::TransportOperator;

fn channel(sigma_t: Vec<f32>, albedo: f32) -> ChannelMedium {
    ChannelMedium {
        sigma_t,
        albedo: CellValues::Uniform(albedo),
        emission: CellValues::Uniform(0.0),
    }
}

/// The grey, isotropic one-channel medium of `channel` on `grid`.
fn grey(grid: &Grid, channel: &ChannelMedium) -> Medium {
    Medium::new(
        *grid,
        vec![channel.clone()],
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap()
}

/// Random medium: σt·h uniform in [0, max_tau] with a fraction of empty cells.
fn random_sigma(n: usize, max_tau: f64, h: f64, empty: f64, seed: u64) -> Vec<f32> {
    let mut rng = Pcg64::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            if rng.random::<f64>() < empty {
                0.0
            } else {
                (rng.random::<f64>() * max_tau / h) as f32
            }
        })
        .collect()
}

#[test]
fn column_sums_never_exceed_one() {
    let h = 0.5;
    let grid = Grid::new([6, 5, 6], h).unwrap();
    for (max_tau, seed) in [(5.0, 1u64), (0.01, 2), (1.0, 3)] {
        let ch = channel(random_sigma(grid.cell_count(), max_tau, h, 0.2, seed), 0.9);
        let f =
            FormFactorMatrix::build(&grey(&grid, &ch), 0, &ExactOptions::default(), None).unwrap();
        let sums = f.column_sums();
        let max = sums.iter().copied().fold(0.0, f64::max);
        assert!(max <= 1.0 + 1e-12, "σt·h ≤ {max_tau}: column sum {max}");
        assert!(max > 0.0);
        // Empty cells neither emit nor intercept.
        for (i, &s) in ch.sigma_t.iter().enumerate() {
            if s == 0.0 {
                assert_eq!(sums[i], 0.0);
                assert_eq!(f.matrix().outer_view(i).unwrap().nnz(), 0);
            }
        }
    }
}

#[test]
fn thick_homogeneous_cube_column_sums_approach_one() {
    // σt·h = 5: light emitted at the centre of a 7³ cube is almost all extinguished inside.
    let grid = Grid::new([7, 7, 7], 1.0).unwrap();
    let ch = channel(vec![5.0; grid.cell_count()], 1.0);
    let f = FormFactorMatrix::build(&grey(&grid, &ch), 0, &ExactOptions::default(), None).unwrap();
    let sums = f.column_sums();
    let centre = grid.index(3, 3, 3);
    assert!(
        sums[centre] <= 1.0 && sums[centre] > 1.0 - 1e-4,
        "centre column sum {}",
        sums[centre]
    );
    // A corner cell loses a good fraction through its three outer faces.
    assert!(sums[0] < 0.9, "corner column sum {}", sums[0]);
}

#[test]
fn exact_operator_is_reciprocal() {
    let h = 1.0;
    let grid = Grid::new([5, 6, 5], h).unwrap();
    let sigma = random_sigma(grid.cell_count(), 2.0, h, 0.1, 7);
    let f = FormFactorMatrix::build(
        &grey(&grid, &channel(sigma.clone(), 0.5)),
        0,
        &ExactOptions::default(),
        None,
    )
    .unwrap();
    let mut worst: f64 = 0.0;
    for i in 0..grid.cell_count() {
        for j in 0..grid.cell_count() {
            if sigma[i] > 0.0 && sigma[j] > 0.0 {
                let sij = f.get(i, j) / sigma[i] as f64;
                let sji = f.get(j, i) / sigma[j] as f64;
                assert!(sij > 0.0);
                worst = worst.max((sij - sji).abs() / sij.max(sji));
            }
        }
    }
    assert!(worst < 1e-4, "worst relative reciprocity error {worst}");
}

/// Escape probability from a uniform isotropically emitting unit cube of optical side τ, by
/// plain Monte Carlo (independent of the library's stratified rays); standard error ≈ 1e-4.
fn cube_escape_probability(tau: f64) -> f64 {
    let mut rng = Pcg64::seed_from_u64(42);
    let samples = 4_000_000;
    let mut sum = 0.0;
    for _ in 0..samples {
        let p: [f64; 3] = [rng.random(), rng.random(), rng.random()];
        let mu: f64 = 2.0 * rng.random::<f64>() - 1.0;
        let phi = 2.0 * std::f64::consts::PI * rng.random::<f64>();
        let s = (1.0 - mu * mu).sqrt();
        let d = [s * phi.cos(), s * phi.sin(), mu];
        let mut len = f64::INFINITY;
        for ax in 0..3 {
            if d[ax] > 0.0 {
                len = len.min((1.0 - p[ax]) / d[ax]);
            } else if d[ax] < 0.0 {
                len = len.min(-p[ax] / d[ax]);
            }
        }
        sum += (-tau * len).exp();
    }
    sum / samples as f64
}

#[test]
fn self_term_matches_independent_quadrature() {
    let grid = Grid::new([1, 1, 1], 2.0).unwrap();
    for tau in [0.1, 1.0, 5.0] {
        let ch = channel(vec![(tau / 2.0) as f32], 1.0);
        let expected = 1.0 - cube_escape_probability(tau);
        let f =
            FormFactorMatrix::build(&grey(&grid, &ch), 0, &ExactOptions::default(), None).unwrap();
        let got = f.get(0, 0);
        let rel = (got - expected).abs() / expected;
        assert!(
            rel < 5e-3,
            "τ = {tau}: F_ii {got} vs {expected} (rel {rel})"
        );
    }
}

#[test]
fn threshold_drops_entries_with_bounded_reported_energy() {
    let h = 1.0;
    let grid = Grid::new([8, 8, 8], h).unwrap();
    let ch = channel(random_sigma(grid.cell_count(), 0.5, h, 0.0, 11), 0.8);
    let full =
        FormFactorMatrix::build(&grey(&grid, &ch), 0, &ExactOptions::default(), None).unwrap();
    let options = ExactOptions {
        threshold: 1e-3,
        ..Default::default()
    };
    let cut = FormFactorMatrix::build(&grey(&grid, &ch), 0, &options, None).unwrap();
    assert!(
        cut.report().entries < full.report().entries * 4 / 5,
        "{} vs {}",
        cut.report().entries,
        full.report().entries
    );
    let (a, b) = (full.column_sums(), cut.column_sums());
    let worst = a.iter().zip(&b).map(|(x, y)| x - y).fold(0.0, f64::max);
    assert!(worst > 0.0);
    assert!(worst <= cut.report().max_dropped_column_sum * (1.0 + 1e-9) + 1e-15);
}

#[test]
fn apply_matches_sparse_product_with_albedo() {
    let grid = Grid::new([5, 4, 3], 1.0).unwrap();
    let mut ch = channel(random_sigma(grid.cell_count(), 1.0, 1.0, 0.2, 5), 0.0);
    let albedo: Vec<f32> = (0..grid.cell_count())
        .map(|i| 0.3 + 0.01 * i as f32)
        .collect();
    ch.albedo = CellValues::PerCell(albedo.clone());
    let f = FormFactorMatrix::build(&grey(&grid, &ch), 0, &ExactOptions::default(), None).unwrap();
    let x: Vec<f64> = (0..grid.cell_count())
        .map(|i| (i as f64 * 0.37).sin() + 1.5)
        .collect();
    let mut y = vec![0.0; x.len()];
    f.apply(&x, &mut y);
    // Serial reference through sprs's own row iterator.
    let reference: Vec<f64> = f
        .matrix()
        .outer_iterator()
        .map(|row| row.iter().map(|(j, v)| v * x[j]).sum())
        .collect();
    for i in 0..x.len() {
        let want = albedo[i] as f64 * reference[i];
        assert!((y[i] - want).abs() <= 1e-12 * want.abs().max(1e-300));
        assert!((f.rows().unwrap().row_dot(i, &x) - want).abs() <= 1e-12 * want.abs().max(1e-300));
    }
    // diag(w)K is symmetric with the symmetrizer's weights.
    let w = f.symmetrizer().unwrap();
    for i in 0..x.len() {
        for j in 0..x.len() {
            let kij = albedo[i] as f64 * f.get(i, j);
            let kji = albedo[j] as f64 * f.get(j, i);
            assert!((w[i] * kij - w[j] * kji).abs() <= 1e-4 * (w[i] * kij).abs().max(1e-300));
        }
    }
}

#[test]
fn bad_input() {
    let ch = ChannelMedium {
        sigma_t: vec![2.0, 0.0],
        albedo: CellValues::Uniform(0.5),
        emission: CellValues::PerCell(vec![0.1, 0.2]),
    };
    let grid = Grid::new([2, 1, 1], 1.0).unwrap();
    let bad = ExactOptions {
        near: NearQuadrature {
            radius: 0,
            ..Default::default()
        },
        ..Default::default()
    };
    assert!(matches!(
        FormFactorMatrix::build(&grey(&grid, &ch), 0, &bad, None),
        Err(FormFactorError::Option { .. })
    ));
    // A channel the medium does not have.
    assert_eq!(
        FormFactorMatrix::build(&grey(&grid, &ch), 1, &ExactOptions::default(), None).err(),
        Some(FormFactorError::Channel {
            channel: 1,
            channels: 1
        })
    );
}
