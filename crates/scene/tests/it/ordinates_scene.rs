//! `[solve] transport_refinement` in a scene file reaches the ordinates operator, and bad
//! values are refused with the key named.

use std::path::Path;

use formfactor::ordinates::{DirectionBins, OrdinatesOperator, OrdinatesOptions};
use scene::Scene;

fn scene_with(solve_extra: &str) -> Result<Scene, String> {
    let text = format!(
        r#"
[volume]
generator = {{ kind = "cloud", seed = 3 }}
dims = [6, 6, 4]

[medium]
albedo = 0.9
phase = {{ kind = "henyey-greenstein", g = 0.8 }}

[[light]]
kind = "directional"
direction = [0.0, 0.0, -1.0]
irradiance = 1.0

[solve]
method = "discrete-ordinates"
bins = 24
{solve_extra}

[[camera]]
name = "c"
eye = [3.0, 3.0, -20.0]
target = [3.0, 3.0, 2.0]
up = [0.0, 1.0, 0.0]
fov_y = 30.0
width = 8
height = 8
"#
    );
    Scene::from_toml_str(&text, Path::new("."), Path::new("inline.toml")).map_err(|e| e.to_string())
}

#[test]
fn transport_refinement_from_the_scene_builds_a_refined_sweep() {
    assert_eq!(scene_with("").unwrap().solve.transport_refinement, 1);
    let scene = scene_with("transport_refinement = 2").unwrap();
    assert_eq!(scene.solve.transport_refinement, 2);
    // (volrad passes it on in `methods::ordinates_options`, tested there.) The operator
    // built with it sweeps 2³ sub-cells.
    let options = OrdinatesOptions {
        transport_refinement: scene.solve.transport_refinement,
        ..OrdinatesOptions::default()
    };
    let refined =
        OrdinatesOperator::new(&scene.medium, 0, DirectionBins::cube(2).unwrap(), options).unwrap();
    assert_eq!(refined.options().transport_refinement, 2);
    // ... and it changes the transport (less sideways spreading), not just a label.
    let plain = OrdinatesOperator::new(
        &scene.medium,
        0,
        DirectionBins::cube(2).unwrap(),
        OrdinatesOptions::default(),
    )
    .unwrap();
    let len = solver::operator::TransportOperator::len(&plain);
    let density: Vec<f64> = (0..len)
        .map(|i| if i % 7 == 0 { 1.0 } else { 0.0 })
        .collect();
    let (mut a, mut b) = (vec![0.0; len], vec![0.0; len]);
    plain.transport(&density, &mut a);
    refined.transport(&density, &mut b);
    let diff: f64 = a.iter().zip(&b).map(|(x, y)| (x - y).abs()).sum();
    let total: f64 = a.iter().map(|x| x.abs()).sum();
    assert!(
        diff > 1e-3 * total,
        "refinement changed nothing ({diff} of {total})"
    );
}

#[test]
fn bad_transport_refinement_is_refused_naming_the_key() {
    for bad in ["0", "5", "-1", "2.5", "\"2\""] {
        let err = scene_with(&format!("transport_refinement = {bad}")).unwrap_err();
        assert!(
            err.contains("solve.transport_refinement") && err.contains("inline.toml"),
            "{bad}: {err}"
        );
    }
    let err = scene_with("transport_refinement = 5").unwrap_err();
    assert!(err.contains("1 to 4"), "{err}");
}

#[test]
fn forward_peak_cone_is_read_and_bad_values_are_refused_naming_the_key() {
    assert_eq!(scene_with("").unwrap().solve.forward_peak_cone, None);
    assert_eq!(
        scene_with("forward_peak_cone = 0")
            .unwrap()
            .solve
            .forward_peak_cone,
        Some(0.0)
    );
    assert_eq!(
        scene_with("forward_peak_cone = 15.5")
            .unwrap()
            .solve
            .forward_peak_cone,
        Some(15.5)
    );
    for bad in ["-1", "90", "\"auto\""] {
        let err = scene_with(&format!("forward_peak_cone = {bad}")).unwrap_err();
        assert!(
            err.contains("solve.forward_peak_cone") && err.contains("inline.toml"),
            "{bad}: {err}"
        );
    }
}
