//! Physics of the renderer against closed forms: transmittance, Max's optical models
//! (eqs. 5, 7, 8), a hand-computed two-cell ray, trilinear reconstruction, early termination,
//! plugged-in scattering and per-pixel averaging.

use gather::OpticalModel;
use gather::{
    render, render_image, Camera, InScattering, RayCarry, RayIntegrator, RenderOptions,
    ScatteringSum, UniformSource, ViewSegment,
};
use glam::DVec3;
use medium::traversal::Ray;
use medium::{CellValues, ChannelMedium, Grid, Interpolation, Medium, PhaseFunction};
use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;

fn homogeneous(dims: [usize; 3], h: f64, sigma_t: f32, emission: f32) -> Medium {
    Medium::homogeneous(
        Grid::new(dims, h).unwrap(),
        sigma_t,
        0.0,
        emission,
        PhaseFunction::Isotropic,
    )
    .unwrap()
}

fn options(model: OpticalModel, background: f64) -> RenderOptions {
    RenderOptions {
        model,
        background,
        // Exact comparisons: no early termination.
        termination: 0.0,
        ..RenderOptions::default()
    }
}

/// Chord of a ray through the box [0, extent] from t = 0, by the slab method (written here
/// independently of the library's clipping).
fn chord(extent: DVec3, ray: &Ray) -> f64 {
    let mut t0: f64 = 0.0;
    let mut t1: f64 = f64::INFINITY;
    for a in 0..3 {
        let (o, d) = (ray.origin[a], ray.direction[a]);
        if d.abs() < 1e-300 {
            if o < 0.0 || o > extent[a] {
                return 0.0;
            }
            continue;
        }
        let (ta, tb) = ((0.0 - o) / d, (extent[a] - o) / d);
        t0 = t0.max(ta.min(tb));
        t1 = t1.min(ta.max(tb));
    }
    (t1 - t0).max(0.0)
}

fn rel_err(got: f64, want: f64) -> f64 {
    (got - want).abs() / want.abs().max(1e-300)
}

/// Cameras all around the box, looking at its centre from many directions.
fn cameras_around(extent: DVec3, orthographic: bool) -> Vec<Camera> {
    let centre = extent * 0.5;
    let mut cams = Vec::new();
    for i in 0..7 {
        for j in 0..5 {
            let theta = 0.2 + 2.7 * i as f64 / 6.0; // polar angle, avoiding the poles
            let phi = 0.37 + std::f64::consts::TAU * j as f64 / 5.0;
            let dir = DVec3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            );
            let eye = centre + dir * 9.0;
            let cam = if orthographic {
                Camera::orthographic(eye, centre, DVec3::Z, 5.0, 9, 7)
            } else {
                Camera::perspective(eye, centre, DVec3::Z, 35.0, 9, 7)
            };
            cams.push(cam.unwrap());
        }
    }
    cams
}

fn check_transmittance(orthographic: bool) {
    let sigma_t = 0.8f32;
    let medium = homogeneous([5, 4, 3], 0.7, sigma_t, 0.0);
    let extent = medium.grid().extent();
    let opts = options(OpticalModel::AbsorptionOnly, 1.0);
    let mut inside = 0;
    for cam in cameras_around(extent, orthographic) {
        let img = render(&medium, 0, &cam, &opts, &()).unwrap();
        for y in 0..cam.height {
            for x in 0..cam.width {
                let ray = cam.ray(x as f64 + 0.5, y as f64 + 0.5);
                let l = chord(extent, &ray);
                inside += (l > 0.0) as usize;
                let want = (-(sigma_t as f64) * l).exp();
                let got = img.get(x, y) as f64;
                assert!(
                    rel_err(got, want) < 1e-6,
                    "camera at {}: pixel ({x},{y}) {got} vs exp(−σt L) = {want}",
                    cam.eye
                );
            }
        }
    }
    assert!(inside > 500, "too few rays hit the box ({inside})");
}

#[test]
fn homogeneous_box_transmittance_orthographic() {
    check_transmittance(true);
}

#[test]
fn homogeneous_box_transmittance_perspective() {
    check_transmittance(false);
}

