//! The light pass: energy conservation, closed forms in homogeneous slabs, exact shadows,
//! 1/r² falloff of point lights, spot cones, corner/inside-cell transmittance, and the zonal
//! source term.

use glam::DVec3;
use medium::light_pass::{LightEnergy, LightField, LightPass, LightPassOptions};
use medium::traversal::Ray;
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Light, Medium, PhaseFunction};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64Mcg;

/// The one-channel medium of σt `sigma_t` on `grid` (albedo 0.9, no emission).
fn medium(grid: &Grid, sigma_t: Vec<f32>) -> Medium {
    Medium::grey(*grid, sigma_t, 0.9, PhaseFunction::Isotropic).unwrap()
}

fn random_cloud(grid: &Grid, seed: u64) -> Vec<f32> {
    let mut rng = Pcg64Mcg::seed_from_u64(seed);
    (0..grid.cell_count())
        .map(|_| {
            let u: f64 = rng.random();
            if u < 0.25 {
                0.0
            } else {
                (rng.random::<f64>().powi(2) * 4.0) as f32
            }
        })
        .collect()
}

/// Exact optical depth from `x` toward the light, straight from the traversal.
fn exact_transmittance(grid: &Grid, sigma_t: &[f32], light: &Light, x: DVec3) -> f64 {
    let (ray, t_max) = match *light {
        Light::Directional { direction, .. } => (Ray::new(x, -direction), f64::INFINITY),
        Light::Point { position, .. } | Light::Spot { position, .. } => {
            (Ray::new(x, position - x), (position - x).length())
        }
    };
    (-grid.optical_depth(sigma_t, &ray, 0.0, t_max)).exp()
}

#[test]
fn energy_is_conserved_in_a_random_cloud() {
    let grid = Grid::new([12, 10, 9], 0.7).unwrap();
    let sigma = random_cloud(&grid, 7);
    let dir = DVec3::new(0.45, -0.8, 0.3).normalize();
    let e0 = 2.5;
    let lights = [
        Light::Directional {
            direction: dir,
            irradiance: e0,
        },
        Light::Point {
            position: DVec3::new(3.1, 2.2, 4.0), // inside the grid
            intensity: 1.7,
        },
        Light::Spot {
            position: DVec3::new(-2.0, 3.0, 9.0),
            axis: DVec3::new(1.0, 0.3, -0.6),
            half_angle: 0.5,
            intensity: 10.0,
        },
    ];
    let pass = LightPass::compute(&medium(&grid, sigma.clone()), 0, &lights).unwrap();
    let v = grid.cell_volume();
    for (l, field) in pass.fields.iter().enumerate() {
        let en = field.energy;
        assert!(
            en.entering > 0.0 && en.extinguished > 0.0 && en.leaving > 0.0,
            "{en:?}"
        );
        assert!(en.relative_imbalance() < 1e-6, "light {l}: {en:?}");
        // Extinguished recomputed from the stored (f32) cell averages.
        let from_cells: f64 = field
            .cell_irradiance
            .iter()
            .zip(&sigma)
            .map(|(&e, &s)| e as f64 * s as f64 * v)
            .sum();
        assert!(
            (from_cells + en.leaving - en.entering).abs() < 1e-6 * en.entering,
            "light {l}: cells extinguish {from_cells}, report {en:?}"
        );
    }
    // Directional: what enters is E0 times the grid's area projected along the light.
    let ext = grid.extent();
    let projected =
        dir.x.abs() * ext.y * ext.z + dir.y.abs() * ext.x * ext.z + dir.z.abs() * ext.x * ext.y;
    let entering = pass.fields[0].energy.entering;
    assert!(
        (entering - e0 * projected).abs() < 1e-9 * entering,
        "{entering} vs {}",
        e0 * projected
    );
    // A point light inside the grid: everything it emits enters.
    let entering = pass.fields[1].energy.entering;
    assert!((entering - 4.0 * std::f64::consts::PI * 1.7).abs() < 1e-9 * entering);
}

