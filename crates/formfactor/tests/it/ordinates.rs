//! Discrete ordinates: bins, phase matrix, sweep conservation, the assembled reference,
//! full-solve energy balance and the infinite-medium limit.

use std::f64::consts::PI;

use formfactor::ordinates::bins::rectangle_solid_angle;
use formfactor::ordinates::phase_matrix::{bin_averaged_phase, phase_matrix_error};
use formfactor::ordinates::{
    AssembledOrdinates, DirectionBins, OrdinatesError, OrdinatesOperator, OrdinatesOptions,
    PhaseMatrix,
};
use glam::DVec3;
use medium::light_pass::LightPass;
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Light, Medium, PhaseFunction};
use rand::{Rng, SeedableRng};
use solver::operator::TransportOperator;

fn rng(seed: u64) -> rand_pcg::Pcg64Mcg {
    rand_pcg::Pcg64Mcg::seed_from_u64(seed)
}

fn random_direction(r: &mut impl Rng) -> DVec3 {
    let z: f64 = 1.0 - 2.0 * r.random::<f64>();
    let phi = 2.0 * PI * r.random::<f64>();
    let s = (1.0 - z * z).sqrt();
    DVec3::new(s * phi.cos(), s * phi.sin(), z)
}

/// A heterogeneous channel: smooth σt with some empty cells, varying albedo.
fn blob_channel(grid: &Grid, peak: f64, albedo: f32) -> ChannelMedium {
    let c = grid.center();
    let r = grid.extent().min_element() * 0.5;
    let sigma_t = (0..grid.cell_count())
        .map(|i| {
            let d = (grid.cell_center(i) - c).length() / r;
            (peak * (1.0 - d * d).max(0.0)) as f32
        })
        .collect();
    let alb = (0..grid.cell_count())
        .map(|i| albedo * (0.8 + 0.2 * ((i * 7919) % 13) as f32 / 13.0))
        .collect();
    ChannelMedium {
        sigma_t,
        albedo: CellValues::PerCell(alb),
        emission: CellValues::Uniform(0.0),
    }
}

/// The one-channel medium of `channel` on `grid`.
fn medium(grid: Grid, channel: &ChannelMedium, phase: PhaseFunction) -> Medium {
    Medium::new(
        grid,
        vec![channel.clone()],
        phase,
        Interpolation::Nearest,
        None,
    )
    .unwrap()
}

#[test]
fn solid_angles_sum_to_four_pi() {
    for n in 1..=formfactor::ordinates::MAX_FACE_DIVISIONS {
        let bins = DirectionBins::cube(n).unwrap();
        assert_eq!(bins.len(), 6 * n * n);
        let total: f64 = bins.solid_angles().iter().sum();
        assert!((total - 4.0 * PI).abs() < 1e-12, "n = {n}: {total}");
        assert!(bins.solid_angles().iter().all(|&w| w > 0.0));
    }
    assert_eq!(DirectionBins::max96().len(), 96);
    // One face of a cube subtends 4π/6.
    assert!((rectangle_solid_angle(-1.0, 1.0, -1.0, 1.0, 1.0) - 4.0 * PI / 6.0).abs() < 1e-14);
}

/// `DirectionBins::diffusion_loss` against an independent integration: a fine (θ, φ) grid
/// over the sphere, each direction given to its bin by `bin_of`, summing each bin's solid
/// angle and `∫ ω_i dω`; what a field constant per bin keeps of `∫ ω_i ω_i dω = 4π/3` must be
/// `1 − ε` along each axis (the cube's bins lose the same along x, y and z), and `ε` falls
/// as the bins shrink.
#[test]
fn the_bins_diffusion_loss_is_what_bin_constant_radiance_keeps() {
    let (nt, np) = (1200, 2400);
    let mut previous = 1.0;
    for n in [1, 4, 6, 8] {
        let bins = DirectionBins::cube(n).unwrap();
        let mut omega = vec![0.0; bins.len()];
        let mut first = vec![DVec3::ZERO; bins.len()];
        for i in 0..nt {
            let theta = PI * (i as f64 + 0.5) / nt as f64;
            let d_omega = theta.sin() * (PI / nt as f64) * (2.0 * PI / np as f64);
            for j in 0..np {
                let phi = 2.0 * PI * (j as f64 + 0.5) / np as f64;
                let w = DVec3::new(
                    theta.sin() * phi.cos(),
                    theta.sin() * phi.sin(),
                    theta.cos(),
                );
                let l = bins.bin_of(w);
                omega[l] += d_omega;
                first[l] += w * d_omega;
            }
        }
        let kept = |axis: usize| -> f64 {
            (0..bins.len())
                .map(|l| first[l][axis] * first[l][axis] / omega[l])
                .sum::<f64>()
                / (4.0 * PI / 3.0)
        };
        let loss = bins.diffusion_loss();
        eprintln!("{} bins: diffusion loss {:.2} %", bins.len(), 100.0 * loss);
        for axis in 0..3 {
            assert!(
                (1.0 - kept(axis) - loss).abs() < 2e-4,
                "n = {n}, axis {axis}: {} vs {loss}",
                1.0 - kept(axis)
            );
        }
        assert!(loss > 0.0 && loss < previous, "n = {n}: {loss}");
        previous = loss;
    }
}

#[test]
fn refuses_bad_face_divisions() {
    assert_eq!(
        DirectionBins::cube(0).unwrap_err(),
        OrdinatesError::FaceDivisions(0)
    );
    assert_eq!(
        DirectionBins::cube(13).unwrap_err(),
        OrdinatesError::FaceDivisions(13)
    );
    // By count: every valid count is 6 n², anything else is refused naming it.
    for count in formfactor::ordinates::VALID_BINS {
        assert_eq!(DirectionBins::with_count(count).unwrap().len(), count);
    }
    for count in [0, 7, 100, 1014] {
        assert_eq!(
            DirectionBins::with_count(count).unwrap_err(),
            OrdinatesError::BinCount(count)
        );
    }
}

