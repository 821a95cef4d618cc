//! Volume files: raw little-endian f32, Mitsuba's binary grid (`.vol`), NRRD, OpenVDB
//! (`.vdb`, through [`crate::vdb`]) and NIfTI (`.nii`, `.nii.gz`, through [`crate::nifti`]),
//! read into x-fastest `f32` arrays; raw and NRRD writers
//! that replace their target atomically.
//!
//! Every error names the file and says what was expected and what was found.

use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use crate::MediumError;

/// A scalar volume: `dims = [nx, ny, nz]` and `nx·ny·nz` values, x fastest
/// (`i + nx (j + ny k)`, physics.md).
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeData {
    pub dims: [usize; 3],
    pub values: Vec<f32>,
}

impl VolumeData {
    /// Checks that the value count matches the dims.
    pub fn new(dims: [usize; 3], values: Vec<f32>) -> Result<Self, MediumError> {
        let cells = cell_count(dims)
            .ok_or_else(|| MediumError::invalid("volume dims", format!("{dims:?} overflow")))?;
        if values.len() != cells {
            return Err(MediumError::invalid(
                "volume",
                format!("{} values for dims {dims:?} ({cells} cells)", values.len()),
            ));
        }
        Ok(VolumeData { dims, values })
    }
}

/// The on-disk formats volrad reads, chosen by extension.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VolumeFormat {
    /// Headerless little-endian f32, x fastest; dims come from the scene.
    RawF32,
    /// Mitsuba's binary grid: `VOL`, version 3, float32 encoding, one channel.
    MitsubaVol,
    /// NRRD (`.nrrd` attached or `.nhdr` detached header).
    Nrrd,
    /// OpenVDB (`.vdb`): one float, double or half grid, expanded over its active voxels.
    OpenVdb,
    /// NIfTI-1 or NIfTI-2 single file (`.nii`, or `.nii.gz` compressed): one 3-D volume.
    Nifti,
}

impl VolumeFormat {
    /// `.vol` → Mitsuba, `.nrrd`/`.nhdr` → NRRD, `.vdb` → OpenVDB, `.nii`/`.nii.gz` →
    /// NIfTI, anything else (`.f32`, `.raw`, `.bin`) → raw.
    pub fn from_path(path: &Path) -> VolumeFormat {
        let name = path
            .file_name()
            .and_then(|n| n.to_str())
            .map(|n| n.to_ascii_lowercase());
        if name.as_deref().is_some_and(|n| n.ends_with(".nii.gz")) {
            return VolumeFormat::Nifti;
        }
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        match ext.as_deref() {
            Some("vol") => VolumeFormat::MitsubaVol,
            Some("nrrd") | Some("nhdr") => VolumeFormat::Nrrd,
            Some("vdb") => VolumeFormat::OpenVdb,
            Some("nii") => VolumeFormat::Nifti,
            _ => VolumeFormat::RawF32,
        }
    }
}

impl VolumeFormat {
    /// The format of a file's `bytes`, told by its magic number: `NRRD000x`, `VOL`, OpenVDB's
    /// int64, NIfTI's `sizeof_hdr` (or gzip); `None` for anything else (raw f32 has none).
    pub fn sniff(bytes: &[u8]) -> Option<VolumeFormat> {
        if bytes.starts_with(b"NRRD000") {
            Some(VolumeFormat::Nrrd)
        } else if bytes.starts_with(b"VOL") {
            Some(VolumeFormat::MitsubaVol)
        } else if crate::vdb::has_magic(bytes) {
            Some(VolumeFormat::OpenVdb)
        } else if crate::nifti::has_magic(bytes) {
            Some(VolumeFormat::Nifti)
        } else {
            None
        }
    }