/// Homogeneous layer, light straight down (−z): cell averages are exactly
/// `E0 T_entry (1 − e^{−τ})/τ` with `τ = σt h`, corners exactly `e^{−σt depth}`.
#[test]
fn axis_aligned_slab_matches_closed_form() {
    let (n, nz, h, s) = (3, 8, 0.5, 1.3f32);
    let grid = Grid::new([n, n, nz], h).unwrap();
    let e0 = 3.0;
    let light = Light::Directional {
        direction: DVec3::new(0.0, 0.0, -1.0),
        irradiance: e0,
    };
    let pass = LightPass::compute(&medium(&grid, vec![s; grid.cell_count()]), 0, &[light]).unwrap();
    let f = &pass.fields[0];
    let tau = s as f64 * h;
    for idx in 0..grid.cell_count() {
        let [_, _, k] = grid.coords(idx);
        let layers_above = (nz - 1 - k) as f64;
        let expected = e0 * (-tau * layers_above).exp() * (1.0 - (-tau).exp()) / tau;
        let got = f.cell_irradiance[idx] as f64;
        assert!(
            (got - expected).abs() < 1e-6 * expected,
            "cell {idx}: {got} vs {expected}"
        );
    }
    for k in 0..=nz {
        let expected = (-(s as f64) * h * (nz - k) as f64).exp();
        let got = (-f.corner_optical_depth[grid.corner_index(1, 2, k)] as f64).exp();
        assert!(
            (got - expected).abs() < 1e-6,
            "corner plane {k}: {got} vs {expected}"
        );
    }
}

/// Wide homogeneous slab, oblique light at `μ0 = cos θ`: cells reached only through the top
/// face have the layer average `E0 e^{−σ z/μ0} (1 − e^{−τ})/τ`, `τ = σ h/μ0`.
#[test]
fn oblique_slab_matches_layer_average() {
    let (nx, ny, nz, h) = (20, 20, 5, 1.0);
    let grid = Grid::new([nx, ny, nz], h).unwrap();
    let s = 0.4f64;
    let dir = DVec3::new(0.5, 0.3, -1.0).normalize();
    let mu0 = -dir.z;
    let light = Light::Directional {
        direction: dir,
        irradiance: 1.0,
    };
    let options = LightPassOptions {
        rays_per_cell: 8,
        ..Default::default()
    };
    let pass = LightPass::compute_with(
        &medium(&grid, vec![s as f32; grid.cell_count()]),
        0,
        &[light],
        &options,
    )
    .unwrap();
    let f = &pass.fields[0];
    let tau = s * h / mu0;
    // Lateral shift of the light path across the whole slab, in cells (upwind margin).
    let margin_x = (nz as f64 * dir.x.abs() / mu0).ceil() as usize + 1;
    let margin_y = (nz as f64 * dir.y.abs() / mu0).ceil() as usize + 1;
    let mut worst = 0.0f64;
    for k in 0..nz {
        let depth = (nz - 1 - k) as f64 * h;
        let expected = (-s * depth / mu0).exp() * (1.0 - (-tau).exp()) / tau;
        for j in margin_y..ny {
            for i in margin_x..nx {
                let got = f.cell_irradiance[grid.index(i, j, k)] as f64;
                worst = worst.max((got / expected - 1.0).abs());
            }
        }
    }
    assert!(worst < 2e-3, "worst relative error {worst}");
    // The side faces upwind get more light than the layer average (they see the sky).
    let side = f.cell_irradiance[grid.index(0, ny / 2, 0)] as f64;
    let expected = (-s * (nz - 1) as f64 * h / mu0).exp() * (1.0 - (-tau).exp()) / tau;
    assert!(
        side > 1.2 * expected,
        "upwind edge {side} vs interior {expected}"
    );
}

/// Cell averages converge as the ray lattice is refined (oblique light, random cloud).
#[test]
fn oblique_cell_averages_converge_with_rays_per_cell() {
    let grid = Grid::new([8, 8, 6], 1.0).unwrap();
    let sigma = random_cloud(&grid, 3);
    let light = Light::Directional {
        direction: DVec3::new(0.37, -0.21, -0.9).normalize(),
        irradiance: 1.0,
    };
    let run = |m| {
        let o = LightPassOptions {
            rays_per_cell: m,
            ..Default::default()
        };
        LightPass::compute_with(&medium(&grid, sigma.clone()), 0, &[light], &o)
            .unwrap()
            .fields[0]
            .cell_irradiance
            .clone()
    };
    let reference = run(48);
    let err = |m| {
        run(m)
            .iter()
            .zip(&reference)
            .map(|(&a, &b)| (a - b).abs() as f64)
            .fold(0.0, f64::max)
    };
    let (e2, e8) = (err(2), err(8));
    assert!(e8 < e2 / 4.0, "refining 2 → 8 rays per cell: {e2} → {e8}");
    // Cells up to τ = 4 thick: the edge-straddling tubes still cost about 1 % at m = 8.
    assert!(e8 < 2e-2, "max error at m = 8: {e8}");
}

