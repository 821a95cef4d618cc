//! Scene files: the contract's example parses with its defaults, every bad input of
//! scene-format.md is refused naming the file and the key, and the extensions work.

use std::path::{Path, PathBuf};

use medium::volume_io::{
    write_mitsuba_vol, write_nrrd, write_raw_f32, NrrdWriteOptions, VolumeData,
};
use medium::{CellValues, Interpolation, Light, PhaseFunction};
use scene::{OpticalModel, Projection, SceneOrigin, SolveMethod, VolumeSource};
use scene::{Scene, SceneError};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("volrad-scene-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A 4×3×2 raw volume with values 0..24 / 24 next to the scene.
fn write_volume(dir: &Path) {
    let values: Vec<f32> = (0..24).map(|i| i as f32 / 24.0).collect();
    write_raw_f32(
        &dir.join("vol.f32"),
        &VolumeData::new([4, 3, 2], values).unwrap(),
    )
    .unwrap();
}

const VOLUME: &str = "[volume]\nfile = \"vol.f32\"\ndims = [4, 3, 2]\n";
const MEDIUM: &str = "[medium]\nalbedo = 0.9\n";
const LIGHT: &str =
    "[[light]]\nkind = \"directional\"\ndirection = [0.0, -2.0, 0.0]\nirradiance = 1.5\n";
const CAMERA: &str = "[[camera]]\nname = \"front\"\neye = [2.0, 1.5, -10.0]\ntarget = [2.0, 1.5, 1.0]\nup = [0.0, 1.0, 0.0]\nfov_y = 40.0\nwidth = 16\nheight = 12\n";

fn scene_text(parts: &[&str]) -> String {
    parts.join("\n")
}

fn parse_in(dir: &Path, text: &str) -> Result<Scene, SceneError> {
    let path = dir.join("scene.toml");
    std::fs::write(&path, text).unwrap();
    Scene::from_file(&path)
}

/// Parses `text` next to the standard volume and returns (key, full message) of the error.
fn refused(name: &str, text: &str) -> (String, String) {
    let dir = scratch(name);
    write_volume(&dir);
    let err = parse_in(&dir, text).expect_err("scene should be refused");
    let full = err.to_string();
    match err {
        SceneError::Invalid { file, key, .. } => {
            assert_eq!(file, dir.join("scene.toml"), "{full}");
            assert!(full.contains("scene.toml"), "{full}");
            (key, full)
        }
        other => panic!("expected a scene error, got {other:?}"),
    }
}

fn assert_refused(name: &str, text: &str, key: &str, words: &[&str]) {
    let (k, msg) = refused(name, text);
    assert_eq!(k, key, "{msg}");
    assert!(msg.contains(key), "{msg}");
    for w in words {
        assert!(msg.contains(w), "expected `{w}` in: {msg}");
    }
}

#[test]
fn minimal_scene_gets_the_contract_defaults() {
    let dir = scratch("minimal");
    write_volume(&dir);
    let s = parse_in(&dir, &scene_text(&[VOLUME, MEDIUM, LIGHT, CAMERA])).unwrap();
    let m = &s.medium;
    assert_eq!(m.grid().dims, [4, 3, 2]);
    assert_eq!(m.grid().cell_size, 1.0);
    // Smooth pictures unless the scene asks for cells (issue 24; `nearest` before).
    assert_eq!(m.interpolation(), Interpolation::Trilinear);
    assert_eq!(m.phase(), PhaseFunction::Isotropic);
    assert_eq!(m.channels().len(), 1);
    // σt = value × 1.0, x fastest.
    assert_eq!(m.channels()[0].sigma_t[5], 5.0 / 24.0);
    assert_eq!(m.channels()[0].albedo, CellValues::Uniform(0.9));
    assert!(m.channels()[0].emission.is_zero());
    assert_eq!(m.data().as_ref().unwrap().len(), 24);
    assert_eq!(s.background, 0.0);
    assert_eq!(s.solve.method, SolveMethod::ZonalHierarchical);
    // The fastest robust iteration for the hierarchical zonal system (docs/albedo.md).
    assert_eq!(s.solve.iteration, solver::Method::DsaCg);
    assert_eq!(s.solve.tolerance, 1e-5);
    assert_eq!(s.solve.max_iterations, 2000);
    assert_eq!(s.solve.photons, 1 << 21);
    assert_eq!(s.solve.bins, scene::BinCount::Auto);
    assert_eq!(s.render.model, OpticalModel::Scattering);
    assert_eq!(
        s.render.exposure, None,
        "automatic unless the scene sets it"
    );
    assert_eq!(s.render.spp, 1);
    // The direction is normalised on load.
    match s.lights[0] {
        Light::Directional {
            direction,
            irradiance,
        } => {
            assert!((direction - glam::DVec3::new(0.0, -1.0, 0.0)).length() < 1e-12);
            assert_eq!(irradiance, 1.5);
        }
        other => panic!("{other:?}"),
    }
    assert_eq!(s.cameras[0].name, "front");
    assert_eq!(
        s.cameras[0].projection,
        Projection::Perspective {
            fov_y_degrees: 40.0
        }
    );
    assert_eq!(s.origin, SceneOrigin::File(dir.join("scene.toml")));
    assert_eq!(s.source, VolumeSource::File(dir.join("vol.f32")));
}

/// `interpolation`: `trilinear` when the scene does not say, and either spelling as written;
/// the default changes the look only, not the medium the solvers see.
#[test]
fn interpolation_defaults_to_trilinear_and_nearest_stays() {
    let dir = scratch("interpolation");
    write_volume(&dir);
    let parse = |line: &str| {
        parse_in(
            &dir,
            &scene_text(&[&format!("{VOLUME}{line}"), MEDIUM, LIGHT, CAMERA]),
        )
        .unwrap()
        .medium
    };
    let default = parse("");
    let nearest = parse("interpolation = \"nearest\"\n");
    let trilinear = parse("interpolation = \"trilinear\"\n");
    assert_eq!(default.interpolation(), Interpolation::Trilinear);
    assert_eq!(nearest.interpolation(), Interpolation::Nearest);
    assert_eq!(trilinear, default);
    assert_eq!(
        nearest.with_interpolation(Interpolation::Trilinear),
        default
    );
}

#[test]
fn full_contract_example_parses() {
    let dir = scratch("full");
    write_volume(&dir);
    let text = r#"
[volume]
file = "vol.f32"
dims = [4, 3, 2]
sigma_t_scale = 2.0
cell_size = 0.5
interpolation = "trilinear"

[medium]
albedo = 0.99
phase = { kind = "henyey-greenstein", g = 0.6 }
emission = 0.25

[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.2]
irradiance = 1.0

[background]
radiance = 0.1

[solve]
method = "discrete-ordinates"
bins = 54
iteration = "jacobi"
tolerance = 1e-4
max_iterations = 50

[[camera]]
name = "front"
eye = [12.0, 40.0, -30.0]
target = [12.0, 12.0, 9.0]
up = [0.0, 1.0, 0.0]
fov_y = 40.0
width = 256
height = 192
"#;
    let s = parse_in(&dir, text).unwrap();
    assert_eq!(s.medium.channels()[0].sigma_t[3], 2.0 * 3.0 / 24.0);
    assert_eq!(s.medium.grid().cell_size, 0.5);
    assert_eq!(s.medium.interpolation(), Interpolation::Trilinear);
    assert_eq!(s.medium.phase(), PhaseFunction::HenyeyGreenstein { g: 0.6 });
    assert_eq!(s.medium.channels()[0].emission, CellValues::Uniform(0.25));
    assert_eq!(s.background, 0.1);
    assert_eq!(s.solve.method, SolveMethod::DiscreteOrdinates);
    assert_eq!(s.solve.bins, scene::BinCount::Fixed(54));
    assert_eq!(s.solve.iteration, solver::Method::Jacobi);
    assert_eq!(s.solve.tolerance, 1e-4);
    assert_eq!(s.solve.max_iterations, 50);
    assert_eq!((s.cameras[0].width, s.cameras[0].height), (256, 192));
}

#[test]
fn default_method_follows_the_phase_function_and_render_model_the_method() {
    let dir = scratch("defaults");
    write_volume(&dir);
    let hg = "[medium]\nalbedo = 0.9\nphase = { kind = \"henyey-greenstein\", g = 0.3 }\n";
    let s = parse_in(&dir, &scene_text(&[VOLUME, hg, LIGHT, CAMERA])).unwrap();
    assert_eq!(s.solve.method, SolveMethod::DiscreteOrdinates);
    let none = "[solve]\nmethod = \"none\"\n";
    let s = parse_in(&dir, &scene_text(&[VOLUME, MEDIUM, LIGHT, none, CAMERA])).unwrap();
    assert_eq!(s.render.model, OpticalModel::EmissionAbsorption);
    let render = "[render]\nmodel = \"absorption-only\"\nexposure = 2.5\nspp = 4\n";
    let s = parse_in(&dir, &scene_text(&[VOLUME, MEDIUM, LIGHT, render, CAMERA])).unwrap();
    assert_eq!(s.render.model, OpticalModel::AbsorptionOnly);
    assert_eq!((s.render.exposure, s.render.spp), (Some(2.5), 4));
}

// --- every bad input of the contract -------------------------------------------------------

#[test]
fn unknown_keys_are_refused_with_their_path() {
    let t = |extra_volume: &str, extra_medium: &str, extra_light: &str, extra_top: &str| {
        scene_text(&[
            extra_top,
            &format!("{VOLUME}{extra_volume}"),
            &format!("{MEDIUM}{extra_medium}"),
            &format!("{LIGHT}{extra_light}"),
            CAMERA,
        ])
    };
    assert_refused(
        "unk-top",
        &t("", "", "", "colour = 1\n"),
        "colour",
        &["unknown key"],
    );
    assert_refused(
        "unk-vol",
        &t("sigma_t_scal = 2.0\n", "", "", ""),
        "volume.sigma_t_scal",
        &["unknown key", "sigma_t_scale"],
    );
    assert_refused(
        "unk-med",
        &t("", "albdo = 0.5\n", "", ""),
        "medium.albdo",
        &["unknown key"],
    );
    assert_refused(
        "unk-light",
        &t("", "", "colour = 1.0\n", ""),
        "light[0].colour",
        &["unknown key", "directional"],
    );
    assert_refused(
        "unk-phase",
        &t(
            "",
            "phase = { kind = \"henyey-greenstein\", g = 0.5, k = 1 }\n",
            "",
            "",
        ),
        "medium.phase.k",
        &["unknown key"],
    );
    assert_refused(
        "unk-cam",
        &scene_text(&[VOLUME, MEDIUM, LIGHT, &format!("{CAMERA}fov = 3\n")]),
        "camera[0].fov",
        &["unknown key"],
    );
    assert_refused(
        "unk-solve",
        &scene_text(&[VOLUME, MEDIUM, LIGHT, "[solve]\ntol = 1e-3\n", CAMERA]),
        "solve.tol",
        &["unknown key"],
    );
}

#[test]
fn missing_required_keys_are_refused() {
    assert_refused(
        "miss-vol",
        &scene_text(&[MEDIUM, LIGHT, CAMERA]),
        "volume",
        &["missing"],
    );
    assert_refused(
        "miss-albedo",
        &scene_text(&[VOLUME, "[medium]\n", LIGHT, CAMERA]),
        "medium.albedo",
        &["missing"],
    );
    assert_refused(
        "miss-dims",
        &scene_text(&["[volume]\nfile = \"vol.f32\"\n", MEDIUM, LIGHT, CAMERA]),
        "volume.dims",
        &["missing"],
    );
    assert_refused(
        "miss-file",
        &scene_text(&["[volume]\ndims = [4, 3, 2]\n", MEDIUM, LIGHT, CAMERA]),
        "volume.file",
        &["missing"],
    );
    // Cameras are render-time: a scene without any is complete (solve, info, the service).
    let dir = scratch("miss-cam");
    write_volume(&dir);
    let no_camera = parse_in(&dir, &scene_text(&[VOLUME, MEDIUM, LIGHT])).unwrap();
    assert!(no_camera.cameras.is_empty());
    assert_refused(
        "empty-cam",
        &scene_text(&["camera = []\n", VOLUME, MEDIUM, LIGHT]),
        "camera",
        &["at least one"],
    );
    assert_refused(
        "miss-irr",
        &scene_text(&[
            VOLUME,
            MEDIUM,
            "[[light]]\nkind = \"directional\"\ndirection = [0, -1, 0]\n",
            CAMERA,
        ]),
        "light[0].irradiance",
        &["missing"],
    );
    assert_refused(
        "miss-fov",
        &scene_text(&[VOLUME, MEDIUM, LIGHT, &CAMERA.replace("fov_y = 40.0\n", "")]),
        "camera[0].fov_y",
        &["missing"],
    );
    assert_refused(
        "miss-g",
        &scene_text(&[
            VOLUME,
            "[medium]\nalbedo = 0.5\nphase = { kind = \"henyey-greenstein\" }\n",
            LIGHT,
            CAMERA,
        ]),
        "medium.phase.g",
        &["missing"],
    );
}

#[test]
fn a_volume_file_of_the_wrong_size_is_refused() {
    let (key, msg) = refused(
        "size",
        &scene_text(&[
            "[volume]\nfile = \"vol.f32\"\ndims = [4, 3, 3]\n",
            MEDIUM,
            LIGHT,
            CAMERA,
        ]),
    );
    assert_eq!(key, "volume.dims");
    assert!(
        msg.contains("vol.f32") && msg.contains("96 bytes") && msg.contains("144 bytes"),
        "{msg}"
    );
    // A missing volume file names the file too.
    let (key, msg) = refused(
        "nofile",
        &scene_text(&[
            "[volume]\nfile = \"missing.f32\"\ndims = [4, 3, 2]\n",
            MEDIUM,
            LIGHT,
            CAMERA,
        ]),
    );
    assert_eq!(key, "volume.file");
    assert!(msg.contains("missing.f32"), "{msg}");
    assert_refused(
        "zero-dim",
        &scene_text(&[
            "[volume]\nfile = \"vol.f32\"\ndims = [4, 0, 2]\n",
            MEDIUM,
            LIGHT,
            CAMERA,
        ]),
        "volume.dims",
        &["≥ 1"],
    );
}

#[test]
fn negative_and_non_finite_values_are_refused() {
    let vol = |extra: &str| format!("{VOLUME}{extra}");
    assert_refused(
        "neg-scale",
        &scene_text(&[&vol("sigma_t_scale = -1.0\n"), MEDIUM, LIGHT, CAMERA]),
        "volume.sigma_t_scale",
        &["≥ 0"],
    );
    assert_refused(
        "nan-scale",
        &scene_text(&[&vol("sigma_t_scale = nan\n"), MEDIUM, LIGHT, CAMERA]),
        "volume.sigma_t_scale",
        &["finite"],
    );
    assert_refused(
        "inf-cell",
        &scene_text(&[&vol("cell_size = inf\n"), MEDIUM, LIGHT, CAMERA]),
        "volume.cell_size",
        &["finite"],
    );
    assert_refused(
        "zero-cell",
        &scene_text(&[&vol("cell_size = 0.0\n"), MEDIUM, LIGHT, CAMERA]),
        "volume.cell_size",
        &["> 0"],
    );
    assert_refused(
        "neg-emis",
        &scene_text(&[
            VOLUME,
            "[medium]\nalbedo = 0.5\nemission = -0.1\n",
            LIGHT,
            CAMERA,
        ]),
        "medium.emission",
        &["≥ 0"],
    );
    assert_refused(
        "neg-irr",
        &scene_text(&[VOLUME, MEDIUM, &LIGHT.replace("1.5", "-1.5"), CAMERA]),
        "light[0].irradiance",
        &["negative"],
    );
    assert_refused(
        "nan-dir",
        &scene_text(&[VOLUME, MEDIUM, &LIGHT.replace("-2.0", "nan"), CAMERA]),
        "light[0].direction",
        &["finite"],
    );
    assert_refused(
        "neg-bg",
        &scene_text(&[
            VOLUME,
            MEDIUM,
            LIGHT,
            "[background]\nradiance = -1\n",
            CAMERA,
        ]),
        "background.radiance",
        &["negative"],
    );
    assert_refused(
        "neg-tol",
        &scene_text(&[
            VOLUME,
            MEDIUM,
            LIGHT,
            "[solve]\ntolerance = -1e-5\n",
            CAMERA,
        ]),
        "solve.tolerance",
        &["> 0"],
    );
    for (name, photons) in [
        ("few-photons", "10"),
        ("many-photons", "4e12"),
        ("frac-photons", "1500.5"),
    ] {
        assert_refused(
            name,
            &scene_text(&[
                VOLUME,
                MEDIUM,
                LIGHT,
                &format!("[solve]\nmethod = \"two-pass\"\nphotons = {photons}\n"),
                CAMERA,
            ]),
            "solve.photons",
            &[],
        );
    }
    let dir = scratch("photons-ok");
    write_volume(&dir);
    let text = scene_text(&[
        VOLUME,
        MEDIUM,
        LIGHT,
        "[solve]\nmethod = \"two-pass\"\nphotons = 50000\n",
        CAMERA,
    ]);
    assert_eq!(parse_in(&dir, &text).unwrap().solve.photons, 50_000);

    // Negative or non-finite values inside the volume file.
    let dir = scratch("neg-data");
    let mut values: Vec<f32> = vec![0.5; 24];
    values[13] = -2.0;
    write_raw_f32(
        &dir.join("vol.f32"),
        &VolumeData::new([4, 3, 2], values.clone()).unwrap(),
    )
    .unwrap();
    let err = parse_in(&dir, &scene_text(&[VOLUME, MEDIUM, LIGHT, CAMERA]))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("volume.file") && err.contains("(1, 0, 1)") && err.contains("-2"),
        "{err}"
    );
    values[13] = f32::NAN;
    write_raw_f32(
        &dir.join("vol.f32"),
        &VolumeData::new([4, 3, 2], values).unwrap(),
    )
    .unwrap();
    let err = parse_in(&dir, &scene_text(&[VOLUME, MEDIUM, LIGHT, CAMERA]))
        .unwrap_err()
        .to_string();
    assert!(err.contains("volume.file") && err.contains("NaN"), "{err}");
}

