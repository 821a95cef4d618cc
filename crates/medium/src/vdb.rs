//! OpenVDB files (`.vdb`): one scalar grid of a file written by OpenVDB 7 to 12 (file format
//! 222–225), read into a dense x-fastest `f32` volume over the grid's active voxels, with the
//! placement (index bounding box and world transform) that the scene needs to put it in space.
//!
//! Written from the format as OpenVDB's own reader defines it (`io/Archive.cc`,
//! `io/Compression.{h,cc}`, `tree/{RootNode,InternalNode,LeafNode}.h`, `math/Maps.h`) rather
//! than on a crate: the vdb-rs crate panics on some transforms, and volrad must refuse bad
//! input with an error, never panic, abort on allocation or hang (issue #22). So every count
//! and size read from the file is checked against the bytes that remain before anything is
//! allocated for it, and the dense result is capped at [`MAX_VDB_CELLS`].
//!
//! Supported: float, double and half grids (`Tree_float_5_4_3`, `Tree_double_5_4_3`,
//! `Tree_half_5_4_3`, and the `_HalfFloat` suffix of `saveFloatAsHalf`); no compression, zip
//! (zlib) and Blosc (Blosc1 frames: byte shuffle, LZ4 or zlib codec) with or without the
//! active-mask compression; instanced grids; scale, uniform-scale, translation,
//! scale-translate, uniform-scale-translate, and affine/unitary maps that are axis-aligned
//! positive scales. Refused with an error naming it: older or newer file versions, streams
//! without grid offsets, rotated, sheared or frustum transforms, the blosclz and other Blosc
//! codecs, bit-shuffle.
//!
//! Dense values: voxel `bbox_min + (i, j, k)` goes to volrad cell `(i, j, k)`. Active voxels
//! carry their value, inactive voxels inside the box the value the file stores for them
//! (OpenVDB's `getValue`): a leaf's inactive value, an inactive tile's value, or the grid's
//! background where no node exists. Active tiles are expanded voxel by voxel.

use std::io::Read;
use std::path::Path;

use crate::volume_io::VolumeData;
use crate::MediumError;

/// The largest dense box volrad expands a grid into (2^31 values, 8 GiB of f32): below
/// [`Grid`](crate::Grid)'s 2^32 cell limit, and a bound on what a small file can ask for.
pub const MAX_VDB_CELLS: u64 = 1 << 31;

/// `"VDB "` as OpenVDB's int64 magic number.
const MAGIC: i64 = 0x5644_4220;
/// Whether `bytes` begin with OpenVDB's magic number.
pub fn has_magic(bytes: &[u8]) -> bool {
    bytes.len() >= 8 && bytes[..8] == MAGIC.to_le_bytes()
}

/// NODE_MASK_COMPRESSION: per-grid compression and per-node metadata bytes (OpenVDB 3.0+).
const MIN_VERSION: u32 = 222;
/// HALF_GRID (OpenVDB 12).
const MAX_VERSION: u32 = 225;

const COMPRESS_ZIP: u32 = 0x1;
const COMPRESS_ACTIVE_MASK: u32 = 0x2;
const COMPRESS_BLOSC: u32 = 0x4;

// Per-node metadata byte of the active-mask compression (io/Compression.h).
const NO_MASK_OR_INACTIVE_VALS: u8 = 0;
const NO_MASK_AND_MINUS_BG: u8 = 1;
const NO_MASK_AND_ONE_INACTIVE_VAL: u8 = 2;
const MASK_AND_NO_INACTIVE_VALS: u8 = 3;
const MASK_AND_ONE_INACTIVE_VAL: u8 = 4;
const MASK_AND_TWO_INACTIVE_VALS: u8 = 5;
const NO_MASK_AND_ALL_VALS: u8 = 6;

const HALF_SUFFIX: &str = "_HalfFloat";

/// Where a grid's dense box lies: enough to place volrad's grid in the file's world space.
///
/// OpenVDB voxel `(i, j, k)` has its centre at index point `(i, j, k)` and world position
/// `translation + voxel_size ⊙ (i, j, k)`; volrad cell `(i, j, k)` is voxel
/// `bbox_min + (i, j, k)` and covers `translation + voxel_size ⊙ (bbox_min + (i, j, k) ± ½)`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct VdbPlacement {
    /// The grid's name in the file.
    pub grid: String,
    /// The transform's map type (`UniformScaleMap`, `ScaleTranslateMap`, `AffineMap`, …).
    pub map: String,
    /// Index-space bounding box of the active voxels, inclusive.
    pub bbox_min: [i32; 3],
    pub bbox_max: [i32; 3],
    /// World size of a voxel per axis (positive).
    pub voxel_size: [f64; 3],
    /// World position of index point (0, 0, 0).
    pub translation: [f64; 3],
}

impl VdbPlacement {
    /// The voxel size when it is the same on every axis.
    pub fn uniform_voxel_size(&self) -> Option<f64> {
        let [x, y, z] = self.voxel_size;
        (x == y && y == z).then_some(x)
    }

    /// World position of the dense box's lower corner: the corner of voxel `bbox_min`.
    pub fn world_corner(&self) -> [f64; 3] {
        std::array::from_fn(|a| {
            self.translation[a] + self.voxel_size[a] * (self.bbox_min[a] as f64 - 0.5)
        })
    }
}

/// One grid a file holds, as its descriptor names it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct VdbGridInfo {
    pub name: String,
    /// The tree type without the half suffix, e.g. `Tree_float_5_4_3`.
    pub tree_type: String,
    /// Stored as 16-bit halves (`saveFloatAsHalf`).
    pub half: bool,
}

