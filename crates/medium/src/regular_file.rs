//! Reading a file a user named — a volume, a scene, a solution — only when it is a regular
//! file. A FIFO would block the read forever (until something writes to it), a device may never
//! end (`/dev/zero`) and a directory is no file of data: each is refused before anything is
//! read, with an error that says what the path is (`is a FIFO, not a regular file`).
//!
//! Every reader of such a file in volrad goes through [`open`], [`read`] or
//! [`read_to_string`]. The errors are [`std::io::Error`]s (kind `InvalidInput` for a file of
//! the wrong kind) that callers wrap with the path, as they do any other I/O error.
//!
//! ```
//! # #[cfg(unix)] {
//! let err = medium::regular_file::read(std::path::Path::new("/tmp")).unwrap_err();
//! assert_eq!(err.to_string(), "is a directory, not a regular file");
//! # }
//! ```

use std::fs::{File, FileType, OpenOptions};
use std::io::{self, Read};
use std::path::Path;

/// What a file type is, for an error: "a FIFO", "a directory", "a character device", ...
fn describe(kind: FileType) -> &'static str {
    #[cfg(unix)]
    {
        use std::os::unix::fs::FileTypeExt;
        if kind.is_fifo() {
            return "a FIFO";
        }
        if kind.is_char_device() {
            return "a character device";
        }
        if kind.is_block_device() {
            return "a block device";
        }
        if kind.is_socket() {
            return "a socket";
        }
    }
    if kind.is_dir() {
        "a directory"
    } else {
        "a special file"
    }
}

fn refuse_unless_regular(kind: FileType) -> io::Result<()> {
    if kind.is_file() {
        Ok(())
    } else {
        Err(io::Error::new(
            io::ErrorKind::InvalidInput,
            format!("is {}, not a regular file", describe(kind)),
        ))
    }
}

/// Opens `path` for reading if it is a regular file (after following symbolic links).
///
/// The kind is checked before opening, so a device or FIFO is never opened, and again on the
/// open file, so one swapped in between is refused too; that open does not block (on Unix it
/// is made with `O_NONBLOCK`, which changes nothing for a regular file).
pub fn open(path: &Path) -> io::Result<File> {
    refuse_unless_regular(std::fs::metadata(path)?.file_type())?;
    let mut options = OpenOptions::new();
    options.read(true);
    #[cfg(unix)]
    {
        use std::os::unix::fs::OpenOptionsExt;
        options.custom_flags(libc::O_NONBLOCK);
    }
    let file = options.open(path)?;
    refuse_unless_regular(file.metadata()?.file_type())?;
    Ok(file)
}

/// The whole contents of the regular file `path` ([`open`], then read to the end).
pub fn read(path: &Path) -> io::Result<Vec<u8>> {
    let mut file = open(path)?;
    let mut bytes = Vec::new();
    if let Ok(meta) = file.metadata() {
        bytes.reserve(meta.len().try_into().unwrap_or(0));
    }
    file.read_to_end(&mut bytes)?;
    Ok(bytes)
}

/// The whole contents of the regular file `path` as UTF-8 text.
pub fn read_to_string(path: &Path) -> io::Result<String> {
    String::from_utf8(read(path)?).map_err(|_| {
        io::Error::new(
            io::ErrorKind::InvalidData,
            "stream did not contain valid UTF-8",
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_regular_file_reads_and_a_directory_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.txt");
        std::fs::write(&file, "hello").unwrap();
        assert_eq!(read_to_string(&file).unwrap(), "hello");
        let err = read(dir.path()).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::InvalidInput);
        assert_eq!(err.to_string(), "is a directory, not a regular file");
    }

    #[cfg(unix)]
    #[test]
    fn devices_are_refused_before_reading() {
        // /dev/zero would never end.
        let err = read(Path::new("/dev/zero")).unwrap_err();
        assert_eq!(err.to_string(), "is a character device, not a regular file");
    }
}
