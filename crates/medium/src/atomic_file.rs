//! Writing a file atomically: the one writer behind every file volrad produces (solutions,
//! volumes, images, reports, plots, cache entries).
//!
//! Why: a reader of the target (another process, a service request, the next run) sees either
//! the old file or the whole new one, and a crash or a failed write never leaves a
//! half-written file under the final name. How: the content goes to a temporary file in the
//! target's own directory (so the rename stays on one file system), which is synced to disk
//! and then renamed over the target; on any failure the temporary file is removed and the
//! target is left as it was.
//!
//! A target that is a device or a pipe (`-o /dev/null`, `/dev/stdout`, a FIFO) is written
//! into directly: a rename over it would put a regular file in its place (as root, over
//! `/dev/null` itself). A symbolic link is written through: the file it names is replaced, and
//! the link stays.
//!
//! Temporary names are `.{file}.tmp-{pid}-{n}`, with `n` from a process-wide counter, so
//! concurrent writers (threads or processes) never share one; being hidden and not ending in
//! the target's extension, they are not mistaken for finished files.
//!
//! ```
//! let dir = std::env::temp_dir().join(format!("atomic-file-doc-{}", std::process::id()));
//! std::fs::create_dir_all(&dir).unwrap();
//! let path = dir.join("hello.txt");
//! medium::atomic_file::write_bytes(&path, b"hello").unwrap();
//! assert_eq!(std::fs::read(&path).unwrap(), b"hello");
//! # std::fs::remove_dir_all(&dir).unwrap();
//! ```

use std::fs;
use std::io::{self, Write};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Runs `write` on a fresh temporary path beside `path`, syncs what it wrote and renames it
/// over `path`.
///
/// `write` must create the file at the path it is given (any error it returns is passed
/// through unchanged); `io_error` turns the errors of this function's own steps (a path
/// without a file name, syncing, renaming) into the caller's error type. On any failure the
/// temporary file is removed and `path` is untouched.
pub fn write_with<E>(
    path: &Path,
    write: impl FnOnce(&Path) -> Result<(), E>,
    io_error: impl Fn(io::Error) -> E,
) -> Result<(), E> {
    if is_device_or_pipe(path) {
        return write(path);
    }
    // A symbolic link is written through, not replaced: the rename goes over the file it
    // names (`-o /dev/stdout > file`, or a link the user keeps to the latest result).
    let resolved = resolve_link(path);
    let path = resolved.as_deref().unwrap_or(path);
    let tmp = temp_path(path).map_err(&io_error)?;
    let result = write(&tmp).and_then(|()| sync_and_rename(&tmp, path).map_err(&io_error));
    if result.is_err() {
        let _ = fs::remove_file(&tmp);
    }
    result
}

/// Replaces `path` with `bytes` atomically (see [`write_with`]).
pub fn write_bytes(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_with(
        path,
        |tmp| fs::File::create(tmp).and_then(|mut f| f.write_all(bytes)),
        |e| e,
    )
}

/// Whether `path` (followed through symbolic links) exists and is neither a regular file nor
/// a folder: a device, a FIFO or a socket, which is written into rather than replaced.
fn is_device_or_pipe(path: &Path) -> bool {
    fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir())
}

/// The file a symbolic link at `path` names, when it is one and its target can be resolved (a
/// dangling link is replaced as a file would be).
fn resolve_link(path: &Path) -> Option<PathBuf> {
    fs::symlink_metadata(path)
        .ok()
        .filter(|m| m.file_type().is_symlink())
        .and_then(|_| fs::canonicalize(path).ok())
}

/// `.{file}.tmp-{pid}-{n}` in `path`'s directory; refuses a path without a file name.
fn temp_path(path: &Path) -> io::Result<PathBuf> {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    let name = path.file_name().ok_or_else(|| {
        io::Error::new(io::ErrorKind::InvalidInput, "output path has no file name")
    })?;
    let n = COUNTER.fetch_add(1, Ordering::Relaxed);
    let mut tmp_name = std::ffi::OsString::from(".");
    tmp_name.push(name);
    tmp_name.push(format!(".tmp-{}-{n}", std::process::id()));
    Ok(path.with_file_name(tmp_name))
}