/// A grid read from a `.vdb` file.
#[derive(Clone, Debug, PartialEq)]
pub struct VdbVolume {
    pub data: VolumeData,
    pub placement: VdbPlacement,
    /// Every grid in the file, in file order.
    pub grids: Vec<VdbGridInfo>,
    /// The grid's background value: what it holds outside its active box.
    pub background: f32,
}

impl VdbVolume {
    /// This grid's values on the cells of another grid of the same file, matched by index
    /// (voxel `(i, j, k)` of one is voxel `(i, j, k)` of the other): volrad cell `c` of the
    /// grid placed by `on` is voxel `on.bbox_min + coords(c)`, and cells outside this grid's
    /// active box take its background. Used for a `temperature` grid beside `density`.
    /// Matching by index is what OpenVDB's tools do for grids sharing a transform; the caller
    /// checks the transforms agree.
    pub fn sample_on(&self, on: &VdbPlacement, dims: [usize; 3]) -> Vec<f32> {
        let own = &self.placement;
        let own_dims = self.data.dims;
        let mut out = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let voxel = [
                        on.bbox_min[0] as i64 + i as i64,
                        on.bbox_min[1] as i64 + j as i64,
                        on.bbox_min[2] as i64 + k as i64,
                    ];
                    let local: [i64; 3] =
                        std::array::from_fn(|a| voxel[a] - own.bbox_min[a] as i64);
                    let inside = (0..3).all(|a| local[a] >= 0 && local[a] < own_dims[a] as i64);
                    out.push(if inside {
                        let [x, y, z] = local.map(|v| v as usize);
                        self.data.values[x + own_dims[0] * (y + own_dims[1] * z)]
                    } else {
                        self.background
                    });
                }
            }
        }
        out
    }
}

/// Reads grid `grid` (by name), or the first float, double or half grid, from a `.vdb` file.
pub fn read_vdb(path: &Path, grid: Option<&str>) -> Result<VdbVolume, MediumError> {
    let bytes = crate::volume_io::read_regular(path)?;
    read_vdb_bytes(&bytes, path, grid)
}

/// [`read_vdb`] on bytes already in memory; `path` only names the file in errors.
pub fn read_vdb_bytes(
    bytes: &[u8],
    path: &Path,
    grid: Option<&str>,
) -> Result<VdbVolume, MediumError> {
    read_vdb_bytes_capped(bytes, path, grid, MAX_VDB_CELLS)
}

/// [`read_vdb_bytes`] with a tighter bound than [`MAX_VDB_CELLS`] on the dense box (tests
/// feeding mutated files use it so that a mutated coordinate cannot ask for gigabytes).
pub fn read_vdb_bytes_capped(
    bytes: &[u8],
    path: &Path,
    grid: Option<&str>,
    max_cells: u64,
) -> Result<VdbVolume, MediumError> {
    read(bytes, grid, max_cells.min(MAX_VDB_CELLS)).map_err(|message| MediumError::Volume {
        file: path.to_path_buf(),
        message,
    })
}

type Res<T> = Result<T, String>;

/// A bounds-checked reader over the file's bytes: every read names what it wanted.
#[derive(Clone)]
struct Cursor<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Cursor<'a> {
    fn at(bytes: &'a [u8], pos: usize) -> Self {
        Cursor { bytes, pos }
    }

    fn remaining(&self) -> usize {
        self.bytes.len().saturating_sub(self.pos)
    }

    fn take(&mut self, n: usize, what: &str) -> Res<&'a [u8]> {
        if n > self.remaining() {
            return Err(format!(
                "truncated: {what} needs {n} bytes at offset {} but {} remain",
                self.pos,
                self.remaining()
            ));
        }
        let s = &self.bytes[self.pos..self.pos + n];
        self.pos += n;
        Ok(s)
    }

    fn array<const N: usize>(&mut self, what: &str) -> Res<[u8; N]> {
        let mut a = [0u8; N];
        a.copy_from_slice(self.take(N, what)?);
        Ok(a)
    }

    fn u8(&mut self, what: &str) -> Res<u8> {
        Ok(self.array::<1>(what)?[0])
    }
    fn u32(&mut self, what: &str) -> Res<u32> {
        Ok(u32::from_le_bytes(self.array(what)?))
    }
    fn i32(&mut self, what: &str) -> Res<i32> {
        Ok(i32::from_le_bytes(self.array(what)?))
    }
    fn i64(&mut self, what: &str) -> Res<i64> {
        Ok(i64::from_le_bytes(self.array(what)?))
    }
    fn f64(&mut self, what: &str) -> Res<f64> {
        Ok(f64::from_le_bytes(self.array(what)?))
    }
    fn vec3(&mut self, what: &str) -> Res<[f64; 3]> {
        Ok([self.f64(what)?, self.f64(what)?, self.f64(what)?])
    }
    fn coord(&mut self, what: &str) -> Res<[i32; 3]> {
        Ok([self.i32(what)?, self.i32(what)?, self.i32(what)?])
    }

    /// OpenVDB's string: u32 length, then the bytes.
    fn string(&mut self, what: &str) -> Res<String> {
        let n = self.u32(what)? as usize;
        Ok(String::from_utf8_lossy(self.take(n, what)?).into_owned())
    }

    /// A count whose items each take at least `min_item_bytes`: refused when the rest of the
    /// file could not hold that many, before anything is allocated for them.
    fn count(&mut self, min_item_bytes: usize, what: &str) -> Res<usize> {
        let n = self.u32(what)? as usize;
        let need = n.saturating_mul(min_item_bytes.max(1));
        if need > self.remaining() {
            return Err(format!(
                "{what} is {n}, but {} bytes remain (each needs at least {min_item_bytes})",
                self.remaining()
            ));
        }
        Ok(n)
    }

    /// A node mask of `words` u64 words.
    fn mask(&mut self, words: usize, what: &str) -> Res<Vec<u64>> {
        let b = self.take(words * 8, what)?;
        Ok(b.chunks_exact(8)
            .map(|c| u64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
            .collect())
    }

    /// Skips a MetaMap: u32 count, then name, type name and a size-prefixed value each.
    fn skip_metadata(&mut self, what: &str) -> Res<()> {
        let n = self.count(12, what)?;
        for _ in 0..n {
            self.string(what)?;
            self.string(what)?;
            let size = self.u32(what)? as usize;
            self.take(size, what)?;
        }
        Ok(())
    }
}

