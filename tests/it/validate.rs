//! `volrad validate` end to end on a tiny scene: the report has a row per method with finite
//! errors, the zonal method agrees with the path-traced reference, the images decode, and
//! bad input is refused by name.

use crate::fixtures::{s, stderr, volrad};
use std::path::{Path, PathBuf};

/// An 8×8×6 procedural cloud, isotropic, albedo 0.9, one small camera.
fn tiny_scene(dir: &Path) -> PathBuf {
    let text = r#"
[volume]
generator = { kind = "cloud", seed = 5 }
dims = [8, 8, 6]
sigma_t_scale = 0.6
interpolation = "nearest"

[medium]
albedo = 0.9
phase = { kind = "isotropic" }

[[light]]
kind = "directional"
direction = [0.3, -1.0, 0.2]
irradiance = 1.0

[solve]
tolerance = 1e-6

[[camera]]
name = "front"
eye = [4.0, 4.0, -6.0]
target = [4.0, 4.0, 3.0]
up = [0.0, 1.0, 0.0]
fov_y = 40.0
width = 32
height = 24
"#;
    let path = dir.join("tiny.toml");
    std::fs::write(&path, text).unwrap();
    path
}

/// `volrad -q validate --quick --scene SCENE --output OUT` followed by `extra`.
fn quick_validate(scene: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "-q",
        "validate",
        "--quick",
        "--scene",
        s(scene),
        "--output",
        s(out),
    ];
    args.extend_from_slice(extra);
    volrad(&args)
}

/// The report.json a run wrote into `out`.
fn report_json(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("report.json")).unwrap()).unwrap()
}

#[test]
fn quick_validation_reports_every_method_with_images() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let out = dir.path().join("report");
    let o = quick_validate(
        &scene,
        &out,
        &[
            "--methods",
            "zonal,single-scatter",
            "--reference-spp",
            "256",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));

    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    let row = |method: &str| -> (f64, f64) {
        // The scene's table (the summary at the top has a row per method too).
        let line = md
            .lines()
            .rfind(|l| l.starts_with(&format!("| {method} |")))
            .unwrap_or_else(|| panic!("no row for {method} in\n{md}"));
        let cells: Vec<&str> = line.split('|').map(str::trim).collect();
        let pct = |c: &str| c.trim_end_matches(" %").parse::<f64>().unwrap() / 100.0;
        (pct(cells[2]), pct(cells[3]))
    };
    let (zonal_rms, zonal_mean) = row("zonal");
    let (single_rms, single_mean) = row("single-scatter");
    println!(
        "zonal: {zonal_rms} (mean {zonal_mean}); single scatter: {single_rms} (mean {single_mean})"
    );
    assert!(zonal_rms.is_finite() && single_rms.is_finite());
    // On this 8×8×6 grid every solved method (two-pass too) renders ~10 % brighter than the
    // path tracer (12.7 % RMS, +10 % mean measured; the cloud24 grids agree to 2-3 %), so the
    // bound is loose: it catches a broken solve, render or comparison, not a few percent.
    assert!(zonal_rms < 0.2, "zonal relative RMS {zonal_rms}");
    assert!(zonal_mean.abs() < 0.15, "zonal mean {zonal_mean}");
    // Single scattering misses the multiple scattering at albedo 0.9: clearly darker, so the
    // comparison does discriminate.
    assert!(single_mean < -0.1, "single-scatter mean {single_mean}");
    assert!(
        single_rms > zonal_rms + 0.03,
        "single {single_rms} vs zonal {zonal_rms}"
    );

    // The JSON carries the same figures.
    let json = report_json(&out);
    let methods = json["scenes"][0]["methods"].as_array().unwrap();
    assert_eq!(methods.len(), 2);
    // The table shows the worst of the views.
    let z = methods[0]["views"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["vs_path_tracer"]["relative_rms"].as_f64().unwrap())
        .fold(0.0, f64::max);
    assert!(
        (z - zonal_rms).abs() < 6e-4,
        "json {z} vs markdown {zonal_rms}"
    );
    assert!(methods[0]["solution_file_bytes"].as_u64().unwrap() > 0);

    // Side by side: three 32×24 panels with two 4-pixel gaps.
    for name in [
        "tiny_zonal.png",
        "tiny_single-scatter.png",
        "error-scale.png",
    ] {
        assert!(md.contains(name), "report does not show {name}");
        let img = image::open(out.join(name))
            .unwrap_or_else(|e| panic!("{name}: {e}"))
            .to_rgb8();
        if name != "error-scale.png" {
            assert_eq!(img.dimensions(), (3 * 32 + 2 * 4, 24), "{name}");
            // The method panel is not blank: the cloud is lit.
            let lit = (32 + 4..2 * 32 + 4)
                .flat_map(|x| (0..24).map(move |y| (x, y)))
                .filter(|&(x, y)| img.get_pixel(x, y)[0] > 20)
                .count();
            assert!(lit > 20, "{name}: {lit} lit pixels");
        }
    }
}