#[test]
fn bin_of_is_consistent_with_bin_boundaries() {
    let mut r = rng(5);
    for n in [1, 3, 4, 7] {
        let bins = DirectionBins::cube(n).unwrap();
        // Every bin's centre lies in that bin.
        for (l, c) in bins.centres().iter().enumerate() {
            assert_eq!(bins.bin_of(*c), l, "n {n}: centre of bin {l}");
            assert!((c.length() - 1.0).abs() < 1e-12);
        }
        // A random direction's bin is the rectangle its ray pierces on the cube face.
        for _ in 0..2000 {
            let d = random_direction(&mut r);
            let l = bins.bin_of(d * 3.7);
            let rect = bins.rect(l);
            let axis = rect.face / 2;
            let sign = if rect.face.is_multiple_of(2) {
                1.0
            } else {
                -1.0
            };
            let a = d.to_array();
            assert!(a[axis] * sign > 0.0);
            let p = d / (a[axis] * sign);
            let pa = p.to_array();
            let (u, v) = (pa[(axis + 1) % 3], pa[(axis + 2) % 3]);
            assert!(pa.iter().all(|x| x.abs() <= 1.0 + 1e-12));
            assert!(
                u >= rect.u[0] - 1e-12 && u <= rect.u[1] + 1e-12,
                "u {u} {rect:?}"
            );
            assert!(
                v >= rect.v[0] - 1e-12 && v <= rect.v[1] + 1e-12,
                "v {v} {rect:?}"
            );
        }
        // Bin frequency of uniform directions ∝ solid angle.
        let samples = 200_000;
        let mut hist = vec![0usize; bins.len()];
        for _ in 0..samples {
            hist[bins.bin_of(random_direction(&mut r))] += 1;
        }
        for (l, &h) in hist.iter().enumerate() {
            let p = bins.solid_angles()[l] / (4.0 * PI);
            let sigma = (p * (1.0 - p) / samples as f64).sqrt();
            assert!(
                (h as f64 / samples as f64 - p).abs() < 5.0 * sigma,
                "bin {l}"
            );
        }
    }
}

#[test]
fn phase_matrix_keeps_energy_and_mean_cosine() {
    let bins = DirectionBins::max96();
    for g in [0.0, 0.6, 0.85] {
        let phase = PhaseFunction::HenyeyGreenstein { g };
        let pm = PhaseMatrix::with_default_quadrature(&bins, &phase);
        let err = phase_matrix_error(&bins, &pm, &phase);
        println!("96 bins, g = {g}: {err:?}");
        assert!(err.energy < 1e-12, "g {g}: energy error {}", err.energy);
        assert!(pm.values().iter().all(|&v| v >= 0.0));
        // Discrete mean cosine within 5 % of g (bins ~20° wide smear the peak slightly).
        assert!(
            (err.mean_cosine - g).abs() < 0.05 * g + 1e-3,
            "g {g}: {}",
            err.mean_cosine
        );
        // Reciprocity of the continuous kernel: P_lj ≈ P_jl before renormalisation shifts.
        let m = bins.len();
        for l in 0..m {
            for j in 0..m {
                let (a, b) = (pm.get(l, j), pm.get(j, l));
                assert!(
                    (a - b).abs() <= 0.05 * a.max(b),
                    "g {g}: P[{l},{j}] {a} vs {b}"
                );
            }
        }
    }
    // Isotropic scattering is exactly 1/4π.
    let pm = PhaseMatrix::new(&bins, &PhaseFunction::Isotropic, 3);
    assert!(pm.values().iter().all(|v| (v - 0.25 / PI).abs() < 1e-14));
}

#[test]
fn first_bounce_bin_averages_keep_energy_and_peak_forward() {
    let bins = DirectionBins::max96();
    let d = DVec3::new(0.3, -0.2, -0.9).normalize();
    let p = bin_averaged_phase(&bins, &PhaseFunction::HenyeyGreenstein { g: 0.85 }, d, 12);
    let total: f64 = p.iter().zip(bins.solid_angles()).map(|(a, b)| a * b).sum();
    assert!((total - 1.0).abs() < 1e-12);
    let max_bin = (0..bins.len())
        .max_by(|&a, &b| p[a].total_cmp(&p[b]))
        .unwrap();
    assert_eq!(max_bin, bins.bin_of(d));
}

fn operator(
    grid: Grid,
    channel: &ChannelMedium,
    g: f64,
    n: usize,
    periodic: bool,
) -> OrdinatesOperator {
    OrdinatesOperator::new(
        &medium(grid, channel, PhaseFunction::HenyeyGreenstein { g }),
        0,
        DirectionBins::cube(n).unwrap(),
        OrdinatesOptions {
            periodic_xy: periodic,
            ..Default::default()
        },
    )
    .unwrap()
}

#[test]
fn one_sweep_conserves_energy() {
    let mut r = rng(9);
    for (dims, n, periodic) in [
        ([7, 5, 6], 4, false),
        ([6, 6, 4], 3, false),
        ([4, 3, 5], 4, true),
    ] {
        let grid = Grid::new(dims, 0.7).unwrap();
        let ch = blob_channel(&grid, 3.0, 0.9);
        let op = operator(grid, &ch, 0.7, n, periodic);
        let density: Vec<f64> = (0..op.len()).map(|_| r.random::<f64>()).collect();
        let mut out = vec![0.0; op.len()];
        let e = op.transport(&density, &mut out);
        let imbalance = (e.emitted - e.extinguished - e.escaped_total()).abs() / e.emitted;
        assert!(imbalance < 1e-10, "{dims:?}: {e:?}");
        // Extinguished power computed from the returned radiances agrees.
        let m = op.bins().len();
        let v = grid.cell_volume();
        let from_radiance: f64 = (op.state_cells().iter().enumerate())
            .map(|(k, &c)| {
                op.sigma_t()[c as usize]
                    * v
                    * (0..m)
                        .map(|l| out[k * m + l] * op.bins().solid_angles()[l])
                        .sum::<f64>()
            })
            .sum();
        assert!((from_radiance - e.extinguished).abs() < 1e-10 * e.extinguished);
        if periodic {
            assert!(e.escaped[..4].iter().all(|&x| x == 0.0));
        }
    }
}

