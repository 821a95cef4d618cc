//! The on-disk container of a solution file. The only module that knows the byte layout, so
//! the encoding can change in one place.
//!
//! ```text
//! offset  size  field
//! 0       8     magic  b"VOLRADSL"
//! 8       4     format version (u32 LE)
//! 12      8     payload length in bytes (u64 LE)
//! 20      4     CRC-32 of the payload
//! 24      ...   payload:
//!               u64 LE metadata length, metadata (bincode 2, serde, standard config, of
//!               the solution's record types and the array table),
//!               zero padding to a multiple of 64 bytes from the file start,
//!               then each array as raw little-endian f32 at the offset its table entry
//!               gives (64-byte aligned, so the file can be memory-mapped).
//! ```
//!
//! Reading checks the magic, refuses newer versions by number, checks the length against the
//! file, and sums the checksum over the payload as it streams in, comparing it before anything
//! decoded is returned or any decoding error is reported; each array is read straight into
//! its own vector, so a file is held in memory once. Writing goes to a
//! temporary file in the same directory, is synced, then renamed over the final name, so a
//! crash never leaves a half-written file under that name. A file is written from borrowed
//! arrays and streamed, so writing a solution holds no second copy of its fields (the
//! largest thing a solve keeps).

use std::borrow::Cow;
use std::io::Write;
use std::path::{Path, PathBuf};

use serde::{de::DeserializeOwned, Deserialize, Serialize};

pub const MAGIC: &[u8; 8] = b"VOLRADSL";
/// Bumped whenever the metadata or array layout changes (2: two-pass fields; 3: the metadata
/// is the solution module's own record types, `super::records`, instead of serde derives of
/// library types; 4: the render exposure may be automatic; 6: two-pass fields are arrays, not
/// metadata; 7: the emitters' uncollided fluence, and discrete ordinates' radiance without
/// it; 10: the transport grid may split data cells, `transport_split`; 11: discrete
/// ordinates' emitters' first scattering drawn in the view's direction, `emitted_beam`, and
/// no longer in the bins' higher orders; 12: discrete ordinates store the bins' fluence per
/// cell instead of their radiance per cell and bin, and the higher orders of scattering cells
/// only; 13: `emitted_beam` holds the incident light's shape as a cone and a rest, six values
/// per cell; 14: `emitted_bins`, the widest-lit cells' light in direction bins). Bumping it
/// means
/// refreshing the golden files in
/// `tests/data/solution-golden/` (`VOLRAD_BLESS=1 cargo test --test it solution_file`).
pub const FORMAT_VERSION: u32 = 14;
const FIXED_HEADER: usize = 24;
/// The largest metadata (records and array table, without the arrays) a solution file may
/// hold. The reader decodes with this limit, so a length inside hostile metadata cannot make
/// it allocate more (a string length of 2⁶² aborted the process before; the fuzzer's find).
/// Real metadata is kilobytes: cameras, lights, direction bins, residual history.
pub const MAX_METADATA_BYTES: usize = 64 << 20;
const ALIGN: usize = 64;

/// A named array and where it lives in the payload.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ArrayEntry {
    pub name: String,
    /// Byte offset from the start of the file.
    pub offset: u64,
    /// Number of f32 values.
    pub len: u64,
}

#[derive(Serialize, Deserialize)]
struct Envelope<M> {
    meta: M,
    arrays: Vec<ArrayEntry>,
}