#[test]
fn albedo_outside_unit_interval_is_refused() {
    for (name, albedo) in [
        ("a-hi", "1.01"),
        ("a-lo", "-0.1"),
        ("a-rgb", "[0.5, 1.2, 0.5]"),
    ] {
        assert_refused(
            name,
            &scene_text(&[
                VOLUME,
                &format!("[medium]\nalbedo = {albedo}\n"),
                LIGHT,
                CAMERA,
            ]),
            "medium.albedo",
            &["[0, 1]"],
        );
    }
    let table =
        "[medium]\nalbedo = { kind = \"piecewise-linear\", points = [[0.0, 0.5], [1.0, 1.5]] }\n";
    assert_refused(
        "a-table",
        &scene_text(&[VOLUME, table, LIGHT, CAMERA]),
        "medium.albedo",
        &["[0, 1]", "1.5"],
    );
    let unsorted =
        "[medium]\nalbedo = { kind = \"piecewise-linear\", points = [[1.0, 0.5], [0.0, 0.9]] }\n";
    assert_refused(
        "a-unsorted",
        &scene_text(&[VOLUME, unsorted, LIGHT, CAMERA]),
        "medium.albedo.points",
        &["increasing"],
    );
    let particle = "[medium]\nalbedo = { kind = \"particle\", c = 0.5 }\n";
    assert_refused(
        "a-particle",
        &scene_text(&[VOLUME, particle, LIGHT, CAMERA]),
        "medium.albedo.kind",
        &["unknown kind"],
    );
    // A mistyped emission kind names every kind emission takes, blackbody included; albedo
    // does not offer it.
    let typo = "[medium]\nalbedo = 0.5\nemission = { kind = \"blackbodi\", temperature = 1500 }\n";
    assert_refused(
        "e-typo",
        &scene_text(&[VOLUME, typo, LIGHT, CAMERA]),
        "medium.emission.kind",
        &["unknown kind", "blackbody", "particle"],
    );
    let albedo_bb = "[medium]\nalbedo = { kind = \"blackbody\", temperature = 1500 }\n";
    assert_refused(
        "a-blackbody",
        &scene_text(&[VOLUME, albedo_bb, LIGHT, CAMERA]),
        "medium.albedo.kind",
        &["unknown kind"],
    );
}