/// Sweeping through sub-cells keeps the balance per sweep, and the returned cell averages
/// carry the extinguished power; the refinement option is checked.
#[test]
fn refined_sweep_conserves_energy_and_refuses_bad_options() {
    let mut r = rng(11);
    let grid = Grid::new([5, 4, 6], 0.7).unwrap();
    let blob = medium(
        grid,
        &blob_channel(&grid, 3.0, 0.9),
        PhaseFunction::HenyeyGreenstein { g: 0.5 },
    );
    let make = |refinement: usize, periodic_xy: bool| {
        OrdinatesOperator::new(
            &blob,
            0,
            DirectionBins::cube(3).unwrap(),
            OrdinatesOptions {
                transport_refinement: refinement,
                periodic_xy,
                ..Default::default()
            },
        )
    };
    let op = make(3, false).unwrap();
    let density: Vec<f64> = (0..op.len()).map(|_| r.random::<f64>()).collect();
    let mut out = vec![0.0; op.len()];
    let e = op.transport(&density, &mut out);
    assert!((e.emitted - e.extinguished - e.escaped_total()).abs() < 1e-10 * e.emitted);
    let m = op.bins().len();
    let v = grid.cell_volume();
    let from_radiance: f64 = (op.state_cells().iter().enumerate())
        .map(|(k, &c)| {
            op.sigma_t()[c as usize]
                * v
                * (0..m)
                    .map(|l| out[k * m + l] * op.bins().solid_angles()[l])
                    .sum::<f64>()
        })
        .sum();
    assert!((from_radiance - e.extinguished).abs() < 1e-10 * e.extinguished);
    for (refinement, periodic) in [(0, false), (5, false), (2, true)] {
        assert!(
            matches!(make(refinement, periodic), Err(OrdinatesError::Option(_))),
            "refinement {refinement}, periodic {periodic}"
        );
    }
    assert!(AssembledOrdinates::from_operator(&make(2, false).unwrap()).is_err());
}

/// The exact chord-averaged inflow transmission `⟨e^{−τ ℓ}⟩` is at least the mean chord's
/// `e^{−τ⟨ℓ⟩}` (Jensen), equal for thin cells, and a sweep with it still balances.
#[test]
fn exact_transmission_exceeds_the_mean_chord_and_conserves() {
    let grid = Grid::new([5, 4, 6], 0.7).unwrap();
    let blob = medium(
        grid,
        &blob_channel(&grid, 3.0, 0.9),
        PhaseFunction::Isotropic,
    );
    let op = OrdinatesOperator::new(
        &blob,
        0,
        DirectionBins::cube(4).unwrap(),
        OrdinatesOptions {
            exact_transmission: true,
            ..Default::default()
        },
    )
    .unwrap();
    for piece in op.pieces() {
        for tau0 in [1e-3, 0.3, 1.0, 3.0, 30.0] {
            let (t, ..) = piece.cell_terms(tau0);
            let mean_chord = (-tau0 / piece.projected).exp();
            assert!(
                t >= mean_chord * (1.0 - 1e-3),
                "τ0 {tau0}: {t} < {mean_chord}"
            );
            assert!(t <= 1.0 && (tau0 > 0.01 || (t - mean_chord).abs() < 1e-4));
        }
    }
    let density = vec![1.0; op.len()];
    let mut out = vec![0.0; op.len()];
    let e = op.transport(&density, &mut out);
    assert!((e.emitted - e.extinguished - e.escaped_total()).abs() < 1e-10 * e.emitted);
}

#[test]
fn empty_grid_transmits_everything_and_extinguishes_nothing() {
    let grid = Grid::new([4, 4, 4], 1.0).unwrap();
    let ch = ChannelMedium {
        sigma_t: vec![0.0; 64],
        albedo: CellValues::Uniform(0.5),
        emission: CellValues::Uniform(0.0),
    };
    let op = operator(grid, &ch, 0.0, 2, false);
    // Nothing carries state; an emission density in every cell crosses them all.
    assert_eq!(op.len(), 0);
    let mut out = vec![0.0; op.len()];
    let e = op.transport_emission(&[1.0; 64], &mut out).unwrap();
    assert_eq!(e.extinguished, 0.0);
    // Emitted: e · V · 4π per cell.
    assert!((e.emitted - 64.0 * 4.0 * PI).abs() < 1e-9);
    assert!((e.escaped_total() - e.emitted).abs() < 1e-9 * e.emitted);
}

/// The assembled matrix is the sweep's, cell step for cell step: with every cell scattering
/// (all columns present), and with a wall of empty cells between scattering ones, which the
/// linear faces' sweep crosses by its step for cells without medium.
#[test]
fn assembled_matrix_agrees_with_sweeps() {
    let mut r = rng(21);
    for (dims, n, g, empty_wall) in [
        ([3, 4, 3], 2, 0.6, false),
        ([3, 2, 2], 4, 0.85, false),
        ([2, 3, 3], 3, 0.3, false),
        ([4, 3, 3], 2, 0.6, true),
    ] {
        let grid = Grid::new(dims, 1.3).unwrap();
        let ch = blob_channel(&grid, 4.0, 0.95);
        let ch = ChannelMedium {
            sigma_t: (0..grid.cell_count())
                .map(|c| {
                    if empty_wall && grid.coords(c)[0] == 1 {
                        0.0
                    } else {
                        ch.sigma_t[c] + 0.3
                    }
                })
                .collect(),
            ..ch
        };
        let op = operator(grid, &ch, g, n, false);
        let asm = AssembledOrdinates::from_operator(&op).unwrap();
        assert_eq!(asm.len(), op.len());
        let x: Vec<f64> = (0..op.len()).map(|_| r.random::<f64>()).collect();
        let mut y1 = vec![0.0; op.len()];
        let mut y2 = vec![0.0; op.len()];
        op.apply(&x, &mut y1);
        asm.apply(&x, &mut y2);
        let scale = y1.iter().fold(0.0f64, |a, b| a.max(b.abs()));
        for (a, b) in y1.iter().zip(&y2) {
            assert!((a - b).abs() < 1e-12 * scale, "{dims:?} n {n}: {a} vs {b}");
        }
    }
}