fn bit(mask: &[u64], n: usize) -> bool {
    mask[n >> 6] >> (n & 63) & 1 == 1
}

/// The positions of the set bits of `word`, lowest first.
fn set_bits(mut word: u64) -> impl Iterator<Item = usize> {
    std::iter::from_fn(move || {
        (word != 0).then(|| {
            let b = word.trailing_zeros() as usize;
            word &= word - 1;
            b
        })
    })
}

/// Stored value types.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Scalar {
    F16,
    F32,
    F64,
}

impl Scalar {
    fn from_tree_type(t: &str) -> Option<Scalar> {
        match t {
            "Tree_float_5_4_3" => Some(Scalar::F32),
            "Tree_double_5_4_3" => Some(Scalar::F64),
            "Tree_half_5_4_3" => Some(Scalar::F16),
            _ => None,
        }
    }

    fn size(self) -> usize {
        match self {
            Scalar::F16 => 2,
            Scalar::F32 => 4,
            Scalar::F64 => 8,
        }
    }

    fn decode(self, b: &[u8]) -> f32 {
        match self {
            Scalar::F16 => f16_to_f32(u16::from_le_bytes([b[0], b[1]])),
            Scalar::F32 => f32::from_le_bytes([b[0], b[1], b[2], b[3]]),
            Scalar::F64 => {
                f64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]]) as f32
            }
        }
    }
}

/// IEEE binary16 to binary32, exactly (every half is an f32).
fn f16_to_f32(h: u16) -> f32 {
    let sign = if h & 0x8000 != 0 { -1.0f32 } else { 1.0 };
    let exp = u32::from((h >> 10) & 0x1f);
    let man = u32::from(h & 0x3ff);
    match exp {
        0 => sign * man as f32 * (1.0 / 16_777_216.0), // subnormal: man · 2^-24
        31 => f32::from_bits(((h as u32 & 0x8000) << 16) | 0x7f80_0000 | (man << 13)),
        _ => f32::from_bits(((h as u32 & 0x8000) << 16) | ((exp + 112) << 23) | (man << 13)),
    }
}

/// How one grid's values are stored.
struct Codec {
    scalar: Scalar,
    /// Leaf and tile arrays stored as halves (saveFloatAsHalf).
    half: bool,
    compression: u32,
    background: f32,
}

impl Codec {
    /// One full-precision value (background, root tiles, a node's inactive values).
    fn value(&self, cur: &mut Cursor, what: &str) -> Res<f32> {
        Ok(self.scalar.decode(cur.take(self.scalar.size(), what)?))
    }

    /// `readCompressedValues`: the values of a node with `count` slots and active mask `mask`.
    fn node_values(&self, cur: &mut Cursor, count: usize, mask: &[u64]) -> Res<Vec<f32>> {
        let meta = cur.u8("node metadata byte")?;
        if meta > NO_MASK_AND_ALL_VALS {
            return Err(format!(
                "node metadata byte {meta} at offset {} is not 0–6",
                cur.pos - 1
            ));
        }
        let bg = self.background;
        let mut inactive1 = bg;
        // Modes 2, 4 and 5 store their inactive values; mode 6 stores every value.
        let mut inactive0 = match meta {
            NO_MASK_OR_INACTIVE_VALS => bg,
            NO_MASK_AND_MINUS_BG | MASK_AND_NO_INACTIVE_VALS => -bg,
            _ => bg,
        };
        if matches!(
            meta,
            NO_MASK_AND_ONE_INACTIVE_VAL | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS
        ) {
            inactive0 = self.value(cur, "inactive value")?;
            if meta == MASK_AND_TWO_INACTIVE_VALS {
                inactive1 = self.value(cur, "inactive value")?;
            }
        }
        let selection = if matches!(
            meta,
            MASK_AND_NO_INACTIVE_VALS | MASK_AND_ONE_INACTIVE_VAL | MASK_AND_TWO_INACTIVE_VALS
        ) {
            Some(cur.mask(count / 64, "selection mask")?)
        } else {
            None
        };
        let mask_compressed = self.compression & COMPRESS_ACTIVE_MASK != 0;
        let stored = if mask_compressed && meta != NO_MASK_AND_ALL_VALS {
            mask.iter().map(|w| w.count_ones() as usize).sum()
        } else {
            count
        };
        let values = self.data(cur, stored)?;
        if stored == count {
            return Ok(values);
        }
        let mut out = Vec::with_capacity(count);
        let mut next = values.into_iter();
        for n in 0..count {
            out.push(if bit(mask, n) {
                next.next().unwrap_or(bg)
            } else if selection.as_ref().is_some_and(|s| bit(s, n)) {
                inactive1
            } else {
                inactive0
            });
        }
        Ok(out)
    }