#[test]
fn asymmetry_of_magnitude_one_or_more_is_refused() {
    for (name, phase, key) in [
        (
            "g1",
            "{ kind = \"henyey-greenstein\", g = 1.0 }",
            "medium.phase.g",
        ),
        (
            "gneg",
            "{ kind = \"henyey-greenstein\", g = -1.5 }",
            "medium.phase.g",
        ),
        (
            "g2",
            "{ kind = \"two-lobe\", r = 0.12, g1 = -0.5, g2 = 1.0 }",
            "medium.phase.g2",
        ),
    ] {
        assert_refused(
            name,
            &scene_text(&[
                VOLUME,
                &format!("[medium]\nalbedo = 0.5\nphase = {phase}\n"),
                LIGHT,
                CAMERA,
            ]),
            key,
            &["|g| < 1"],
        );
    }
    assert_refused(
        "phase-kind",
        &scene_text(&[
            VOLUME,
            "[medium]\nalbedo = 0.5\nphase = { kind = \"rayleigh\" }\n",
            LIGHT,
            CAMERA,
        ]),
        "medium.phase.kind",
        &["rayleigh", "henyey-greenstein"],
    );
}

#[test]
fn zero_light_direction_is_refused() {
    assert_refused(
        "zero-dir",
        &scene_text(&[
            VOLUME,
            MEDIUM,
            &LIGHT.replace("[0.0, -2.0, 0.0]", "[0, 0, 0]"),
            CAMERA,
        ]),
        "light[0].direction",
        &["zero"],
    );
    let spot = "[[light]]\nkind = \"spot\"\nposition = [2, 8, 1]\naxis = [0, 0, 0]\nhalf_angle_degrees = 20\nintensity = 5\n";
    assert_refused(
        "zero-axis",
        &scene_text(&[VOLUME, MEDIUM, spot, CAMERA]),
        "light[0].axis",
        &["zero"],
    );
    assert_refused(
        "light-kind",
        &scene_text(&[VOLUME, MEDIUM, "[[light]]\nkind = \"laser\"\n", CAMERA]),
        "light[0].kind",
        &["laser", "directional"],
    );
}