#[test]
fn transmittance_of_random_rays_in_f64() {
    let sigma_t = 1.3f32;
    let medium = homogeneous([6, 3, 4], 0.5, sigma_t, 0.0);
    let extent = medium.grid().extent();
    let opts = options(OpticalModel::AbsorptionOnly, 2.0);
    let integ = RayIntegrator::new(&medium, 0, &opts, &()).unwrap();
    let mut rng = Pcg64::seed_from_u64(11);
    for _ in 0..2000 {
        let origin = DVec3::new(
            rng.random_range(-2.0..5.0),
            rng.random_range(-2.0..4.0),
            rng.random_range(-2.0..4.0),
        );
        let dir = DVec3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
        );
        if dir.length() < 1e-3 {
            continue;
        }
        let ray = Ray::new(origin, dir);
        let want = 2.0 * (-(sigma_t as f64) * chord(extent, &ray)).exp();
        assert!(rel_err(integ.radiance(&ray), want) < 1e-9, "{ray:?}");
    }
}

#[test]
fn emission_absorption_matches_closed_form() {
    let (sigma_t, e, i0) = (0.9f32, 0.35f32, 0.2);
    let medium = homogeneous([4, 5, 3], 1.0, sigma_t, e);
    let extent = medium.grid().extent();
    let opts = options(OpticalModel::EmissionAbsorption, i0);
    let (s, e) = (sigma_t as f64, e as f64);
    for cam in cameras_around(extent, false).iter().step_by(3) {
        let img = render(&medium, 0, cam, &opts, &()).unwrap();
        for y in 0..cam.height {
            for x in 0..cam.width {
                let l = chord(extent, &cam.ray(x as f64 + 0.5, y as f64 + 0.5));
                let t = (-s * l).exp();
                let want = e / s * (1.0 - t) + i0 * t;
                assert!(rel_err(img.get(x, y) as f64, want) < 1e-6);
            }
        }
    }
}

#[test]
fn emission_only_is_emission_times_length() {
    // σt is ignored by the emission-only model (Max eq. 5): nothing is attenuated, not even
    // the background.
    let medium = homogeneous([3, 3, 3], 0.8, 5.0, 0.6);
    let extent = medium.grid().extent();
    let opts = options(OpticalModel::EmissionOnly, 0.1);
    let integ = RayIntegrator::new(&medium, 0, &opts, &()).unwrap();
    let mut rng = Pcg64::seed_from_u64(5);
    let mut hits = 0;
    for _ in 0..500 {
        let target = DVec3::new(
            rng.random_range(0.0..2.4),
            rng.random_range(0.0..2.4),
            rng.random_range(0.0..2.4),
        );
        let origin = DVec3::new(
            -1.0,
            rng.random_range(-1.0..3.0),
            rng.random_range(-1.0..3.0),
        );
        let ray = Ray::new(origin, target - origin);
        let l = chord(extent, &ray);
        hits += (l > 0.0) as usize;
        let want = 0.6 * l + 0.1;
        assert!(rel_err(integ.radiance(&ray), want) < 1e-6);
    }
    assert!(hits > 400);
}

#[test]
fn absorption_only_ignores_emission() {
    let medium = homogeneous([2, 2, 2], 1.0, 0.5, 7.0);
    let opts = options(OpticalModel::AbsorptionOnly, 1.0);
    let integ = RayIntegrator::new(&medium, 0, &opts, &()).unwrap();
    let ray = Ray::new(DVec3::new(-1.0, 1.0, 1.0), DVec3::X);
    assert!(rel_err(integ.radiance(&ray), (-1.0f64).exp()) < 1e-12);
}

