//! The environment light (`[[light]] kind = "environment"`): light from every direction that
//! every solving method carries and the path tracer picks up where scattered paths leave.

use std::path::Path;

use gather::Camera;
use montecarlo::path_trace::{path_trace, PathTraceOptions, Surroundings};
use scene::Scene;
use volrad::engine::pipeline::{render_view, solve_scene};
use volrad::engine::solution::Solution;
use volrad::engine::SolveHooks;

use crate::fixtures::{masked_error, path_traced};

/// A 12×12×10 generated cloud (optical depth through the middle about 10) under a uniform
/// environment of radiance 0.5, seen from one side.
fn scene_text(albedo: f64, phase: &str, method: &str, extra_light: &str) -> String {
    scene_text_at([12, 12, 10], 1.0, albedo, phase, method, extra_light)
}

/// The same cloud sampled on `dims` cells of side `cell_size` (the generator scales the
/// cloud to the grid; σt per unit length stays).
fn scene_text_at(
    dims: [usize; 3],
    cell_size: f64,
    albedo: f64,
    phase: &str,
    method: &str,
    extra_light: &str,
) -> String {
    format!(
        r#"
[volume]
generator = {{ kind = "cloud", seed = 3 }}
dims = {dims:?}
cell_size = {cell_size}
sigma_t_scale = 2.0
# The medium the path tracer traces, which every test here compares with.
interpolation = "nearest"

[medium]
albedo = {albedo}
phase = {phase}

[[light]]
kind = "environment"
radiance = 0.5
{extra_light}
[solve]
method = "{method}"

[[camera]]
name = "side"
eye = [6.0, -20.0, 14.0]
target = [6.0, 6.0, 5.0]
up = [0.0, 0.0, 1.0]
fov_y = 26.0
width = 64
height = 48
"#
    )
}

fn parse(text: &str) -> Scene {
    Scene::from_toml_str(text, Path::new("."), Path::new("environment-test.toml")).unwrap()
}

fn solve(scene: &Scene) -> Solution {
    solve_scene(scene, &scene.solve, &SolveHooks::default()).unwrap()
}

/// The largest relative difference of a pixel of `image` from `radiance`.
fn worst_relative_pixel(image: &gather::Image, radiance: f64) -> f64 {
    image
        .pixels
        .iter()
        .map(|&v| (v as f64 / radiance - 1.0).abs())
        .fold(0.0, f64::max)
}

const ISOTROPIC: &str = r#"{ kind = "isotropic" }"#;
const FORWARD: &str = r#"{ kind = "henyey-greenstein", g = 0.6 }"#;

/// The white furnace: a non-absorbing medium in a uniform environment holds its radiance
/// everywhere, so every pixel is L, whatever the medium in front (issue #20: to 0.5 %).
#[test]
fn a_non_absorbing_medium_in_a_uniform_environment_vanishes_in_every_method() {
    for (method, phase) in [
        ("zonal", ISOTROPIC),
        ("zonal-hierarchical", ISOTROPIC),
        ("discrete-ordinates", ISOTROPIC),
        ("discrete-ordinates", FORWARD),
    ] {
        let scene = parse(&scene_text(1.0, phase, method, ""));
        let image = render_view(&solve(&scene), &scene.cameras[0], Some(4)).unwrap();
        let worst = worst_relative_pixel(&image, 0.5);
        assert!(
            worst < 0.005,
            "{method} with {phase}: a pixel is {:.2} % off the environment's radiance",
            100.0 * worst
        );
    }
    // The path tracer: every path ends in the environment with throughput 1.
    let scene = parse(&scene_text(1.0, FORWARD, "zonal", ""));
    let camera = Camera::from_spec(&scene.cameras[0]).unwrap();
    let traced = path_trace(
        &scene.medium,
        0,
        &scene.lights,
        Surroundings {
            background: scene.background,
            environment: scene.environment,
            ground: None,
        },
        &camera,
        &PathTraceOptions {
            spp: 4,
            ..PathTraceOptions::default()
        },
    )
    .unwrap();
    assert!(traced.pixels.iter().all(|&v| (v - 0.5).abs() < 1e-5));
}

