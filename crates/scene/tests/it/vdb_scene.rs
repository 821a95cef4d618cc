//! `[volume] file = "x.vdb"`: grid choice, cell size from the file's voxel size, placement on
//! the scene, and `coordinates = "file"` — on files written by the OpenVDB library
//! (crates/medium/tests/data/vdb).

use std::path::{Path, PathBuf};

use glam::DVec3;
use medium::Light;
use scene::{Scene, SceneError};

fn vdb_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../medium/tests/data/vdb")
}

const REST: &str = "[medium]\nalbedo = 0.9\n\n[[light]]\nkind = \"point\"\nposition = [1.0, 2.0, 3.0]\nintensity = 1.0\n\n[[camera]]\nname = \"c\"\neye = [1.0, 2.0, -20.0]\ntarget = [1.0, 2.0, 3.0]\nup = [0.0, 1.0, 0.0]\nfov_y = 30.0\nwidth = 8\nheight = 8\n";

/// Parses a scene whose `[volume]` is `volume`, placed in a scratch directory that holds
/// copies of the test files.
fn parse(name: &str, volume: &str) -> Result<Scene, SceneError> {
    let dir = std::env::temp_dir().join(format!("volrad-vdb-scene-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    for f in ["multi.vdb", "scale_translate.vdb", "nonuniform.vdb"] {
        std::fs::copy(vdb_dir().join(f), dir.join(f)).unwrap();
    }
    std::fs::write(dir.join("v.f32"), [0u8; 8 * 4]).unwrap();
    let path = dir.join("scene.toml");
    std::fs::write(&path, format!("[volume]\n{volume}\n{REST}")).unwrap();
    Scene::from_file(&path)
}

fn refused(name: &str, volume: &str, key: &str, words: &[&str]) {
    match parse(name, volume) {
        Err(SceneError::Invalid {
            key: k, message, ..
        }) => {
            assert_eq!(k, key, "{message}");
            for w in words {
                assert!(message.contains(w), "expected `{w}` in: {message}");
            }
        }
        other => panic!("expected `{key}` refused, got {other:?}"),
    }
}

#[test]
fn a_vdb_grid_becomes_the_volume_with_its_placement() {
    let s = parse("default", "file = \"multi.vdb\"").unwrap();
    assert_eq!(s.medium.grid().dims, [12, 10, 9]);
    assert_eq!(s.medium.grid().cell_size, 1.0);
    let p = s.volume_placement().unwrap();
    assert_eq!((p.grid.as_str(), p.bbox_min), ("density", [-4, 0, 2]));

    let t = parse(
        "temperature",
        // Its inactive voxels hold ±300 (the background and its negative): a table keeps σt ≥ 0.
        "file = \"multi.vdb\"\ngrid = \"temperature\"\ndims = [8, 8, 16]\nsigma_t = { kind = \"piecewise-linear\", points = [[-300.0, 0.0], [1200.0, 1.0]] }",
    )
    .unwrap();
    assert_eq!(t.medium.grid().dims, [8, 8, 16]);
    assert_eq!(t.volume_placement().unwrap().grid, "temperature");

    // cell_size defaults to the file's uniform voxel size.
    let s = parse("voxel", "file = \"scale_translate.vdb\"").unwrap();
    assert_eq!(s.medium.grid().cell_size, 0.5);
    // Positions stay in volrad's grid frame by default.
    assert_eq!(s.cameras[0].eye, DVec3::new(1.0, 2.0, -20.0));
}

#[test]
fn file_coordinates_shift_cameras_and_lights_by_the_grid_corner() {
    let s = parse(
        "file-coords",
        "file = \"scale_translate.vdb\"\ncoordinates = \"file\"",
    )
    .unwrap();
    let p = s.volume_placement().unwrap();
    let corner = DVec3::from_array(p.world_corner());
    // translation (1.25, -2, 3.5), voxel 0.5, bbox_min (3, 4, -2): corner = t + 0.5 (min − ½).
    assert_eq!(corner, DVec3::new(2.5, -0.25, 2.25));
    assert_eq!(s.cameras[0].eye, DVec3::new(1.0, 2.0, -20.0) - corner);
    assert_eq!(s.cameras[0].target, DVec3::new(1.0, 2.0, 3.0) - corner);
    match s.lights[0] {
        Light::Point { position, .. } => assert_eq!(position, DVec3::new(1.0, 2.0, 3.0) - corner),
        ref other => panic!("{other:?}"),
    }
}

#[test]
fn vdb_keys_are_refused_naming_the_key() {
    refused(
        "missing-grid",
        "file = \"multi.vdb\"\ngrid = \"flames\"",
        "volume.file",
        &["no grid named `flames`", "`density`", "`temperature`"],
    );
    refused(
        "grid-on-raw",
        "file = \"v.f32\"\ndims = [2, 2, 2]\ngrid = \"density\"",
        "volume.grid",
        &["OpenVDB", "v.f32"],
    );
    refused(
        "grid-on-generator",
        "generator = { kind = \"dipole\" }\ndims = [2, 2, 2]\ngrid = \"density\"",
        "volume.grid",
        &["generator"],
    );
    refused(
        "dims-disagree",
        "file = \"multi.vdb\"\ndims = [1, 2, 3]",
        "volume.file",
        &["[12, 10, 9]", "[1, 2, 3]"],
    );
    refused(
        "nonuniform",
        "file = \"nonuniform.vdb\"",
        "volume.cell_size",
        &["not uniform", "[0.5, 1.0, 2.0]"],
    );
    refused(
        "coords-raw",
        "file = \"v.f32\"\ndims = [2, 2, 2]\ncoordinates = \"file\"",
        "volume.coordinates",
        &["OpenVDB"],
    );
    refused(
        "coords-cell-size",
        "file = \"scale_translate.vdb\"\ncell_size = 1.0\ncoordinates = \"file\"",
        "volume.coordinates",
        &["cell_size 1"],
    );
    refused(
        "coords-word",
        "file = \"multi.vdb\"\ncoordinates = \"world\"",
        "volume.coordinates",
        &["`world`"],
    );
    // A non-uniform grid is read when cell_size is given (in grid coordinates).
    let s = parse(
        "nonuniform-ok",
        "file = \"nonuniform.vdb\"\ncell_size = 0.5",
    )
    .unwrap();
    assert_eq!(s.medium.grid().dims, [6, 5, 4]);
}
