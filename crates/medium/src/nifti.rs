//! NIfTI files (`.nii`, `.nii.gz`): the single-file NIfTI-1 (`n+1`) and NIfTI-2 (`n+2`)
//! volumes that medical and neuro-imaging tools write, read into a dense x-fastest `f32`
//! volume with their voxel spacing (`pixdim[1..=3]`), so a scientist's CT or MR scan can be
//! a volrad medium.
//!
//! Written here rather than on the `nifti` crate: the format needs ~one header struct, and
//! volrad must refuse bad input with an error, never panic, abort on allocation or hang
//! (issue #22). Every size read from the header is checked against volrad's cell limit and
//! against the bytes actually present before anything is allocated for it; a gzip stream is
//! decoded only up to the bytes the header asks for, and not at all when the compressed size
//! cannot hold them.
//!
//! Supported: either byte order (told by `sizeof_hdr`, 348 or 540), one 3-D volume (`dim[0]`
//! of 1 to 7: missing dimensions count as 1, those past the third must be 1), datatypes uint8, int8, int16, uint16,
//! int32, uint32, float32 and float64, `scl_slope`/`scl_inter` scaling (applied when the
//! slope is finite and non-zero, in f64, then rounded to f32), `vox_offset` (extensions in
//! between are skipped), gzip-compressed files (told by the gzip magic, not the name).
//! Refused with an error naming it: header/image pairs (`ni1`/`ni2`, `.hdr` + `.img`), other
//! datatypes (complex, RGB, 64-bit integers, float128), time series and vector volumes.
//!
//! The qform/sform orientation is ignored: volrad places voxel `(i, j, k)` at its cell
//! `(i, j, k)`, the grid's corner at the origin (docs/scene-format.md).

use std::io::Read;
use std::path::Path;

use crate::volume_io::{gunzip_bounded, SampleType, VolumeData, MAX_DEFLATE_RATIO};
use crate::{Grid, MediumError};

const NIFTI1_HEADER: usize = 348;
const NIFTI2_HEADER: usize = 540;

/// The sample type of NIfTI `datatype` code `code` (nifti1.h), or why it is not read.
fn nifti_type(code: i16) -> Result<SampleType, String> {
    Ok(match code {
        2 => SampleType::U8,
        256 => SampleType::I8,
        4 => SampleType::I16,
        512 => SampleType::U16,
        8 => SampleType::I32,
        768 => SampleType::U32,
        16 => SampleType::F32,
        64 => SampleType::F64,
        other => {
            let name = match other {
                0 => "unknown (0)",
                1 => "binary (1)",
                32 => "complex64 (32)",
                128 => "RGB24 (128)",
                1024 => "int64 (1024)",
                1280 => "uint64 (1280)",
                1536 => "float128 (1536)",
                1792 => "complex128 (1792)",
                2048 => "complex256 (2048)",
                2304 => "RGBA32 (2304)",
                _ => "",
            };
            let name = if name.is_empty() {
                format!("code {other}")
            } else {
                name.to_string()
            };
            return Err(format!(
                    "NIfTI datatype {name} is not supported (uint8, int8, int16, uint16, int32, uint32, float32, float64)"
                ));
        }
    })
}

/// What a NIfTI header says about its volume (the parts volrad uses).
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct NiftiHeader {
    /// 1 (348-byte header) or 2 (540-byte header).
    pub version: u8,
    pub big_endian: bool,
    pub datatype: SampleType,
    /// `dim[1..=3]`.
    pub dims: [usize; 3],
    /// `pixdim[1..=3]`: the voxel spacing per axis, as stored (NIfTI-1 stores f32).
    pub pixdim: [f64; 3],
    pub scl_slope: f64,
    pub scl_inter: f64,
    /// Byte offset of the voxel data in the (decompressed) file.
    pub vox_offset: u64,
}

impl NiftiHeader {
    /// The voxel spacing when it is the same, finite and positive on every axis: volrad's
    /// cells are cubes.
    pub fn uniform_voxel_size(&self) -> Option<f64> {
        let [x, y, z] = self.pixdim;
        (x == y && y == z && x.is_finite() && x > 0.0).then_some(x)
    }

    /// The scaling NIfTI asks for: `value = slope · stored + inter` when the slope is finite
    /// and non-zero (a zero or NaN slope means "no scaling", as nibabel reads it too).
    fn scaling(&self) -> Option<(f64, f64)> {
        let slope = self.scl_slope;
        if !slope.is_finite() || slope == 0.0 {
            return None;
        }
        let inter = if self.scl_inter.is_finite() {
            self.scl_inter
        } else {
            0.0
        };
        // The identity is skipped so that stored values, -0.0 included, come through as is.
        (slope != 1.0 || inter != 0.0).then_some((slope, inter))
    }
}