#[test]
fn unknown_method_names_are_refused() {
    assert_refused(
        "method",
        &scene_text(&[
            VOLUME,
            MEDIUM,
            LIGHT,
            "[solve]\nmethod = \"monte-carlo\"\n",
            CAMERA,
        ]),
        "solve.method",
        &["monte-carlo", "discrete-ordinates"],
    );
    assert_refused(
        "iter",
        &scene_text(&[
            VOLUME,
            MEDIUM,
            LIGHT,
            "[solve]\niteration = \"sor\"\n",
            CAMERA,
        ]),
        "solve.iteration",
        &["sor"],
    );
    assert_refused(
        "bins",
        &scene_text(&[VOLUME, MEDIUM, LIGHT, "[solve]\nbins = 100\n", CAMERA]),
        "solve.bins",
        &["6n²"],
    );
    assert_refused(
        "model",
        &scene_text(&[
            VOLUME,
            MEDIUM,
            LIGHT,
            "[render]\nmodel = \"xray\"\n",
            CAMERA,
        ]),
        "render.model",
        &["xray", "absorption-only"],
    );
    assert_refused(
        "interp",
        &scene_text(&[
            &format!("{VOLUME}interpolation = \"cubic\"\n"),
            MEDIUM,
            LIGHT,
            CAMERA,
        ]),
        "volume.interpolation",
        &["cubic"],
    );
}

