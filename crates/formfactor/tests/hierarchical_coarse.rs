//! The hierarchical operator's Galerkin coarse matrix (formed from its links, for the solver's
//! two-level methods) against the same matrix probed with one application per aggregate.

use formfactor::{HierarchicalOperator, HierarchicalOptions, NearQuadrature};
use medium::{CellValues, ChannelMedium, Grid};
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
        &grid,
        &channel,
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
