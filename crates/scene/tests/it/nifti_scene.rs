//! `[volume] file = "x.nii"` / `"x.nii.gz"`: the volume and its cell size from the file's
//! voxel spacing (pixdim), on files written by nibabel (crates/medium/tests/data/nifti).

use std::path::{Path, PathBuf};

use scene::{Scene, SceneError};

fn nifti_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../medium/tests/data/nifti")
}

const REST: &str = "[medium]\nalbedo = 0.9\n\n[[light]]\nkind = \"point\"\nposition = [1.0, 2.0, 3.0]\nintensity = 1.0\n\n[[camera]]\nname = \"c\"\neye = [1.0, 2.0, -20.0]\ntarget = [1.0, 2.0, 3.0]\nup = [0.0, 1.0, 0.0]\nfov_y = 30.0\nwidth = 8\nheight = 8\n";

fn parse(name: &str, volume: &str) -> Result<Scene, SceneError> {
    let dir =
        std::env::temp_dir().join(format!("volrad-nifti-scene-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    for f in ["float32_gz.nii.gz", "nonuniform.nii", "uint8.nii"] {
        std::fs::copy(nifti_dir().join(f), dir.join(f)).unwrap();
    }
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
fn a_nifti_volume_takes_its_cell_size_from_pixdim() {
    let s = parse("gz", "file = \"float32_gz.nii.gz\"").unwrap();
    assert_eq!(s.medium.grid().dims, [7, 5, 4]);
    assert_eq!(s.medium.grid().cell_size, 0.5);
    // NIfTI orientation is ignored: no placement, the grid's corner at the origin.
    assert!(s.volume_placement().is_none());
    let u = parse("u8", "file = \"uint8.nii\"").unwrap();
    assert_eq!(u.medium.grid().cell_size, 1.0);
    // An explicit cell_size wins, and makes a non-uniform spacing usable.
    let n = parse("explicit", "file = \"nonuniform.nii\"\ncell_size = 0.7").unwrap();
    assert_eq!(n.medium.grid().cell_size, 0.7);
}

#[test]
fn nifti_keys_are_refused_naming_the_key() {
    refused(
        "nonuniform",
        "file = \"nonuniform.nii\"",
        "volume.cell_size",
        &["pixdim", "not uniform", "give cell_size"],
    );
    refused(
        "grid",
        "file = \"uint8.nii\"\ngrid = \"density\"",
        "volume.grid",
        &["OpenVDB", "uint8.nii"],
    );
    refused(
        "coordinates",
        "file = \"uint8.nii\"\ncoordinates = \"file\"",
        "volume.coordinates",
        &["OpenVDB"],
    );
    refused(
        "dims",
        "file = \"uint8.nii\"\ndims = [5, 7, 4]",
        "volume.file",
        &["[7, 5, 4]", "[5, 7, 4]"],
    );
}