#[test]
fn assembled_refuses_periodic_and_large() {
    let grid = Grid::new([2, 2, 2], 1.0).unwrap();
    let ch = blob_channel(&grid, 1.0, 0.5);
    assert!(AssembledOrdinates::from_operator(&operator(grid, &ch, 0.0, 2, true)).is_err());
    let grid = Grid::new([8, 8, 8], 1.0).unwrap();
    let ch = blob_channel(&grid, 1.0, 0.5);
    assert!(AssembledOrdinates::from_operator(&operator(grid, &ch, 0.0, 4, false)).is_err());
}

/// Source iteration `x ← E + K x` to a relative change of `tol`; returns (x, iterations).
fn jacobi(op: &OrdinatesOperator, e: &[f64], tol: f64) -> (Vec<f64>, usize) {
    let mut x = e.to_vec();
    let mut y = vec![0.0; x.len()];
    let norm: f64 = e.iter().map(|v| v * v).sum::<f64>().sqrt();
    for it in 1..=5000 {
        op.apply(&x, &mut y);
        let mut change = 0.0;
        for i in 0..x.len() {
            let new = e[i] + y[i];
            change += (new - x[i]) * (new - x[i]);
            x[i] = new;
        }
        if change.sqrt() < tol * norm {
            return (x, it);
        }
    }
    panic!("no convergence");
}

#[test]
fn full_solve_balances_first_bounce_and_emission() {
    let grid = Grid::new([8, 7, 6], 1.0).unwrap();
    let mut ch = blob_channel(&grid, 2.5, 0.95);
    ch.emission = CellValues::PerCell(
        (0..grid.cell_count())
            .map(|i| (i % 5) as f32 * 0.01)
            .collect(),
    );
    let op = operator(grid, &ch, 0.85, 4, false);
    // A directional light from above-left with a made-up smooth irradiance field.
    let irradiance: Vec<f64> = (0..grid.cell_count())
        .map(|c| (-0.3 * grid.coords(c)[0] as f64).exp())
        .collect();
    let emission: Vec<f64> = (0..grid.cell_count())
        .map(|i| ch.emission.get(i) as f64)
        .collect();
    let dir = DVec3::new(0.5, 0.2, -0.8).normalize();
    let external = op.external_density(&[(dir, &irradiance)]).unwrap();
    let mut e = vec![0.0; op.len()];
    op.transport_external(&external, None, &mut e, None);
    let (x, iters) = jacobi(&op, &e, 1e-9);
    let b = op.energy_balance(&x, &external, None);
    // Source power = emission V 4π + σs V irradiance.
    let expect: f64 = (0..grid.cell_count())
        .map(|c| emission[c] * 4.0 * PI + op.sigma_s()[c] * irradiance[c])
        .sum::<f64>()
        * grid.cell_volume();
    assert!((b.source - expect).abs() < 1e-10 * expect);
    assert!(
        b.relative_imbalance() < 1e-4,
        "{b:?} after {iters} iterations"
    );
    assert!(b.absorbed > 0.0 && b.escaped.iter().all(|&v| v > 0.0));
}

#[test]
fn gauss_seidel_reaches_the_jacobi_solution_in_fewer_sweeps() {
    let grid = Grid::new([6, 6, 5], 1.0).unwrap();
    let ch = blob_channel(&grid, 3.0, 0.98);
    let op = operator(grid, &ch, 0.6, 4, false);
    let irradiance = vec![1.0; grid.cell_count()];
    let external = op.external_density(&[(DVec3::NEG_Z, &irradiance)]).unwrap();
    let mut e = vec![0.0; op.len()];
    op.transport(&external, &mut e);
    let (xj, jac_iters) = jacobi(&op, &e, 1e-10);
    let run = op.sweep_until_change(&e, 1e-10, 5000);
    let (g, gs_iters) = (run.solution, run.iterations);
    assert!(
        run.final_change < 1e-10,
        "no convergence: {}",
        run.final_change
    );
    assert!(
        gs_iters > 0 && gs_iters <= jac_iters,
        "GS {gs_iters}, Jacobi {jac_iters}"
    );
    let scale = xj.iter().fold(0.0f64, |a, b| a.max(b.abs()));
    for (a, b) in xj.iter().zip(&g) {
        assert!((a - b).abs() < 1e-7 * scale);
    }
}

/// Deep inside a thick periodic slab with uniform emission, radiance is isotropic and equals
/// `e / (σt (1 − a))` whatever the phase function.
#[test]
fn infinite_medium_limit() {
    let nz = 48;
    let grid = Grid::new([1, 1, nz], 1.0).unwrap();
    let (sigma, albedo, emission) = (1.0f32, 0.5f32, 0.2f64);
    let ch = ChannelMedium {
        sigma_t: vec![sigma; nz],
        albedo: CellValues::Uniform(albedo),
        emission: CellValues::Uniform(emission as f32),
    };
    for g in [0.0, 0.85] {
        let op = operator(grid, &ch, g, 2, true);
        let mut e = vec![0.0; op.len()];
        op.transport_emission(&vec![emission; nz], &mut e).unwrap();
        let (x, _) = jacobi(&op, &e, 1e-11);
        let expect = emission / (sigma as f64 * (1.0 - albedo as f64));
        let m = op.bins().len();
        let centre = &x[(nz / 2) * m..(nz / 2 + 1) * m];
        for (l, &v) in centre.iter().enumerate() {
            assert!(
                (v / expect - 1.0).abs() < 1e-3,
                "g {g}, bin {l}: {v} vs {expect}"
            );
        }
        let fluence = op.fluence(&x)[nz / 2];
        assert!((fluence / (4.0 * PI * expect) - 1.0).abs() < 1e-3);
    }
}