#[derive(Debug, thiserror::Error)]
pub enum ContainerError {
    #[error("{path}: not a volrad solution file (bad magic)")]
    BadMagic { path: PathBuf },
    #[error("{path}: solution format version {found} is newer than this volrad understands ({supported}); upgrade volrad")]
    NewerVersion {
        path: PathBuf,
        found: u32,
        supported: u32,
    },
    #[error("{path}: solution format version {found} was written by an older volrad (this one reads {supported}); solve the scene again")]
    OlderVersion {
        path: PathBuf,
        found: u32,
        supported: u32,
    },
    #[error("{path}: truncated: header says {expected} bytes of payload, file has {actual}")]
    Truncated {
        path: PathBuf,
        expected: u64,
        actual: u64,
    },
    #[error("{path}: checksum mismatch (stored {stored:08x}, computed {computed:08x}): the file is corrupt")]
    Checksum {
        path: PathBuf,
        stored: u32,
        computed: u32,
    },
    #[error("{path}: malformed metadata: {message}")]
    Malformed { path: PathBuf, message: String },
    /// Reading or writing failed. (The OS error is the message, not a source, so that an
    /// error chain prints it once.)
    #[error("{path}: {error}")]
    Io {
        path: PathBuf,
        error: std::io::Error,
    },
}

/// Metadata plus named f32 arrays, as read from disk (owned) or to be written (borrowed
/// where the caller keeps them).
#[derive(Clone, Debug, PartialEq)]
pub struct Container<'a, M> {
    pub meta: M,
    pub arrays: Vec<(String, Cow<'a, [f32]>)>,
}

impl<M> Container<'_, M> {
    pub fn array(&self, name: &str) -> Option<&[f32]> {
        self.arrays
            .iter()
            .find(|(n, _)| n == name)
            .map(|(_, v)| v.as_ref())
    }
}

fn align_up(x: usize) -> usize {
    x.div_ceil(ALIGN) * ALIGN
}

/// Where everything goes: the encoded metadata, the array table and the file's length.
struct Layout {
    envelope: Vec<u8>,
    entries: Vec<ArrayEntry>,
    end: usize,
}

