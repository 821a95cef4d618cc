//! `[solve] transport_refinement` in a scene file splits the transport grid, and bad
//! values are refused with the key named.

use std::path::Path;

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

/// `transport_refinement` is `"auto"` by default or a whole number; the split grid it asks
/// for is `medium::coarsening::Coarsening::split`'s (tested there) and volrad's
/// `budget::transport_grid` (tests/it/transport_grid.rs).
#[test]
fn transport_refinement_from_the_scene_is_auto_or_a_split() {
    use scene::TransportRefinement;
    assert_eq!(
        scene_with("").unwrap().solve.transport_refinement,
        TransportRefinement::Auto
    );
    assert_eq!(
        scene_with("transport_refinement = \"auto\"")
            .unwrap()
            .solve
            .transport_refinement,
        TransportRefinement::Auto
    );
    assert_eq!(
        scene_with("transport_refinement = 2")
            .unwrap()
            .solve
            .transport_refinement,
        TransportRefinement::Fixed(2)
    );
    // With a coarser transport grid it is refused: one or the other.
    let err = scene_with("transport_refinement = 2\ntransport_scale = 2").unwrap_err();
    assert!(
        err.contains("solve.transport_refinement") && err.contains("not both"),
        "{err}"
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
