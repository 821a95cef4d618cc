//! The procedural generators: deterministic by seed, normalised, isolated, shaped as described.

use medium::generators::{cloud, dipole, Generator};

const DIMS: [usize; 3] = [24, 20, 16];

fn at(v: &[f32], d: [usize; 3], i: usize, j: usize, k: usize) -> f32 {
    v[i + d[0] * (j + d[1] * k)]
}

#[test]
fn cloud_is_deterministic_by_seed_and_differs_between_seeds() {
    let a = cloud(DIMS, 7);
    let b = cloud(DIMS, 7);
    let c = cloud(DIMS, 8);
    assert_eq!(a.len(), 24 * 20 * 16);
    assert_eq!(a, b);
    let differing = a
        .iter()
        .zip(&c)
        .filter(|(x, y)| (*x - *y).abs() > 1e-3)
        .count();
    assert!(
        differing > a.len() / 50,
        "seeds 7 and 8 differ in only {differing} cells"
    );
    assert_eq!(Generator::Cloud { seed: 7 }.generate(DIMS), a);
}

#[test]
fn cloud_is_normalised_non_negative_and_isolated() {
    for seed in [1, 7, 12345] {
        let v = cloud(DIMS, seed);
        let peak = v.iter().copied().fold(0.0f32, f32::max);
        assert!((peak - 1.0).abs() < 1e-6, "peak {peak}");
        assert!(v.iter().all(|&x| x.is_finite() && x >= 0.0));
        // Zero on every boundary cell.
        for k in 0..DIMS[2] {
            for j in 0..DIMS[1] {
                for i in 0..DIMS[0] {
                    let edge = i == 0
                        || j == 0
                        || k == 0
                        || i == DIMS[0] - 1
                        || j == DIMS[1] - 1
                        || k == DIMS[2] - 1;
                    if edge {
                        assert_eq!(at(&v, DIMS, i, j, k), 0.0, "seed {seed} cell ({i},{j},{k})");
                    }
                }
            }
        }
        // A cloud, not a speck or a fog: a reasonable fraction of the grid is occupied.
        let occupied = v.iter().filter(|&&x| x > 0.0).count() as f64 / v.len() as f64;
        assert!(
            (0.03..0.6).contains(&occupied),
            "seed {seed}: occupied {occupied}"
        );
    }
}

#[test]
fn cloud_edges_are_rough_not_ellipsoidal() {
    // Noise makes the density along a row non-monotone somewhere (bumps), which a sum of
    // smooth concave blobs alone would rarely produce in many rows.
    let v = cloud([48, 48, 36], 7);
    let d = [48, 48, 36];
    let mut bumpy_rows = 0;
    for k in 0..36 {
        for j in 0..48 {
            let row: Vec<f32> = (0..48).map(|i| at(&v, d, i, j, k)).collect();
            let peaks = row
                .windows(3)
                .filter(|w| w[1] > w[0] + 1e-4 && w[1] > w[2] + 1e-4)
                .count();
            if peaks >= 2 {
                bumpy_rows += 1;
            }
        }
    }
    assert!(
        bumpy_rows > 10,
        "only {bumpy_rows} rows with several local maxima"
    );
}

#[test]
fn dipole_is_symmetric_peaked_at_centre_and_follows_the_far_field() {
    let d = [33, 33, 33];
    let v = dipole(d);
    assert_eq!(v, Generator::Dipole.generate(d));
    let peak = v.iter().copied().fold(0.0f32, f32::max);
    assert!((peak - 1.0).abs() < 1e-6);
    // The peak sits on the dipole's axis (y) next to the softened centre.
    let argmax = v.iter().position(|&x| x == peak).unwrap();
    let (i, j, k) = (argmax % 33, (argmax / 33) % 33, argmax / (33 * 33));
    assert!(
        i == 16 && k == 16 && j.abs_diff(16) <= 2,
        "peak at ({i},{j},{k})"
    );
    // Mirror symmetric in every axis about the centre.
    for (i, j, k) in [(3, 5, 7), (10, 2, 30), (20, 25, 1)] {
        let x = at(&v, d, i, j, k);
        assert!((x - at(&v, d, 32 - i, j, k)).abs() < 1e-6 * x.max(1e-6) + 1e-9);
        assert!((x - at(&v, d, i, 32 - j, k)).abs() < 1e-6 * x.max(1e-6) + 1e-9);
        assert!((x - at(&v, d, i, j, 32 - k)).abs() < 1e-6 * x.max(1e-6) + 1e-9);
    }
    // Far field: on the axis of m (y) |B| is twice its value on the equator at equal r,
    // and it falls off as 1/r³ (softening negligible at r = 8 and 16 cells).
    let axis8 = at(&v, d, 16, 24, 16) as f64;
    let equator8 = at(&v, d, 24, 16, 16) as f64;
    assert!(
        (axis8 / equator8 - 2.0).abs() < 1e-4,
        "{}",
        axis8 / equator8
    );
    let axis16 = at(&v, d, 16, 32, 16) as f64;
    let eps2: f64 = 1.5 * 1.5;
    let expected = ((64.0 + eps2) / (256.0 + eps2)).powf(1.5);
    assert!(
        (axis16 / axis8 - expected).abs() < 1e-4,
        "{} vs {expected}",
        axis16 / axis8
    );
}