    /// The file-name suffix [`VolumeFormat::from_path`] reads `bytes` of this format by:
    /// `nii.gz` for a gzip-compressed NIfTI file.
    pub fn extension(self, bytes: &[u8]) -> &'static str {
        match self {
            VolumeFormat::RawF32 => "f32",
            VolumeFormat::MitsubaVol => "vol",
            VolumeFormat::Nrrd => "nrrd",
            VolumeFormat::OpenVdb => "vdb",
            VolumeFormat::Nifti if crate::nifti::is_gzip(bytes) => "nii.gz",
            VolumeFormat::Nifti => "nii",
        }
    }

    /// The format's name in messages.
    pub fn name(self) -> &'static str {
        match self {
            VolumeFormat::RawF32 => "raw f32",
            VolumeFormat::MitsubaVol => "Mitsuba .vol",
            VolumeFormat::Nrrd => "NRRD",
            VolumeFormat::OpenVdb => "OpenVDB",
            VolumeFormat::Nifti => "NIfTI",
        }
    }
}

/// Reads a self-describing volume file's `bytes` (not raw f32, which has no header) received
/// from elsewhere — an upload: at most `max_cells` cells, refused from the header before the
/// data is read or inflated where the format allows, and NRRD data attached to its header
/// ([`read_nrrd_bytes_attached`]). `label` names the bytes in errors. A `.vdb` gives its
/// first float grid.
pub fn read_volume_bytes_capped(
    bytes: &[u8],
    format: VolumeFormat,
    label: &Path,
    max_cells: u64,
) -> Result<VolumeData, MediumError> {
    let data = match format {
        VolumeFormat::RawF32 => {
            return Err(vol_err(
                label,
                "raw f32 has no header: its dims must be given",
            ))
        }
        VolumeFormat::Nrrd => read_nrrd_bytes_attached(bytes, label, max_cells)?,
        // Uncompressed: the data it describes is in `bytes`, so no larger than they are.
        VolumeFormat::MitsubaVol => read_mitsuba_vol_bytes(bytes, label)?,
        VolumeFormat::OpenVdb => {
            crate::vdb::read_vdb_bytes_capped(bytes, label, None, max_cells)?.data
        }
        VolumeFormat::Nifti => crate::nifti::read_nifti_bytes_capped(bytes, label, max_cells)?.data,
    };
    let cells = data.dims.iter().map(|&d| d as u64).product::<u64>();
    if cells > max_cells {
        return Err(vol_err(
            label,
            format!("{cells} cells, over the limit of {max_cells}"),
        ));
    }
    Ok(data)
}

fn cell_count(dims: [usize; 3]) -> Option<usize> {
    dims.iter().try_fold(1usize, |acc, &d| acc.checked_mul(d))
}

fn vol_err(file: &Path, message: impl Into<String>) -> MediumError {
    MediumError::Volume {
        file: file.to_path_buf(),
        message: message.into(),
    }
}

fn io_err(file: &Path, error: std::io::Error) -> MediumError {
    MediumError::Io {
        file: file.to_path_buf(),
        error,
    }
}

/// Deflate cannot expand better than about 1032:1: a gzip stream shorter than this fraction of
/// the size a header promises is truncated, and is refused before any of it is inflated.
pub(crate) const MAX_DEFLATE_RATIO: u64 = 1032;

/// The first `needed` bytes of a gzip stream (all members), and whether more data follow
/// them. The rest is decoded into a sink (no memory; at most [`MAX_DEFLATE_RATIO`] times the
/// compressed size) so that a truncated stream or a wrong CRC is refused rather than read as
/// if complete, and a stream that inflates without bound (a gzip bomb) costs no memory.
pub(crate) fn gunzip_bounded(bytes: &[u8], needed: u64) -> Result<(Vec<u8>, bool), String> {
    let mut dec = flate2::read::MultiGzDecoder::new(bytes);
    let mut out = Vec::new();
    let bad = |e: std::io::Error| format!("gzip data cannot be decoded: {e}");
    dec.by_ref()
        .take(needed)
        .read_to_end(&mut out)
        .map_err(bad)?;
    let mut more = false;
    if (out.len() as u64) == needed {
        let bound = (bytes.len() as u64).saturating_mul(MAX_DEFLATE_RATIO);
        more = std::io::copy(&mut dec.take(bound), &mut std::io::sink()).map_err(bad)? > 0;
    }
    Ok((out, more))
}

