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

/// `emission = { kind = "blackbody", grid = "temperature" }` on multi.vdb: the temperature
/// grid (box (0,0,0)–(7,7,15), background 300) sampled on the density grid's cells (box
/// (−4,0,2)–(7,9,10)) by index, against the values OpenVDB wrote (multi.temperature.f32).
#[test]
fn a_temperature_grid_gives_per_cell_blackbody_emission() {
    let medium = "[medium]\nalbedo = 0.5\nemission = { kind = \"blackbody\", grid = \"temperature\", scale = 1e3 }\n";
    let dir = std::env::temp_dir().join(format!("volrad-vdb-scene-{}-fire", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    std::fs::copy(vdb_dir().join("multi.vdb"), dir.join("multi.vdb")).unwrap();
    let path = dir.join("scene.toml");
    let rest = REST.replace("[medium]\nalbedo = 0.9\n", medium);
    std::fs::write(&path, format!("[volume]\nfile = \"multi.vdb\"\n{rest}")).unwrap();
    let s = Scene::from_file(&path).unwrap();

    let bytes = std::fs::read(vdb_dir().join("multi.temperature.f32")).unwrap();
    let temps: Vec<f32> = bytes
        .chunks_exact(4)
        .map(|b| f32::from_le_bytes([b[0], b[1], b[2], b[3]]))
        .collect();
    assert_eq!(temps.len(), 8 * 8 * 16);
    let ch = s.medium.channels();
    assert_eq!(ch.len(), 3);
    let [nx, ny, nz] = s.medium.grid().dims;
    let (mut inside, mut outside, mut glowing) = (0, 0, 0);
    for k in 0..nz {
        for j in 0..ny {
            for i in 0..nx {
                let cell = i + nx * (j + ny * k);
                let voxel = [i as i32 - 4, j as i32, k as i32 + 2];
                let in_box = (0..3).all(|a| voxel[a] >= 0 && voxel[a] <= [7, 7, 15][a]);
                let t = if in_box {
                    inside += 1;
                    let [x, y, z] = voxel.map(|v| v as usize);
                    temps[x + 8 * (y + 8 * z)] as f64
                } else {
                    outside += 1;
                    300.0
                };
                let rgb = medium::blackbody::rgb(t);
                let sigma_a = 0.5 * ch[0].sigma_t[cell] as f64;
                for c in 0..3 {
                    let want = 1e3 * sigma_a * rgb[c];
                    let got = ch[c].emission.get(cell) as f64;
                    assert!(
                        (got - want).abs() <= 1e-3 * want + 1e-30,
                        "cell ({i}, {j}, {k}) at {t} K channel {c}: {got} vs {want}"
                    );
                }
                if ch[0].emission.get(cell) > 0.0 && t > 1000.0 {
                    glowing += 1;
                }
            }
        }
    }
    // Both parts of the rule were exercised, and the emission is not all zero.
    assert!(
        inside > 0 && outside > 0 && glowing > 0,
        "{inside} {outside} {glowing}"
    );
}

#[test]
fn a_temperature_grid_is_refused_naming_the_key() {
    let emission =
        |e: &str| format!("[medium]\nalbedo = 0.5\nemission = {{ kind = \"blackbody\", {e} }}\n");
    for (e, words) in [
        ("grid = \"flames\"", &["flames"][..]),
        ("grid = 3", &["string"][..]),
    ] {
        let dir =
            std::env::temp_dir().join(format!("volrad-vdb-scene-{}-fire-bad", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::copy(vdb_dir().join("multi.vdb"), dir.join("multi.vdb")).unwrap();
        let path = dir.join("scene.toml");
        let rest = REST.replace("[medium]\nalbedo = 0.9\n", &emission(e));
        std::fs::write(&path, format!("[volume]\nfile = \"multi.vdb\"\n{rest}")).unwrap();
        match Scene::from_file(&path) {
            Err(SceneError::Invalid { key, message, .. }) => {
                assert_eq!(key, "medium.emission.grid", "{message}");
                for w in words {
                    assert!(message.contains(w), "`{w}` not in {message}");
                }
            }
            other => panic!("{e}: expected a refusal, got {other:?}"),
        }
    }
}
