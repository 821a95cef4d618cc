//! One check per parser of untrusted input, on arbitrary bytes: scene TOML, JSON scenes (the
//! service's JSON → TOML path), NRRD, Mitsuba `.vol`, OpenVDB, NIfTI, solution files and the
//! render endpoint's query string. Each returns normally when the parser answered `Ok` with a
//! consistent value or an `Err` whose message says something (and, for files, names the
//! file), and panics otherwise — as the parser itself would on a bug.
//!
//! The cargo-fuzz targets (`fuzz/fuzz_targets/*.rs`) and the property tests
//! (`tests/it/fuzz.rs`, run by `cargo test`) call these same functions, so what the fuzzer
//! checks is what CI checks. No check touches the filesystem beyond what the input itself
//! names (a scene's volume file, an NRRD's detached data file), resolved against
//! [`NO_DIR`], a directory that does not exist.

use std::path::Path;

use crate::engine::solution::container::FORMAT_VERSION;
use crate::engine::solution::Solution;
use crate::service::routes;

/// Relative paths in fuzzed input resolve here: a directory that does not exist.
pub const NO_DIR: &str = "/nonexistent-volrad-fuzz";

/// The largest grid (nx·ny·nz) a fuzzed scene is parsed with. Larger ones are valid requests,
/// bounded by the machine's memory (`medium::resources::check_memory`), but a generator would
/// spend seconds to minutes filling them: such inputs are skipped, not parsed.
pub const MAX_FUZZ_CELLS: u128 = 1 << 16;

/// The dense-box bound passed to the OpenVDB and NIfTI readers (their `_capped` forms), so a
/// mutated header cannot ask for gigabytes; real files are bounded by the machine.
pub const MAX_FUZZ_VOLUME_CELLS: u64 = 1 << 22;

/// The OpenVDB reader's tighter bound: a mutated leaf or tile origin spans a box the reader
/// then fills, and at [`MAX_FUZZ_VOLUME_CELLS`] that filling took most of the fuzzer's time
/// (200–300 inputs/s). The samples the corpus starts from are at most 10⁴ cells; a larger box
/// is refused after the whole topology is read, so the parser is exercised all the same.
pub const MAX_FUZZ_VDB_CELLS: u64 = 1 << 16;

/// An error must say what was wrong: not empty, and naming `label` when one is given.
fn check_error(message: &str, label: Option<&str>) {
    assert!(!message.trim().is_empty(), "an error with an empty message");
    if let Some(label) = label {
        assert!(
            message.contains(label),
            "an error that does not name `{label}`: {message}"
        );
    }
}

/// A parsed volume must hold one value per cell of its dims.
fn check_volume(v: &medium::volume_io::VolumeData) {
    let cells = v.dims.iter().try_fold(1usize, |a, &d| a.checked_mul(d));
    assert_eq!(cells, Some(v.values.len()), "dims {:?}", v.dims);
}

/// Whether `volume.dims` asks for more than [`MAX_FUZZ_CELLS`] (see there).
fn too_many_cells(table: &toml::Table) -> bool {
    let Some(dims) = table
        .get("volume")
        .and_then(|v| v.get("dims"))
        .and_then(|d| d.as_array())
    else {
        return false;
    };
    let cells = dims.iter().fold(1u128, |acc, d| match d {
        toml::Value::Integer(n) => acc.saturating_mul(n.unsigned_abs() as u128),
        toml::Value::Float(x) if x.is_finite() => {
            acc.saturating_mul(x.abs().min(u64::MAX as f64) as u128)
        }
        _ => acc,
    });
    cells > MAX_FUZZ_CELLS
}

fn scene_text(text: &str, label: &str) {
    if text
        .parse::<toml::Table>()
        .is_ok_and(|t| too_many_cells(&t))
    {
        return;
    }
    match scene::Scene::from_toml_str(text, Path::new(NO_DIR), Path::new(label)) {
        Ok(scene) => {
            let cells: usize = scene.medium.grid().dims.iter().product();
            assert!(cells as u128 <= MAX_FUZZ_CELLS, "{cells} cells");
        }
        Err(e) => check_error(&e.to_string(), Some(label)),
    }
}

/// A scene file's text (`Scene::from_toml_str`).
pub fn scene_toml(bytes: &[u8]) {
    scene_text(&String::from_utf8_lossy(bytes), "fuzz.toml");
}

/// A JSON scene as the service reads it: JSON → a TOML table → TOML text → the scene parser.
/// The TOML text the service writes must read back as the same table.
pub fn scene_json(bytes: &[u8]) {
    let text = String::from_utf8_lossy(bytes);
    let table = match routes::json_scene_table(&text) {
        Ok(t) => t,
        Err(e) => return check_error(&e.message, None),
    };
    let canonical = match toml::to_string(&table) {
        Ok(c) => c,
        Err(e) => return check_error(&e.to_string(), None),
    };
    let again: toml::Table = canonical
        .parse()
        .unwrap_or_else(|e| panic!("the TOML written for a JSON scene does not parse: {e}"));
    assert_eq!(
        again, table,
        "the TOML written for a JSON scene reads back differently"
    );
    scene_text(&canonical, "fuzz.json");
}

/// An NRRD header (attached data, or a detached `data file` looked for beside it).
pub fn nrrd(bytes: &[u8]) {
    let path = Path::new(NO_DIR).join("fuzz.nrrd");
    match medium::volume_io::read_nrrd_bytes(bytes, &path) {
        Ok(v) => check_volume(&v),
        // A detached data file's errors name that file.
        Err(e) => check_error(&e.to_string(), None),
    }
}