impl<M: Serialize> Container<'_, M> {
    /// The metadata's encoding and every array's offset.
    fn layout(&self) -> Result<Layout, String> {
        let config = bincode::config::standard();
        // The table's offsets depend on the metadata length, which depends on the table's
        // encoding: iterate to a fixed point (two passes suffice in practice).
        let mut entries: Vec<ArrayEntry> = self
            .arrays
            .iter()
            .map(|(name, data)| ArrayEntry {
                name: name.clone(),
                offset: 0,
                len: data.len() as u64,
            })
            .collect();
        let mut envelope_bytes;
        loop {
            envelope_bytes = bincode::serde::encode_to_vec(
                Envelope {
                    meta: &self.meta,
                    arrays: entries.clone(),
                },
                config,
            )
            .map_err(|e| e.to_string())?;
            if envelope_bytes.len() > MAX_METADATA_BYTES {
                return Err(format!(
                    "metadata of {} bytes exceeds the {MAX_METADATA_BYTES}-byte limit",
                    envelope_bytes.len()
                ));
            }
            let mut offset = align_up(FIXED_HEADER + 8 + envelope_bytes.len());
            let mut changed = false;
            for e in entries.iter_mut() {
                if e.offset != offset as u64 {
                    e.offset = offset as u64;
                    changed = true;
                }
                offset = align_up(offset + e.len as usize * 4);
            }
            if !changed {
                break;
            }
        }
        let end = entries
            .last()
            .map_or(FIXED_HEADER + 8 + envelope_bytes.len(), |e| {
                e.offset as usize + e.len as usize * 4
            });
        Ok(Layout {
            envelope: envelope_bytes,
            entries,
            end,
        })
    }

    /// The length in bytes of the file [`write`](Self::write) would write, without encoding
    /// the arrays.
    pub fn encoded_len(&self) -> Result<usize, String> {
        Ok(self.layout()?.end)
    }

    /// Encodes the whole file into memory (the same encoder as [`write`](Self::write)).
    pub fn to_bytes(&self) -> Result<Vec<u8>, String> {
        let layout = self.layout()?;
        let mut out = std::io::Cursor::new(Vec::with_capacity(layout.end));
        self.stream(&layout, &mut out).map_err(|e| e.to_string())?;
        Ok(out.into_inner())
    }

    /// Streams the file into `file`, a block at a time. The header holds the payload's
    /// checksum, so the payload is first summed (a pass over memory) and then written: the
    /// file is written front to back, never sought back into, so the target may be a pipe.
    fn stream<F: Write>(&self, layout: &Layout, file: F) -> std::io::Result<()> {
        let mut crc = crc32fast::Hasher::new();
        self.payload(layout, |bytes| {
            crc.update(bytes);
            Ok(())
        })?;
        let mut header = [0u8; FIXED_HEADER];
        header[..8].copy_from_slice(MAGIC);
        header[8..12].copy_from_slice(&FORMAT_VERSION.to_le_bytes());
        header[12..20].copy_from_slice(&((layout.end - FIXED_HEADER) as u64).to_le_bytes());
        header[20..24].copy_from_slice(&crc.finalize().to_le_bytes());
        let mut out = std::io::BufWriter::with_capacity(1 << 20, file);
        out.write_all(&header)?;
        self.payload(layout, |bytes| out.write_all(bytes))?;
        out.into_inner().map_err(|e| e.into_error())?.flush()
    }

    /// Hands the payload (everything after the fixed header: the metadata, the padding and
    /// the arrays as little-endian bytes) to `put`, block by block.
    fn payload(
        &self,
        layout: &Layout,
        mut put: impl FnMut(&[u8]) -> std::io::Result<()>,
    ) -> std::io::Result<()> {
        const ZEROS: [u8; ALIGN] = [0; ALIGN];
        put(&(layout.envelope.len() as u64).to_le_bytes())?;
        put(&layout.envelope)?;
        // The file offset reached so far.
        let mut at = FIXED_HEADER + 8 + layout.envelope.len();
        let mut block = Vec::with_capacity(STREAM_BLOCK * 4);
        for (e, (_, data)) in layout.entries.iter().zip(&self.arrays) {
            let offset = e.offset as usize;
            while at < offset {
                let n = (offset - at).min(ALIGN);
                put(&ZEROS[..n])?;
                at += n;
            }
            for values in data.chunks(STREAM_BLOCK) {
                block.clear();
                block.extend(values.iter().flat_map(|v| v.to_le_bytes()));
                put(&block)?;
                at += block.len();
            }
        }
        debug_assert_eq!(at, layout.end);
        Ok(())
    }

    /// Writes atomically: temp file beside the target, fsync, rename.
    pub fn write(&self, path: &Path) -> Result<(), ContainerError> {
        let io = |error| ContainerError::Io {
            path: path.to_path_buf(),
            error,
        };
        let layout = self.layout().map_err(|message| ContainerError::Malformed {
            path: path.to_path_buf(),
            message,
        })?;
        medium::atomic_file::write_with(
            path,
            |tmp| {
                std::fs::File::create(tmp)
                    .and_then(|f| self.stream(&layout, f))
                    .map_err(io)
            },
            io,
        )
    }
}

/// Values per block of a streamed array (256 KiB).
const STREAM_BLOCK: usize = 1 << 16;