/// With absorption the cloud darkens against the environment, by as much as the path tracer
/// says: zonal-hierarchical within its 2 % floor, discrete ordinates (g = 0.6) within 3 %,
/// two-pass (its photons also leave from the environment) within 4 % with its noise.
/// The environment's first bounce is constant in each cell, so the error grows with the
/// cells' optical depth: on the 12×12×10 grid (σt·h up to 2) it is 2.6 % (zonal); on this
/// 24×24×20 one (σt·h ≤ 1) 1.0 % (docs/validation.md).
#[test]
fn an_absorbing_cloud_in_a_uniform_environment_matches_the_path_tracer() {
    for (method, phase, floor) in [
        ("zonal-hierarchical", ISOTROPIC, 0.02),
        ("discrete-ordinates", FORWARD, 0.03),
        // Photon noise (2²¹ photons from the environment) counts as error.
        ("two-pass", FORWARD, 0.04),
    ] {
        let scene = parse(&scene_text_at([24, 24, 20], 0.5, 0.7, phase, method, ""));
        let image = render_view(&solve(&scene), &scene.cameras[0], Some(16)).unwrap();
        let traced = path_traced(&scene, 0, 256);
        let darkest = image.pixels.iter().copied().fold(f32::INFINITY, f32::min);
        assert!(
            darkest < 0.4,
            "{method}: the cloud does not darken ({darkest})"
        );
        // Over the cloud only (pixels the path tracer shows darker than the environment by
        // 5 %): the background matches by construction and would dilute the error.
        let (rms, mean, count) = masked_error(&image, 0, &traced, |_, r| r < 0.95 * 0.5);
        println!("{method} in a uniform environment vs the path tracer: {count} cloud pixels, relative RMS {rms:.4}, mean {mean:+.4}");
        assert!(count > 200, "{method}: only {count} cloud pixels");
        assert!(
            rms < floor && mean.abs() < 0.01,
            "{method}: relative RMS {rms:.4}, mean {mean:+.4}"
        );
    }
}

/// The environment's first bounce comes from per-cell values (a light's is integrated exactly
/// by the render), so its error is spatial: the same cloud on cells half as large (optical
/// depth per cell up to 2, then up to 1) is closer to the path tracer. Drawn between cell
/// centres keeping each cell's mean (a `nearest` medium's light), the coarse cells are already
/// within 1.5 % (measured 1.03 %, and 0.83 % on the fine ones).
#[test]
fn the_environment_error_shrinks_with_the_cells() {
    let error = |dims: [usize; 3], cell: f64| {
        let scene = parse(&scene_text_at(
            dims,
            cell,
            0.7,
            ISOTROPIC,
            "zonal-hierarchical",
            "",
        ));
        let image = render_view(&solve(&scene), &scene.cameras[0], Some(16)).unwrap();
        let traced = path_traced(&scene, 0, 256);
        let (rms, mean, count) = masked_error(&image, 0, &traced, |_, r| r < 0.95 * 0.5);
        println!("zonal-hierarchical on {dims:?} cells of {cell}: {count} cloud pixels, relative RMS {rms:.4}, mean {mean:+.4}");
        rms
    };
    let (coarse, fine) = (error([12, 12, 10], 1.0), error([24, 24, 20], 0.5));
    assert!(
        fine < 0.9 * coarse && coarse < 0.015,
        "relative RMS {coarse:.4} on the coarse cells, {fine:.4} on the fine ones"
    );
}