    /// `readData`: `count` values, raw, zipped or in a Blosc frame, each chunk preceded by
    /// its i64 byte count (negative for data stored uncompressed).
    fn data(&self, cur: &mut Cursor, count: usize) -> Res<Vec<f32>> {
        let scalar = if self.half { Scalar::F16 } else { self.scalar };
        if self.half && count == 0 {
            return Ok(Vec::new()); // HalfReader writes and reads nothing for no values
        }
        // count ≤ 32768 slots of ≤ 8 bytes: the expected size is small and bounded.
        let expected = count * scalar.size();
        let decoded;
        let bytes: &[u8] = if self.compression & (COMPRESS_BLOSC | COMPRESS_ZIP) != 0 {
            let codec = if self.compression & COMPRESS_BLOSC != 0 {
                "Blosc"
            } else {
                "zip"
            };
            let n = cur.i64(&format!("{codec} chunk size"))?;
            if n <= 0 {
                if n.unsigned_abs() != expected as u64 {
                    return Err(format!(
                        "an uncompressed {codec} chunk of {} bytes where {expected} were expected",
                        n.unsigned_abs()
                    ));
                }
                cur.take(expected, "uncompressed values")?
            } else {
                let len = usize::try_from(n).unwrap_or(usize::MAX);
                let chunk = cur.take(len, &format!("{codec} chunk"))?;
                decoded = if self.compression & COMPRESS_BLOSC != 0 {
                    blosc_decompress(chunk, expected)?
                } else {
                    zlib_exact(chunk, expected, "zip chunk")?
                };
                &decoded
            }
        } else {
            cur.take(expected, "values")?
        };
        Ok(bytes
            .chunks_exact(scalar.size())
            .map(|c| scalar.decode(c))
            .collect())
    }
}

/// Inflates a zlib stream that must give exactly `expected` bytes (reading at most one more).
fn zlib_exact(src: &[u8], expected: usize, what: &str) -> Res<Vec<u8>> {
    let mut out = Vec::with_capacity(expected);
    flate2::read::ZlibDecoder::new(src)
        .take(expected as u64 + 1)
        .read_to_end(&mut out)
        .map_err(|e| format!("{what} cannot be inflated: {e}"))?;
    if out.len() != expected {
        return Err(format!(
            "{what} inflates to {}{} bytes, expected {expected}",
            out.len(),
            if out.len() > expected { "+" } else { "" }
        ));
    }
    Ok(out)
}

/// Decodes one Blosc1 frame (what `blosc_decompress` reads) that must hold `expected` bytes:
/// a 16-byte header (format version, codec version, flags, type size, sizes), block offsets,
/// then per block one or `typesize` split streams, each an i32 size and a codec stream (or the
/// bytes themselves when the size equals the split's length), byte-unshuffled at the end.
fn blosc_decompress(src: &[u8], expected: usize) -> Res<Vec<u8>> {
    const MEMCPYED: u8 = 0x2;
    if src.len() < 16 {
        return Err(format!(
            "a Blosc frame of {} bytes has no header",
            src.len()
        ));
    }
    let u32_at = |o: usize| u32::from_le_bytes([src[o], src[o + 1], src[o + 2], src[o + 3]]);
    let (version, flags, typesize) = (src[0], src[2], usize::from(src[3]));
    let nbytes = u32_at(4) as usize;
    let blocksize = u32_at(8) as usize;
    let ctbytes = u32_at(12) as usize;
    if nbytes != expected {
        return Err(format!(
            "a Blosc frame holds {nbytes} bytes where {expected} were expected"
        ));
    }
    if ctbytes > src.len() || ctbytes < 16 {
        return Err(format!(
            "a Blosc frame says it is {ctbytes} bytes long in a chunk of {}",
            src.len()
        ));
    }
    let src = &src[..ctbytes];
    if nbytes == 0 {
        return Ok(Vec::new());
    }
    if version > 2 || flags & 0x08 != 0 {
        return Err(format!(
            "Blosc format version {version} (flags {flags:#04x}) is newer than volrad reads (1–2)"
        ));
    }
    if flags & 0x04 != 0 {
        return Err("Blosc bit-shuffle is not supported (OpenVDB writes byte shuffle)".into());
    }
    if flags & MEMCPYED != 0 {
        if ctbytes != nbytes + 16 {
            return Err(format!(
                "a stored Blosc frame of {ctbytes} bytes for {nbytes} bytes of data"
            ));
        }
        return Ok(src[16..].to_vec());
    }
    if typesize == 0 || blocksize == 0 || blocksize > nbytes {
        return Err(format!(
            "a Blosc frame with type size {typesize} and block size {blocksize} for {nbytes} bytes"
        ));
    }
    let codec = flags >> 5;
    if codec != 1 && codec != 3 {
        let name = match codec {
            0 => "blosclz",
            2 => "snappy",
            4 => "zstd",
            _ => "unknown",
        };
        return Err(format!(
            "Blosc codec {codec} ({name}) is not supported (volrad reads LZ4, which OpenVDB writes, and zlib)"
        ));
    }
    let nblocks = nbytes.div_ceil(blocksize);
    let leftover = nbytes % blocksize;
    if 16 + nblocks.saturating_mul(4) > ctbytes {
        return Err(format!(
            "a Blosc frame of {ctbytes} bytes cannot hold {nblocks} block offsets"
        ));
    }
    let shuffle = flags & 0x1 != 0 && typesize > 1;
    let dont_split = flags & 0x10 != 0;
    let mut out = vec![0u8; nbytes];
    let mut tmp = vec![0u8; blocksize];
    for j in 0..nblocks {
        let last = j == nblocks - 1 && leftover > 0;
        let bsize = if last { leftover } else { blocksize };
        // The same rule as blosc_d: split streams for whole blocks of small types.
        let nsplits = if !dont_split && typesize <= 16 && bsize / typesize >= 128 && !last {
            typesize
        } else {
            1
        };
        if bsize % nsplits != 0 {
            return Err(format!(
                "a Blosc block of {bsize} bytes does not split into {nsplits}"
            ));
        }
        let neblock = bsize / nsplits;
        let mut off = u32_at(16 + 4 * j) as usize;
        for s in 0..nsplits {
            if off + 4 > ctbytes {
                return Err(format!("a Blosc block offset {off} is past the frame"));
            }
            let cbytes = i32::from_le_bytes([src[off], src[off + 1], src[off + 2], src[off + 3]]);
            off += 4;
            let cbytes = usize::try_from(cbytes)
                .ok()
                .filter(|&c| c <= ctbytes - off)
                .ok_or_else(|| format!("a Blosc stream of {cbytes} bytes is past the frame"))?;
            let stream = &src[off..off + cbytes];
            let dst = &mut tmp[s * neblock..(s + 1) * neblock];
            if cbytes == neblock {
                dst.copy_from_slice(stream);
            } else if codec == 1 {
                let n = lz4_flex::block::decompress_into(stream, dst)
                    .map_err(|e| format!("a Blosc LZ4 stream cannot be decoded: {e}"))?;
                if n != neblock {
                    return Err(format!(
                        "a Blosc LZ4 stream gives {n} bytes, expected {neblock}"
                    ));
                }
            } else {
                dst.copy_from_slice(&zlib_exact(stream, neblock, "a Blosc zlib stream")?);
            }
            off += cbytes;
        }
        let block = &mut out[j * blocksize..j * blocksize + bsize];
        if shuffle {
            // Byte k of element i was stored at k · n + i; trailing bytes are not shuffled.
            let n = bsize / typesize;
            for i in 0..n {
                for k in 0..typesize {
                    block[i * typesize + k] = tmp[k * n + i];
                }
            }
            block[n * typesize..].copy_from_slice(&tmp[n * typesize..bsize]);
        } else {
            block.copy_from_slice(&tmp[..bsize]);
        }
    }
    Ok(out)
}