/// Reads a whole volume file through [`crate::regular_file`]: a FIFO, device or directory is
/// refused, naming the path and what it is, before anything is read.
pub(crate) fn read_regular(path: &Path) -> Result<Vec<u8>, MediumError> {
    crate::regular_file::read(path).map_err(|e| io_err(path, e))
}

/// Reads a volume in the format its extension names. `dims` is required for raw files; for
/// `.vol`, NRRD, `.vdb` and NIfTI the file gives them and `dims`, when given, must agree. A `.vdb`
/// gives its first float, double or half grid; [`load_volume_with`] chooses a grid and
/// returns its placement.
pub fn load_volume(path: &Path, dims: Option<[usize; 3]>) -> Result<VolumeData, MediumError> {
    load_volume_with(path, &VolumeRequest { dims, grid: None }).map(|v| v.data)
}

/// What a caller asks of a volume file beyond its path.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct VolumeRequest<'a> {
    /// Required for raw files; checked against the file's own otherwise.
    pub dims: Option<[usize; 3]>,
    /// The grid of a `.vdb` file (default: its first float, double or half grid); refused
    /// for other formats, which hold one volume.
    pub grid: Option<&'a str>,
}

/// A volume and, for a `.vdb`, where its grid lies in the file's world.
#[derive(Clone, Debug, PartialEq)]
pub struct LoadedVolume {
    pub data: VolumeData,
    pub placement: Option<crate::vdb::VdbPlacement>,
    /// A NIfTI file's voxel spacing per axis (`pixdim[1..=3]`, as stored): the scene's
    /// default cell size when the three are equal. (A `.vdb`'s is in `placement`.)
    pub voxel_size: Option<[f64; 3]>,
}

/// [`load_volume`] with a grid choice, also returning a `.vdb` grid's placement or a NIfTI
/// file's voxel spacing.
pub fn load_volume_with(path: &Path, request: &VolumeRequest) -> Result<LoadedVolume, MediumError> {
    let format = VolumeFormat::from_path(path);
    if request.grid.is_some() && format != VolumeFormat::OpenVdb {
        return Err(vol_err(
            path,
            "a grid name applies to OpenVDB (.vdb) files only",
        ));
    }
    let mut voxel_size = None;
    let (data, placement) = match format {
        VolumeFormat::RawF32 => {
            let dims = request.dims.ok_or_else(|| {
                vol_err(
                    path,
                    "a raw f32 volume needs dims [nx, ny, nz] (it has no header)",
                )
            })?;
            return Ok(LoadedVolume {
                data: read_raw_f32(path, dims)?,
                placement: None,
                voxel_size: None,
            });
        }
        VolumeFormat::MitsubaVol => (read_mitsuba_vol(path)?, None),
        VolumeFormat::Nrrd => (read_nrrd(path)?, None),
        VolumeFormat::OpenVdb => {
            let v = crate::vdb::read_vdb(path, request.grid)?;
            (v.data, Some(v.placement))
        }
        VolumeFormat::Nifti => {
            let v = crate::nifti::read_nifti(path)?;
            voxel_size = Some(v.header.pixdim);
            (v.data, None)
        }
    };
    if let Some(d) = request.dims {
        if d != data.dims {
            let what = if placement.is_some() {
                "the grid's active voxels span"
            } else {
                "the file's header says"
            };
            return Err(vol_err(
                path,
                format!("{what} dims {:?} but {d:?} were given", data.dims),
            ));
        }
    }
    Ok(LoadedVolume {
        data,
        placement,
        voxel_size,
    })
}