/// The background is the environment; a second source of truth, a second environment or a
/// method that cannot carry it is refused before any work.
#[test]
fn environment_scenes_are_checked_before_work() {
    let scene = parse(&scene_text(0.9, ISOTROPIC, "zonal", ""));
    assert_eq!(scene.background, 0.0, "the environment is the backdrop");
    assert!(scene.lights.is_empty());
    assert_eq!(
        scene.environment.unwrap().uniform_radiance(),
        Some([0.5; 3])
    );

    let err = |text: String| {
        Scene::from_toml_str(&text, Path::new("."), Path::new("t.toml"))
            .unwrap_err()
            .to_string()
    };
    let both = scene_text(0.9, ISOTROPIC, "zonal", "[background]\nradiance = 0.1\n");
    assert!(err(both).contains("`background`"));
    let twice = scene_text(
        0.9,
        ISOTROPIC,
        "zonal",
        "[[light]]\nkind = \"environment\"\nradiance = 1.0\n",
    );
    assert!(err(twice).contains("light[1].kind"));
    let negative = scene_text(0.9, ISOTROPIC, "zonal", "").replace("0.5\n", "-0.5\n");
    assert!(err(negative).contains("light[0].radiance"));

    for method in ["single-scatter", "none"] {
        let scene = parse(&scene_text(0.9, ISOTROPIC, method, ""));
        let e = solve_scene(&scene, &scene.solve, &SolveHooks::default())
            .err()
            .unwrap()
            .to_string();
        assert!(
            e.contains("environment") && e.contains(method),
            "{method}: {e}"
        );
    }
}

/// A stored solution keeps its environment: the file read back renders the same picture.
#[test]
fn a_solution_file_keeps_the_environment() {
    let scene = parse(&scene_text(
        0.8,
        FORWARD,
        "discrete-ordinates",
        "[[light]]\nkind = \"directional\"\ndirection = [0.3, 0.4, -1.0]\nirradiance = 2.0\n",
    ));
    let solution = solve(&scene);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("env.volrad");
    solution.write(&path).unwrap();
    let read = Solution::read(&path).unwrap();
    assert_eq!(read.environment, scene.environment);
    let a = render_view(&solution, &scene.cameras[0], Some(1)).unwrap();
    let b = render_view(&read, &scene.cameras[0], Some(1)).unwrap();
    assert_eq!(a.pixels, b.pixels);
}

/// A 24×24×20 cloud under Preetham's sky and its sun (z up), seen level with the horizon.
fn sky_scene(method: &str, phase: &str) -> Scene {
    parse(
        &scene_text_at([24, 24, 20], 0.5, 0.9, phase, method, "")
            .replace(
                "kind = \"environment\"\nradiance = 0.5",
                "kind = \"sky\"\nsun_elevation_degrees = 40.0\nsun_azimuth_degrees = 60.0",
            )
            .replace("eye = [6.0, -20.0, 14.0]", "eye = [6.0, -20.0, 5.0]"),
    )
}

/// The sky is above the horizon (blue at the top of the frame), the ground below, the
/// sun is a light, the medium is solved in colour, and the solution renders what the path
/// tracer sees, channel by channel (3 % over the cloud): discrete ordinates (g = 0.6) take the
/// sky on their bins, zonal-hierarchical (isotropic) its fluence over 384 directions.
#[test]
fn a_sky_lights_the_cloud_from_above_as_the_path_tracer_sees_it() {
    for (method, phase) in [
        ("discrete-ordinates", FORWARD),
        ("zonal-hierarchical", ISOTROPIC),
    ] {
        sky_matches_the_path_tracer(method, phase);
    }
}