/// An opaque block between the light and a thin cloud layer: the cells wholly behind it go
/// dark, every cell not behind it keeps exactly its unshadowed value.
#[test]
fn opaque_block_shadows_exactly_the_cells_behind_it() {
    let grid = Grid::new([12, 4, 10], 1.0).unwrap();
    let thin = |g: &Grid| -> Vec<f32> {
        (0..g.cell_count())
            .map(|c| if g.coords(c)[2] < 2 { 0.05 } else { 0.0 })
            .collect()
    };
    let mut blocked = thin(&grid);
    let (bx, bz) = ((4usize, 7usize), (6usize, 8usize));
    for j in 0..4 {
        for k in bz.0..bz.1 {
            for i in bx.0..bx.1 {
                blocked[grid.index(i, j, k)] = 1e4;
            }
        }
    }
    for direction in [
        DVec3::new(0.0, 0.0, -1.0),
        DVec3::new(1.0, 0.0, -1.0).normalize(),
    ] {
        let light = [Light::Directional {
            direction,
            irradiance: 1.0,
        }];
        let open = LightPass::compute(&medium(&grid, thin(&grid)), 0, &light).unwrap();
        let shaded = LightPass::compute(&medium(&grid, blocked.clone()), 0, &light).unwrap();
        // Point x is in the block's shadow when its ray toward the light crosses the block.
        let (lo, hi) = (
            DVec3::new(bx.0 as f64, 0.0, bz.0 as f64),
            DVec3::new(bx.1 as f64, 4.0, bz.1 as f64),
        );
        let in_shadow = |x: DVec3| {
            let (mut t0, mut t1) = (0.0f64, f64::INFINITY);
            for a in [0, 2] {
                let d = -direction[a];
                if d == 0.0 {
                    if x[a] <= lo[a] || x[a] >= hi[a] {
                        return false;
                    }
                    continue;
                }
                let (ta, tb) = ((lo[a] - x[a]) / d, (hi[a] - x[a]) / d);
                t0 = t0.max(ta.min(tb));
                t1 = t1.min(ta.max(tb));
            }
            t0 < t1
        };
        let (mut dark, mut lit) = (0, 0);
        for c in 0..grid.cell_count() {
            let [_, _, k] = grid.coords(c);
            if k >= 2 {
                continue;
            }
            let min = grid.cell_min(c);
            let samples: Vec<bool> = (0..512)
                .map(|s| {
                    let f = DVec3::new((s % 8) as f64, ((s / 8) % 8) as f64, (s / 64) as f64);
                    in_shadow(min + (f + 0.5) / 8.0)
                })
                .collect();
            let (before, after) = (
                open.fields[0].cell_irradiance[c] as f64,
                shaded.fields[0].cell_irradiance[c] as f64,
            );
            if samples.iter().all(|&s| s) {
                dark += 1;
                assert!(
                    after < 1e-12 * before,
                    "{direction}: cell {c} behind the block: {after}"
                );
            } else if samples.iter().all(|&s| !s) {
                lit += 1;
                assert!(
                    (after - before).abs() <= 1e-7 * before,
                    "{direction}: cell {c}: {before} → {after}"
                );
            } else {
                assert!(
                    after < before && after > 0.0,
                    "{direction}: half-shadowed cell {c}"
                );
            }
        }
        assert!(
            dark >= 8 && lit >= 8,
            "{direction}: {dark} dark, {lit} lit cells"
        );
    }
}

/// Point light in vacuum: `irradiance_at` is exactly `I/r²`, cell averages match the cell
/// average of `I/r²` (fine quadrature), and `T ≡ 1`.
#[test]
fn point_light_in_vacuum_falls_as_inverse_square() {
    let grid = Grid::new([10, 10, 10], 1.0).unwrap();
    let pos = DVec3::new(5.0, 5.0, -3.0);
    let intensity = 50.0;
    let light = Light::Point {
        position: pos,
        intensity,
    };
    let pass =
        LightPass::compute(&medium(&grid, vec![0.0; grid.cell_count()]), 0, &[light]).unwrap();
    let f = &pass.fields[0];
    assert!(f.corner_optical_depth.iter().all(|&t| t == 0.0));
    let mut rng = Pcg64Mcg::seed_from_u64(5);
    for _ in 0..100 {
        let x = DVec3::new(rng.random(), rng.random(), rng.random()) * 10.0;
        let cell = grid.cell_at(x).unwrap();
        let (flow, e) = pass.irradiance_at(0, x, cell);
        let r = x - pos;
        assert!((e - intensity / r.length_squared()).abs() < 1e-12 * e);
        assert!((flow - r.normalize()).length() < 1e-12);
    }
    // Cell averages of I/r² by 6³ midpoint quadrature, for the column under the light.
    let mut ratios = Vec::new();
    for k in 0..10 {
        let c = grid.index(5, 5, k);
        let min = grid.cell_min(c);
        let mut sum = 0.0;
        for s in 0..216 {
            let fpos = DVec3::new((s % 6) as f64, ((s / 6) % 6) as f64, (s / 36) as f64);
            sum += intensity / (min + (fpos + 0.5) / 6.0 - pos).length_squared();
        }
        let expected = sum / 216.0;
        let got = f.cell_irradiance[c] as f64;
        assert!(
            (got / expected - 1.0).abs() < 0.02,
            "cell k={k}: {got} vs {expected}"
        );
        ratios.push(got);
    }
    // Near/far: distances from 3.5 to 12.5 below the light → ratio ≈ (12.5/3.5)² ≈ 12.8.
    let ratio = ratios[0] / ratios[9];
    assert!(
        (ratio / (12.5f64 / 3.5).powi(2) - 1.0).abs() < 0.05,
        "ratio {ratio}"
    );
}