/// Reads headerless little-endian f32 values; the file size must be exactly `nx·ny·nz·4`.
pub fn read_raw_f32(path: &Path, dims: [usize; 3]) -> Result<VolumeData, MediumError> {
    let expected = cell_count(dims)
        .and_then(|n| n.checked_mul(4))
        .ok_or_else(|| vol_err(path, format!("dims {dims:?} are too large")))?;
    let mut file = crate::regular_file::open(path).map_err(|e| io_err(path, e))?;
    let actual = file.metadata().map_err(|e| io_err(path, e))?.len();
    if actual != expected as u64 {
        return Err(vol_err(
            path,
            format!("file has {actual} bytes but dims {dims:?} need {expected} bytes (nx·ny·nz·4)"),
        ));
    }
    let mut bytes = Vec::with_capacity(expected);
    file.read_to_end(&mut bytes).map_err(|e| io_err(path, e))?;
    if bytes.len() != expected {
        return Err(vol_err(
            path,
            format!(
                "file changed while reading: {} bytes, expected {expected}",
                bytes.len()
            ),
        ));
    }
    Ok(VolumeData {
        dims,
        values: f32_from_le(&bytes),
    })
}

fn f32_from_le(bytes: &[u8]) -> Vec<f32> {
    bytes
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

const VOL_HEADER_BYTES: usize = 48;

/// Reads Mitsuba's binary grid: `b"VOL"`, version byte 3, i32 encoding (1 = float32), i32
/// `xres, yres, zres`, i32 channels (must be 1), 6 f32 bounding box, then x-fastest data.
pub fn read_mitsuba_vol(path: &Path) -> Result<VolumeData, MediumError> {
    read_mitsuba_vol_bytes(&read_regular(path)?, path)
}

/// [`read_mitsuba_vol`] on bytes already in memory; `path` only names the file in errors.
pub fn read_mitsuba_vol_bytes(bytes: &[u8], path: &Path) -> Result<VolumeData, MediumError> {
    if bytes.len() < VOL_HEADER_BYTES {
        return Err(vol_err(
            path,
            format!(
                "{} bytes is too short for a Mitsuba .vol header ({VOL_HEADER_BYTES} bytes)",
                bytes.len()
            ),
        ));
    }
    if &bytes[0..3] != b"VOL" {
        return Err(vol_err(
            path,
            "not a Mitsuba .vol file (expected magic `VOL`)",
        ));
    }
    if bytes[3] != 3 {
        return Err(vol_err(
            path,
            format!(
                "Mitsuba .vol version {} is not supported (expected 3)",
                bytes[3]
            ),
        ));
    }
    let i32_at =
        |o: usize| i32::from_le_bytes([bytes[o], bytes[o + 1], bytes[o + 2], bytes[o + 3]]);
    let encoding = i32_at(4);
    if encoding != 1 {
        return Err(vol_err(
            path,
            format!("Mitsuba .vol encoding {encoding} is not supported (expected 1 = float32)"),
        ));
    }
    let res = [i32_at(8), i32_at(12), i32_at(16)];
    if res.iter().any(|&r| r <= 0) {
        return Err(vol_err(
            path,
            format!("resolution {res:?} must be positive"),
        ));
    }
    let channels = i32_at(20);
    if channels != 1 {
        return Err(vol_err(
            path,
            format!("{channels} channels are not supported (expected a 1-channel density grid)"),
        ));
    }
    let dims = res.map(|r| r as usize);
    let expected = cell_count(dims)
        .and_then(|n| n.checked_mul(4))
        .and_then(|n| n.checked_add(VOL_HEADER_BYTES))
        .ok_or_else(|| vol_err(path, format!("dims {dims:?} are too large")))?;
    if bytes.len() != expected {
        return Err(vol_err(
            path,
            format!(
                "file has {} bytes but a {dims:?} float32 grid needs {expected} (48-byte header + nx·ny·nz·4)",
                bytes.len()
            ),
        ));
    }
    Ok(VolumeData {
        dims,
        values: f32_from_le(&bytes[VOL_HEADER_BYTES..]),
    })
}

/// Writes Mitsuba's binary grid (float32, one channel) with bounding box
/// `[0, 0, 0] – dims · cell_size`, atomically.
pub fn write_mitsuba_vol(
    path: &Path,
    volume: &VolumeData,
    cell_size: f32,
) -> Result<(), MediumError> {
    check_len(path, volume)?;
    let mut out = Vec::with_capacity(VOL_HEADER_BYTES + volume.values.len() * 4);
    out.extend_from_slice(b"VOL");
    out.push(3);
    out.extend_from_slice(&1i32.to_le_bytes());
    for d in volume.dims {
        let d = i32::try_from(d).map_err(|_| vol_err(path, format!("dim {d} exceeds i32")))?;
        out.extend_from_slice(&d.to_le_bytes());
    }
    out.extend_from_slice(&1i32.to_le_bytes());
    for v in [0.0, 0.0, 0.0] {
        out.extend_from_slice(&f32::to_le_bytes(v));
    }
    for d in volume.dims {
        out.extend_from_slice(&(d as f32 * cell_size).to_le_bytes());
    }
    for v in &volume.values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    write_atomically(path, &out)
}

/// A sample type of a volume file (NRRD's `type`, NIfTI's `datatype`): the integer and
/// floating-point types volrad reads, whatever the format's name for them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub enum SampleType {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    F32,
    F64,
}