fn sky_matches_the_path_tracer(method: &str, phase: &str) {
    let scene = sky_scene(method, phase);
    assert_eq!(
        scene.medium.channels().len(),
        3,
        "a sky makes the medium coloured"
    );
    assert_eq!(scene.lights.len(), 1, "the sky places its sun");
    let image = render_view(&solve(&scene), &scene.cameras[0], Some(16)).unwrap();
    let (w, h) = (image.width as usize, image.height as usize);
    let px = |x: usize, y: usize| -> [f32; 3] {
        let i = 3 * (y * w + x);
        [image.pixels[i], image.pixels[i + 1], image.pixels[i + 2]]
    };
    let top = px(1, 0);
    let bottom = px(1, h - 1);
    assert!(top[2] > 1.2 * top[0], "the sky overhead is blue: {top:?}");
    // The ground is lit by the white sun and the blue sky: greyer than the sky.
    assert!(
        bottom[1] > 0.0 && bottom[2] / bottom[0] < top[2] / top[0],
        "the ground {bottom:?} is not greyer than the sky {top:?}"
    );
    for c in 0..3 {
        let traced = path_traced(&scene, c, 256);
        // Over the cloud: where the path tracer's pixel differs by 5 % from the bare sky or
        // ground of the render's edge column on the same row.
        let bare = |i: usize| {
            let (x, y) = (i % w, i / w);
            image.pixels[3 * (y * w + if x < w / 2 { 0 } else { w - 1 }) + c] as f64
        };
        let (rms, mean, count) = masked_error(&image, c, &traced, |i, r| {
            (r - bare(i)).abs() > 0.05 * bare(i)
        });
        println!(
            "sky, {method}, channel {c}: {count} cloud pixels, relative RMS {rms:.4}, mean {mean:+.4}"
        );
        assert!(
            count > 300,
            "{method}, channel {c}: only {count} cloud pixels"
        );
        assert!(
            rms < 0.03 && mean.abs() < 0.01,
            "{method}, channel {c}: relative RMS {rms:.4}, mean {mean:+.4}"
        );
    }
}

/// Writes an equirectangular map of `width × height` texels (row 0 the zenith, z up; column
/// `x` at azimuth `360° (x + ½)/width` counter-clockwise from +x) into `dir/name`, each texel
/// `texel(from)` for the unit direction `from` at its centre; `.pfm` or `.exr` by the name.
fn write_map(
    dir: &Path,
    name: &str,
    (width, height): (usize, usize),
    texel: impl Fn(glam::DVec3) -> [f32; 3],
) {
    let mut pixels = Vec::with_capacity(width * height * 3);
    for y in 0..height {
        let theta = std::f64::consts::PI * (y as f64 + 0.5) / height as f64;
        for x in 0..width {
            let phi = std::f64::consts::TAU * (x as f64 + 0.5) / width as f64;
            let from = glam::DVec3::new(
                theta.sin() * phi.cos(),
                theta.sin() * phi.sin(),
                theta.cos(),
            );
            pixels.extend(texel(from));
        }
    }
    gather::image_io::Image::new(width as u32, height as u32, 3, pixels)
        .unwrap()
        .save(&dir.join(name), 1.0)
        .unwrap();
}

/// The relative RMS and mean difference of `got` from `want` over channel `c` of their `n`
/// interleaved channels.
fn relative_difference(got: &[f32], want: &[f32], c: usize, n: usize) -> (f64, f64) {
    let (mut err2, mut ref2, mut diff, mut sum) = (0.0, 0.0, 0.0, 0.0);
    for (g, r) in got.iter().zip(want).skip(c).step_by(n) {
        let (g, r) = (*g as f64, *r as f64);
        err2 += (g - r) * (g - r);
        ref2 += r * r;
        diff += g - r;
        sum += r;
    }
    ((err2 / ref2).sqrt(), diff / sum)
}

/// The cloud of [`scene_text`] lit by the map `file` in `dir` instead of a uniform radiance.
fn map_scene(dir: &Path, file: &str, albedo: f64, phase: &str, method: &str) -> Scene {
    let text = scene_text(albedo, phase, method, "").replace(
        "kind = \"environment\"\nradiance = 0.5",
        &format!("kind = \"environment\"\nfile = \"{file}\""),
    );
    Scene::from_toml_str(&text, dir, Path::new("map-test.toml")).unwrap()
}

/// A map of one radiance everywhere is the uniform environment: the white furnace holds
/// (every pixel L to 0.5 %) in the zonal methods and discrete ordinates, read from PFM and
/// from EXR.
#[test]
fn a_map_of_one_radiance_is_the_uniform_environment() {
    let dir = tempfile::tempdir().unwrap();
    write_map(dir.path(), "grey.pfm", (64, 32), |_| [0.5; 3]);
    write_map(dir.path(), "grey.exr", (64, 32), |_| [0.5; 3]);
    for (file, method, phase) in [
        ("grey.pfm", "zonal-hierarchical", ISOTROPIC),
        ("grey.exr", "discrete-ordinates", FORWARD),
        ("grey.exr", "zonal", ISOTROPIC),
    ] {
        let scene = map_scene(dir.path(), file, 1.0, phase, method);
        assert!(!scene.environment.as_ref().unwrap().is_coloured(), "{file}");
        let image = render_view(&solve(&scene), &scene.cameras[0], Some(4)).unwrap();
        let worst = worst_relative_pixel(&image, 0.5);
        assert!(
            worst < 0.005,
            "{method} from {file}: a pixel is {:.2} % off",
            100.0 * worst
        );
    }
}