/// A volume read from a NIfTI file.
#[derive(Clone, Debug, PartialEq)]
pub struct NiftiVolume {
    pub data: VolumeData,
    pub header: NiftiHeader,
}

/// Reads a `.nii` or `.nii.gz` file.
pub fn read_nifti(path: &Path) -> Result<NiftiVolume, MediumError> {
    let bytes = crate::volume_io::read_regular(path)?;
    read_nifti_bytes(&bytes, path)
}

/// [`read_nifti`] on bytes already in memory (gzip-compressed or not); `path` only names the
/// file in errors.
pub fn read_nifti_bytes(bytes: &[u8], path: &Path) -> Result<NiftiVolume, MediumError> {
    read_nifti_bytes_capped(bytes, path, u64::from(u32::MAX))
}

/// [`read_nifti_bytes`] with a tighter bound than volrad's cell limit on the volume (tests
/// use it so that mutated headers cannot ask for GiBs of memory).
pub fn read_nifti_bytes_capped(
    bytes: &[u8],
    path: &Path,
    max_cells: u64,
) -> Result<NiftiVolume, MediumError> {
    read(bytes, max_cells).map_err(|message| MediumError::Volume {
        file: path.to_path_buf(),
        message,
    })
}

/// Whether `bytes` are gzip-compressed (a `.nii.gz`; only the header tells more).
pub fn is_gzip(bytes: &[u8]) -> bool {
    bytes.starts_with(&[0x1f, 0x8b])
}

/// Whether `bytes` may be a NIfTI file: gzip-compressed, or beginning with a `sizeof_hdr` of
/// 348 (NIfTI-1) or 540 (NIfTI-2) in either byte order.
pub fn has_magic(bytes: &[u8]) -> bool {
    is_gzip(bytes)
        || (bytes.len() >= 4
            && [348i32, 540]
                .iter()
                .any(|n| bytes[..4] == n.to_le_bytes() || bytes[..4] == n.to_be_bytes()))
}

/// At most `limit` bytes of a gzip stream (all members); fewer if the stream ends first.
fn gunzip_prefix(bytes: &[u8], limit: u64) -> Result<Vec<u8>, String> {
    let mut out = Vec::new();
    flate2::read::MultiGzDecoder::new(bytes)
        .take(limit)
        .read_to_end(&mut out)
        .map_err(|e| format!("gzip data cannot be decoded: {e}"))?;
    Ok(out)
}

fn read(bytes: &[u8], max_cells: u64) -> Result<NiftiVolume, String> {
    let gzip = is_gzip(bytes);
    // The header first: at most 540 bytes, so a corrupt stream cannot make us inflate more.
    let head = if gzip {
        gunzip_prefix(bytes, NIFTI2_HEADER as u64)?
    } else {
        bytes[..bytes.len().min(NIFTI2_HEADER)].to_vec()
    };
    let header = parse_header(&head)?;
    let ty = header.datatype;
    let cells = header.dims.iter().map(|&d| d as u64).product::<u64>();
    if cells > max_cells {
        return Err(format!(
            "dims {:?} make {cells} voxels; volrad reads at most {max_cells}",
            header.dims
        ));
    }
    // Cell count ≤ 2^32 and 8-byte voxels: no overflow in u64.
    let data_bytes = cells * ty.size() as u64;
    let needed = header.vox_offset + data_bytes;
    let what = || {
        format!(
            "dims {:?} of {:?} at vox_offset {} need {needed} bytes",
            header.dims, ty, header.vox_offset
        )
    };
    let decoded;
    let all: &[u8] = if gzip {
        let bound = (bytes.len() as u64).saturating_mul(MAX_DEFLATE_RATIO);
        if needed > bound {
            return Err(format!(
                "{}; a gzip stream of {} bytes cannot hold that many: the file is truncated or its header is corrupt",
                what(),
                bytes.len()
            ));
        }
        decoded = gunzip_bounded(bytes, needed)?.0;
        &decoded
    } else {
        bytes
    };
    if (all.len() as u64) < needed {
        let unpacked = if gzip { " decompressed" } else { "" };
        return Err(format!(
            "{}, but the file has {}{unpacked} bytes: it is truncated",
            what(),
            all.len()
        ));
    }
    // Both fit in usize: `needed` bytes are in memory.
    let data = &all[header.vox_offset as usize..needed as usize];
    let scaling = header.scaling();
    let values = data
        .chunks_exact(ty.size())
        .map(|c| {
            let v = ty.decode(c, header.big_endian);
            match scaling {
                Some((slope, inter)) => (v * slope + inter) as f32,
                None => v as f32,
            }
        })
        .collect();
    Ok(NiftiVolume {
        data: VolumeData {
            dims: header.dims,
            values,
        },
        header,
    })
}

