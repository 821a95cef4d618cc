//! Every parser of untrusted input on arbitrary and mutated input, through the checks the
//! cargo-fuzz targets run (`volrad::fuzzing`; `fuzz/`, docs/reliability.md): scene TOML, JSON
//! scenes, NRRD, Mitsuba `.vol`, OpenVDB, NIfTI, solution files and render query strings. Each
//! input must give `Ok` with a consistent value or an `Err` that says what was wrong — never a
//! panic, an abort or a hang. Binary formats are also fed mutations of valid files, so the
//! inputs get past the magic numbers; text formats, edits of sample scenes and headers. The
//! inputs the fuzzer found crashing are kept in `tests/data/fuzz-regressions/`.

use std::path::{Path, PathBuf};

use proptest::prelude::*;
use volrad::fuzzing;

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

fn read(path: &str) -> Vec<u8> {
    std::fs::read(repo(path)).unwrap_or_else(|e| panic!("{path}: {e}"))
}

/// The sample scenes of `data/`, at 8×8×6 cells (the checks skip grids over
/// `fuzzing::MAX_FUZZ_CELLS`, which the samples' 64×64×48 exceeds).
fn scene_seeds() -> Vec<String> {
    let mut names: Vec<PathBuf> = std::fs::read_dir(repo("data"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "toml"))
        .collect();
    names.sort();
    names
        .iter()
        .map(|p| {
            std::fs::read_to_string(p)
                .unwrap()
                .lines()
                .map(|l| {
                    if l.starts_with("dims = [") {
                        "dims = [8, 8, 6]"
                    } else {
                        l
                    }
                })
                .collect::<Vec<_>>()
                .join("\n")
        })
        .collect()
}

/// The sample scenes as JSON, as a client of the service would post them.
fn json_seeds() -> Vec<String> {
    scene_seeds()
        .iter()
        .map(|t| serde_json::to_string(&t.parse::<toml::Table>().unwrap()).unwrap())
        .collect()
}

fn nrrd_seeds() -> Vec<Vec<u8>> {
    let head = "NRRD0004\ntype: float\ndimension: 3\nsizes: 3 2 1\nendian: little\n";
    let values: Vec<u8> = (0..6)
        .flat_map(|i| (i as f32 * 0.5).to_le_bytes())
        .collect();
    let mut gz = flate2::write::GzEncoder::new(Vec::new(), flate2::Compression::default());
    std::io::Write::write_all(&mut gz, &values).unwrap();
    let mut raw = format!("{head}encoding: raw\n\n").into_bytes();
    raw.extend_from_slice(&values);
    let mut gzip = format!("{head}encoding: gzip\n\n").into_bytes();
    gzip.extend_from_slice(&gz.finish().unwrap());
    vec![read("data/smoke32.nrrd"), raw, gzip]
}

fn vol_seed() -> Vec<u8> {
    let mut v = b"VOL\x03".to_vec();
    for i in [1i32, 2, 2, 1, 1] {
        v.extend_from_slice(&i.to_le_bytes());
    }
    for x in [0f32, 0.0, 0.0, 2.0, 2.0, 1.0, 0.0, 0.25, 0.5, 1.0] {
        v.extend_from_slice(&x.to_le_bytes());
    }
    v
}

fn vdb_seeds() -> Vec<Vec<u8>> {
    [
        "data/cloud24.vdb",
        "crates/medium/tests/data/vdb/tiles.vdb",
        "crates/medium/tests/data/vdb/half.vdb",
    ]
    .iter()
    .map(|p| read(p))
    .collect()
}

fn nifti_seeds() -> Vec<Vec<u8>> {
    ["uint8.nii", "int32_nifti2.nii", "float32_gz.nii.gz"]
        .iter()
        .map(|n| read(&format!("crates/medium/tests/data/nifti/{n}")))
        .collect()
}

fn solution_seeds() -> Vec<Vec<u8>> {
    [
        "small.volrad",
        "small-ordinates.volrad",
        "small-two-pass.volrad",
    ]
    .iter()
    .map(|n| read(&format!("tests/data/solution-golden/{n}")))
    .collect()
}

const QUERY_SEEDS: [&str; 4] = [
    "camera=front",
    "eye=1,2,3&target=2,2,2&up=0,0,1&fov=30&width=64&height=48",
    "spp=4&exposure=1.5&format=pfm",
    "format=png&width=1&height=1",
];

/// Byte edits: (position, byte) pairs, and where to cut the input (none when past its end).
fn byte_edits() -> impl Strategy<Value = (Vec<(prop::sample::Index, u8)>, prop::sample::Index, bool)>
{
    (
        prop::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..8),
        any::<prop::sample::Index>(),
        prop::bool::weighted(0.2),
    )
}

fn mutate(
    mut bytes: Vec<u8>,
    (edits, cut, truncate): &(Vec<(prop::sample::Index, u8)>, prop::sample::Index, bool),
) -> Vec<u8> {
    for (at, b) in edits {
        let i = at.index(bytes.len());
        bytes[i] = *b;
    }
    if *truncate {
        bytes.truncate(cut.index(bytes.len() + 1));
    }
    bytes
}