/// Preetham's sky sampled into a map (256 × 128 texels) and lit by its sun as a separate
/// directional light renders as the sky itself: the backdrop pixel by pixel (the map's
/// orientation) and the cloud within 2 % RMS per channel (the solvers read the map averaged
/// over texels of about 11°, the sky at their directions); a solution file keeps the map.
#[test]
fn a_map_of_the_sky_renders_as_the_sky() {
    let sky = sky_scene("discrete-ordinates", FORWARD);
    let environment = sky.environment.clone().unwrap();
    let dir = tempfile::tempdir().unwrap();
    write_map(dir.path(), "sky.pfm", (256, 128), |from| {
        [0, 1, 2].map(|c| environment.radiance_along(-from, c, 3) as f32)
    });
    let (to_sun, irradiance) = environment.sun().unwrap();
    let text = scene_text_at([24, 24, 20], 0.5, 0.9, FORWARD, "discrete-ordinates", "")
        .replace(
            "kind = \"environment\"\nradiance = 0.5",
            &format!(
                "kind = \"environment\"\nfile = \"sky.pfm\"\n\n[[light]]\nkind = \"directional\"\n\
                 direction = {:?}\nirradiance = {irradiance}",
                (-to_sun).to_array()
            ),
        )
        .replace("eye = [6.0, -20.0, 14.0]", "eye = [6.0, -20.0, 5.0]");
    let mapped = Scene::from_toml_str(&text, dir.path(), Path::new("sky-map.toml")).unwrap();
    assert_eq!(mapped.medium.channels().len(), 3, "a coloured map");
    let want = render_view(&solve(&sky), &sky.cameras[0], Some(4)).unwrap();
    let solution = solve(&mapped);
    let got = render_view(&solution, &mapped.cameras[0], Some(4)).unwrap();
    let w = want.width as usize;
    // The backdrop: the top and bottom rows (sky and ground), left and right of the cloud.
    for y in [0, want.height as usize - 1] {
        for x in [0, 1, w - 2, w - 1] {
            for c in 0..3 {
                let i = 3 * (y * w + x) + c;
                let (a, b) = (want.pixels[i] as f64, got.pixels[i] as f64);
                assert!(
                    (b / a - 1.0).abs() < 0.01,
                    "backdrop ({x}, {y}) channel {c}: {b} vs {a}"
                );
            }
        }
    }
    for c in 0..3 {
        let (rms, mean) = relative_difference(&got.pixels, &want.pixels, c, 3);
        println!("sky map, channel {c}: relative RMS {rms:.4}, mean {mean:+.4}");
        assert!(
            rms < 0.02 && mean.abs() < 0.01,
            "channel {c}: RMS {rms:.4}, mean {mean:+.4}"
        );
    }
    let path = dir.path().join("map.volrad");
    solution.write(&path).unwrap();
    let read = Solution::read(&path).unwrap();
    assert_eq!(read.environment, mapped.environment);
    let again = render_view(&read, &mapped.cameras[0], Some(4)).unwrap();
    assert_eq!(again.pixels, got.pixels);
}