impl SampleType {
    /// Bytes per sample.
    pub fn size(self) -> usize {
        match self {
            SampleType::I8 | SampleType::U8 => 1,
            SampleType::I16 | SampleType::U16 => 2,
            SampleType::I32 | SampleType::U32 | SampleType::F32 => 4,
            SampleType::F64 => 8,
        }
    }

    /// One sample as f64 (exact for every type), from `b.len() >= self.size()`.
    pub fn decode(self, b: &[u8], big_endian: bool) -> f64 {
        macro_rules! num {
            ($t:ty, $n:literal) => {{
                let mut a = [0u8; $n];
                a.copy_from_slice(&b[..$n]);
                if big_endian {
                    <$t>::from_be_bytes(a)
                } else {
                    <$t>::from_le_bytes(a)
                }
            }};
        }
        match self {
            SampleType::I8 => f64::from(b[0] as i8),
            SampleType::U8 => f64::from(b[0]),
            SampleType::I16 => f64::from(num!(i16, 2)),
            SampleType::U16 => f64::from(num!(u16, 2)),
            SampleType::I32 => f64::from(num!(i32, 4)),
            SampleType::U32 => f64::from(num!(u32, 4)),
            SampleType::F32 => f64::from(num!(f32, 4)),
            SampleType::F64 => num!(f64, 8),
        }
    }
}

/// NRRD's spelling of a sample type.
fn nrrd_type(s: &str) -> Option<SampleType> {
    Some(match s {
        "signed char" | "int8" | "int8_t" => SampleType::I8,
        "uchar" | "unsigned char" | "uint8" | "uint8_t" => SampleType::U8,
        "short" | "short int" | "signed short" | "signed short int" | "int16" | "int16_t" => {
            SampleType::I16
        }
        "ushort" | "unsigned short" | "unsigned short int" | "uint16" | "uint16_t" => {
            SampleType::U16
        }
        "int" | "signed int" | "int32" | "int32_t" => SampleType::I32,
        "uint" | "unsigned int" | "uint32" | "uint32_t" => SampleType::U32,
        "float" => SampleType::F32,
        "double" => SampleType::F64,
        _ => return None,
    })
}