#[test]
fn no_light_is_allowed_only_with_emission() {
    assert_refused(
        "dark",
        &scene_text(&[VOLUME, MEDIUM, CAMERA]),
        "light",
        &["no light and no emission"],
    );
    let dir = scratch("glow");
    write_volume(&dir);
    let s = parse_in(
        &dir,
        &scene_text(&[VOLUME, "[medium]\nalbedo = 0.0\nemission = 0.3\n", CAMERA]),
    )
    .unwrap();
    assert!(s.lights.is_empty());
    // Zero emission everywhere still counts as none.
    assert_refused(
        "dark-table",
        &scene_text(&[
            VOLUME,
            "[medium]\nalbedo = 0.5\nemission = { kind = \"particle\", c = 0.0 }\n",
            CAMERA,
        ]),
        "light",
        &["no light"],
    );
}

#[test]
fn syntax_errors_and_wrong_types_name_where() {
    let (key, msg) = refused("syntax", &format!("{VOLUME}\n[medium\nalbedo = 0.5\n"));
    assert!(key.starts_with("(line"), "{key}: {msg}");
    assert_refused(
        "type",
        &scene_text(&[VOLUME, "[medium]\nalbedo = \"high\"\n", LIGHT, CAMERA]),
        "medium.albedo",
        &["a number"],
    );
    assert_refused(
        "dims-type",
        &scene_text(&[
            "[volume]\nfile = \"vol.f32\"\ndims = [4, 3]\n",
            MEDIUM,
            LIGHT,
            CAMERA,
        ]),
        "volume.dims",
        &["3 elements"],
    );
    assert_refused(
        "dup-cam",
        &scene_text(&[VOLUME, MEDIUM, LIGHT, CAMERA, CAMERA]),
        "camera[1].name",
        &["duplicate"],
    );
}

// --- extensions ----------------------------------------------------------------------------

#[test]
fn transfer_tables_particle_emission_and_rgb_channels() {
    let dir = scratch("transfer");
    write_volume(&dir);
    let text = scene_text(&[
        "[volume]\nfile = \"vol.f32\"\ndims = [4, 3, 2]\nsigma_t_scale = [1.0, 2.0, 4.0]\n",
        "[medium]\nalbedo = { kind = \"piecewise-linear\", points = [[0.0, 0.5], [1.0, 0.99]] }\nemission = { kind = \"particle\", c = 0.5 }\n",
        CAMERA,
    ]);
    let s = parse_in(&dir, &text).unwrap();
    assert_eq!(s.medium.channels().len(), 3);
    for (c, scale) in [1.0f32, 2.0, 4.0].iter().enumerate() {
        let ch = &s.medium.channels()[c];
        for cell in [0, 7, 23] {
            let value = cell as f32 / 24.0;
            assert!((ch.sigma_t[cell] - scale * value).abs() < 1e-6);
            let a = 0.5 + 0.49 * value as f64;
            assert!((ch.albedo.get(cell) as f64 - a).abs() < 1e-6);
            // Max eq. 8: emission = C σt.
            assert!((ch.emission.get(cell) - 0.5 * ch.sigma_t[cell]).abs() < 1e-6);
        }
    }
    // A σt table, a preset and an RGB table.
    let text = scene_text(&[
        "[volume]\nfile = \"vol.f32\"\ndims = [4, 3, 2]\nsigma_t_scale = 3.0\nsigma_t = { kind = \"preset\", name = \"threshold\" }\n",
        "[medium]\nalbedo = { kind = \"piecewise-linear\", points = [[0.0, 0.2, 0.4, 0.6], [1.0, 0.3, 0.5, 0.7]] }\n",
        LIGHT,
        CAMERA,
    ]);
    let s = parse_in(&dir, &text).unwrap();
    assert_eq!(s.medium.channels().len(), 3);
    let ch = &s.medium.channels()[1];
    assert_eq!(ch.sigma_t[0], 0.0); // value 0 < 0.2
    assert_eq!(ch.sigma_t[23], 3.0); // value 0.958 > 0.3
    assert!((ch.sigma_t[6] - 3.0 * 0.5).abs() < 1e-6); // value 0.25, halfway up the ramp
    assert!((s.medium.channels()[2].albedo.get(0) - 0.6).abs() < 1e-6);
    assert_refused(
        "preset-name",
        &scene_text(&[
            VOLUME,
            "[medium]\nalbedo = { kind = \"preset\", name = \"glow\" }\n",
            LIGHT,
            CAMERA,
        ]),
        "medium.albedo.name",
        &["glow", "smoothstep"],
    );
}