#[test]
fn particle_model_matches_max_eq_8_in_a_heterogeneous_medium() {
    // With emission = C σt per cell, Q/σt = C everywhere, so eq. 8 holds along any ray through
    // any σt field: I = C (1 − T) + I0 T with T the ray's total transmittance.
    let grid = Grid::new([6, 5, 4], 0.6).unwrap();
    let mut rng = Pcg64::seed_from_u64(8);
    let sigma_t: Vec<f32> = (0..grid.cell_count())
        .map(|_| {
            if rng.random_bool(0.2) {
                0.0
            } else {
                rng.random_range(0.05..3.0)
            }
        })
        .collect();
    let c = 0.7f32;
    let emission = sigma_t.iter().map(|s| c * s).collect();
    let medium = Medium::new(
        grid,
        vec![ChannelMedium {
            sigma_t: sigma_t.clone(),
            albedo: CellValues::Uniform(0.0),
            emission: CellValues::PerCell(emission),
        }],
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let i0 = 0.3;
    let opts = options(OpticalModel::EmissionAbsorption, i0);
    let integ = RayIntegrator::new(&medium, 0, &opts, &()).unwrap();
    for _ in 0..1000 {
        let origin = DVec3::new(
            -2.0,
            rng.random_range(-1.0..4.0),
            rng.random_range(-1.0..3.0),
        );
        let target = DVec3::new(
            rng.random_range(0.0..3.6),
            rng.random_range(0.0..3.0),
            rng.random_range(0.0..2.4),
        );
        let ray = Ray::new(origin, target - origin);
        let t = (-grid.optical_depth(&sigma_t, &ray, 0.0, f64::INFINITY)).exp();
        let want = c as f64 * (1.0 - t) + i0 * t;
        // The per-cell emission C·σt is stored in f32: 1e-7 relative rounding per cell.
        let got = integ.radiance(&ray);
        assert!(rel_err(got, want) < 5e-7, "{got} vs {want}");
    }
}

fn two_cell_medium(interpolation: Interpolation) -> Medium {
    Medium::new(
        Grid::new([2, 1, 1], 1.0).unwrap(),
        vec![ChannelMedium {
            sigma_t: vec![0.5, 2.0],
            albedo: CellValues::Uniform(0.0),
            emission: CellValues::PerCell(vec![1.0, 3.0]),
        }],
        PhaseFunction::Isotropic,
        interpolation,
        None,
    )
    .unwrap()
}

#[test]
fn two_cell_ray_matches_hand_computation() {
    // Cell 0: σt 0.5, e 1; cell 1: σt 2, e 3; unit cells, ray along +x.
    //   I = (1 − e^{−0.5})/0.5 + e^{−0.5} · 3 (1 − e^{−2})/2 = 1.573607172207835
    //   plus background 0.25 · e^{−2.5}                      → 1.5941284218638099
    let medium = two_cell_medium(Interpolation::Nearest);
    let ray = Ray::new(DVec3::new(-1.0, 0.5, 0.5), DVec3::X);
    let black = RayIntegrator::new(
        &medium,
        0,
        &options(OpticalModel::EmissionAbsorption, 0.0),
        &(),
    )
    .unwrap();
    assert!(rel_err(black.radiance(&ray), 1.573607172207835) < 1e-12);
    let lit = RayIntegrator::new(
        &medium,
        0,
        &options(OpticalModel::EmissionAbsorption, 0.25),
        &(),
    )
    .unwrap();
    assert!(rel_err(lit.radiance(&ray), 1.5941284218638099) < 1e-12);
    // Front-to-back order matters: seen from the other side the dense cell comes first.
    let back = Ray::new(DVec3::new(3.0, 0.5, 0.5), -DVec3::X);
    let want_back =
        3.0 * (1.0 - (-2.0f64).exp()) / 2.0 + (-2.0f64).exp() * (1.0 - (-0.5f64).exp()) / 0.5;
    assert!(rel_err(black.radiance(&back), want_back) < 1e-12);
    // A ray starting inside cell 1 sees only the part of the grid in front of it.
    let inside = Ray::new(DVec3::new(1.5, 0.5, 0.5), DVec3::X);
    assert!(rel_err(black.radiance(&inside), 3.0 * (1.0 - (-1.0f64).exp()) / 2.0) < 1e-12);
}

#[test]
fn trilinear_equals_nearest_in_a_homogeneous_medium() {
    let medium = homogeneous([5, 5, 5], 0.5, 1.7, 0.4);
    let nearest = RayIntegrator::new(
        &medium,
        0,
        &options(OpticalModel::EmissionAbsorption, 0.3),
        &(),
    )
    .unwrap();
    let mut rng = Pcg64::seed_from_u64(3);
    let rays: Vec<Ray> = (0..300)
        .map(|_| {
            let a = DVec3::new(
                rng.random_range(0.3..2.2),
                rng.random_range(0.3..2.2),
                rng.random_range(0.3..2.2),
            );
            let b = DVec3::new(
                rng.random_range(0.3..2.2),
                rng.random_range(0.3..2.2),
                rng.random_range(0.3..2.2),
            );
            Ray::new(a, b - a)
        })
        .collect();
    let want: Vec<f64> = rays.iter().map(|r| nearest.radiance(r)).collect();
    let medium = medium.with_interpolation(Interpolation::Trilinear);
    let tri = RayIntegrator::new(
        &medium,
        0,
        &options(OpticalModel::EmissionAbsorption, 0.3),
        &(),
    )
    .unwrap();
    for (r, w) in rays.iter().zip(want) {
        assert!(rel_err(tri.radiance(r), w) < 1e-9, "{r:?}");
    }
}

#[test]
fn trilinear_interpolates_between_cell_centres() {
    // Emission 0 and 2 in two unit cells: the trilinear field at x = 0.75 is 0.5 (a quarter of
    // the way from the centre at 0.5 to the centre at 1.5), so a ray along y there collects
    // 0.5 · 1 under emission only; nearest would give 0.
    let medium = two_cell_medium(Interpolation::Trilinear);
    let mut ch = medium.channels()[0].clone();
    ch.emission = CellValues::PerCell(vec![0.0, 2.0]);
    let medium = Medium::new(
        *medium.grid(),
        vec![ch],
        PhaseFunction::Isotropic,
        Interpolation::Trilinear,
        None,
    )
    .unwrap();
    let integ =
        RayIntegrator::new(&medium, 0, &options(OpticalModel::EmissionOnly, 0.0), &()).unwrap();
    let ray = Ray::new(DVec3::new(0.75, -1.0, 0.5), DVec3::Y);
    assert!(rel_err(integ.radiance(&ray), 0.5) < 1e-12);
    // Outside the outermost centres the value is clamped to the edge cell's.
    let edge = Ray::new(DVec3::new(1.8, -1.0, 0.5), DVec3::Y);
    assert!(rel_err(integ.radiance(&edge), 2.0) < 1e-12);
}

#[test]
fn early_termination_stays_within_its_tolerance() {
    // τ = 40 along the ray: the default tolerance (1e-4 relative) may stop the ray early.
    let (s, e) = (4.0f32, 0.5f32);
    let medium = homogeneous([10, 2, 2], 1.0, s, e);
    let ray = Ray::new(DVec3::new(-1.0, 1.0, 1.0), DVec3::X);
    let want = (e / s) as f64 * (1.0 - (-40.0f64).exp());
    for (model, src) in [
        (OpticalModel::EmissionAbsorption, &() as &dyn InScattering),
        (OpticalModel::Scattering, &UniformSource(0.25)),
    ] {
        let opts = RenderOptions {
            model,
            background: 0.3,
            ..RenderOptions::default()
        };
        let integ = RayIntegrator::new(&medium, 0, &opts, src).unwrap();
        let extra = if model == OpticalModel::Scattering {
            0.25 / 4.0
        } else {
            0.0
        };
        let want = want + extra * (1.0 - (-40.0f64).exp());
        let got = integ.radiance(&ray);
        assert!(rel_err(got, want) <= 1e-4, "{model:?}: {got} vs {want}");
    }
}

/// Q_s = 1 for light flowing towards +z, 0 otherwise: checks the direction convention.
struct FlowsUp;

impl InScattering for FlowsUp {
    fn segment(&self, seg: &ViewSegment, _: &mut RayCarry) -> f64 {
        if -seg.ray.direction.z > 0.5 {
            seg.weight
        } else {
            0.0
        }
    }
    fn at(&self, _: DVec3, _: usize, flow: DVec3) -> f64 {
        if flow.z > 0.5 {
            1.0
        } else {
            0.0
        }
    }
    fn max_source(&self) -> f64 {
        1.0
    }
}

#[test]
fn plugged_in_scattering_adds_to_emission() {
    let (s, e, q) = (0.6f32, 0.2, 0.3);
    let medium = homogeneous([3, 3, 3], 1.0, s, e);
    let s = s as f64;
    let ray = Ray::new(DVec3::new(1.5, 1.5, 5.0), -DVec3::Z);
    let closed = |q: f64| (e as f64 + q) / s * (1.0 - (-3.0 * s).exp());
    let (a, b) = (UniformSource(q), UniformSource(2.0 * q));
    let sum = ScatteringSum::new(vec![&a, &b]);
    for interp in [Interpolation::Nearest, Interpolation::Trilinear] {
        let medium = medium.clone().with_interpolation(interp);
        let run = |model, src: &dyn InScattering| {
            RayIntegrator::new(&medium, 0, &options(model, 0.0), src)
                .unwrap()
                .radiance(&ray)
        };
        assert!(rel_err(run(OpticalModel::Scattering, &a), closed(q)) < 1e-9);
        assert!(rel_err(run(OpticalModel::SingleScatterUnshadowed, &a), closed(q)) < 1e-9);
        assert!(rel_err(run(OpticalModel::Scattering, &sum), closed(3.0 * q)) < 1e-9);
        assert!(rel_err(run(OpticalModel::Scattering, &(a, b)), closed(3.0 * q)) < 1e-9);
        assert!(rel_err(run(OpticalModel::Scattering, &Some(a)), closed(q)) < 1e-9);
        assert!(
            rel_err(
                run(OpticalModel::Scattering, &None::<UniformSource>),
                closed(0.0)
            ) < 1e-9
        );
        // Non-scattering models ignore the scattered source.
        assert!(rel_err(run(OpticalModel::EmissionAbsorption, &a), closed(0.0)) < 1e-9);
        // The ray looks down (−z), so the light reaching the eye flows up (+z).
        assert!(rel_err(run(OpticalModel::Scattering, &FlowsUp), closed(1.0)) < 1e-9);
        let up = Ray::new(DVec3::new(1.5, 1.5, -2.0), DVec3::Z);
        let got = RayIntegrator::new(
            &medium,
            0,
            &options(OpticalModel::Scattering, 0.0),
            &FlowsUp,
        )
        .unwrap()
        .radiance(&up);
        assert!(rel_err(got, closed(0.0)) < 1e-9, "{interp:?}");
    }
}

/// A 1×1-pixel orthographic view straight down onto the right edge (x = 4) of a 4×4×1 slab of
/// σt = 1, the pixel covering world x ∈ [xc − 0.5, xc + 0.5].
fn edge_pixel(xc: f64, spp: u32) -> f64 {
    let medium = homogeneous([4, 4, 1], 1.0, 1.0, 0.0);
    let cam = Camera::orthographic(
        DVec3::new(xc, 2.0, 5.0),
        DVec3::new(xc, 2.0, 0.0),
        DVec3::Y,
        1.0,
        1,
        1,
    )
    .unwrap();
    let opts = RenderOptions {
        spp,
        ..options(OpticalModel::AbsorptionOnly, 1.0)
    };
    render(&medium, 0, &cam, &opts, &()).unwrap().get(0, 0) as f64
}

#[test]
fn pixel_is_the_mean_of_stratified_samples_over_its_area() {
    let t = (-1.0f64).exp();
    // Centre sample only: x = 4.25 lies outside the slab.
    assert!(rel_err(edge_pixel(4.25, 1), 1.0) < 1e-7);
    // Half the pixel over the slab, 2×2 strata: half the samples see T.
    assert!(rel_err(edge_pixel(4.0, 4), 0.5 * (t + 1.0)) < 1e-7);
    // A quarter over the slab, 4×4 strata: one column of four sees T.
    assert!(rel_err(edge_pixel(4.25, 16), 0.25 * t + 0.75) < 1e-7);
    // 2 samples (2×1 strata, side by side): x = 3.75 and 4.25.
    assert!(rel_err(edge_pixel(4.0, 2), 0.5 * (t + 1.0)) < 1e-7);
}

#[test]
fn pixel_zero_zero_is_top_left() {
    // Only the top-left quarter of the slab (x < 2, y ≥ 2) absorbs; looking down −z with +y up.
    let grid = Grid::new([4, 4, 1], 1.0).unwrap();
    let sigma_t: Vec<f32> = (0..16)
        .map(|i| if i % 4 < 2 && i / 4 >= 2 { 1.0 } else { 0.0 })
        .collect();
    let medium = Medium::grey(grid, sigma_t, 0.0, PhaseFunction::Isotropic).unwrap();
    let cam = Camera::orthographic(
        DVec3::new(2.0, 2.0, 5.0),
        DVec3::new(2.0, 2.0, 0.0),
        DVec3::Y,
        4.0,
        2,
        2,
    )
    .unwrap();
    let img = render(
        &medium,
        0,
        &cam,
        &options(OpticalModel::AbsorptionOnly, 1.0),
        &(),
    )
    .unwrap();
    let t = (-1.0f64).exp();
    assert!(rel_err(img.get(0, 0) as f64, t) < 1e-7);
    for (x, y) in [(1, 0), (0, 1), (1, 1)] {
        assert_eq!(img.get(x, y), 1.0, "pixel ({x},{y})");
    }
}

#[test]
fn colour_media_render_each_channel() {
    let grid = Grid::new([3, 3, 3], 1.0).unwrap();
    let chans: Vec<ChannelMedium> = [0.2f32, 0.8, 2.0]
        .iter()
        .map(|&s| ChannelMedium {
            sigma_t: vec![s; 27],
            albedo: CellValues::Uniform(0.5),
            emission: CellValues::Uniform(0.5),
        })
        .collect();
    let medium = Medium::new(
        grid,
        chans,
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let cam = Camera::orthographic(
        DVec3::new(1.5, 1.5, 9.0),
        DVec3::new(1.5, 1.5, 0.0),
        DVec3::Y,
        1.0,
        4,
        3,
    )
    .unwrap();
    let opts = options(OpticalModel::Scattering, 0.0);
    let q = UniformSource(0.1);
    let srcs: [&dyn InScattering; 3] = [&(), &q, &()];
    let img = render_image(&medium, &cam, &opts, &srcs).unwrap();
    assert_eq!((img.width, img.height, img.channels), (4, 3, 3));
    for (c, (s, extra)) in [(0.2f64, 0.0f64), (0.8, 0.1), (2.0, 0.0)]
        .iter()
        .enumerate()
    {
        let want = (0.5 + extra) / s * (1.0 - (-3.0 * s).exp());
        assert!(
            rel_err(img.get(2, 1, c as u32) as f64, want) < 1e-6,
            "channel {c}"
        );
    }
    // One source per channel, or none at all.
    assert!(render_image(&medium, &cam, &opts, &srcs[..2]).is_err());
    assert!(render_image(&medium, &cam, &opts, &[]).is_ok());
}

#[test]
fn bad_render_inputs_are_refused() {
    let medium = homogeneous([2, 2, 2], 1.0, 1.0, 0.0);
    let cam = Camera::orthographic(DVec3::Z * 5.0, DVec3::ZERO, DVec3::Y, 1.0, 2, 2).unwrap();
    let base = RenderOptions::default();
    assert!(
        render(&medium, 1, &cam, &base, &()).is_err(),
        "channel out of range"
    );
    for bad in [
        RenderOptions {
            spp: 0,
            ..base.clone()
        },
        RenderOptions {
            background: f64::NAN,
            ..base.clone()
        },
        RenderOptions {
            background: -1.0,
            ..base.clone()
        },
        RenderOptions {
            trilinear_step: 0.0,
            ..base.clone()
        },
        RenderOptions {
            termination: 1.0,
            ..base.clone()
        },
    ] {
        assert!(render(&medium, 0, &cam, &bad, &()).is_err(), "{bad:?}");
    }
}

/// Trilinear σt or emission at a point, written independently: cell-centred values clamped
/// at the grid's edges.
fn trilinear_at(grid: &Grid, values: &[f32], x: DVec3) -> f64 {
    let mut idx = [[0usize; 2]; 3];
    let mut w = [[0.0f64; 2]; 3];
    for a in 0..3 {
        let n = grid.dims[a];
        let u = (x[a] / grid.cell_size - 0.5).clamp(0.0, (n - 1) as f64);
        let i0 = u.floor() as usize;
        let i1 = (i0 + 1).min(n - 1);
        let f = u - i0 as f64;
        idx[a] = [i0, i1];
        w[a] = [1.0 - f, f];
    }
    let mut sum = 0.0;
    for (c, wz) in idx[2].iter().zip(w[2]) {
        for (b, wy) in idx[1].iter().zip(w[1]) {
            for (a, wx) in idx[0].iter().zip(w[0]) {
                sum += wx * wy * wz * values[grid.index(*a, *b, *c)] as f64;
            }
        }
    }
    sum
}

#[test]
fn sparse_media_match_brute_force_integration() {
    // A few emitting, absorbing cells in the middle of a large empty grid: the renderer skips
    // the empty margins, which must not change any result (nearest or trilinear, rays starting
    // outside, inside, and in the empty margin).
    let grid = Grid::new([12, 10, 9], 0.5).unwrap();
    let mut sigma_t = vec![0.0f32; grid.cell_count()];
    let mut emission = vec![0.0f32; grid.cell_count()];
    for (c, s, e) in [
        ((5, 4, 4), 1.5, 0.4),
        ((6, 4, 4), 0.7, 0.0),
        ((6, 5, 5), 2.0, 1.0),
    ] {
        let i = grid.index(c.0, c.1, c.2);
        sigma_t[i] = s;
        emission[i] = e;
    }
    let mut rng = Pcg64::seed_from_u64(21);
    let rays: Vec<Ray> = (0..400)
        .map(|_| {
            let origin = DVec3::new(
                rng.random_range(-2.0..8.0),
                rng.random_range(-2.0..7.0),
                rng.random_range(-2.0..6.5),
            );
            let target = DVec3::new(
                rng.random_range(2.5..3.5),
                rng.random_range(2.0..3.0),
                rng.random_range(2.0..3.0),
            );
            Ray::new(origin, target - origin)
        })
        .collect();
    for interpolation in [Interpolation::Nearest, Interpolation::Trilinear] {
        let medium = Medium::new(
            grid,
            vec![ChannelMedium {
                sigma_t: sigma_t.clone(),
                albedo: CellValues::Uniform(0.0),
                emission: CellValues::PerCell(emission.clone()),
            }],
            PhaseFunction::Isotropic,
            interpolation,
            None,
        )
        .unwrap();
        let i0 = 0.2;
        let opts = RenderOptions {
            trilinear_step: 0.004,
            ..options(OpticalModel::EmissionAbsorption, i0)
        };
        let integ = RayIntegrator::new(&medium, 0, &opts, &()).unwrap();
        for ray in &rays {
            let Some((_, t1)) = grid.clip(ray, 0.0, f64::INFINITY) else {
                assert_eq!(integ.radiance(ray), i0);
                continue;
            };
            let (radiance, t) = match interpolation {
                // Reference: the analytic per-cell integral over every cell of the whole grid.
                Interpolation::Nearest => {
                    let (mut t, mut radiance) = (1.0f64, 0.0f64);
                    for seg in grid.traverse(ray, 0.0, f64::INFINITY) {
                        let (s, e) = (sigma_t[seg.cell] as f64, emission[seg.cell] as f64);
                        let a = (-s * seg.length()).exp();
                        radiance += if s > 0.0 {
                            t * e * (1.0 - a) / s
                        } else {
                            t * e * seg.length()
                        };
                        t *= a;
                    }
                    (radiance, t)
                }
                // Reference: a fine midpoint march of the continuous field over the whole grid.
                Interpolation::Trilinear => {
                    let n = 20_000;
                    let dt = t1 / n as f64;
                    let (mut t, mut radiance) = (1.0f64, 0.0f64);
                    for k in 0..n {
                        let x = ray.at((k as f64 + 0.5) * dt);
                        if grid.cell_at(x).is_none() {
                            continue;
                        }
                        let s = trilinear_at(&grid, &sigma_t, x);
                        // Midpoint values, each step integrated exactly (second order).
                        let a = (-s * dt).exp();
                        let w = if s > 0.0 { (1.0 - a) / s } else { dt };
                        radiance += t * trilinear_at(&grid, &emission, x) * w;
                        t *= a;
                    }
                    (radiance, t)
                }
            };
            let want = radiance + t * i0;
            let got = integ.radiance(ray);
            let tolerance = match interpolation {
                Interpolation::Nearest => 1e-12,
                Interpolation::Trilinear => 1e-5,
            };
            assert!(
                (got - want).abs() < tolerance * want,
                "{interpolation:?} {ray:?}: {got} vs brute force {want}"
            );
        }
    }
}

/// A uniform source that counts the cells it is asked about.
struct Counting {
    q: f64,
    calls: std::sync::atomic::AtomicUsize,
}

impl InScattering for Counting {
    fn segment(&self, seg: &ViewSegment, _: &mut RayCarry) -> f64 {
        self.calls
            .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
        self.q * seg.weight
    }
    fn at(&self, _: DVec3, _: usize, _: DVec3) -> f64 {
        self.q
    }
    fn max_source(&self) -> f64 {
        self.q
    }
}

#[test]
fn early_termination_stops_thick_rays() {
    // 40 cells of τ = 1 each: the ray should stop after about ln(10⁴) ≈ 9–10 cells, and visit
    // all 40 with termination disabled.
    let medium = homogeneous([40, 1, 1], 1.0, 1.0, 0.0);
    let ray = Ray::new(DVec3::new(-1.0, 0.5, 0.5), DVec3::X);
    for (termination, lo, hi) in [(1e-4, 8, 13), (0.0, 40, 40)] {
        let source = Counting {
            q: 0.5,
            calls: 0.into(),
        };
        let opts = RenderOptions {
            model: OpticalModel::Scattering,
            termination,
            ..RenderOptions::default()
        };
        let got = RayIntegrator::new(&medium, 0, &opts, &source)
            .unwrap()
            .radiance(&ray);
        let calls = source.calls.into_inner();
        assert!(
            (lo..=hi).contains(&calls),
            "termination {termination}: {calls} cells"
        );
        assert!(rel_err(got, 0.5 * (1.0 - (-40.0f64).exp())) <= termination.max(1e-12));
    }
}

/// A render index built once serves every view with the image `render` gives, bit for bit,
/// for each optical model; an index built for another model or grid is refused.
#[test]
fn a_shared_render_index_gives_the_same_images_and_refuses_another_medium() {
    use gather::{render_indexed, RenderIndex};
    let dims = [7, 6, 5];
    let mut rng = Pcg64::seed_from_u64(3);
    // Patchy: empty cells between occupied ones, so empty-space jumps happen.
    let sigma_t: Vec<f32> = (0..dims.iter().product::<usize>())
        .map(|_| {
            if rng.random_bool(0.4) {
                rng.random_range(0.1..1.5)
            } else {
                0.0
            }
        })
        .collect();
    let emission = CellValues::PerCell(sigma_t.iter().map(|s| 0.5 * s).collect());
    let medium = Medium::new(
        Grid::new(dims, 1.0).unwrap(),
        vec![ChannelMedium {
            sigma_t,
            albedo: CellValues::Uniform(0.0),
            emission,
        }],
        PhaseFunction::Isotropic,
        Interpolation::Nearest,
        None,
    )
    .unwrap();
    let source = UniformSource(0.3);
    for model in [
        OpticalModel::EmissionAbsorption,
        OpticalModel::AbsorptionOnly,
        OpticalModel::EmissionOnly,
        OpticalModel::Scattering,
    ] {
        let opts = RenderOptions {
            model,
            background: 0.1,
            ..RenderOptions::default()
        };
        let index = RenderIndex::new(&medium, 0, model).unwrap();
        for cam in cameras_around(medium.grid().extent(), false) {
            let fresh = render(&medium, 0, &cam, &opts, &source).unwrap();
            let shared = render_indexed(&medium, &cam, &opts, &source, &index).unwrap();
            assert_eq!(fresh.pixels, shared.pixels, "{model:?}");
        }
        let other_model = if model == OpticalModel::AbsorptionOnly {
            OpticalModel::EmissionOnly
        } else {
            OpticalModel::AbsorptionOnly
        };
        let cam = &cameras_around(medium.grid().extent(), false)[0];
        let wrong = RenderOptions {
            model: other_model,
            ..opts
        };
        assert!(render_indexed(&medium, cam, &wrong, &source, &index).is_err());
    }
    let other_grid = homogeneous([7, 6, 4], 1.0, 0.5, 0.0);
    let index = RenderIndex::new(&medium, 0, OpticalModel::AbsorptionOnly).unwrap();
    let cam = &cameras_around(other_grid.grid().extent(), false)[0];
    let opts = options(OpticalModel::AbsorptionOnly, 0.0);
    assert!(render_indexed(&other_grid, cam, &opts, &(), &index).is_err());
}