impl<M: DeserializeOwned> Container<'static, M> {
    /// Decodes a file image, checking everything before trusting anything.
    pub fn from_bytes(bytes: &[u8], path: &Path) -> Result<Self, ContainerError> {
        Self::decode(bytes, bytes.len() as u64, path)
    }

    /// Reads and decodes the file at `path` as it streams in: each array goes straight into
    /// its own vector, so reading holds the file once, not twice.
    pub fn read(path: &Path) -> Result<Self, ContainerError> {
        let io = |error| ContainerError::Io {
            path: path.to_path_buf(),
            error,
        };
        // A FIFO, device or directory is refused, naming it, before anything is read.
        let file = medium::regular_file::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        Self::decode(
            std::io::BufReader::with_capacity(STREAM_BLOCK * 4, file),
            len,
            path,
        )
    }

    /// Decodes `len` bytes from `source`, in one pass: the header is checked first (magic,
    /// version, length), the checksum is summed over the whole payload as it is read, and
    /// it is compared before anything decoded is returned or any decoding error reported —
    /// so a damaged file is reported as damaged, not as whatever its damage looks like.
    /// Sizes come from the file's own length: a hostile table cannot make it allocate more.
    fn decode(source: impl std::io::Read, len: u64, path: &Path) -> Result<Self, ContainerError> {
        let path_buf = || path.to_path_buf();
        let io = |error| ContainerError::Io {
            path: path_buf(),
            error,
        };
        let mut payload = Incoming {
            source,
            crc: crc32fast::Hasher::new(),
            at: 0,
        };
        let mut header = [0u8; FIXED_HEADER];
        let head = (len.min(FIXED_HEADER as u64)) as usize;
        payload.source.read_exact(&mut header[..head]).map_err(io)?;
        payload.at = head as u64;
        if head < 8 || &header[..8] != MAGIC {
            return Err(ContainerError::BadMagic { path: path_buf() });
        }
        if head < FIXED_HEADER {
            return Err(ContainerError::Truncated {
                path: path_buf(),
                expected: FIXED_HEADER as u64,
                actual: len,
            });
        }
        let version = u32::from_le_bytes(header[8..12].try_into().unwrap());
        if version > FORMAT_VERSION {
            return Err(ContainerError::NewerVersion {
                path: path_buf(),
                found: version,
                supported: FORMAT_VERSION,
            });
        }
        if version < FORMAT_VERSION {
            return Err(ContainerError::OlderVersion {
                path: path_buf(),
                found: version,
                supported: FORMAT_VERSION,
            });
        }
        let payload_len = u64::from_le_bytes(header[12..20].try_into().unwrap());
        let actual = len - FIXED_HEADER as u64;
        if payload_len != actual {
            return Err(ContainerError::Truncated {
                path: path_buf(),
                expected: payload_len,
                actual,
            });
        }
        let stored = u32::from_le_bytes(header[20..24].try_into().unwrap());
        let decoded = match Self::decode_payload(&mut payload, len) {
            Err(Unread::Io(error)) => return Err(io(error)),
            Ok(container) => Ok(container),
            Err(Unread::Malformed(message)) => Err(message),
        };
        // The rest of the payload is summed whatever the decoding found.
        payload.skip_to(len).map_err(io)?;
        let computed = payload.crc.finalize();
        if stored != computed {
            return Err(ContainerError::Checksum {
                path: path_buf(),
                stored,
                computed,
            });
        }
        decoded.map_err(|message| ContainerError::Malformed {
            path: path_buf(),
            message,
        })
    }

    /// The metadata and the arrays, read from the payload's start (`payload.at` is the fixed
    /// header's end).
    fn decode_payload<R: std::io::Read>(
        payload: &mut Incoming<R>,
        len: u64,
    ) -> Result<Self, Unread> {
        let malformed = |m: String| Unread::Malformed(m);
        if len < (FIXED_HEADER + 8) as u64 {
            return Err(malformed("no metadata".into()));
        }
        let mut meta_len = [0u8; 8];
        payload.read(&mut meta_len)?;
        let meta_len = u64::from_le_bytes(meta_len);
        if meta_len > MAX_METADATA_BYTES as u64 {
            return Err(malformed(format!(
                "metadata length {meta_len} exceeds the {MAX_METADATA_BYTES}-byte limit"
            )));
        }
        if payload.at + meta_len > len {
            return Err(malformed(format!(
                "metadata length {meta_len} exceeds the file"
            )));
        }
        let mut meta_bytes = vec![0u8; meta_len as usize];
        payload.read(&mut meta_bytes)?;
        let (envelope, _): (Envelope<M>, usize) = bincode::serde::decode_from_slice(
            &meta_bytes,
            bincode::config::standard().with_limit::<MAX_METADATA_BYTES>(),
        )
        .map_err(|e| malformed(e.to_string()))?;
        drop(meta_bytes);
        let mut arrays = Vec::with_capacity(envelope.arrays.len());
        let mut block = vec![0u8; STREAM_BLOCK * 4];
        for e in envelope.arrays {
            let end = e
                .len
                .checked_mul(4)
                .and_then(|n| n.checked_add(e.offset))
                .filter(|&end| end <= len)
                .ok_or_else(|| malformed(format!("array `{}` lies outside the file", e.name)))?;
            // The writer lays the arrays out in the table's order after the metadata.
            if e.offset < payload.at {
                return Err(malformed(format!(
                    "array `{}` overlaps what comes before it",
                    e.name
                )));
            }
            payload.skip_to(e.offset)?;
            let mut data: Vec<f32> = Vec::with_capacity(e.len as usize);
            let mut left = end - e.offset;
            while left > 0 {
                let n = left.min(block.len() as u64) as usize;
                payload.read(&mut block[..n])?;
                data.extend(
                    block[..n]
                        .chunks_exact(4)
                        .map(|c| f32::from_le_bytes(c.try_into().unwrap())),
                );
                left -= n as u64;
            }
            arrays.push((e.name, Cow::Owned(data)));
        }
        Ok(Container {
            meta: envelope.meta,
            arrays,
        })
    }
}