/// Reads an NRRD volume: `dimension: 3`, a numeric `type`, `encoding` raw or gzip, `endian`
/// for multi-byte types, data attached after the blank line or in a detached `data file`
/// (relative to the header). Values are converted to f32 without rescaling.
pub fn read_nrrd(path: &Path) -> Result<VolumeData, MediumError> {
    read_nrrd_bytes(&read_regular(path)?, path)
}

/// [`read_nrrd`] on the header file's bytes already in memory; `path` names the file in
/// errors and is where a detached `data file` is looked for (beside it).
pub fn read_nrrd_bytes(bytes: &[u8], path: &Path) -> Result<VolumeData, MediumError> {
    nrrd_from_bytes(bytes, path, u64::MAX, true)
}

/// [`read_nrrd_bytes`] for bytes from elsewhere (an upload): the data must follow the header
/// in `bytes` (a detached `data file` would name a file on this machine), and a header asking
/// for more than `max_cells` cells is refused before any data is read or inflated.
pub fn read_nrrd_bytes_attached(
    bytes: &[u8],
    path: &Path,
    max_cells: u64,
) -> Result<VolumeData, MediumError> {
    nrrd_from_bytes(bytes, path, max_cells, false)
}

fn nrrd_from_bytes(
    bytes: &[u8],
    path: &Path,
    max_cells: u64,
    allow_detached: bool,
) -> Result<VolumeData, MediumError> {
    if !bytes.starts_with(b"NRRD000") {
        return Err(vol_err(
            path,
            "not an NRRD file (expected magic `NRRD000x`)",
        ));
    }
    // The header ends at the first empty line (or at end of file for a detached header).
    let mut pos = 0;
    let mut header_end = bytes.len();
    let mut lines = Vec::new();
    while pos < bytes.len() {
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |p| pos + p);
        let line = String::from_utf8_lossy(&bytes[pos..end])
            .trim_end_matches('\r')
            .to_string();
        pos = (end + 1).min(bytes.len());
        if line.is_empty() {
            header_end = pos;
            break;
        }
        lines.push(line);
    }
    let mut fields: Vec<(String, String)> = Vec::new();
    for line in lines.iter().skip(1) {
        if line.starts_with('#') || line.contains(":=") {
            continue; // comments and key/value pairs carry no layout
        }
        let Some((k, v)) = line.split_once(": ") else {
            return Err(vol_err(
                path,
                format!("malformed NRRD header line `{line}`"),
            ));
        };
        fields.push((k.trim().to_ascii_lowercase(), v.trim().to_string()));
    }
    let field = |names: &[&str]| {
        fields
            .iter()
            .find(|(k, _)| names.contains(&k.as_str()))
            .map(|(_, v)| v.as_str())
    };
    let required = |name: &str| {
        field(&[name]).ok_or_else(|| vol_err(path, format!("NRRD header has no `{name}` field")))
    };

    let ty_text = required("type")?;
    let ty = nrrd_type(ty_text).ok_or_else(|| {
        vol_err(
            path,
            format!("NRRD type `{ty_text}` is not supported (float, double, uchar, ushort, short, int, uint)"),
        )
    })?;
    let dimension = required("dimension")?;
    if dimension != "3" {
        return Err(vol_err(
            path,
            format!("NRRD dimension {dimension} is not supported (expected 3)"),
        ));
    }
    let sizes_text = required("sizes")?;
    let sizes: Vec<usize> = sizes_text
        .split_whitespace()
        .map(|s| s.parse::<usize>())
        .collect::<Result<_, _>>()
        .map_err(|_| {
            vol_err(
                path,
                format!("NRRD sizes `{sizes_text}` are not whole numbers"),
            )
        })?;
    if sizes.len() != 3 || sizes.contains(&0) {
        return Err(vol_err(
            path,
            format!("NRRD sizes `{sizes_text}` must be three positive numbers"),
        ));
    }
    let dims = [sizes[0], sizes[1], sizes[2]];
    let cells = dims
        .iter()
        .try_fold(1u64, |acc, &d| acc.checked_mul(d as u64))
        .unwrap_or(u64::MAX);
    if cells > max_cells {
        return Err(vol_err(
            path,
            format!("NRRD sizes `{sizes_text}` are {cells} cells, over the limit of {max_cells}"),
        ));
    }
    let encoding = required("encoding")?;
    let gzip = match encoding {
        "raw" => false,
        "gzip" | "gz" => true,
        other => {
            return Err(vol_err(
                path,
                format!("NRRD encoding `{other}` is not supported (raw or gzip)"),
            ))
        }
    };
    let little = match field(&["endian"]) {
        Some("little") => true,
        Some("big") => false,
        None if ty.size() == 1 => true,
        None => {
            return Err(vol_err(
                path,
                format!("NRRD type `{ty_text}` needs an `endian` field"),
            ))
        }
        Some(other) => {
            return Err(vol_err(
                path,
                format!("NRRD endian `{other}` (little or big)"),
            ))
        }
    };
    let byte_skip: i64 = match field(&["byte skip", "byteskip"]) {
        None => 0,
        Some(s) => s
            .parse()
            .map_err(|_| vol_err(path, format!("NRRD byte skip `{s}` is not an integer")))?,
    };

    let (data_path, raw): (PathBuf, Vec<u8>) = match field(&["data file", "datafile"]) {
        Some(name) => {
            if !allow_detached {
                return Err(vol_err(
                    path,
                    format!("NRRD `data file: {name}`: the data must follow the header in the same file"),
                ));
            }
            if name.starts_with("LIST") || name.split_whitespace().count() > 1 {
                return Err(vol_err(
                    path,
                    format!("NRRD `data file: {name}`: only a single detached file is supported"),
                ));
            }
            let base = path.parent().unwrap_or(Path::new("."));
            let p = base.join(name);
            let raw = read_regular(&p)?;
            (p, raw)
        }
        None => (path.to_path_buf(), bytes[header_end..].to_vec()),
    };

    let needed = cell_count(dims)
        .and_then(|n| n.checked_mul(ty.size()))
        .ok_or_else(|| vol_err(path, format!("sizes {dims:?} are too large")))?;
    // NRRD's byte skip counts bytes of the decoded data; -1 means "the data are the last
    // bytes", allowed for raw encoding only.
    let decoded: Vec<u8> = if gzip {
        // Inflate only what the header asks for (the skip, then the data); more is an error.
        // ("The last bytes", skip −1, would need the whole stream: raw encoding only.)
        if byte_skip < 0 {
            return Err(vol_err(
                path,
                format!("NRRD byte skip {byte_skip} is not supported with encoding `{encoding}`"),
            ));
        }
        let limit = (byte_skip as u64).saturating_add(needed as u64);
        if limit > (raw.len() as u64).saturating_mul(MAX_DEFLATE_RATIO) {
            return Err(vol_err(
                &data_path,
                format!(
                    "sizes {dims:?} of type `{ty_text}` need {needed} bytes, more than a gzip \
                     stream of {} bytes can hold: the file is truncated or its header is wrong",
                    raw.len()
                ),
            ));
        }
        let (out, more) = gunzip_bounded(&raw, limit).map_err(|e| vol_err(&data_path, e))?;
        if more {
            return Err(vol_err(
                &data_path,
                format!(
                    "NRRD data has more than the {needed} bytes sizes {dims:?} of type \
                     `{ty_text}` need"
                ),
            ));
        }
        out
    } else {
        raw
    };
    let payload: &[u8] = match byte_skip {
        -1 if !gzip => &decoded[decoded.len().saturating_sub(needed)..],
        s if s >= 0 => &decoded[(s as usize).min(decoded.len())..],
        s => {
            return Err(vol_err(
                path,
                format!("NRRD byte skip {s} is not supported with encoding `{encoding}`"),
            ))
        }
    };
    if payload.len() != needed {
        return Err(vol_err(
            &data_path,
            format!(
                "NRRD data has {} bytes but sizes {dims:?} of type `{ty_text}` need {needed}",
                payload.len()
            ),
        ));
    }
    let values = payload
        .chunks_exact(ty.size())
        .map(|c| ty.decode(c, !little) as f32)
        .collect();
    Ok(VolumeData { dims, values })
}