/// A grid descriptor from the file header.
struct Descriptor {
    info: VdbGridInfo,
    instance_parent: String,
    grid_pos: u64,
}

/// The world transform, reduced to a per-axis scale and a translation.
fn read_transform(cur: &mut Cursor) -> Res<(String, [f64; 3], [f64; 3])> {
    let map = cur.string("transform map type")?;
    let what = "transform";
    let (scale, translation) = match map.as_str() {
        "UniformScaleMap" | "ScaleMap" => {
            let s = cur.vec3(what)?;
            cur.take(4 * 24, what)?; // voxel size, inverse scale, 1/s², 1/2s: derived
            (s, [0.0; 3])
        }
        "UniformScaleTranslateMap" | "ScaleTranslateMap" => {
            let t = cur.vec3(what)?;
            let s = cur.vec3(what)?;
            cur.take(4 * 24, what)?;
            (s, t)
        }
        "TranslationMap" => ([1.0; 3], cur.vec3(what)?),
        "AffineMap" | "UnitaryMap" => {
            let mut m = [0.0; 16];
            for v in &mut m {
                *v = cur.f64(what)?;
            }
            // Row-vector convention: world = (i, j, k, 1) · M, translation in the last row.
            let off_diagonal = [m[1], m[2], m[3], m[4], m[6], m[7], m[8], m[9], m[11]];
            if off_diagonal.iter().any(|&v| v != 0.0) || m[15] != 1.0 {
                return Err(format!(
                    "the {map} rotates or shears (matrix rows {:?}); volrad reads axis-aligned scales and translations only",
                    m.chunks(4).collect::<Vec<_>>()
                ));
            }
            ([m[0], m[5], m[10]], [m[12], m[13], m[14]])
        }
        "NonlinearFrustumMap" => {
            return Err(
                "the transform is a NonlinearFrustumMap; volrad reads axis-aligned scales and translations only"
                    .into(),
            )
        }
        other => return Err(format!("unknown transform map type `{other}`")),
    };
    if !scale.iter().all(|&s| s.is_finite() && s > 0.0) {
        return Err(format!(
            "the {map} has voxel size {scale:?}; volrad needs finite positive sizes (no mirroring)"
        ));
    }
    if !translation.iter().all(|t| t.is_finite()) {
        return Err(format!("the {map} has translation {translation:?}"));
    }
    Ok((map, scale, translation))
}

/// What a walk over the tree topology reports: tiles (origin, side, value, active) and
/// leaves (origin, active mask). Walked twice: once to find the active box, once to paint.
trait Visitor {
    fn tile(&mut self, origin: [i64; 3], side: i64, value: f32, active: bool);
    fn leaf(&mut self, origin: [i64; 3], mask: &[u64]);
}

/// First walk: the active bounding box and the leaves in file (= buffer) order.
#[derive(Default)]
struct Survey {
    lo: [i64; 3],
    hi: [i64; 3],
    any: bool,
    leaves: Vec<([i64; 3], [u64; 8])>,
}

impl Survey {
    fn include(&mut self, lo: [i64; 3], hi: [i64; 3]) {
        if !self.any {
            (self.lo, self.hi, self.any) = (lo, hi, true);
        } else {
            for a in 0..3 {
                self.lo[a] = self.lo[a].min(lo[a]);
                self.hi[a] = self.hi[a].max(hi[a]);
            }
        }
    }
}

impl Visitor for Survey {
    fn tile(&mut self, origin: [i64; 3], side: i64, _value: f32, active: bool) {
        if active {
            self.include(origin, origin.map(|o| o + side - 1));
        }
    }
    fn leaf(&mut self, origin: [i64; 3], mask: &[u64]) {
        let mut m = [0u64; 8];
        m.copy_from_slice(mask);
        self.leaves.push((origin, m));
        for (w, &word) in m.iter().enumerate() {
            for b in set_bits(word) {
                let n = w * 64 + b;
                let p = [
                    origin[0] + (n >> 6) as i64,
                    origin[1] + ((n >> 3) & 7) as i64,
                    origin[2] + (n & 7) as i64,
                ];
                self.include(p, p);
            }
        }
    }
}