/// Text edits: at a few places, replace a character by one of the text's own syntax (digits,
/// signs, brackets, quotes, separators) or delete it.
fn text_edits() -> impl Strategy<Value = Vec<(prop::sample::Index, prop::sample::Index)>> {
    prop::collection::vec(
        (any::<prop::sample::Index>(), any::<prop::sample::Index>()),
        1..6,
    )
}

fn mutate_text(text: &str, edits: &[(prop::sample::Index, prop::sample::Index)]) -> String {
    const ALPHABET: &[char] = &[
        '0', '1', '9', '-', '+', '.', 'e', '[', ']', '{', '}', '"', '\'', '=', ',', ':', '&', '%',
        '\n', ' ', '#', 'x', '\u{0}', 'é', '\u{FFFF}',
    ];
    let mut chars: Vec<char> = text.chars().collect();
    for (at, with) in edits {
        if chars.is_empty() {
            break;
        }
        let i = at.index(chars.len());
        match with.index(ALPHABET.len() + 1) {
            n if n == ALPHABET.len() => {
                chars.remove(i);
            }
            n => chars[i] = ALPHABET[n],
        }
    }
    chars.into_iter().collect()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn arbitrary_bytes_never_break_a_parser(bytes in prop::collection::vec(any::<u8>(), 0..600)) {
        fuzzing::scene_toml(&bytes);
        fuzzing::scene_json(&bytes);
        fuzzing::nrrd(&bytes);
        fuzzing::mitsuba_vol(&bytes);
        fuzzing::vdb(&bytes);
        fuzzing::nifti(&bytes);
        fuzzing::solution(&bytes);
        fuzzing::render_query(&bytes);
        fuzzing::environment_map(&bytes);
    }

    /// Bytes behind each binary format's magic number, so the parser reads past it.
    #[test]
    fn arbitrary_bytes_behind_a_magic_number(tail in prop::collection::vec(any::<u8>(), 0..600)) {
        for magic in [&b"NRRD0004\n"[..], b"VOL\x03", b"\x20BDV\0\0\0\0\xe0\0\0\0", &348i32.to_le_bytes(), &540i32.to_le_bytes()] {
            let bytes = [magic, &tail].concat();
            fuzzing::nrrd(&bytes);
            fuzzing::mitsuba_vol(&bytes);
            fuzzing::vdb(&bytes);
            fuzzing::nifti(&bytes);
        }
        for magic in [&b"\x76\x2f\x31\x01\x02\0\0\0"[..], b"PF\n2 2\n-1.0\n", b"Pf\n3 1\n1.0\n"] {
            fuzzing::environment_map(&[magic, &tail].concat());
        }
        fuzzing::solution(&tail);
    }

    #[test]
    fn mutated_scenes(which in any::<prop::sample::Index>(), edits in text_edits()) {
        let seeds = scene_seeds();
        let text = mutate_text(&seeds[which.index(seeds.len())], &edits);
        fuzzing::scene_toml(text.as_bytes());
    }

    #[test]
    fn mutated_json_scenes(which in any::<prop::sample::Index>(), edits in text_edits()) {
        let seeds = json_seeds();
        let text = mutate_text(&seeds[which.index(seeds.len())], &edits);
        fuzzing::scene_json(text.as_bytes());
    }

    #[test]
    fn mutated_nrrd(which in any::<prop::sample::Index>(), edits in byte_edits(), text in text_edits()) {
        let seeds = nrrd_seeds();
        let seed = seeds[which.index(seeds.len())].clone();
        fuzzing::nrrd(&mutate(seed.clone(), &edits));
        // Edits of the header text alone (it is text; the data are not).
        let end = seed.windows(2).position(|w| w == b"\n\n").map_or(seed.len(), |p| p + 2);
        let header = mutate_text(&String::from_utf8_lossy(&seed[..end]), &text);
        fuzzing::nrrd(&[header.as_bytes(), &seed[end..]].concat());
    }

    #[test]
    fn mutated_mitsuba_vol(edits in byte_edits()) {
        fuzzing::mitsuba_vol(&mutate(vol_seed(), &edits));
    }

    #[test]
    fn mutated_vdb(which in any::<prop::sample::Index>(), edits in byte_edits()) {
        let seeds = vdb_seeds();
        fuzzing::vdb(&mutate(seeds[which.index(seeds.len())].clone(), &edits));
    }

    #[test]
    fn mutated_nifti(which in any::<prop::sample::Index>(), edits in byte_edits()) {
        let seeds = nifti_seeds();
        fuzzing::nifti(&mutate(seeds[which.index(seeds.len())].clone(), &edits));
    }

    /// Mutated solutions, as they are (the checksum refuses them) and with a valid header so
    /// that the metadata decoder and the consistency checks see them.
    #[test]
    fn mutated_solutions(which in any::<prop::sample::Index>(), edits in byte_edits()) {
        let seeds = solution_seeds();
        fuzzing::solution(&mutate(seeds[which.index(seeds.len())].clone(), &edits));
    }

    #[test]
    fn mutated_render_queries(which in any::<prop::sample::Index>(), edits in text_edits()) {
        let q = mutate_text(QUERY_SEEDS[which.index(QUERY_SEEDS.len())], &edits);
        fuzzing::render_query(q.as_bytes());
    }
}