#[test]
fn generators_headered_files_lights_and_orthographic_cameras() {
    let dir = scratch("gen");
    let gen = "[volume]\ngenerator = { kind = \"cloud\", seed = 3 }\ndims = [16, 12, 10]\nsigma_t_scale = 2.0\n";
    let spot = "[[light]]\nkind = \"spot\"\nposition = [8, 20, 5]\naxis = [0, -1, 0]\nhalf_angle_degrees = 30\nintensity = 100\n\n[[light]]\nkind = \"point\"\nposition = [8, 6, -5]\nintensity = 10\n";
    let ortho = "[[camera]]\nname = \"side\"\neye = [-20, 6, 5]\ntarget = [8, 6, 5]\nup = [0, 1, 0]\nprojection = \"orthographic\"\northo_height = 14.0\nwidth = 8\nheight = 8\n";
    let s = parse_in(&dir, &scene_text(&[gen, MEDIUM, spot, ortho])).unwrap();
    assert_eq!(
        s.source,
        VolumeSource::Generator(medium::generators::Generator::Cloud { seed: 3 })
    );
    let peak = s.medium.channels()[0].max_sigma_t();
    assert!((peak - 2.0).abs() < 1e-6, "{peak}");
    assert_eq!(s.lights.len(), 2);
    match s.lights[0] {
        Light::Spot { half_angle, .. } => assert!((half_angle - 30f64.to_radians()).abs() < 1e-12),
        other => panic!("{other:?}"),
    }
    assert_eq!(
        s.cameras[0].projection,
        Projection::Orthographic { height: 14.0 }
    );
    assert_refused(
        "ortho-miss",
        &scene_text(&[
            VOLUME,
            MEDIUM,
            LIGHT,
            &ortho.replace("ortho_height = 14.0\n", ""),
        ]),
        "camera[0].ortho_height",
        &["missing"],
    );
    assert_refused(
        "both",
        &scene_text(&[
            &format!("{VOLUME}generator = {{ kind = \"dipole\" }}\n"),
            MEDIUM,
            LIGHT,
            CAMERA,
        ]),
        "volume.generator",
        &["not both"],
    );
    assert_refused(
        "gen-kind",
        &scene_text(&[
            "[volume]\ngenerator = { kind = \"smoke\" }\ndims = [4, 4, 4]\n",
            MEDIUM,
            LIGHT,
            CAMERA,
        ]),
        "volume.generator.kind",
        &["smoke", "cloud"],
    );
    assert_refused(
        "gen-nodims",
        &scene_text(&[
            "[volume]\ngenerator = { kind = \"dipole\" }\n",
            MEDIUM,
            LIGHT,
            CAMERA,
        ]),
        "volume.dims",
        &["missing"],
    );

    // Headered files need no dims; given dims must agree.
    let v = VolumeData::new([2, 3, 4], (0..24).map(|i| i as f32).collect()).unwrap();
    write_mitsuba_vol(&dir.join("v.vol"), &v, 1.0).unwrap();
    write_nrrd(
        &dir.join("v.nrrd"),
        &v,
        &NrrdWriteOptions {
            gzip: true,
            ..Default::default()
        },
    )
    .unwrap();
    for name in ["v.vol", "v.nrrd"] {
        let s = parse_in(
            &dir,
            &scene_text(&[
                &format!("[volume]\nfile = \"{name}\"\n"),
                MEDIUM,
                LIGHT,
                CAMERA,
            ]),
        )
        .unwrap();
        assert_eq!(s.medium.grid().dims, [2, 3, 4]);
        assert_eq!(s.medium.channels()[0].sigma_t[23], 23.0);
        let err = parse_in(
            &dir,
            &scene_text(&[
                &format!("[volume]\nfile = \"{name}\"\ndims = [4, 3, 2]\n"),
                MEDIUM,
                LIGHT,
                CAMERA,
            ]),
        )
        .unwrap_err()
        .to_string();
        assert!(
            err.contains("volume.file") && err.contains("[2, 3, 4]"),
            "{err}"
        );
    }
}

/// `[solve] bins` is `"auto"` (volrad chooses from the medium) or one of the `6 n²` counts;
/// any other string or count is refused naming the key and what it expects.
#[test]
fn solve_bins_are_auto_or_a_valid_count() {
    let dir = scratch("bins");
    write_volume(&dir);
    let parse = |solve: &str| {
        let text = scene_text(&[VOLUME, MEDIUM, LIGHT, solve, CAMERA]);
        Scene::from_toml_str(&text, &dir, &dir.join("scene.toml"))
    };
    assert_eq!(
        parse("[solve]\nbins = \"auto\"\n").unwrap().solve.bins,
        scene::BinCount::Auto
    );
    assert_eq!(
        parse("[solve]\nbins = 216\n").unwrap().solve.bins,
        scene::BinCount::Fixed(216)
    );
    assert_eq!(
        parse("[solve]\nbins = 864\n").unwrap().solve.bins,
        scene::BinCount::Fixed(864)
    );
    for bad in ["bins = \"many\"", "bins = 97", "bins = 1014"] {
        let err = parse(&format!("[solve]\n{bad}\n")).unwrap_err().to_string();
        assert!(
            err.contains("solve.bins") && err.contains("auto") && err.contains("6n²"),
            "{bad}: {err}"
        );
    }
    // The count a solve sweeps: the scene's, or the rule's on the medium it is given.
    let hg = PhaseFunction::HenyeyGreenstein { g: 0.6 };
    assert_eq!(scene::BinCount::Fixed(54).count(&hg, 1000), 54);
    assert_eq!(scene::BinCount::Auto.count(&hg, 1000), 216);
    assert_eq!(
        scene::BinCount::Auto.count(&PhaseFunction::Isotropic, 1000),
        96
    );
}