/// Optional header content for [`write_nrrd`].
#[derive(Clone, Debug, Default, PartialEq)]
pub struct NrrdWriteOptions {
    /// Written as `# key: value` comment lines.
    pub comments: Vec<(String, String)>,
    /// One unit name for every axis (`units: "m" "m" "m"`).
    pub units: Option<String>,
    /// World spacing per axis (`spacings: h h h`).
    pub spacings: Option<[f64; 3]>,
    /// Compress the data with gzip instead of writing it raw.
    pub gzip: bool,
}

/// Writes headerless little-endian f32, atomically (temp file + rename).
pub fn write_raw_f32(path: &Path, volume: &VolumeData) -> Result<(), MediumError> {
    check_len(path, volume)?;
    let mut out = Vec::with_capacity(volume.values.len() * 4);
    for v in &volume.values {
        out.extend_from_slice(&v.to_le_bytes());
    }
    write_atomically(path, &out)
}

/// Writes an attached-data NRRD (`type: float`, little endian, raw unless `options.gzip`),
/// atomically.
pub fn write_nrrd(
    path: &Path,
    volume: &VolumeData,
    options: &NrrdWriteOptions,
) -> Result<(), MediumError> {
    check_len(path, volume)?;
    let one_line = |s: &str| s.replace(['\n', '\r'], " ");
    let mut header = String::from("NRRD0004\n# written by volrad\n");
    for (k, v) in &options.comments {
        header.push_str(&format!("# {}: {}\n", one_line(k), one_line(v)));
    }
    header.push_str("type: float\ndimension: 3\n");
    let [nx, ny, nz] = volume.dims;
    header.push_str(&format!("sizes: {nx} {ny} {nz}\n"));
    if let Some([a, b, c]) = options.spacings {
        header.push_str(&format!("spacings: {a} {b} {c}\n"));
    }
    if let Some(u) = &options.units {
        let u = one_line(u).replace('"', "'");
        header.push_str(&format!("units: \"{u}\" \"{u}\" \"{u}\"\n"));
    }
    header.push_str("endian: little\n");
    header.push_str(if options.gzip {
        "encoding: gzip\n\n"
    } else {
        "encoding: raw\n\n"
    });
    let mut data = Vec::with_capacity(volume.values.len() * 4);
    for v in &volume.values {
        data.extend_from_slice(&v.to_le_bytes());
    }
    let mut out = header.into_bytes();
    if options.gzip {
        let mut enc = flate2::write::GzEncoder::new(out, flate2::Compression::default());
        enc.write_all(&data).map_err(|e| io_err(path, e))?;
        out = enc.finish().map_err(|e| io_err(path, e))?;
    } else {
        out.extend_from_slice(&data);
    }
    write_atomically(path, &out)
}

fn check_len(path: &Path, volume: &VolumeData) -> Result<(), MediumError> {
    if cell_count(volume.dims) != Some(volume.values.len()) {
        return Err(vol_err(
            path,
            format!(
                "refusing to write {} values with dims {:?}",
                volume.values.len(),
                volume.dims
            ),
        ));
    }
    Ok(())
}

/// Replaces `path` with `bytes` through [`atomic_file`](crate::atomic_file), so readers see
/// the old file or the new one, never half of one.
fn write_atomically(path: &Path, bytes: &[u8]) -> Result<(), MediumError> {
    crate::atomic_file::write_bytes(path, bytes).map_err(|e| io_err(path, e))
}
