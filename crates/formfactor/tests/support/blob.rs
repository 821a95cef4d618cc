//! Source iteration, and the isotropic blob of the ordinates–zonal comparison on refined
//! grids. Shared by tests/it/ordinates_zonal.rs and examples/ordinates_zonal_gap.rs.

use std::f64::consts::PI;

use formfactor::ordinates::{DirectionBins, OrdinatesOperator, OrdinatesOptions};
use formfactor::{ExactOptions, FormFactorMatrix};
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Medium, PhaseFunction};
use solver::operator::TransportOperator;

/// Source iteration `x ← e + K x` to a relative change of 1e-10.
pub fn iterate(op: &dyn TransportOperator, e: &[f64]) -> Vec<f64> {
    let mut x = e.to_vec();
    let mut y = vec![0.0; x.len()];
    let norm: f64 = e.iter().map(|v| v * v).sum::<f64>().sqrt();
    for _ in 0..5000 {
        op.apply(&x, &mut y);
        let mut change = 0.0;
        for i in 0..x.len() {
            let new = e[i] + y[i];
            change += (new - x[i]) * (new - x[i]);
            x[i] = new;
        }
        if change.sqrt() < 1e-10 * norm {
            return x;
        }
    }
    panic!("no convergence");
}

/// The blob of tests/it/ordinates_zonal.rs' `isotropic_ordinates_agree_with_zonal` on a grid refined `r`× per axis
/// (the same piecewise-constant medium, isotropic scattering); the emission is the callers'.
pub fn refined_blob(r: usize) -> Medium {
    let coarse = Grid::new([7, 7, 7], 1.0).unwrap();
    let grid = Grid::new([7 * r, 7 * r, 7 * r], 1.0 / r as f64).unwrap();
    let c = coarse.center();
    let sigma_t = (0..grid.cell_count())
        .map(|i| {
            let [x, y, z] = grid.coords(i);
            let ci = coarse.index(x / r, y / r, z / r);
            let d = (coarse.cell_center(ci) - c).length() / 3.5;
            (0.15 + 0.6 * (1.0 - d * d).max(0.0)) as f32
        })
        .collect();
    let channel = ChannelMedium {
        sigma_t,
        albedo: CellValues::Uniform(0.9),
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

/// Scattered source `σs ∫I dω / 4π` (ordinates) or `g − e` (zonal) averaged back onto the
/// 7³ cells.
pub fn coarse_average(grid: &Grid, r: usize, fine: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; 343];
    for (i, v) in fine.iter().enumerate() {
        let [x, y, z] = grid.coords(i);
        out[(x / r) + 7 * ((y / r) + 7 * (z / r))] += v / (r * r * r) as f64;
    }
    out
}

pub fn scattered_zonal(r: usize) -> Vec<f64> {
    let blob = refined_blob(r);
    let grid = *blob.grid();
    let e = vec![1.0; grid.cell_count()];
    let zonal = FormFactorMatrix::build(&blob, 0, &ExactOptions::default(), None).unwrap();
    let g = iterate(&zonal, &e);
    coarse_average(&grid, r, &g.iter().map(|v| v - 1.0).collect::<Vec<_>>())
}

pub fn scattered_ordinates(r: usize, n: usize) -> Vec<f64> {
    let blob = refined_blob(r);
    let grid = *blob.grid();
    let e = vec![1.0; grid.cell_count()];
    let op = OrdinatesOperator::new(
        &blob,
        0,
        DirectionBins::cube(n).unwrap(),
        OrdinatesOptions {
            exact_transmission: std::env::var("ZONAL_EXACT_T").is_ok_and(|v| v == "1"),
            transport_refinement: std::env::var("ZONAL_REFINE").map_or(1, |v| v.parse().unwrap()),
            face_coupling: std::env::var("ZONAL_MAX_SHARES").is_err(),
            linear_source: std::env::var("ZONAL_FLAT").is_err(),
            ..Default::default()
        },
    )
    .unwrap();
    let mut t = vec![0.0; op.len()];
    op.transport_emission(&e, &mut t).unwrap();
    let radiance = iterate(&op, &t);
    let fluence = op.fluence(&radiance);
    let s: Vec<f64> = (0..grid.cell_count())
        .map(|i| op.sigma_s()[i] * fluence[i] / (4.0 * PI))
        .collect();
    coarse_average(&grid, r, &s)
}

pub fn rms_against(reference: &[f64], x: &[f64]) -> (f64, f64) {
    let num: f64 = x.iter().zip(reference).map(|(a, b)| (a - b).powi(2)).sum();
    let den: f64 = reference.iter().map(|b| b * b).sum();
    let mean = x.iter().sum::<f64>() / reference.iter().sum::<f64>() - 1.0;
    ((num / den).sqrt(), mean)
}