/// Why a payload could not be decoded: the source failed, or what it holds is not a
/// solution file (reported only once the checksum has been found right).
enum Unread {
    Io(std::io::Error),
    Malformed(String),
}

impl From<std::io::Error> for Unread {
    fn from(e: std::io::Error) -> Self {
        Unread::Io(e)
    }
}

/// A payload being read: the bytes so far summed into the checksum.
struct Incoming<R> {
    source: R,
    crc: crc32fast::Hasher,
    /// Bytes read from the file's start.
    at: u64,
}

impl<R: std::io::Read> Incoming<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<()> {
        self.source.read_exact(buf)?;
        self.crc.update(buf);
        self.at += buf.len() as u64;
        Ok(())
    }

    /// Reads (and sums) up to `offset`.
    fn skip_to(&mut self, offset: u64) -> std::io::Result<()> {
        let mut block = [0u8; 4096];
        while self.at < offset {
            let n = (offset - self.at).min(block.len() as u64) as usize;
            self.read(&mut block[..n])?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
    struct Meta {
        name: String,
        dims: [usize; 3],
    }

    fn sample() -> Container<'static, Meta> {
        Container {
            meta: Meta {
                name: "cloud".into(),
                dims: [2, 3, 4],
            },
            arrays: vec![
                ("a".into(), (0..24).map(|i| i as f32 * 0.5).collect()),
                ("b".into(), Cow::Owned(vec![])),
                ("c".into(), Cow::Owned(vec![f32::MAX, -0.0, 1e-30])),
            ],
        }
    }

    /// The streamed file is the encoded one, byte for byte (header, padding, checksum).
    #[test]
    fn a_written_file_is_its_encoding() {
        let dir = std::env::temp_dir().join(format!("container-write-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("s.volrad");
        let mut c = sample();
        // Longer than a streamed block, so the file is written in several.
        let long: Vec<f32> = (0..STREAM_BLOCK + 17).map(|i| i as f32).collect();
        c.arrays.insert(1, ("long".into(), Cow::Borrowed(&long)));
        c.write(&path).unwrap();
        let written = std::fs::read(&path).unwrap();
        assert_eq!(written, c.to_bytes().unwrap());
        assert_eq!(c.encoded_len().unwrap(), written.len());
        assert_eq!(
            Container::<Meta>::from_bytes(&written, Path::new("x")).unwrap(),
            c
        );
        // Read back as it streams in, the same; one flipped value in the long array (read
        // in several blocks) is found by the checksum, not passed on.
        assert_eq!(Container::<Meta>::read(&path).unwrap(), c);
        let mut bad = written.clone();
        let at = bad.len() - 4 * (STREAM_BLOCK / 2);
        bad[at] ^= 0x01;
        std::fs::write(&path, &bad).unwrap();
        let err = Container::<Meta>::read(&path).unwrap_err();
        std::fs::remove_dir_all(&dir).unwrap();
        assert!(matches!(err, ContainerError::Checksum { .. }), "{err}");
    }

    /// A pipe cannot be sought back into: the file is written front to back, so `volrad solve
    /// -o /dev/stdout | …` and a FIFO get the whole file (before, the checksum was written
    /// last by seeking back to the header, which failed on a pipe after all the work).
    #[cfg(unix)]
    #[test]
    fn a_pipe_gets_the_whole_file() {
        let dir = tempfile::tempdir().unwrap();
        let fifo = dir.path().join("s.volrad");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        let mut c = sample();
        let long: Vec<f32> = (0..STREAM_BLOCK + 17).map(|i| i as f32 * 0.25).collect();
        c.arrays.push(("long".into(), Cow::Owned(long)));
        let reader = {
            let fifo = fifo.clone();
            std::thread::spawn(move || std::fs::read(fifo).unwrap())
        };
        c.write(&fifo).unwrap();
        let piped = reader.join().unwrap();
        assert_eq!(piped, c.to_bytes().unwrap());
        assert_eq!(
            Container::<Meta>::from_bytes(&piped, Path::new("pipe")).unwrap(),
            c
        );
        // Still a FIFO, not replaced by a regular file.
        use std::os::unix::fs::FileTypeExt;
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
    }

    #[test]
    fn round_trip_is_exact_and_aligned() {
        let c = sample();
        let bytes = c.to_bytes().unwrap();
        let back = Container::<Meta>::from_bytes(&bytes, Path::new("x")).unwrap();
        assert_eq!(back, c);
        assert_eq!(bytes.len() % 4, 0);
    }

    #[test]
    fn every_single_byte_corruption_is_refused() {
        let bytes = sample().to_bytes().unwrap();
        for i in 0..bytes.len() {
            let mut bad = bytes.clone();
            bad[i] ^= 0x40;
            assert!(
                Container::<Meta>::from_bytes(&bad, Path::new("x")).is_err(),
                "flipping byte {i} went unnoticed"
            );
        }
    }

    #[test]
    fn truncation_newer_version_and_foreign_files_are_refused() {
        let bytes = sample().to_bytes().unwrap();
        for cut in [0, 5, 23, 30, bytes.len() - 1] {
            let err = Container::<Meta>::from_bytes(&bytes[..cut], Path::new("x")).unwrap_err();
            assert!(
                matches!(
                    err,
                    ContainerError::Truncated { .. } | ContainerError::BadMagic { .. }
                ),
                "cut at {cut}: {err}"
            );
        }
        let mut newer = bytes.clone();
        newer[8..12].copy_from_slice(&(FORMAT_VERSION + 1).to_le_bytes());
        let err = Container::<Meta>::from_bytes(&newer, Path::new("x")).unwrap_err();
        assert!(
            matches!(err, ContainerError::NewerVersion { found, .. } if found == FORMAT_VERSION + 1)
        );
        assert!(err.to_string().contains("upgrade"));
        let mut older = bytes.clone();
        older[8..12].copy_from_slice(&(FORMAT_VERSION - 1).to_le_bytes());
        let err = Container::<Meta>::from_bytes(&older, Path::new("x")).unwrap_err();
        assert!(matches!(err, ContainerError::OlderVersion { .. }), "{err}");
        assert!(err.to_string().contains("solve the scene again"));
        let err = Container::<Meta>::from_bytes(b"P6\n2 2\n255\n....", Path::new("x")).unwrap_err();
        assert!(matches!(err, ContainerError::BadMagic { .. }));
    }

    #[test]
    fn atomic_write_leaves_no_temp_and_replaces_whole_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("s.volrad");
        sample().write(&path).unwrap();
        sample().write(&path).unwrap();
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names.len(), 1, "{names:?}");
        assert_eq!(Container::<Meta>::read(&path).unwrap(), sample());
    }
}