/// A Mitsuba `.vol` grid.
pub fn mitsuba_vol(bytes: &[u8]) {
    match medium::volume_io::read_mitsuba_vol_bytes(bytes, Path::new("fuzz.vol")) {
        Ok(v) => check_volume(&v),
        Err(e) => check_error(&e.to_string(), Some("fuzz.vol")),
    }
}

/// An OpenVDB file: its first float, double or half grid, and a grid asked for by name.
pub fn vdb(bytes: &[u8]) {
    for grid in [None, Some("density")] {
        let path = Path::new("fuzz.vdb");
        match medium::vdb::read_vdb_bytes_capped(bytes, path, grid, MAX_FUZZ_VDB_CELLS) {
            Ok(v) => check_volume(&v.data),
            Err(e) => check_error(&e.to_string(), Some("fuzz.vdb")),
        }
    }
}

/// A NIfTI-1 or -2 file, gzip-compressed or not.
pub fn nifti(bytes: &[u8]) {
    let path = Path::new("fuzz.nii");
    match medium::nifti::read_nifti_bytes_capped(bytes, path, MAX_FUZZ_VOLUME_CELLS) {
        Ok(v) => check_volume(&v.data),
        Err(e) => check_error(&e.to_string(), Some("fuzz.nii")),
    }
}

/// An environment map, as OpenEXR and as PFM: read, then checked as a scene's map is.
pub fn environment_map(bytes: &[u8]) {
    for (image, label) in [
        (gather::image_io::parse_exr(bytes), "EXR"),
        (gather::image_io::parse_pfm(bytes), "PFM"),
    ] {
        match image {
            Ok(image) => {
                let n = image.width as usize * image.height as usize * image.channels as usize;
                assert_eq!(image.pixels.len(), n, "{label}");
                let map = medium::environment_map::EnvironmentMap::from_interleaved(
                    image.width as usize,
                    image.height as usize,
                    image.channels as usize,
                    &image.pixels,
                    glam::DVec3::Z,
                    0.0,
                    1.0,
                );
                if let Ok(map) = map {
                    let (_, sources) = map.split_bright_sources();
                    assert!(sources.iter().all(|s| s.irradiance.is_finite()));
                }
            }
            Err(e) => check_error(&e, None),
        }
    }
}

/// A solution file (`Solution::from_bytes`), as given and with its fixed header made valid
/// (magic, version, length, checksum), so that mutations reach the decoder behind the
/// checksum. A solution read is written again without a panic.
pub fn solution(bytes: &[u8]) {
    let path = Path::new("fuzz.volrad");
    let check = |bytes: &[u8]| match Solution::from_bytes(bytes, path) {
        Ok(s) => drop(s.to_bytes()),
        Err(e) => check_error(&e.to_string(), Some("fuzz.volrad")),
    };
    check(bytes);
    check(&with_valid_header(bytes));
}

/// `bytes` (at least the fixed 24-byte header, zero-padded) with the magic, version, payload
/// length and CRC-32 a reader accepts.
pub fn with_valid_header(bytes: &[u8]) -> Vec<u8> {
    let mut out = bytes.to_vec();
    if out.len() < 24 {
        out.resize(24, 0);
    }
    out[..8].copy_from_slice(crate::engine::solution::container::MAGIC);
    out[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
    let payload = (out.len() - 24) as u64;
    out[12..20].copy_from_slice(&payload.to_le_bytes());
    let crc = crc32fast::hash(&out[24..]);
    out[20..24].copy_from_slice(&crc.to_le_bytes());
    out
}

/// The query string of `GET /v1/scenes/{id}/render`, through the service's decoding and
/// checks, and the camera it resolves to against a scene with one camera on a 4×4×4 grid.
/// A camera accepted is one a render accepts, within the default limits.
pub fn render_query(bytes: &[u8]) {
    let limits = crate::service::Limits::default();
    let text = String::from_utf8_lossy(bytes);
    let query = match routes::query_from_str(&text) {
        Ok(q) => q,
        Err(e) => return check_error(&e.message, None),
    };
    let request = match routes::parse_render_query(&query, &limits) {
        Ok(r) => r,
        Err(e) => return check_error(&e.message, None),
    };
    if let Some(spp) = request.spp {
        assert!((1..=limits.max_spp).contains(&spp), "spp {spp}");
    }
    let grid = medium::Grid::new([4, 4, 4], 1.0).expect("a 4×4×4 grid");
    let cameras = [scene::CameraSpec {
        name: "front".into(),
        eye: glam::DVec3::new(2.0, -10.0, 2.0),
        target: glam::DVec3::splat(2.0),
        up: glam::DVec3::Z,
        projection: scene::Projection::Perspective {
            fov_y_degrees: 40.0,
        },
        width: 64,
        height: 48,
    }];
    match routes::render_camera(&request.camera, &cameras, &grid, &limits) {
        Ok(cam) => {
            assert!(cam.width <= limits.max_image_side && cam.height <= limits.max_image_side);
            assert!(u64::from(cam.width) * u64::from(cam.height) <= limits.max_image_pixels);
            if let Err(e) = gather::Camera::from_spec(&cam) {
                panic!("a camera the query checks accepted, a render refuses: {e}");
            }
        }
        Err(e) => check_error(&e.message, None),
    }
}