/// Second walk: the dense box, painted with tile values.
struct Dense {
    lo: [i64; 3],
    dims: [usize; 3],
    values: Vec<f32>,
    background: f32,
}

impl Dense {
    /// Fills the part of the cube `[origin, origin + side)` inside the box.
    fn fill(&mut self, origin: [i64; 3], side: i64, value: f32) {
        let mut r = [(0usize, 0usize); 3];
        for a in 0..3 {
            let lo = (origin[a] - self.lo[a]).max(0);
            let hi = (origin[a] + side - self.lo[a]).min(self.dims[a] as i64);
            if lo >= hi {
                return;
            }
            r[a] = (lo as usize, hi as usize);
        }
        let [nx, ny, _] = self.dims;
        for k in r[2].0..r[2].1 {
            for j in r[1].0..r[1].1 {
                let row = nx * (j + ny * k);
                self.values[row + r[0].0..row + r[0].1].fill(value);
            }
        }
    }

    /// Writes a leaf's 512 values (z fastest in the leaf) where they fall inside the box.
    fn leaf_values(&mut self, origin: [i64; 3], values: &[f32]) {
        let [nx, ny, nz] = self.dims;
        for (n, &v) in values.iter().enumerate().take(512) {
            let p = [
                origin[0] + (n >> 6) as i64 - self.lo[0],
                origin[1] + ((n >> 3) & 7) as i64 - self.lo[1],
                origin[2] + (n & 7) as i64 - self.lo[2],
            ];
            if p.iter().all(|&c| c >= 0)
                && (p[0] as usize) < nx
                && (p[1] as usize) < ny
                && (p[2] as usize) < nz
            {
                self.values[p[0] as usize + nx * (p[1] as usize + ny * p[2] as usize)] = v;
            }
        }
    }
}

impl Visitor for Dense {
    fn tile(&mut self, origin: [i64; 3], side: i64, value: f32, active: bool) {
        // Inactive tiles holding the background are already painted.
        if active || value.to_bits() != self.background.to_bits() {
            self.fill(origin, side, value);
        }
    }
    fn leaf(&mut self, _origin: [i64; 3], _mask: &[u64]) {}
}

/// Reads the topology of one internal node (log2 side `log2dim`, children of log2 extent
/// `child_log2`) at `origin`, reporting its tiles and, below it, nodes and leaves.
fn internal_node(
    cur: &mut Cursor,
    codec: &Codec,
    origin: [i64; 3],
    log2dim: u32,
    child_log2: u32,
    visit: &mut dyn Visitor,
) -> Res<()> {
    let slots = 1usize << (3 * log2dim);
    let child_mask = cur.mask(slots / 64, "internal node child mask")?;
    let value_mask = cur.mask(slots / 64, "internal node value mask")?;
    let values = codec.node_values(cur, slots, &value_mask)?;
    let dim_mask = (1usize << log2dim) - 1;
    let local = |n: usize| -> [i64; 3] {
        [
            origin[0] + (((n >> (2 * log2dim)) & dim_mask) << child_log2) as i64,
            origin[1] + (((n >> log2dim) & dim_mask) << child_log2) as i64,
            origin[2] + ((n & dim_mask) << child_log2) as i64,
        ]
    };
    // Tiles, 64 slots at a time: the visitors ignore inactive tiles that hold the background
    // (most of a sparse node's 32,768 or 4,096 slots), so only active tiles and inactive ones
    // with another value are reported; a word of background values is told by one OR.
    let background = codec.background.to_bits();
    for (w, chunk) in values.chunks_exact(64).enumerate() {
        let tiles = !child_mask[w];
        let mut reported = tiles & value_mask[w];
        let other = chunk
            .iter()
            .fold(0u32, |acc, v| acc | (v.to_bits() ^ background));
        if other != 0 {
            for (b, v) in chunk.iter().enumerate() {
                if v.to_bits() != background {
                    reported |= tiles & (1 << b);
                }
            }
        }
        for b in set_bits(reported) {
            let n = w * 64 + b;
            visit.tile(
                local(n),
                1 << child_log2,
                chunk[b],
                value_mask[w] >> b & 1 == 1,
            );
        }
    }
    for (w, &children) in child_mask.iter().enumerate() {
        for b in set_bits(children) {
            let n = w * 64 + b;
            if child_log2 == 3 {
                let mask = cur.mask(8, "leaf value mask")?;
                visit.leaf(local(n), &mask);
            } else {
                internal_node(cur, codec, local(n), 4, 3, visit)?;
            }
        }
    }
    Ok(())
}

/// The root node's topology after the background: tiles, then children (node-5 subtrees).
fn root_topology(cur: &mut Cursor, codec: &Codec, visit: &mut dyn Visitor) -> Res<()> {
    let tile_bytes = 12 + codec.scalar.size() + 1;
    let tiles = cur.count(tile_bytes, "root tile count")?;
    // A node-5 child is at least its origin, two 4 KiB masks and a metadata byte.
    let children = cur.count(12 + 2 * 4096 + 1, "root child count")?;
    let mut seen = std::collections::HashSet::new();
    let mut key = |c: [i32; 3], what: &str| -> Res<[i64; 3]> {
        if c.iter().any(|v| v & 4095 != 0) {
            return Err(format!(
                "root {what} at {c:?} is not aligned to the 4096-voxel root grid"
            ));
        }
        if !seen.insert(c) {
            return Err(format!("root {what} at {c:?} appears twice"));
        }
        Ok(c.map(i64::from))
    };
    for _ in 0..tiles {
        let c = cur.coord("root tile")?;
        let value = codec.value(cur, "root tile value")?;
        let active = cur.u8("root tile state")? != 0;
        visit.tile(key(c, "tile")?, 4096, value, active);
    }
    for _ in 0..children {
        let c = cur.coord("root child")?;
        let origin = key(c, "child")?;
        internal_node(cur, codec, origin, 5, 7, visit)?;
    }
    Ok(())
}