/// A map's keys are checked when the scene is read, naming the key.
#[test]
fn environment_map_keys_are_checked() {
    let dir = tempfile::tempdir().unwrap();
    write_map(dir.path(), "grey.pfm", (8, 4), |_| [0.5; 3]);
    std::fs::write(dir.path().join("sky.png"), b"not a map").unwrap();
    let err = |extra: &str, file: &str| {
        let text = scene_text(0.9, ISOTROPIC, "zonal", "").replace(
            "kind = \"environment\"\nradiance = 0.5",
            &format!("kind = \"environment\"\nfile = \"{file}\"\n{extra}"),
        );
        Scene::from_toml_str(&text, dir.path(), Path::new("t.toml"))
            .err()
            .map(|e| e.to_string())
            .unwrap_or_default()
    };
    assert_eq!(err("scale = 2.0\nrotation_degrees = 30.0", "grey.pfm"), "");
    assert!(err("", "missing.exr").contains("light[0].file"));
    assert!(err("", "sky.png").contains(".exr or .pfm"));
    assert!(err("radiance = 0.5", "grey.pfm").contains("not both"));
    assert!(err("scale = -1.0", "grey.pfm").contains("light[0].scale"));
    assert!(err("up = [0.0, 0.0, 0.0]", "grey.pfm").contains("light[0].up"));
    let uniform_with_scale = scene_text(0.9, ISOTROPIC, "zonal", "")
        .replace("radiance = 0.5", "radiance = 0.5\nscale = 2.0");
    let e = Scene::from_toml_str(&uniform_with_scale, dir.path(), Path::new("t.toml"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("light[0].scale"), "{e}");
}

/// An EXR whose light comes from one bright texel over a dim sky gives the image of a
/// directional light of the same irradiance under a uniform sky (issue #20: to 1 %): the
/// texel is split off the map as that light, whose first bounce the render takes exactly.
#[test]
fn a_map_with_one_bright_texel_is_a_directional_light() {
    let (w, h, x0, y0) = (256usize, 128usize, 32usize, 40usize);
    let (t0, t1) = (
        std::f64::consts::PI * y0 as f64 / h as f64,
        std::f64::consts::PI * (y0 + 1) as f64 / h as f64,
    );
    let omega = (t0.cos() - t1.cos()) * std::f64::consts::TAU / w as f64;
    let (theta, phi) = (
        0.5 * (t0 + t1),
        std::f64::consts::TAU * (x0 as f64 + 0.5) / w as f64,
    );
    let to_texel = glam::DVec3::new(
        theta.sin() * phi.cos(),
        theta.sin() * phi.sin(),
        theta.cos(),
    );
    let dir = tempfile::tempdir().unwrap();
    write_map(dir.path(), "sun.exr", (w, h), |from| {
        if from.dot(to_texel) > 1.0 - 1e-12 {
            [(1.0 / omega) as f32; 3]
        } else {
            [0.05; 3]
        }
    });
    for (method, phase) in [
        ("discrete-ordinates", FORWARD),
        ("zonal-hierarchical", ISOTROPIC),
    ] {
        let text = scene_text_at([24, 24, 20], 0.5, 0.9, phase, method, "")
            .replace("eye = [6.0, -20.0, 14.0]", "eye = [6.0, -20.0, 8.0]");
        let mapped = Scene::from_toml_str(
            &text.replace(
                "kind = \"environment\"\nradiance = 0.5",
                "kind = \"environment\"\nfile = \"sun.exr\"",
            ),
            dir.path(),
            Path::new("sun-map.toml"),
        )
        .unwrap();
        assert_eq!(mapped.lights.len(), 1, "the texel is a light");
        let lit = parse(&text.replace(
            "kind = \"environment\"\nradiance = 0.5",
            &format!(
                "kind = \"environment\"\nradiance = 0.05\n\n[[light]]\nkind = \"directional\"\n\
                 direction = {:?}\nirradiance = 1.0",
                (-to_texel).to_array()
            ),
        ));
        let want = render_view(&solve(&lit), &lit.cameras[0], Some(4)).unwrap();
        let got = render_view(&solve(&mapped), &mapped.cameras[0], Some(4)).unwrap();
        assert_eq!(got.channels, 1, "a grey map and a grey medium");
        let (rms, mean) = relative_difference(&got.pixels, &want.pixels, 0, 1);
        println!("one bright texel, {method}: relative RMS {rms:.5}, mean {mean:+.5}");
        assert!(
            rms < 0.01 && mean.abs() < 0.01,
            "{method}: RMS {rms:.4}, mean {mean:+.4}"
        );
    }
}