/// A spot light: zero outside its cone, the point light's values wholly inside it.
#[test]
fn spot_light_respects_its_cone() {
    let grid = Grid::new([14, 14, 8], 1.0).unwrap();
    let sigma = vec![0.1f32; grid.cell_count()];
    let pos = DVec3::new(7.0, 7.0, 12.0);
    let axis = DVec3::new(0.0, 0.0, -1.0);
    let half_angle = 0.35f64;
    let lights = [
        Light::Spot {
            position: pos,
            axis,
            half_angle,
            intensity: 4.0,
        },
        Light::Point {
            position: pos,
            intensity: 4.0,
        },
    ];
    let pass = LightPass::compute(&medium(&grid, sigma), 0, &lights).unwrap();
    let (spot, point) = (&pass.fields[0], &pass.fields[1]);
    let (mut inside, mut outside) = (0, 0);
    for c in 0..grid.cell_count() {
        let centre = grid.cell_center(c);
        let to = centre - pos;
        let angle = to.normalize().dot(axis).clamp(-1.0, 1.0).acos();
        // Angular radius of the cell seen from the light.
        let radius = (0.5 * 3f64.sqrt() * grid.cell_size / to.length()).asin();
        if angle > half_angle + radius {
            outside += 1;
            assert_eq!(spot.cell_irradiance[c], 0.0, "cell {c} outside the cone");
            assert_eq!(pass.irradiance_at(0, centre, c).1, 0.0);
        } else if angle < half_angle - radius {
            inside += 1;
            assert_eq!(
                spot.cell_irradiance[c], point.cell_irradiance[c],
                "cell {c}"
            );
            assert!(spot.cell_irradiance[c] > 0.0);
        }
    }
    assert!(
        inside > 20 && outside > 200,
        "{inside} inside, {outside} outside"
    );
    assert!(spot.energy.relative_imbalance() < 1e-6);
}