/// The seeds themselves parse: the mutations start from valid input.
#[test]
fn the_seeds_are_valid() {
    for text in scene_seeds() {
        scene::Scene::from_toml_str(&text, Path::new(fuzzing::NO_DIR), Path::new("seed.toml"))
            .map(drop)
            .or_else(|e| {
                // Sample scenes that name a volume file find none in NO_DIR.
                if e.to_string().contains("volume.file") {
                    Ok(())
                } else {
                    Err(e)
                }
            })
            .unwrap();
    }
    for text in json_seeds() {
        volrad::service::routes::json_scene_table(&text).unwrap();
    }
    for bytes in nrrd_seeds() {
        medium::volume_io::read_nrrd_bytes(&bytes, Path::new("seed.nrrd")).unwrap();
    }
    medium::volume_io::read_mitsuba_vol_bytes(&vol_seed(), Path::new("seed.vol")).unwrap();
    for bytes in vdb_seeds() {
        medium::vdb::read_vdb_bytes(&bytes, Path::new("seed.vdb"), None).unwrap();
    }
    for bytes in nifti_seeds() {
        medium::nifti::read_nifti_bytes(&bytes, Path::new("seed.nii")).unwrap();
    }
    for bytes in solution_seeds() {
        volrad::engine::solution::Solution::from_bytes(&bytes, Path::new("seed.volrad")).unwrap();
    }
    for q in QUERY_SEEDS {
        let map = volrad::service::routes::query_from_str(q).unwrap();
        volrad::service::routes::parse_render_query(&map, &Default::default()).unwrap();
    }
}

/// Inputs that once broke a parser (tests/data/fuzz-regressions/, named by parser), each now
/// refused with an error:
/// - `solution-string-length.volrad` (found by `cargo fuzz run solution`): a string length of
///   about 8·10¹⁸ in the metadata made the decoder allocate it and abort the process;
/// - `nrrd-size-overflow.nrrd` (found reading the code): sizes whose byte count overflows
///   (2⁶² doubles) panicked on the multiplication;
/// - `scene_toml-hot-blackbody.toml` (found by `cargo fuzz run scene_toml` as a 14 s
///   timeout): a scene whose blackbody temperatures reach 91,200 K built a colour table of
///   91,200 × 471 Planck evaluations before it was refused for a misspelt camera key (the
///   table's size is tested in `medium::blackbody`);
/// - `environment_map-pfm-size-overflow.pfm` (found by `cargo fuzz run environment_map`): a
///   PFM header of 1,444,444,444² RGB pixels, whose byte count overflows 64 bits, panicked on
///   the multiplication (overflow checks on) or wrapped (off).
#[test]
fn inputs_that_broke_a_parser_are_refused() {
    let dir = repo("tests/data/fuzz-regressions");
    let mut seen = 0;
    for entry in std::fs::read_dir(&dir).unwrap() {
        let path = entry.unwrap().path();
        let name = path.file_name().unwrap().to_string_lossy().to_string();
        let bytes = std::fs::read(&path).unwrap();
        let label = Path::new(&name);
        let err = match name.split('-').next().unwrap() {
            "solution" => {
                fuzzing::solution(&bytes);
                volrad::engine::solution::Solution::from_bytes(
                    &fuzzing::with_valid_header(&bytes),
                    label,
                )
                .map(drop)
                .unwrap_err()
                .to_string()
            }
            "scene_toml" => {
                fuzzing::scene_toml(&bytes);
                let text = String::from_utf8_lossy(&bytes);
                scene::Scene::from_toml_str(&text, Path::new(fuzzing::NO_DIR), label)
                    .map(drop)
                    .unwrap_err()
                    .to_string()
            }
            "nrrd" => {
                fuzzing::nrrd(&bytes);
                medium::volume_io::read_nrrd_bytes(&bytes, label)
                    .map(drop)
                    .unwrap_err()
                    .to_string()
            }
            "environment_map" => {
                fuzzing::environment_map(&bytes);
                // The parsers of bytes name no file: the reader prefixes it.
                let err = gather::image_io::parse_pfm(&bytes).map(drop).unwrap_err();
                assert!(err.contains("data bytes"), "{err}");
                format!("{name}: {err}")
            }
            other => panic!("{name}: no parser `{other}`"),
        };
        assert!(err.starts_with(&format!("{name}: ")), "{err}");
        seen += 1;
    }
    assert_eq!(seen, 4);
}