/// Little- or big-endian reads at fixed offsets of a header known to be long enough.
struct Fields<'a> {
    b: &'a [u8],
    big: bool,
}

impl Fields<'_> {
    fn arr<const N: usize>(&self, at: usize) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&self.b[at..at + N]);
        if self.big {
            a.reverse();
        }
        a
    }
    fn i16(&self, at: usize) -> i16 {
        i16::from_le_bytes(self.arr(at))
    }
    fn i32(&self, at: usize) -> i32 {
        i32::from_le_bytes(self.arr(at))
    }
    fn i64(&self, at: usize) -> i64 {
        i64::from_le_bytes(self.arr(at))
    }
    fn f32(&self, at: usize) -> f64 {
        f64::from(f32::from_le_bytes(self.arr(at)))
    }
    fn f64(&self, at: usize) -> f64 {
        f64::from_le_bytes(self.arr(at))
    }
}

fn parse_header(b: &[u8]) -> Result<NiftiHeader, String> {
    if b.len() < 4 {
        return Err(format!(
            "{} bytes is too short for a NIfTI header ({NIFTI1_HEADER} bytes)",
            b.len()
        ));
    }
    let sizeof_hdr = |big: bool| Fields { b, big }.i32(0);
    // `sizeof_hdr` is 348 (NIfTI-1) or 540 (NIfTI-2) in the file's byte order: that is how
    // the byte order is told.
    let (version, big) = [false, true]
        .into_iter()
        .find_map(|big| match sizeof_hdr(big) {
            348 => Some((1u8, big)),
            540 => Some((2u8, big)),
            _ => None,
        })
        .ok_or_else(|| {
            format!(
                "not a NIfTI file: sizeof_hdr is {} (expected 348 or 540 in either byte order)",
                sizeof_hdr(false)
            )
        })?;
    let size = if version == 1 {
        NIFTI1_HEADER
    } else {
        NIFTI2_HEADER
    };
    if b.len() < size {
        return Err(format!(
            "{} bytes is too short for a NIfTI-{version} header ({size} bytes)",
            b.len()
        ));
    }
    let f = Fields { b, big };
    let magic = if version == 1 { &b[344..348] } else { &b[4..8] };
    let single = if version == 1 { b"n+1\0" } else { b"n+2\0" };
    let pair = if version == 1 { b"ni1\0" } else { b"ni2\0" };
    if magic == pair {
        return Err(format!(
            "a NIfTI-{version} header of a .hdr/.img pair (magic `ni{version}`); volrad reads single-file .nii and .nii.gz: convert it (e.g. nibabel: nib.save(nib.load(\"x.hdr\"), \"x.nii\"))"
        ));
    }
    if magic != single {
        return Err(format!(
            "not a single-file NIfTI-{version} volume: magic is {:?} (expected \"n+{version}\")",
            String::from_utf8_lossy(magic).trim_end_matches('\0')
        ));
    }
    let (datatype, dim, pixdim, vox_offset, slope, inter) = if version == 1 {
        let dim: [i64; 8] = std::array::from_fn(|i| i64::from(f.i16(40 + 2 * i)));
        let pixdim: [f64; 8] = std::array::from_fn(|i| f.f32(76 + 4 * i));
        let off = f.f32(108);
        // NIfTI-1 stores the offset as a float; it must be a whole byte count.
        if !(off.is_finite() && off >= 0.0 && off.fract() == 0.0 && off < 1e15) {
            return Err(format!(
                "vox_offset {off} is not a whole, non-negative byte offset"
            ));
        }
        (f.i16(70), dim, pixdim, off as u64, f.f32(112), f.f32(116))
    } else {
        let dim: [i64; 8] = std::array::from_fn(|i| f.i64(16 + 8 * i));
        let pixdim: [f64; 8] = std::array::from_fn(|i| f.f64(104 + 8 * i));
        let off = u64::try_from(f.i64(168))
            .map_err(|_| format!("vox_offset {} is negative", f.i64(168)))?;
        (f.i16(12), dim, pixdim, off, f.f64(176), f.f64(184))
    };
    if vox_offset < size as u64 {
        return Err(format!(
            "vox_offset {vox_offset} lies inside the {size}-byte header"
        ));
    }
    let datatype = nifti_type(datatype)?;
    let ndim = dim[0];
    if !(1..=7).contains(&ndim) {
        return Err(format!(
            "dim[0] = {ndim}: a NIfTI file has 1 to 7 dimensions"
        ));
    }
    let ndim = ndim as usize;
    // Dimensions beyond 3 must be 1 (a single volume); below 3 they count as 1.
    if let Some(extra) = (4..=ndim).find(|&i| dim[i] != 1) {
        return Err(format!(
            "dim[{extra}] = {}: volrad reads one 3-D volume; a {ndim}-D NIfTI must have dims 4..{ndim} equal to 1 (dim = {:?})",
            dim[extra],
            &dim[1..=ndim]
        ));
    }
    let mut dims = [1usize; 3];
    for (a, d) in dims.iter_mut().enumerate().take(ndim.min(3)) {
        let n = dim[a + 1];
        *d = usize::try_from(n)
            .ok()
            .filter(|&n| n > 0)
            .ok_or_else(|| format!("dim[{}] = {n} must be positive", a + 1))?;
    }
    Grid::new(dims, 1.0).map_err(|e| e.to_string())?;
    Ok(NiftiHeader {
        version,
        big_endian: big,
        datatype,
        dims,
        pixdim: [pixdim[1], pixdim[2], pixdim[3]],
        scl_slope: slope,
        scl_inter: inter,
        vox_offset,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A minimal little- or big-endian NIfTI-1 header + data, for unit tests.
    fn nifti1(dims: [i16; 3], datatype: i16, big: bool, data: &[u8]) -> Vec<u8> {
        let mut b = vec![0u8; 352];
        let put = |b: &mut Vec<u8>, at: usize, v: &[u8]| {
            let mut v = v.to_vec();
            if big {
                v.reverse();
            }
            b[at..at + v.len()].copy_from_slice(&v);
        };
        put(&mut b, 0, &348i32.to_le_bytes());
        put(&mut b, 40, &3i16.to_le_bytes());
        for (i, d) in dims.iter().enumerate() {
            put(&mut b, 42 + 2 * i, &d.to_le_bytes());
        }
        put(&mut b, 70, &datatype.to_le_bytes());
        for i in 0..3 {
            put(&mut b, 80 + 4 * i, &1.0f32.to_le_bytes());
        }
        put(&mut b, 108, &352.0f32.to_le_bytes());
        b[344..348].copy_from_slice(b"n+1\0");
        b.extend_from_slice(data);
        b
    }

    #[test]
    fn reads_a_big_endian_int16_volume() {
        let data: Vec<u8> = [1i16, -2, 300, 4]
            .iter()
            .flat_map(|v| v.to_be_bytes())
            .collect();
        let v = read(&nifti1([2, 2, 1], 4, true, &data), 1 << 20).unwrap();
        assert!(v.header.big_endian);
        assert_eq!(v.data.dims, [2, 2, 1]);
        assert_eq!(v.data.values, vec![1.0, -2.0, 300.0, 4.0]);
    }

    #[test]
    fn a_2d_image_is_one_slice_and_a_time_series_is_refused() {
        let mut image = nifti1([2, 2, 9], 2, false, &[1, 2, 3, 4]);
        image[40..42].copy_from_slice(&2i16.to_le_bytes());
        let v = read(&image, 1 << 20).unwrap();
        assert_eq!(v.data.dims, [2, 2, 1]);
        assert_eq!(v.data.values, vec![1.0, 2.0, 3.0, 4.0]);
        let mut series = nifti1([1, 1, 1], 2, false, &[1, 2]);
        series[40..42].copy_from_slice(&4i16.to_le_bytes());
        series[48..50].copy_from_slice(&2i16.to_le_bytes());
        assert!(read(&series, 1 << 20).unwrap_err().contains("dim[4] = 2"));
    }

    #[test]
    fn refuses_pairs_short_data_and_bad_dims() {
        let mut pair = nifti1([1, 1, 1], 2, false, &[7]);
        pair[344..348].copy_from_slice(b"ni1\0");
        assert!(read(&pair, 1 << 20).unwrap_err().contains(".hdr/.img"));
        let short = nifti1([2, 2, 2], 16, false, &[0; 31]);
        assert!(read(&short, 1 << 20).unwrap_err().contains("truncated"));
        let zero = nifti1([2, 0, 2], 2, false, &[]);
        assert!(read(&zero, 1 << 20).unwrap_err().contains("dim[2] = 0"));
        let huge = nifti1([200, 200, 200], 64, false, &[]);
        assert!(read(&huge, 1 << 20).unwrap_err().contains("at most"));
    }
}