/// Corner transmittance is the exact `exp(−τ)` toward the light; inside a homogeneous slab,
/// `transmittance_at` is exact where the ray to the light leaves through the top face.
#[test]
fn corner_and_interior_transmittance() {
    let grid = Grid::new([7, 6, 5], 0.8).unwrap();
    let sigma = random_cloud(&grid, 11);
    let lights = [
        Light::Directional {
            direction: DVec3::new(-0.3, 0.5, -0.8).normalize(),
            irradiance: 1.0,
        },
        Light::Point {
            position: DVec3::new(2.0, -3.0, 7.0),
            intensity: 1.0,
        },
    ];
    let pass = LightPass::compute(&medium(&grid, sigma.clone()), 0, &lights).unwrap();
    let [nx, ny, nz] = grid.dims;
    for (l, light) in lights.iter().enumerate() {
        for k in 0..=nz {
            for j in 0..=ny {
                for i in 0..=nx {
                    let x = DVec3::new(i as f64, j as f64, k as f64) * grid.cell_size;
                    let exact = exact_transmittance(&grid, &sigma, light, x);
                    let got =
                        (-pass.fields[l].corner_optical_depth[grid.corner_index(i, j, k)]).exp();
                    assert!(
                        (got as f64 - exact).abs() < 1e-6,
                        "light {l} corner {i},{j},{k}"
                    );
                }
            }
        }
    }
    // Homogeneous slab, oblique light: where the ray to the light leaves the cell through the
    // top face (T constant there) `transmittance_at` is exact; through a side face, T is
    // exponential in height and the linear face value errs by at most (kh)²/8·e^{kh}, k = σ/μ0.
    let grid = Grid::new([6, 6, 4], 1.0).unwrap();
    let s = 0.7;
    let dir = DVec3::new(0.2, 0.1, -1.0).normalize();
    let mu0 = -dir.z;
    let light = Light::Directional {
        direction: dir,
        irradiance: 1.0,
    };
    let pass = LightPass::compute(
        &medium(&grid, vec![s as f32; grid.cell_count()]),
        0,
        &[light],
    )
    .unwrap();
    let mut rng = Pcg64Mcg::seed_from_u64(9);
    let (mut top, mut side) = (0, 0);
    for _ in 0..400 {
        let x = DVec3::new(
            2.0 + 3.0 * rng.random::<f64>(),
            2.0 + 3.0 * rng.random::<f64>(),
            4.0 * rng.random::<f64>(),
        );
        let cell = grid.cell_at(x).unwrap();
        let exact = (-s * (4.0 - x.z) / mu0).exp();
        let got = pass.transmittance_at(0, x, cell);
        let up = x.z.floor() + 1.0 - x.z;
        let exit = x - dir * (up / mu0);
        if exit.x.floor() == x.x.floor() && exit.y.floor() == x.y.floor() {
            top += 1;
            assert!((got - exact).abs() < 1e-6, "{x}: {got} vs {exact}");
        } else {
            side += 1;
            let k = s / mu0;
            let bound = k * k / 8.0 * k.exp() * exact;
            assert!((got - exact).abs() <= bound, "{x}: {got} vs {exact}");
        }
    }
    assert!(top > 100 && side > 20, "{top} top exits, {side} side exits");
}

#[test]
fn refuses_bad_input() {
    let grid = Grid::new([2, 2, 2], 1.0).unwrap();
    let light = [Light::Directional {
        direction: DVec3::Z,
        irradiance: 1.0,
    }];
    // σt is the medium's to check (`optical::medium_new_refuses_bad_sigma_t`); a channel it
    // does not have is the light pass's.
    let grey = medium(&grid, vec![1.0; 8]);
    assert!(LightPass::compute(&grey, 0, &light).is_ok());
    assert!(LightPass::compute(&grey, 1, &light).is_err());
    let pass = LightPass::compute(&grey, 0, &light).unwrap();
    assert!(pass.zonal_source(&grey, 0).is_ok());
    assert!(pass.zonal_source(&grey, 1).is_err());
    // A medium on another grid than the pass's.
    let other = Grid::new([2, 2, 3], 1.0).unwrap();
    assert!(pass
        .zonal_source(&medium(&other, vec![1.0; 12]), 0)
        .is_err());
    let bad = [Light::Directional {
        direction: DVec3::ZERO,
        irradiance: 1.0,
    }];
    assert!(LightPass::compute(&grey, 0, &bad).is_err());
    let zero_m = LightPassOptions {
        rays_per_cell: 0,
        ..Default::default()
    };
    assert!(LightPass::compute_with(&grey, 0, &light, &zero_m).is_err());
}

/// `E_i = e_i + a_i σt_i Σ_lights cell_irradiance_i / 4π`, summed over the lights; an empty
/// cell keeps only its emission.
#[test]
fn zonal_source_adds_emission_and_scattered_light_of_every_light() {
    let grid = Grid::new([2, 1, 1], 1.0).unwrap();
    let ch = ChannelMedium {
        sigma_t: vec![2.0, 0.0],
        albedo: CellValues::Uniform(0.5),
        emission: CellValues::PerCell(vec![0.1, 0.2]),
    };
    let field = |cell_irradiance: Vec<f32>| LightField {
        light: Light::Directional {
            direction: DVec3::Z,
            irradiance: 1.0,
        },
        cell_irradiance,
        corner_optical_depth: std::sync::Arc::new(vec![0.0; 12]),
        energy: LightEnergy::default(),
    };
    let half = (2.0 * std::f64::consts::PI) as f32;
    let pass = LightPass {
        grid,
        sigma_t: ch.sigma_t.clone(),
        fields: vec![field(vec![half, 0.5]), field(vec![half, 0.5])],
    };
    let medium = Medium::new(
        grid,
        vec![ch],
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let e = pass.zonal_source(&medium, 0).unwrap();
    assert!((e[0] - (0.1 + 0.5 * 2.0)).abs() < 1e-7, "{e:?}");
    assert!((e[1] - 0.2).abs() < 1e-7, "{e:?}");
}