/// The system's source is the lights' first bounce transported plus the channel's emission
/// transported, the empty cells' emission too; its fluence tally holds every cell, and at the
/// cells with medium it is the rows' own.
#[test]
fn the_source_is_the_first_bounce_and_the_channels_emission_transported() {
    let grid = Grid::new([4, 3, 5], 1.0).unwrap();
    let mut ch = blob_channel(&grid, 2.0, 0.9);
    ch.emission = CellValues::PerCell(
        (0..grid.cell_count())
            .map(|i| (i % 3) as f32 * 0.1)
            .collect(),
    );
    let op = operator(grid, &ch, 0.5, 2, false);
    let empty = ch.sigma_t.iter().filter(|&&s| s == 0.0).count();
    assert!(empty > 0 && op.state_cells().len() == grid.cell_count() - empty);
    let lights = [
        Light::Directional {
            direction: DVec3::new(0.3, 0.2, -0.9).normalize(),
            irradiance: 1.0,
        },
        Light::Point {
            position: DVec3::new(-1.0, 1.5, 2.5),
            intensity: 3.0,
        },
    ];
    let pass =
        LightPass::compute(&medium(grid, &ch, PhaseFunction::Isotropic), 0, &lights).unwrap();
    let first = op.first_bounce_density_from_pass(&pass).unwrap();
    assert!(first.iter().any(|&v| v > 0.0));
    let mut all = vec![0.0; op.len()];
    let mut fluence = vec![0.0; grid.cell_count()];
    op.transport_external(&first, None, &mut all, Some(&mut fluence));
    let mut scattered = vec![0.0; op.len()];
    op.transport(&first, &mut scattered);
    let emission: Vec<f64> = (0..grid.cell_count())
        .map(|c| ch.emission.get(c) as f64)
        .collect();
    let mut emitted = vec![0.0; op.len()];
    op.transport_emission(&emission, &mut emitted).unwrap();
    for (i, (a, (s, e))) in all.iter().zip(scattered.iter().zip(&emitted)).enumerate() {
        assert!((a - s - e).abs() <= 1e-12 * a.abs().max(1.0), "entry {i}");
    }
    let rows = op.fluence(&all);
    for c in 0..grid.cell_count() {
        match op.state_row(c) {
            Some(_) => assert!((fluence[c] - rows[c]).abs() <= 1e-12 * rows[c].max(1.0)),
            // Light crosses the empty cells: emitted there and from the cloud.
            None => assert!(rows[c] == 0.0 && fluence[c] > 0.0, "cell {c}"),
        }
    }
}

/// The state is the cells with medium; the light in the empty cells is the same as in a
/// medium whose empty cells hold a trace of it (and so carry state). Uniform face fluxes:
/// with linear ones the sweep crosses a cell without medium by a step of its own (the
/// faces' profiles are not carried across), which a trace of medium would not take.
#[test]
fn empty_cells_carry_no_state_but_their_fluence_is_the_trace_mediums() {
    let grid = Grid::new([6, 5, 5], 1.0).unwrap();
    let ch = blob_channel(&grid, 2.0, 0.9);
    let mut traced = ch.clone();
    for s in &mut traced.sigma_t {
        if *s == 0.0 {
            *s = 1e-5;
        }
    }
    let irradiance: Vec<f64> = (0..grid.cell_count())
        .map(|c| (-0.2 * grid.coords(c)[2] as f64).exp())
        .collect();
    let dir = DVec3::new(0.2, -0.3, -0.9).normalize();
    let solve = |ch: &ChannelMedium| {
        let op = OrdinatesOperator::new(
            &medium(grid, ch, PhaseFunction::HenyeyGreenstein { g: 0.6 }),
            0,
            DirectionBins::cube(2).unwrap(),
            OrdinatesOptions {
                linear_faces: false,
                ..Default::default()
            },
        )
        .unwrap();
        let external = op.external_density(&[(dir, &irradiance)]).unwrap();
        let mut e = vec![0.0; op.len()];
        let mut fixed = vec![0.0; grid.cell_count()];
        op.transport_external(&external, None, &mut e, Some(&mut fixed));
        let (x, _) = jacobi(&op, &e, 1e-11);
        (op.fluence_everywhere(&x, &fixed), op.len())
    };
    let (sparse, sparse_len) = solve(&ch);
    let (dense, dense_len) = solve(&traced);
    let m = 24;
    let empty = ch.sigma_t.iter().filter(|&&s| s == 0.0).count();
    assert!(empty > 0);
    assert_eq!(dense_len, grid.cell_count() * m);
    assert_eq!(sparse_len, (grid.cell_count() - empty) * m);
    for (c, (a, b)) in sparse.iter().zip(&dense).enumerate() {
        assert!(
            *b > 0.0 && (a / b - 1.0).abs() < 1e-3,
            "cell {c}: {a} vs {b}"
        );
    }
}

#[test]
fn refuses_mismatched_inputs() {
    let grid = Grid::new([2, 2, 2], 1.0).unwrap();
    let ch = blob_channel(&grid, 1.0, 0.5);
    let op = operator(grid, &ch, 0.0, 1, false);
    assert!(matches!(
        op.transport_emission(&[1.0; 3], &mut vec![0.0; op.len()]),
        Err(OrdinatesError::Length {
            what: "emission",
            ..
        })
    ));
    assert!(op.external_density(&[(DVec3::Z, &[1.0; 7])]).is_err());
    // A channel the medium does not have.
    assert!(matches!(
        OrdinatesOperator::new(
            &medium(grid, &ch, PhaseFunction::Isotropic),
            1,
            DirectionBins::cube(1).unwrap(),
            OrdinatesOptions::default()
        ),
        Err(OrdinatesError::Channel {
            channel: 1,
            channels: 1
        })
    ));
    // A light pass of another grid, and one whose fields were cut short.
    let light = [Light::Directional {
        direction: DVec3::NEG_Z,
        irradiance: 1.0,
    }];
    let other = Grid::new([2, 2, 3], 1.0).unwrap();
    let foreign = LightPass::compute(
        &medium(
            other,
            &blob_channel(&other, 1.0, 0.5),
            PhaseFunction::Isotropic,
        ),
        0,
        &light,
    )
    .unwrap();
    assert_eq!(
        op.first_bounce_density_from_pass(&foreign),
        Err(OrdinatesError::ForeignLightPass)
    );
    let mut short =
        LightPass::compute(&medium(grid, &ch, PhaseFunction::Isotropic), 0, &light).unwrap();
    assert!(op.first_bounce_density_from_pass(&short).is_ok());
    short.fields[0].cell_irradiance.pop();
    assert!(matches!(
        op.first_bounce_density_from_pass(&short),
        Err(OrdinatesError::Length { .. })
    ));
}