/// A second report into the same folder removes the images the first one showed and it does
/// not (here: a method left out), and keeps other files.
#[test]
fn a_new_report_removes_the_images_only_the_old_one_showed() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let out = dir.path().join("report");
    let o = quick_validate(&scene, &out, &["--methods", "zonal,single-scatter"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("tiny_single-scatter.png").exists());
    std::fs::write(out.join("notes.png"), b"not validate's").unwrap();
    let o = quick_validate(&scene, &out, &["--methods", "zonal"]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(out.join("tiny_zonal.png").exists());
    assert!(!out.join("tiny_single-scatter.png").exists());
    assert!(out.join("notes.png").exists());
    assert!(out.join("error-scale.png").exists());
}

#[test]
fn variants_and_orbit_views_are_each_measured_and_the_worst_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let out = dir.path().join("report");
    let o = quick_validate(
        &scene,
        &out,
        &[
            "--methods",
            "single-scatter,zonal",
            "--views",
            "4",
            "--vary",
            "albedo=0.3,0.95",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let json = report_json(&out);
    let scenes = json["scenes"].as_array().unwrap();
    assert_eq!(scenes.len(), 2, "one case per albedo");
    assert_eq!(scenes[0]["name"], "tiny_a0.3");
    assert_eq!(scenes[1]["variant"], "albedo 0.95");
    // Single scattering misses more of the light at the higher albedo, in every view: the
    // variant really changed the medium the solve and the reference saw.
    let single_mean = |case: usize, view: usize| {
        scenes[case]["methods"][0]["views"][view]["vs_path_tracer"]["mean_ratio_error"]
            .as_f64()
            .unwrap()
    };
    for view in 0..4 {
        assert!(
            single_mean(1, view) < single_mean(0, view) - 0.05,
            "view {view}: albedo 0.95 {} vs 0.3 {}",
            single_mean(1, view),
            single_mean(0, view)
        );
    }
    let views = scenes[0]["reference"]["views"].as_array().unwrap();
    let names: Vec<&str> = views
        .iter()
        .map(|v| v["camera"].as_str().unwrap())
        .collect();
    assert_eq!(names, ["front", "front+090", "front+180", "front+270"]);

    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("## Worst view per method"), "{md}");
    // The summary names, for each method, the case and view of its worst error.
    let summary = md
        .lines()
        .find(|l| l.starts_with("| single-scatter | 2 |"))
        .unwrap_or_else(|| panic!("no summary row in\n{md}"));
    assert!(summary.contains("tiny_a0.95, front"), "{summary}");
    // A table row per view, a picture of the first view and of the worst.
    assert!(md.contains("| front+270 | 270° |"), "{md}");
    let pictures = std::fs::read_dir(&out)
        .unwrap()
        .filter(|e| {
            let n = e.as_ref().unwrap().file_name();
            let n = n.to_string_lossy();
            n.starts_with("tiny_a0.95_zonal") && n.ends_with(".png")
        })
        .count();
    assert!((1..=2).contains(&pictures), "{pictures} pictures");

    let o = quick_validate(&scene, &out, &["--vary", "g=1.5"]);
    assert!(!o.status.success());
    // Refused by the scene checker, naming the key and the variant, before any work.
    let e = stderr(&o);
    assert!(e.contains("medium.phase.g") && e.contains("g 1.5"), "{e}");
}

/// Cases that differ only in how the medium is solved (here the bins) share the first one's
/// path-traced references, and say so; a case that changes the medium gets its own.
#[test]
fn cases_that_only_change_the_solve_share_their_references() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let out = dir.path().join("report");
    let o = quick_validate(
        &scene,
        &out,
        &[
            "--methods",
            "discrete-ordinates",
            "--views",
            "2",
            "--vary",
            "albedo=0.5,0.9",
            "--vary",
            "bins=24,54",
        ],
    );
    assert!(o.status.success(), "{}", stderr(&o));
    let json = report_json(&out);
    let scenes = json["scenes"].as_array().unwrap();
    let names: Vec<&str> = scenes.iter().map(|c| c["name"].as_str().unwrap()).collect();
    assert_eq!(
        names,
        [
            "tiny_a0.5_b24",
            "tiny_a0.5_b54",
            "tiny_a0.9_b24",
            "tiny_a0.9_b54"
        ]
    );
    let made_for: Vec<&serde_json::Value> =
        scenes.iter().map(|c| &c["reference"]["made_for"]).collect();
    assert!(
        made_for[0].is_null() && made_for[2].is_null(),
        "{made_for:?}"
    );
    assert_eq!(made_for[1], "tiny_a0.5_b24");
    assert_eq!(made_for[3], "tiny_a0.9_b24");
    // Shared means not traced again: the second bin count reports the first one's tracing
    // times to the last digit (a second tracing of the same, seeded, image would be the same
    // picture but never the same clock), and the albedo 0.9 case traces its own.
    let seconds = |case: usize| scenes[case]["reference"]["views"][0]["seconds"].as_f64();
    assert!(seconds(0).is_some());
    assert_eq!(seconds(0), seconds(1));
    assert_eq!(seconds(2), seconds(3));
    assert_ne!(seconds(0), seconds(2));
    let noise = |case: usize| scenes[case]["reference"]["views"][0]["relative_noise"].as_f64();
    assert_ne!(noise(0), noise(2));
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(
        md.contains("(made for tiny_a0.5_b24, which sees the same medium)"),
        "{md}"
    );
}

#[test]
fn unknown_method_and_missing_scene_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let scene = tiny_scene(dir.path());
    let out = dir.path().join("report");
    let o = quick_validate(&scene, &out, &["--methods", "zonal,photon-mapping"]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(
        e.contains("`photon-mapping`") && e.contains("discrete-ordinates"),
        "{e}"
    );
    assert!(!out.join("report.md").exists());

    let missing = dir.path().join("nope.toml");
    let o = quick_validate(&missing, &out, &[]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("nope.toml") && e.contains("not found"), "{e}");
}