#[test]
fn builtin_default_is_the_sky_lit_cloud_sample_and_its_camera_sees_all_of_it() {
    let s = Scene::builtin_default().unwrap();
    assert_eq!(s.origin, SceneOrigin::BuiltIn("sky-lit cloud"));
    // The same scene as data/cloud-sky.toml: one built-in scene, not a second copy.
    let sample = Scene::from_file(
        &PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../data/cloud-sky.toml"),
    )
    .unwrap();
    assert_eq!(s.medium, sample.medium);
    assert_eq!(s.solve, sample.solve);
    assert_eq!(s.cameras, sample.cameras);
    assert_eq!(s.medium.grid().dims, [128, 128, 96]);
    assert_eq!(s.solve.transport_scale, scene::TransportScale::Fixed(4));
    assert_eq!(s.medium.channels().len(), 3, "the sky is coloured");
    assert!(
        s.environment.is_some() && s.lights.len() == 1,
        "a sky and its sun"
    );
    assert!(s.ground.is_some(), "above a ground");
    assert_eq!(s.medium.channels()[0].albedo, CellValues::Uniform(0.99));
    assert_eq!(s.solve.method, SolveMethod::DiscreteOrdinates);
    assert_eq!(s.render.model, OpticalModel::Scattering);
    // The camera sees the whole cloud: every occupied cell projects inside the image.
    let cam = &s.cameras[0];
    let forward = (cam.target - cam.eye).normalize();
    let right = forward.cross(cam.up).normalize();
    let up = right.cross(forward);
    let Projection::Perspective { fov_y_degrees } = cam.projection else {
        panic!("the built-in camera is a perspective camera")
    };
    let half = (0.5 * fov_y_degrees).to_radians().tan();
    let aspect = f64::from(cam.width) / f64::from(cam.height);
    let sigma = &s.medium.channels()[0].sigma_t;
    let mut seen = 0;
    for (cell, _) in sigma.iter().enumerate().filter(|(_, &x)| x > 0.0) {
        let p = s.medium.grid().cell_center(cell) - cam.eye;
        let z = p.dot(forward);
        assert!(
            z > 0.0 && (p.dot(up) / z).abs() < half && (p.dot(right) / z).abs() < half * aspect
        );
        seen += 1;
    }
    assert!(seen > 1000, "{seen}");
}

/// A generated volume larger than the machine's memory is refused, naming the key and what
/// it would need, before anything is allocated (it used to abort on a failed allocation).
#[test]
fn a_generated_volume_too_large_for_the_machine_is_refused_before_allocating() {
    // 1600³ cells fit volrad's index (< 2³²) but need about 46 GiB.
    let need = 1600u64.pow(3) * 12;
    let Some(available) = medium::resources::available_memory() else {
        panic!("this test needs /proc/meminfo (Linux)");
    };
    assert!(
        need > available,
        "the machine has {available} bytes: the case is too small"
    );
    let text = format!(
        "[volume]\ngenerator = {{ kind = \"cloud\" }}\ndims = [1600, 1600, 1600]\n{MEDIUM}{LIGHT}"
    );
    let err = Scene::from_toml_str(&text, Path::new("."), Path::new("big.toml"))
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("volume.dims") && err.contains("GiB") && err.contains("available"),
        "{err}"
    );
}

#[test]
fn from_toml_str_resolves_paths_against_base_dir() {
    let dir = scratch("str");
    write_volume(&dir);
    let text = scene_text(&[VOLUME, MEDIUM, LIGHT, CAMERA]);
    let s = Scene::from_toml_str(&text, &dir, Path::new("inline.toml")).unwrap();
    assert_eq!(s.medium.grid().dims, [4, 3, 2]);
    let err = Scene::from_toml_str(&text, Path::new("/nonexistent"), Path::new("inline.toml"))
        .unwrap_err();
    assert!(err.to_string().starts_with("inline.toml"), "{err}");
}

#[test]
fn problems_are_reported_in_file_order_and_cameras_found_by_name() {
    // Unknown key in [volume] comes before the missing [[light]].
    assert_refused(
        "order",
        &format!("{VOLUME}sigma_t_scal = 1\n{MEDIUM}"),
        "volume.sigma_t_scal",
        &["unknown key"],
    );
    let dir = scratch("camname");
    write_volume(&dir);
    let side = CAMERA
        .replace("\"front\"", "\"side\"")
        .replace("[2.0, 1.5, -10.0]", "[-10.0, 1.5, 1.0]");
    let s = parse_in(&dir, &scene_text(&[VOLUME, MEDIUM, LIGHT, CAMERA, &side])).unwrap();
    assert_eq!(s.camera("side").unwrap().eye.x, -10.0);
    assert!(s.camera("top").is_none());
}

#[test]
fn sections_of_the_wrong_shape_are_refused_and_volume_data_is_kept() {
    let single_light = "[light]\nkind = \"directional\"\ndirection = [0, -1, 0]\nirradiance = 1\n";
    assert_refused(
        "light-table",
        &scene_text(&[VOLUME, MEDIUM, single_light, CAMERA]),
        "light",
        &["[[light]]"],
    );
    assert_refused(
        "vol-array",
        &scene_text(&["[[volume]]\nfile = \"vol.f32\"\n", MEDIUM, LIGHT, CAMERA]),
        "volume",
        &["expected a table"],
    );
    let dir = scratch("data");
    write_volume(&dir);
    let s = parse_in(
        &dir,
        &scene_text(&[
            &format!("{VOLUME}sigma_t_scale = 5.0\n"),
            MEDIUM,
            LIGHT,
            CAMERA,
        ]),
    )
    .unwrap();
    let data = s.volume_data().unwrap();
    assert_eq!(data.dims, [4, 3, 2]);
    // The raw values, not σt.
    assert_eq!(data.values[12], 12.0 / 24.0);
    assert_eq!(s.medium.channels()[0].sigma_t[12], 5.0 * 12.0 / 24.0);
}