#[test]
fn asymmetry_tilt_keeps_energy_and_matches_g() {
    let bins = DirectionBins::max96();
    for g in [0.6, 0.85, -0.3] {
        let phase = PhaseFunction::HenyeyGreenstein { g };
        let mut pm = PhaseMatrix::new(&bins, &phase, 4);
        pm.match_asymmetry(&bins, g);
        for j in 0..bins.len() {
            assert!((pm.column_energy(&bins, j) - 1.0).abs() < 1e-12);
            assert!(
                (pm.mean_cosine(&bins, j) - g).abs() < 1e-9,
                "g {g} column {j}"
            );
        }
        assert!(pm.values().iter().all(|&v| v > 0.0));
    }
}

/// Making up the quadrature's lost mean cosine by scattering less into the neighbouring bins
/// keeps energy, reaches g, and leaves side and back scattering as the quadrature gave them,
/// where the tilt thins back scattering (by about 9 % at 384 bins, HG(0.85): the light the
/// sun-side views of a cloud see, which came out about 2 % dark).
#[test]
fn forward_asymmetry_match_keeps_back_scattering() {
    let bins = DirectionBins::cube(8).unwrap();
    let g = 0.85;
    let phase = PhaseFunction::HenyeyGreenstein { g };
    let raw = PhaseMatrix::new(&bins, &phase, 3);
    let mut forward = raw.clone();
    forward.match_asymmetry_forward(&bins, g);
    let mut tilted = raw.clone();
    tilted.match_asymmetry(&bins, g);
    let m = bins.len();
    let c = bins.centres();
    let omega = bins.solid_angles();
    // Back scattering (more than 120° from the incoming bin), summed over all columns.
    let back = |pm: &PhaseMatrix| -> f64 {
        let mut sum = 0.0;
        for j in 0..m {
            for l in 0..m {
                if c[l].dot(c[j]) < -0.5 {
                    sum += pm.get(l, j) * omega[l] * omega[j];
                }
            }
        }
        sum
    };
    for j in 0..m {
        assert!((forward.column_energy(&bins, j) - 1.0).abs() < 1e-12);
        assert!(
            (forward.mean_cosine(&bins, j) - g).abs() < 1e-9,
            "column {j}"
        );
        for l in 0..m {
            if c[l].dot(c[j]) < 0.9 {
                assert_eq!(forward.get(l, j), raw.get(l, j), "{l} ← {j}");
            }
        }
    }
    assert!(
        raw.mean_cosine(&bins, 0) < g - 1e-3,
        "the quadrature loses asymmetry"
    );
    assert!(forward.values().iter().all(|&v| v >= 0.0));
    assert_eq!(back(&forward), back(&raw));
    assert!(back(&tilted) < 0.95 * back(&raw));
}