fn read(bytes: &[u8], wanted: Option<&str>, max_cells: u64) -> Res<VdbVolume> {
    let mut cur = Cursor::at(bytes, 0);
    if bytes.len() < 8 || i64::from_le_bytes(cur.array("magic")?) != MAGIC {
        return Err("not an OpenVDB file (expected the magic number `VDB `)".into());
    }
    let version = cur.u32("file format version")?;
    if version < MIN_VERSION {
        return Err(format!(
            "OpenVDB file format version {version} is too old: volrad reads {MIN_VERSION}–{MAX_VERSION} (OpenVDB 3 and later); re-save the file with a newer OpenVDB"
        ));
    }
    if version > MAX_VERSION {
        return Err(format!(
            "OpenVDB file format version {version} is newer than volrad reads ({MIN_VERSION}–{MAX_VERSION})"
        ));
    }
    let _library = (cur.u32("library version")?, cur.u32("library version")?);
    let has_offsets = cur.u8("grid offsets flag")? != 0;
    cur.take(36, "UUID")?;
    cur.skip_metadata("file metadata")?;
    if !has_offsets {
        return Err("the file is an OpenVDB stream without grid offsets; volrad reads files written by openvdb::io::File".into());
    }
    let count = cur.i32("grid count")?;
    let count = usize::try_from(count).map_err(|_| format!("grid count {count} is negative"))?;
    // A descriptor is at least three empty strings and three offsets.
    if count.saturating_mul(36) > cur.remaining() {
        return Err(format!(
            "grid count {count} does not fit in the {} bytes left",
            cur.remaining()
        ));
    }
    let mut descriptors = Vec::with_capacity(count);
    for _ in 0..count {
        let unique = cur.string("grid name")?;
        // A unique name is `name` or `name\x1eN` for repeated names.
        let name = unique.split('\x1e').next().unwrap_or("").to_string();
        let mut tree_type = cur.string("grid type")?;
        let half = tree_type.ends_with(HALF_SUFFIX);
        if half {
            tree_type.truncate(tree_type.len() - HALF_SUFFIX.len());
        }
        let instance_parent = cur.string("instance parent")?;
        let grid_pos = cur.i64("grid offset")?;
        let _block_pos = cur.i64("block offset")?;
        let end_pos = cur.i64("end offset")?;
        descriptors.push(Descriptor {
            info: VdbGridInfo {
                name,
                tree_type,
                half,
            },
            instance_parent,
            grid_pos: u64::try_from(grid_pos).unwrap_or(u64::MAX),
        });
        // Each descriptor is followed by its grid; the next descriptor starts at its end.
        cur = match usize::try_from(end_pos) {
            Ok(p) if p > cur.pos && p <= bytes.len() => Cursor::at(bytes, p),
            _ => {
                return Err(format!(
                    "grid `{}` ends at offset {end_pos}, outside the file ({} bytes) or before its descriptor",
                    descriptors.last().map_or("", |d: &Descriptor| d.info.name.as_str()),
                    bytes.len()
                ))
            }
        };
    }
    let grids: Vec<VdbGridInfo> = descriptors.iter().map(|d| d.info.clone()).collect();
    let listing = || {
        if grids.is_empty() {
            "the file has no grids".to_string()
        } else {
            let names: Vec<String> = grids
                .iter()
                .map(|g| format!("`{}` ({})", g.name, g.tree_type))
                .collect();
            format!("the file has {}", names.join(", "))
        }
    };
    let chosen = match wanted {
        Some(name) => descriptors
            .iter()
            .find(|d| d.info.name == name)
            .ok_or_else(|| format!("no grid named `{name}`: {}", listing()))?,
        None => descriptors
            .iter()
            .find(|d| Scalar::from_tree_type(&d.info.tree_type).is_some())
            .ok_or_else(|| format!("no float, double or half grid: {}", listing()))?,
    };
    let scalar = Scalar::from_tree_type(&chosen.info.tree_type).ok_or_else(|| {
        format!(
            "grid `{}` has type {}; volrad reads float, double and half grids",
            chosen.info.name, chosen.info.tree_type
        )
    })?;

    let grid_cursor = |d: &Descriptor| -> Res<Cursor> {
        match usize::try_from(d.grid_pos) {
            Ok(p) if p < bytes.len() => Ok(Cursor::at(bytes, p)),
            _ => Err(format!(
                "grid `{}` starts at offset {} past the end of the file ({} bytes)",
                d.info.name,
                d.grid_pos,
                bytes.len()
            )),
        }
    };
    // The chosen grid's own metadata and transform.
    let mut cur = grid_cursor(chosen)?;
    let compression = cur.u32("grid compression flags")?;
    cur.skip_metadata("grid metadata")?;
    let (map, voxel_size, translation) = read_transform(&mut cur)?;
    // An instance shares the tree of its parent (written once, after the parent's transform).
    let tree_owner = if chosen.instance_parent.is_empty() {
        chosen
    } else {
        let parent = descriptors
            .iter()
            .find(|d| d.info.name == chosen.instance_parent && d.instance_parent.is_empty())
            .ok_or_else(|| {
                format!(
                    "grid `{}` is an instance of `{}`, which the file does not have",
                    chosen.info.name, chosen.instance_parent
                )
            })?;
        if parent.info.tree_type != chosen.info.tree_type || parent.info.half != chosen.info.half {
            return Err(format!(
                "grid `{}` is an instance of `{}` of another type",
                chosen.info.name, parent.info.name
            ));
        }
        parent
    };
    let compression = if std::ptr::eq(tree_owner, chosen) {
        compression
    } else {
        cur = grid_cursor(tree_owner)?;
        let c = cur.u32("grid compression flags")?;
        cur.skip_metadata("grid metadata")?;
        read_transform(&mut cur)?;
        c
    };
    if compression & !(COMPRESS_ZIP | COMPRESS_ACTIVE_MASK | COMPRESS_BLOSC) != 0 {
        return Err(format!("unknown compression flags {compression:#x}"));
    }
    let _buffer_count = cur.i32("tree buffer count")?;
    let mut codec = Codec {
        scalar,
        half: chosen.info.half,
        compression,
        background: 0.0,
    };
    codec.background = codec.value(&mut cur, "background")?;
    let in_grid = |e: String| format!("grid `{}`: {e}", chosen.info.name);

    let topology = cur.clone();
    let mut survey = Survey::default();
    root_topology(&mut cur, &codec, &mut survey).map_err(in_grid)?;
    let buffers = cur;
    if !survey.any {
        return Err(in_grid("the grid has no active voxels".into()));
    }
    let extents: [u64; 3] = std::array::from_fn(|a| (survey.hi[a] - survey.lo[a] + 1) as u64);
    let dims = extents.map(|e| e as usize);
    let cells = extents.iter().fold(1u64, |n, &e| n.saturating_mul(e));
    if cells > max_cells {
        return Err(in_grid(format!(
            "the active voxels span {:?}..={:?}, a {}×{}×{} box of {cells} values; volrad expands at most {max_cells}",
            survey.lo, survey.hi, dims[0], dims[1], dims[2]
        )));
    }
    let bbox_min = survey.lo.map(|v| v as i32);
    let bbox_max = survey.hi.map(|v| v as i32);
    if survey
        .lo
        .iter()
        .chain(&survey.hi)
        .any(|&v| i32::try_from(v).is_err())
    {
        return Err(in_grid(format!(
            "the active box {:?}..={:?} leaves the 32-bit index space",
            survey.lo, survey.hi
        )));
    }
    let mut values = Vec::new();
    values.try_reserve_exact(cells as usize).map_err(|_| {
        in_grid(format!(
            "cannot allocate {cells} values ({} MiB) for the {}×{}×{} active box",
            (cells * 4) >> 20,
            dims[0],
            dims[1],
            dims[2]
        ))
    })?;
    values.resize(cells as usize, codec.background);
    let mut dense = Dense {
        lo: survey.lo,
        dims,
        values,
        background: codec.background,
    };
    root_topology(&mut topology.clone(), &codec, &mut dense).map_err(in_grid)?;

    // Leaf buffers follow the topology, in the same depth-first order. Each repeats its value
    // mask; like OpenVDB reading a seekable file, the topology's mask is the one used.
    let mut cur = buffers;
    for (origin, mask) in &survey.leaves {
        cur.take(64, "leaf value mask").map_err(in_grid)?;
        let v = codec
            .node_values(&mut cur, 512, mask)
            .map_err(|e| in_grid(format!("leaf at {origin:?}: {e}")))?;
        dense.leaf_values(*origin, &v);
    }
    Ok(VdbVolume {
        background: codec.background,
        data: VolumeData {
            dims,
            values: dense.values,
        },
        placement: VdbPlacement {
            grid: chosen.info.name.clone(),
            map,
            bbox_min,
            bbox_max,
            voxel_size,
            translation,
        },
        grids,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn halves_convert_exactly() {
        assert_eq!(f16_to_f32(0x3c00), 1.0);
        assert_eq!(f16_to_f32(0xc000), -2.0);
        assert_eq!(f16_to_f32(0x7bff), 65504.0);
        assert_eq!(f16_to_f32(0x0001), 2f32.powi(-24));
        assert_eq!(f16_to_f32(0x8000).to_bits(), (-0.0f32).to_bits());
        assert!(f16_to_f32(0x7e00).is_nan());
        assert_eq!(f16_to_f32(0x7c00), f32::INFINITY);
    }

    /// A hand-built Blosc frame: shuffled, split into 4 LZ4 streams, as OpenVDB writes leaves.
    #[test]
    fn blosc_frame_with_shuffle_and_splits() {
        let values: Vec<f32> = (0..512).map(|i| i as f32 * 0.5).collect();
        let raw: Vec<u8> = values.iter().flat_map(|v| v.to_le_bytes()).collect();
        let n = 512;
        let mut shuffled = vec![0u8; raw.len()];
        for i in 0..n {
            for k in 0..4 {
                shuffled[k * n + i] = raw[i * 4 + k];
            }
        }
        let mut body = Vec::new();
        for s in 0..4 {
            let c = lz4_flex::block::compress(&shuffled[s * n..(s + 1) * n]);
            body.extend_from_slice(&(c.len() as i32).to_le_bytes());
            body.extend_from_slice(&c);
        }
        let mut frame = vec![2, 1, 0x1 | (1 << 5), 4];
        frame.extend_from_slice(&(raw.len() as u32).to_le_bytes());
        frame.extend_from_slice(&(raw.len() as u32).to_le_bytes());
        frame.extend_from_slice(&((16 + 4 + body.len()) as u32).to_le_bytes());
        frame.extend_from_slice(&20u32.to_le_bytes());
        frame.extend_from_slice(&body);
        assert_eq!(blosc_decompress(&frame, raw.len()).unwrap(), raw);
        assert!(blosc_decompress(&frame, raw.len() - 4).is_err());
        frame[2] = 0x1; // blosclz
        assert!(blosc_decompress(&frame, raw.len())
            .unwrap_err()
            .contains("blosclz"));
    }
}