/// Counts a user controls that would run without bound are refused with the bound named:
/// lights (a light-pass sweep each), samples per pixel, the GMRES restart (a basis vector each).
#[test]
fn unbounded_counts_are_refused_naming_their_bound() {
    let many_lights = LIGHT.repeat(medium::light_pass::MAX_LIGHTS + 1);
    assert_refused(
        "many-lights",
        &scene_text(&[VOLUME, MEDIUM, &many_lights, CAMERA]),
        "light",
        &["1025 lights", "1024"],
    );
    assert_refused(
        "huge-spp",
        &scene_text(&[VOLUME, MEDIUM, LIGHT, "[render]\nspp = 1000000\n", CAMERA]),
        "render.spp",
        &["1000000", "4096"],
    );
    assert_refused(
        "huge-gmres",
        &scene_text(&[
            VOLUME,
            MEDIUM,
            LIGHT,
            "[solve]\niteration = \"gmres:100000000\"\n",
            CAMERA,
        ]),
        "solve.iteration",
        &["gmres:100000000", "1000"],
    );
    // The bounds themselves are accepted.
    let dir = scratch("bounds-ok");
    write_volume(&dir);
    let ok = scene_text(&[
        VOLUME,
        MEDIUM,
        LIGHT,
        "[render]\nspp = 4096\n[solve]\niteration = \"gmres:1000\"\n",
        CAMERA,
    ]);
    parse_in(&dir, &ok).unwrap();
}

/// `emission = { kind = "blackbody", ... }`: three channels, each cell emitting
/// `scale · (1 − a) · σt · rgb(T)`, with T a constant or a transfer of the data value.
#[test]
fn blackbody_emission_is_planck_colour_times_absorption() {
    let dir = scratch("blackbody");
    write_volume(&dir);
    let medium = "[medium]\nalbedo = 0.25\nemission = { kind = \"blackbody\", temperature = 1500, scale = 2.0 }\n";
    let s = parse_in(&dir, &scene_text(&[VOLUME, medium, LIGHT, CAMERA])).unwrap();
    let ch = s.medium.channels();
    assert_eq!(ch.len(), 3);
    let rgb = medium::blackbody::rgb(1500.0);
    assert!(rgb[0] > rgb[1] && rgb[1] > rgb[2], "{rgb:?}");
    for cell in 1..24 {
        let sigma_a = 0.75 * ch[0].sigma_t[cell] as f64;
        assert!(sigma_a > 0.0);
        for c in 0..3 {
            let want = 2.0 * sigma_a * rgb[c];
            let got = ch[c].emission.get(cell) as f64;
            assert!(
                (got - want).abs() <= 1e-4 * want.max(1e-3 * 2.0 * sigma_a * rgb[1]),
                "cell {cell} channel {c}: {got} vs {want}"
            );
        }
    }
    // σt = 0 in cell 0 (value 0): nothing to absorb, nothing emitted.
    assert!(ch.iter().all(|c| c.emission.get(0) == 0.0));

    // A transfer from data value to kelvin: values i/24 map to 800 + 1000·v kelvin.
    let medium = "[medium]\nalbedo = 0.0\nemission = { kind = \"blackbody\", temperature = { kind = \"piecewise-linear\", points = [[0.0, 800.0], [1.0, 1800.0]] } }\n";
    let s = parse_in(&dir, &scene_text(&[VOLUME, medium, CAMERA])).unwrap();
    let ch = s.medium.channels();
    assert_eq!(ch.len(), 3);
    for cell in [6, 12, 23] {
        let t = 800.0 + 1000.0 * (cell as f64 / 24.0);
        let rgb = medium::blackbody::rgb(t);
        let sigma_t = ch[1].sigma_t[cell] as f64;
        for c in 0..2 {
            let got = ch[c].emission.get(cell) as f64 / sigma_t;
            assert!(
                (got / rgb[c] - 1.0).abs() < 1e-3,
                "cell {cell} ({t} K) channel {c}: {got} vs {}",
                rgb[c]
            );
        }
    }
    // Hotter cells glow far brighter.
    assert!(
        ch[1].emission.get(23) / ch[1].sigma_t[23]
            > 100.0 * ch[1].emission.get(6) / ch[1].sigma_t[6]
    );

    // T ≤ 0 gives no emission (and a scene without light is then refused for lack of any).
    let medium = "[medium]\nalbedo = 0.5\nemission = { kind = \"blackbody\", temperature = 0 }\n";
    let s = parse_in(&dir, &scene_text(&[VOLUME, medium, LIGHT, CAMERA])).unwrap();
    assert!(s.medium.channels().iter().all(|c| c.emission.is_zero()));
}

#[test]
fn blackbody_bad_temperatures_are_refused_naming_the_key() {
    let cases = [
        ("temperature = 2e5", "medium.emission.temperature", "100000"),
        ("temperature = nan", "medium.emission.temperature", "finite"),
        ("temperature = inf", "medium.emission.temperature", "finite"),
        (
            "temperature = { kind = \"piecewise-linear\", points = [[0.0, 800.0], [1.0, 3e5]] }",
            "medium.emission.temperature",
            "300000",
        ),
        (
            "temperature = { kind = \"piecewise-linear\", points = [[0.0, 1.0, 2.0, 3.0]] }",
            "medium.emission.temperature.points",
            "kelvin",
        ),
        (
            "temperature = \"hot\"",
            "medium.emission.temperature",
            "number",
        ),
        ("scale = 1.0", "medium.emission.temperature", "missing"),
        (
            "temperature = 1000, scale = -1.0",
            "medium.emission.scale",
            "",
        ),
        ("grid = \"temperature\"", "medium.emission.grid", ".vdb"),
        (
            "temperature = 1000, grid = \"t\"",
            "medium.emission.grid",
            "not both",
        ),
        (
            "temperature = 1000, colour = 1",
            "medium.emission.colour",
            "unknown key",
        ),
    ];
    for (i, (emission, key, word)) in cases.into_iter().enumerate() {
        let medium =
            format!("[medium]\nalbedo = 0.5\nemission = {{ kind = \"blackbody\", {emission} }}\n");
        let (k, full) = refused(
            &format!("blackbody-bad-{i}"),
            &scene_text(&[VOLUME, &medium, LIGHT, CAMERA]),
        );
        assert_eq!(k, key, "{emission}: {full}");
        assert!(full.contains(word), "{emission}: `{word}` not in {full}");
    }
}
