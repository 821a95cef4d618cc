//! `[solve] transport_refinement` in a scene file splits the transport grid, and bad
//! values are refused with the key named.

use std::path::Path;

use medium::coarsening::Coarsening;
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

/// `transport_refinement = r` asks for the transport grid that splits each data cell into
/// r³ cells: its medium has the data's totals on r³ times the cells, and the light traced
/// on it falls off inside the thick cells of the data grid.
#[test]
fn transport_refinement_from_the_scene_splits_the_transport_grid() {
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
    let scene = scene_with("transport_refinement = 2").unwrap();
    assert_eq!(
        scene.solve.transport_refinement,
        TransportRefinement::Fixed(2)
    );
    // (volrad builds it in `budget::transport_grid`, tested there and in tests/it.)
    let split = Coarsening::split(scene.medium.grid(), 2).unwrap();
    let fine = split.medium(&scene.medium).unwrap();
    assert_eq!(
        fine.grid().cell_count(),
        8 * scene.medium.grid().cell_count()
    );
    let extinction = |m: &medium::Medium| {
        m.channels()[0]
            .sigma_t
            .iter()
            .map(|&s| s as f64)
            .sum::<f64>()
            * m.grid().cell_volume()
    };
    let (a, b) = (extinction(&scene.medium), extinction(&fine));
    assert!((a - b).abs() < 1e-9 * a, "{a} vs {b}");
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