fn sync_and_rename(tmp: &Path, path: &Path) -> io::Result<()> {
    // Opened for writing: some platforms refuse to flush a read-only handle.
    fs::OpenOptions::new().write(true).open(tmp)?.sync_all()?;
    fs::rename(tmp, path)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let dir =
            std::env::temp_dir().join(format!("volrad-atomic-file-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        fs::create_dir_all(&dir).unwrap();
        dir
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn replaces_a_whole_existing_file_and_leaves_no_temp_file() {
        let dir = scratch("replace");
        let path = dir.join("out.bin");
        write_bytes(&path, &[7u8; 10_000]).unwrap();
        write_bytes(&path, b"short").unwrap();
        // Replaced, not overwritten in place: nothing of the longer old content remains.
        assert_eq!(fs::read(&path).unwrap(), b"short");
        assert_eq!(names(&dir), ["out.bin"]);
        // A bare file name's temp file is in the working directory too.
        let tmp = temp_path(Path::new("out.png")).unwrap();
        assert_eq!(tmp.parent(), Some(Path::new("")));
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_failing_write_leaves_the_old_file_and_no_temp_file() {
        let dir = scratch("failing");
        let path = dir.join("keep.txt");
        write_bytes(&path, b"old").unwrap();
        let mut seen = None;
        let err = write_with(
            &path,
            |tmp| {
                seen = Some(tmp.to_path_buf());
                fs::write(tmp, b"half of the n").map_err(|e| e.to_string())?;
                Err("encoder gave up".to_string())
            },
            |e| e.to_string(),
        )
        .unwrap_err();
        assert_eq!(err, "encoder gave up");
        let tmp = seen.unwrap();
        assert_eq!(tmp.parent(), Some(dir.as_path()));
        let tmp_name = tmp.file_name().unwrap().to_string_lossy().into_owned();
        let prefix = format!(".keep.txt.tmp-{}-", std::process::id());
        assert!(tmp_name.starts_with(&prefix), "{tmp_name}");
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(names(&dir), ["keep.txt"]);

        // A closure that reports success without creating the file fails at the sync.
        let err = write_with(&path, |_| Ok(()), |e| e).unwrap_err();
        assert_eq!(err.kind(), io::ErrorKind::NotFound);
        assert_eq!(fs::read(&path).unwrap(), b"old");
        assert_eq!(names(&dir), ["keep.txt"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    /// A FIFO given as the target receives the bytes and stays a FIFO (a rename over it
    /// would have left a regular file: what `-o /dev/null` did to `/dev/null` as root).
    #[cfg(unix)]
    #[test]
    fn a_pipe_is_written_into_not_replaced() {
        use std::os::unix::fs::FileTypeExt;
        let dir = scratch("fifo");
        let path = dir.join("pipe");
        let c_path = std::ffi::CString::new(path.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: a valid NUL-terminated path; mkfifo only creates a file system node.
        assert_eq!(unsafe { libc::mkfifo(c_path.as_ptr(), 0o600) }, 0);
        let reader = {
            let path = path.clone();
            std::thread::spawn(move || fs::read(path).unwrap())
        };
        write_bytes(&path, b"through the pipe").unwrap();
        assert_eq!(reader.join().unwrap(), b"through the pipe");
        assert!(fs::metadata(&path).unwrap().file_type().is_fifo());
        assert_eq!(names(&dir), ["pipe"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    /// A symbolic link stays a link: the file it names gets the new content (the rename
    /// replaced the link itself with a regular file before, leaving its target stale; for
    /// `-o /dev/stdout > file`, as root, that was `/dev/stdout`).
    #[cfg(unix)]
    #[test]
    fn a_symbolic_link_is_written_through() {
        let dir = scratch("link");
        let target = dir.join("latest-7.bin");
        let link = dir.join("latest.bin");
        write_bytes(&target, b"old").unwrap();
        std::os::unix::fs::symlink(&target, &link).unwrap();
        write_bytes(&link, b"new").unwrap();
        assert!(fs::symlink_metadata(&link)
            .unwrap()
            .file_type()
            .is_symlink());
        assert_eq!(fs::read(&target).unwrap(), b"new");
        assert_eq!(names(&dir), ["latest-7.bin", "latest.bin"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn concurrent_writers_use_distinct_temp_files() {
        let dir = scratch("concurrent");
        let path = dir.join("shared.bin");
        std::thread::scope(|s| {
            for t in 0..8u8 {
                let path = &path;
                s.spawn(move || {
                    for _ in 0..20 {
                        write_bytes(path, &[t; 4096]).unwrap();
                    }
                });
            }
        });
        // Whatever writer came last, the file is one writer's whole content.
        let bytes = fs::read(&path).unwrap();
        assert_eq!(bytes.len(), 4096);
        assert!(bytes.iter().all(|&b| b == bytes[0]));
        assert_eq!(names(&dir), ["shared.bin"]);
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_path_without_a_file_name_is_refused() {
        let dir = scratch("no-name");
        for path in [Path::new("/"), Path::new(""), &dir.join("..")] {
            let mut called = false;
            let err = write_with(
                path,
                |_| {
                    called = true;
                    Ok(())
                },
                |e| e,
            )
            .unwrap_err();
            assert!(!called, "{}", path.display());
            assert_eq!(err.kind(), io::ErrorKind::InvalidInput);
            assert!(err.to_string().contains("no file name"), "{err}");
        }
        assert!(names(&dir).is_empty());
        fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn a_write_into_a_missing_directory_says_it_is_not_found() {
        let dir = scratch("missing");
        let missing = dir.join("no-such-dir");
        let err = write_bytes(&missing.join("v.f32"), b"data").unwrap_err();
        // The operating system's own error, unwrapped (callers add the path): not found.
        assert_eq!(err.kind(), io::ErrorKind::NotFound, "{err}");
        assert!(err.raw_os_error().is_some(), "{err:?}");
        #[cfg(unix)]
        assert!(
            err.to_string().contains("No such file or directory"),
            "{err}"
        );
        // The writer never creates directories on its own.
        assert!(!missing.exists());
        assert!(names(&dir).is_empty());
        fs::remove_dir_all(&dir).unwrap();
    }
}
