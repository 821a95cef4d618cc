//! With isotropic scattering the discrete-ordinates solution, integrated over angle, must
//! agree with the zonal solution of the same medium (both solve the same isotropic problem
//! with a source uniform in each cell; the zonal form factors transport it exactly).

use std::f64::consts::PI;

use formfactor::ordinates::{DirectionBins, OrdinatesOperator, OrdinatesOptions};
use formfactor::{ExactOptions, FormFactorMatrix};
use medium::{CellValues, ChannelMedium, Grid, PhaseFunction};
use solver::operator::TransportOperator;

/// Source iteration `x ← e + K x` to a relative change of 1e-10.
fn iterate(op: &dyn TransportOperator, e: &[f64]) -> Vec<f64> {
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

#[test]
fn isotropic_ordinates_agree_with_zonal() {
    let grid = Grid::new([7, 7, 7], 1.0).unwrap();
    let scale: f64 = std::env::var("ZONAL_SCALE").map_or(1.0, |v| v.parse().unwrap());
    let c = grid.center();
    let channel = ChannelMedium {
        sigma_t: (0..grid.cell_count())
            .map(|i| {
                let d = (grid.cell_center(i) - c).length() / 3.5;
                ((0.15 + 0.6 * (1.0 - d * d).max(0.0)) * scale) as f32
            })
            .collect(),
        albedo: CellValues::Uniform(0.9),
        emission: CellValues::Uniform(0.0),
    };
    let n = grid.cell_count();
    let uniform = std::env::var("ZONAL_SOURCE_LAYER").is_err();
    // Uniform emission (or, with ZONAL_SOURCE_LAYER set, one emitting layer).
    let emission: Vec<f64> = (0..n)
        .map(|i| {
            if uniform || grid.coords(i)[2] == 1 {
                1.0
            } else {
                0.0
            }
        })
        .collect();

    let zonal = FormFactorMatrix::build(&grid, &channel, &ExactOptions::default(), None).unwrap();
    let g_zonal = iterate(&zonal, &emission);

    // The same problem by discrete ordinates (96 bins), sweeping each cell whole and as
    // 2×2×2 sub-cells.
    let gap = |refinement: usize| -> f64 {
        let op = OrdinatesOperator::from_channel(
            grid,
            &channel,
            PhaseFunction::Isotropic,
            DirectionBins::cube(4).unwrap(),
            OrdinatesOptions {
                transport_refinement: refinement,
                ..Default::default()
            },
        )
        .unwrap();
        let external = op.external_density(Some(&emission), &[]).unwrap();
        let mut e = vec![0.0; op.len()];
        op.transport(&external, &mut e);
        let radiance = iterate(&op, &e);
        // The zonal unknown is the cell's source per length: e + σs ∫I dω / 4π.
        let fluence = op.fluence(&radiance);
        let g_ordinates: Vec<f64> = (0..n)
            .map(|i| emission[i] + op.sigma_s()[i] * fluence[i] / (4.0 * PI))
            .collect();
        let mut worst = 0.0f64;
        let mut sum_sq = (0.0, 0.0);
        for i in 0..n {
            let scattered_z = g_zonal[i] - emission[i];
            let scattered_o = g_ordinates[i] - emission[i];
            worst = worst.max((scattered_o / scattered_z - 1.0).abs());
            sum_sq.0 += (scattered_o - scattered_z).powi(2);
            sum_sq.1 += scattered_z.powi(2);
        }
        let rms = (sum_sq.0 / sum_sq.1).sqrt();
        for k in 0..7 {
            let i = grid.index(3, 3, k);
            let j = grid.index(0, 3, k);
            println!(
                "z {k}: centre zonal {:.4e} ordinates {:.4e}; edge zonal {:.4e} ordinates {:.4e}",
                g_zonal[i] - emission[i],
                g_ordinates[i] - emission[i],
                g_zonal[j] - emission[j],
                g_ordinates[j] - emission[j]
            );
        }
        let total_z: f64 = (0..n).map(|i| g_zonal[i] - emission[i]).sum();
        let total_o: f64 = (0..n).map(|i| g_ordinates[i] - emission[i]).sum();
        println!(
            "transport refinement {refinement}: totals zonal {total_z:.4e} ordinates \
             {total_o:.4e}; scattered source relative RMS {rms:.4}, worst cell {worst:.4}"
        );
        rms
    };
    let (whole, refined) = (gap(1), gap(2));
    // Measured: 3.5 % RMS with whole cells (ordinates low in the centre, high at the rim:
    // the step scheme spreads flux sideways), 1.6 % with 2×2×2 sub-cells (0.9 % with 3³,
    // 0.55 % with 4³: first order in the sub-cell size). More bins do not close the gap
    // (384 bins: 4.2 %), so it is spatial, not angular (`explore_ordinates_zonal_gap`).
    assert!(
        refined < 0.02,
        "relative RMS {refined} with 2×2×2 sub-cells"
    );
    // The default (whole cells) keeps a guard of its own.
    assert!(whole < 0.04, "relative RMS {whole} with whole cells");
    assert!(
        refined < 0.7 * whole,
        "sub-cells {refined} vs whole cells {whole}"
    );
}

/// The blob of [`isotropic_ordinates_agree_with_zonal`] on a grid refined `r`× per axis
/// (the same piecewise-constant medium), uniform emission 1.
fn refined_blob(r: usize) -> (Grid, ChannelMedium) {
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
    (grid, channel)
}

/// Scattered source `σs ∫I dω / 4π` (ordinates) or `g − e` (zonal) averaged back onto the
/// 7³ cells.
fn coarse_average(grid: &Grid, r: usize, fine: &[f64]) -> Vec<f64> {
    let mut out = vec![0.0; 343];
    for (i, v) in fine.iter().enumerate() {
        let [x, y, z] = grid.coords(i);
        out[(x / r) + 7 * ((y / r) + 7 * (z / r))] += v / (r * r * r) as f64;
    }
    out
}

fn scattered_zonal(r: usize) -> Vec<f64> {
    let (grid, channel) = refined_blob(r);
    let e = vec![1.0; grid.cell_count()];
    let zonal = FormFactorMatrix::build(&grid, &channel, &ExactOptions::default(), None).unwrap();
    let g = iterate(&zonal, &e);
    coarse_average(&grid, r, &g.iter().map(|v| v - 1.0).collect::<Vec<_>>())
}

fn scattered_ordinates(r: usize, n: usize) -> Vec<f64> {
    let (grid, channel) = refined_blob(r);
    let e = vec![1.0; grid.cell_count()];
    let op = OrdinatesOperator::from_channel(
        grid,
        &channel,
        PhaseFunction::Isotropic,
        DirectionBins::cube(n).unwrap(),
        OrdinatesOptions {
            exact_transmission: std::env::var("ZONAL_EXACT_T").is_ok_and(|v| v == "1"),
            transport_refinement: std::env::var("ZONAL_REFINE").map_or(1, |v| v.parse().unwrap()),
            ..Default::default()
        },
    )
    .unwrap();
    let external = op.external_density(Some(&e), &[]).unwrap();
    let mut t = vec![0.0; op.len()];
    op.transport(&external, &mut t);
    let radiance = iterate(&op, &t);
    let fluence = op.fluence(&radiance);
    let s: Vec<f64> = (0..grid.cell_count())
        .map(|i| op.sigma_s()[i] * fluence[i] / (4.0 * PI))
        .collect();
    coarse_average(&grid, r, &s)
}

fn rms_against(reference: &[f64], x: &[f64]) -> (f64, f64) {
    let num: f64 = x.iter().zip(reference).map(|(a, b)| (a - b).powi(2)).sum();
    let den: f64 = reference.iter().map(|b| b * b).sum();
    let mean = x.iter().sum::<f64>() / reference.iter().sum::<f64>() - 1.0;
    ((num / den).sqrt(), mean)
}

/// Where the ordinates–zonal gap comes from: angular (bins `6 n²`, `ZONAL_N=4,6,8`) or
/// spatial (both methods on grids refined `r`×, `ZONAL_R=1,2,3`; the 7³ zonal solution is the
/// reference). `cargo test --release --test ordinates_zonal explore -- --ignored --nocapture`
#[test]
#[ignore]
fn explore_ordinates_zonal_gap() {
    let list = |key: &str, default: &str| -> Vec<usize> {
        std::env::var(key)
            .unwrap_or(default.into())
            .split(',')
            .map(|v| v.parse().unwrap())
            .collect()
    };
    let reference = scattered_zonal(1);
    for r in list("ZONAL_ZR", "1").into_iter().filter(|&r| r > 1) {
        let (rms, mean) = rms_against(&reference, &scattered_zonal(r));
        println!("zonal refined {r}x: RMS {rms:.4} mean {mean:+.4} vs zonal 7³");
    }
    for r in list("ZONAL_R", "1") {
        for n in list("ZONAL_N", "4") {
            let (rms, mean) = rms_against(&reference, &scattered_ordinates(r, n));
            println!(
                "ordinates refined {r}x, {} bins: RMS {rms:.4} mean {mean:+.4} vs zonal 7³",
                6 * n * n
            );
        }
    }
}