/// The renderer's interpolation between bin centres: weights sum to 1, a bin's centre (its
/// square's midpoint) gets that bin alone, and a function linear in face coordinates is
/// reproduced exactly everywhere on the face — also between the outer centres and the face
/// edges, where it extrapolates rather than holding the edge value (holding it put the DISORT
/// slab's radiance next to a cube edge 9 % off).
#[test]
fn face_bilinear_is_exact_at_centres_and_for_linear_fields() {
    use formfactor::ordinates::bins::{face_bilinear, FaceRect};
    let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
    for n in 1..=formfactor::ordinates::MAX_FACE_DIVISIONS {
        let bins = DirectionBins::cube(n).unwrap();
        for l in 0..bins.len() {
            let r = bins.rect(l);
            let mid = r.point(0.5 * (r.u[0] + r.u[1]), 0.5 * (r.v[0] + r.v[1]));
            let w = face_bilinear(n, mid);
            let at_l: f64 = w.iter().filter(|p| p.0 == l).map(|p| p.1).sum();
            assert!((at_l - 1.0).abs() < 1e-12, "n {n} bin {l}: {w:?}");
        }
        if n == 1 {
            continue;
        }
        for _ in 0..200 {
            let face = rng.random_range(0..6);
            let (u, v) = (rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
            let dir = FaceRect {
                face,
                u: [u, u],
                v: [v, v],
            }
            .point(u, v)
                * rng.random_range(0.5..2.0);
            // f = 1 + 2u − 3v at each bin's midpoint.
            let f = |b: usize| {
                let r = bins.rect(b);
                1.0 + (r.u[0] + r.u[1]) - 1.5 * (r.v[0] + r.v[1])
            };
            let w = face_bilinear(n, dir);
            let total: f64 = w.iter().map(|p| p.1).sum();
            let value: f64 = w.iter().map(|&(b, x)| x * f(b)).sum();
            assert!((total - 1.0).abs() < 1e-12);
            assert!(
                (value - (1.0 + 2.0 * u - 3.0 * v)).abs() < 1e-9,
                "n {n} face {face} ({u}, {v}): {value}"
            );
            assert!(w.iter().all(|&(b, _)| b / (n * n) == face));
        }
    }
}

/// The cone-clipped peak's mass matches a direct quadrature of HG above its cone value, and
/// grows with the cone and with g.
#[test]
fn forward_peak_fraction_is_the_clipped_mass() {
    use formfactor::ordinates::sweep::forward_peak_fraction;
    for (g, degrees) in [(0.6, 12.0), (0.85, 12.0), (0.85, 25.0), (0.95, 8.0)] {
        let mu_c = f64::to_radians(degrees).cos();
        let p = PhaseFunction::HenyeyGreenstein { g };
        let n = 200_000;
        let h = (1.0 - mu_c) / n as f64;
        let numeric: f64 = (0..n)
            .map(|i| {
                let mu = mu_c + (i as f64 + 0.5) * h;
                2.0 * PI * (p.eval(mu) - p.eval(mu_c)) * h
            })
            .sum();
        let f = forward_peak_fraction(g, mu_c);
        assert!(
            (f - numeric).abs() < 1e-6,
            "g {g}, {degrees}°: {f} vs {numeric}"
        );
    }
    let f = |g: f64, d: f64| forward_peak_fraction(g, f64::to_radians(d).cos());
    assert!(f(0.85, 25.0) > f(0.85, 12.0) && f(0.95, 12.0) > f(0.85, 12.0));
    assert!(f(0.85, 12.0) > 0.1 && f(0.85, 12.0) < 0.5);
}

/// With the forward peak truncated (σt* = σt − f σs, σs* = (1 − f) σs) the absorption
/// `(σt − σs) I` is unchanged, so a full solve still balances the source exactly; the
/// solution is the same radiance to within the truncation's approximation, and the option
/// refuses phase functions it cannot truncate.
#[test]
fn truncated_forward_peak_keeps_energy_and_the_solution() {
    let grid = Grid::new([8, 7, 6], 1.0).unwrap();
    let ch = blob_channel(&grid, 2.5, 0.95);
    let blob = medium(grid, &ch, PhaseFunction::HenyeyGreenstein { g: 0.85 });
    let make = |degrees: f64, blob: &Medium| {
        OrdinatesOperator::new(
            blob,
            0,
            DirectionBins::cube(4).unwrap(),
            OrdinatesOptions {
                forward_truncation_degrees: degrees,
                ..Default::default()
            },
        )
    };
    let irradiance: Vec<f64> = (0..grid.cell_count())
        .map(|c| (-0.3 * grid.coords(c)[0] as f64).exp())
        .collect();
    let dir = DVec3::new(0.5, 0.2, -0.8).normalize();
    let mut fluence = Vec::new();
    for degrees in [0.0, 12.0] {
        let op = make(degrees, &blob).unwrap();
        let external = op.external_density(&[(dir, &irradiance)]).unwrap();
        let mut e = vec![0.0; op.len()];
        op.transport(&external, &mut e);
        let (x, iters) = jacobi(&op, &e, 1e-9);
        let b = op.energy_balance(&x, &external, None);
        assert!(
            b.relative_imbalance() < 1e-4,
            "{degrees}°: {b:?} after {iters} iterations"
        );
        fluence.push(op.fluence(&x));
    }
    // Fluence is an angular integral: the forward peak's shape hardly matters to it.
    let (a, b) = (&fluence[0], &fluence[1]);
    let diff = a
        .iter()
        .zip(b)
        .map(|(x, y)| (x - y) * (x - y))
        .sum::<f64>()
        .sqrt();
    let norm = a.iter().map(|x| x * x).sum::<f64>().sqrt();
    assert!(diff < 0.05 * norm, "fluence moved by {}", diff / norm);
    assert!(diff > 0.0, "the truncation changed nothing");

    let iso = medium(grid, &ch, PhaseFunction::Isotropic);
    assert!(matches!(make(12.0, &iso), Err(OrdinatesError::Option(_))));
    assert!(matches!(make(95.0, &blob), Err(OrdinatesError::Option(_))));
}

/// What `volrad info`'s time model counts for the scattering product: every cell with
/// medium of a 512-cell block that holds a scattering cell, none of a block without one, and
/// the last, shorter block's own.
#[test]
fn the_scattering_product_counts_the_blocks_that_scatter() {
    use formfactor::ordinates::scattering_product_cells;
    let n = 3 * 512 + 100;
    let medium: Vec<bool> = (0..n).map(|c| c % 2 == 0).collect();
    let mut scatters = vec![false; n];
    assert_eq!(scattering_product_cells(&medium, &scatters), 0);
    scatters[510] = true; // block 0
    assert_eq!(scattering_product_cells(&medium, &scatters), 256);
    scatters[3 * 512 + 98] = true; // the short last block
    assert_eq!(scattering_product_cells(&medium, &scatters), 306);
    scatters.iter_mut().for_each(|s| *s = true);
    assert_eq!(scattering_product_cells(&vec![true; n], &scatters), n);
}

/// Max's fixed face shares spread a beam sideways at every cell (numerical diffusion); the
/// face-coupled sweep passes the flux that entered by one face on by the piece's own chords.
/// A unit source in a corner cell, swept along one bin's diagonal through a 16³ void: the
/// beam's spread across its direction (the weighted variance of the cells it reaches,
/// perpendicular to the bin's centre) is measured for both: 4.6 against 10.1 cells².
#[test]
fn face_coupling_keeps_a_beam_narrower_than_max_shares() {
    let grid = Grid::new([16, 16, 16], 1.0).unwrap();
    let n = grid.cell_count();
    // A trace of medium, so that every cell carries the beam's radiance.
    let void = ChannelMedium {
        sigma_t: vec![1e-6; n],
        albedo: CellValues::Uniform(0.0),
        emission: CellValues::Uniform(0.0),
    };
    let medium = medium(grid, &void, PhaseFunction::Isotropic);
    let bins = DirectionBins::cube(4).unwrap();
    let m = bins.len();
    // The most diagonal bin going up all three axes.
    let (l, d) = bins
        .centres()
        .iter()
        .enumerate()
        .filter(|(_, c)| c.min_element() > 0.0)
        .max_by(|a, b| a.1.min_element().total_cmp(&b.1.min_element()))
        .map(|(l, c)| (l, c.normalize()))
        .unwrap();
    let spread = |face_coupling: bool| -> f64 {
        let options = OrdinatesOptions {
            face_coupling,
            ..Default::default()
        };
        let op = OrdinatesOperator::new(&medium, 0, bins.clone(), options).unwrap();
        let mut density = vec![0.0; n * m];
        density[l] = 1.0; // cell (0, 0, 0)
        let mut out = vec![0.0; n * m];
        let e = op.transport(&density, &mut out);
        assert!((e.emitted - e.extinguished - e.escaped_total()).abs() < 1e-9 * e.emitted);
        assert!(e.extinguished < 1e-4 * e.emitted);
        let w: Vec<f64> = (0..n).map(|c| out[c * m + l]).collect();
        let total: f64 = w.iter().sum();
        let mean = (0..n).fold(DVec3::ZERO, |a, c| a + grid.cell_center(c) * w[c]) / total;
        (0..n)
            .map(|c| {
                let r = grid.cell_center(c) - mean;
                w[c] * (r.length_squared() - r.dot(d).powi(2))
            })
            .sum::<f64>()
            / total
    };
    let (coupled, shares) = (spread(true), spread(false));
    println!("lateral variance of the beam: face-coupled {coupled:.3}, Max's shares {shares:.3}");
    assert!(coupled < 0.6 * shares, "coupled {coupled}, shares {shares}");
}

/// volrad's bin choice follows the forward peak (96 for isotropic-like, 216 for moderate,
/// 864 for strong forward scattering) and steps down where the sweeps' work (`cells × bins`,
/// more per cell-bin above 384 bins) would pass its cap, never below Max's 96.
#[test]
fn auto_bins_follow_the_forward_peak_within_the_state_cap() {
    use formfactor::ordinates::{
        auto_bin_count, auto_bins_work, AUTO_BINS_MAX_CELL_BINS, VALID_BINS,
    };
    let small = 24 * 24 * 18;
    assert_eq!(auto_bin_count(0.0, small), 96);
    assert_eq!(auto_bin_count(-0.5, small), 96);
    assert_eq!(auto_bin_count(0.6, small), 216);
    assert_eq!(auto_bin_count(0.85, small), 864);
    assert_eq!(auto_bin_count(0.95, small), 864);
    // The 64 × 64 × 48 grid (the large samples' transport grid) takes 384: 600 would pass
    // the cap.
    let cloud64 = 64 * 64 * 48;
    assert!(cloud64 * 384 <= AUTO_BINS_MAX_CELL_BINS && cloud64 * 600 > AUTO_BINS_MAX_CELL_BINS);
    assert_eq!(auto_bin_count(0.85, cloud64), 384);
    // Above 384 bins a cell-bin counts more (the scattering product's share grows): a
    // 48 × 48 × 36 grid fits 864 × its cells but not their work, and takes 600; 40 × 40 × 30
    // takes all 864.
    let cloud48 = 48 * 48 * 36;
    assert!(cloud48 * 864 <= AUTO_BINS_MAX_CELL_BINS);
    assert!(auto_bins_work(cloud48, 864) > AUTO_BINS_MAX_CELL_BINS as f64);
    assert_eq!(auto_bin_count(0.85, cloud48), 600);
    assert_eq!(auto_bin_count(0.85, 40 * 40 * 30), 864);
    // Up to 384 bins the work is cells × bins.
    assert_eq!(auto_bins_work(1000, 384), 384_000.0);
    assert_eq!(auto_bins_work(1000, 96), 96_000.0);
    // At 96 × 96 × 72, 216 bins would pass the cap, 96 fit.
    let cloud96 = 96 * 96 * 72;
    assert!(cloud96 * 216 > AUTO_BINS_MAX_CELL_BINS && cloud96 * 96 <= AUTO_BINS_MAX_CELL_BINS);
    assert_eq!(auto_bin_count(0.85, cloud96), 96);
    // Between: 384 would not fit, 216 does.
    let mid = AUTO_BINS_MAX_CELL_BINS / 300;
    assert_eq!(auto_bin_count(0.85, mid), 216);
    // A grid too large for any: Max's 96, which the memory check then judges.
    assert_eq!(auto_bin_count(0.85, usize::MAX / 2), 96);
    for g in [-0.9, 0.0, 0.3, 0.31, 0.7, 0.71, 0.99] {
        for cells in [1, small, mid, cloud64, cloud96, 1 << 30] {
            let b = auto_bin_count(g, cells);
            assert!(
                VALID_BINS.contains(&b) && b >= 96,
                "g {g}, {cells} cells: {b}"
            );
        }
    }
}

/// The beams' profiles a light pass gives (the optical depth's change across each cell from
/// its corner depths) are the analytic ones where the pass is exact (light along a grid
/// axis, a homogeneous medium: `κ = ±σt h` along the light's axis, 0 across it), and they
/// change the first scattering's transport: the lit layer's source is steeper than its
/// neighbours' one-sided difference says.
#[test]
fn beam_profiles_from_a_light_pass_are_the_beams_own() {
    let grid = Grid::new([3, 4, 5], 1.0).unwrap();
    let sigma = 1.5;
    let ch = ChannelMedium {
        sigma_t: vec![sigma as f32; grid.cell_count()],
        albedo: CellValues::Uniform(0.8),
        emission: CellValues::Uniform(0.0),
    };
    let op = operator(grid, &ch, 0.5, 2, false);
    for (direction, axis) in [(DVec3::NEG_Z, 2), (DVec3::X, 0)] {
        let light = [Light::Directional {
            direction,
            irradiance: 1.0,
        }];
        let pass =
            LightPass::compute(&medium(grid, &ch, PhaseFunction::Isotropic), 0, &light).unwrap();
        let external = op.first_bounce_density_from_pass(&pass).unwrap();
        let irradiance: Vec<f64> = pass.fields[0]
            .cell_irradiance
            .iter()
            .map(|&v| v as f64)
            .collect();
        // Upper face less lower face: the depth grows the way the light travels.
        let mut change = [0.0; 3];
        change[axis] = sigma * direction[axis];
        let analytic = op
            .beam_profiles(&[(direction, &irradiance, &vec![change; grid.cell_count()])])
            .unwrap();
        let from_pass = op.beam_profiles_from_pass(&pass).unwrap();
        assert_eq!(from_pass.lights(), 1);
        let mut by_pass = vec![0.0; op.len()];
        let mut by_analytic = vec![0.0; op.len()];
        let mut by_neighbours = vec![0.0; op.len()];
        op.transport_first_bounce(&external, &from_pass, &mut by_pass, None);
        op.transport_first_bounce(&external, &analytic, &mut by_analytic, None);
        op.transport(&external, &mut by_neighbours);
        let scale = by_analytic.iter().fold(0.0f64, |a, &b| a.max(b.abs()));
        let worst = |x: &[f64], y: &[f64]| {
            x.iter()
                .zip(y)
                .fold(0.0f64, |a, (p, q)| a.max((p - q).abs()))
                / scale
        };
        let (pass_gap, neighbours_gap) = (
            worst(&by_pass, &by_analytic),
            worst(&by_neighbours, &by_analytic),
        );
        assert!(pass_gap < 1e-5, "{direction}: {pass_gap}");
        assert!(neighbours_gap > 1e-2, "{direction}: {neighbours_gap}");
    }
}
