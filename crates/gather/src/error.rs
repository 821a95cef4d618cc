//! Errors of the gather crate: small, matchable, and naming what was wrong.

use std::path::PathBuf;

/// Everything that can go wrong while setting up a camera, rendering or writing an image.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum GatherError {
    /// A camera specification that cannot form an image (eye on the target, up parallel to
    /// the view direction, field of view outside (0°, 180°), zero size, non-finite values).
    #[error("camera `{name}`: {message}")]
    Camera { name: String, message: String },
    /// Render options or inputs that do not fit the medium (spp of 0, channel out of range...).
    #[error("invalid render input: {0}")]
    Render(String),
    /// An image file that is not what it claims to be (malformed PFM header, short data...).
    #[error("{file}: {message}")]
    Format { file: PathBuf, message: String },
    /// An output path whose extension names no format volrad writes.
    #[error("{file}: unknown image extension `{extension}` (expected .png, .pfm or .exr)")]
    UnknownExtension { file: PathBuf, extension: String },
    /// An encoder (PNG, EXR) failed.
    #[error("{file}: {message}")]
    Encode { file: PathBuf, message: String },
    #[error("{file}: {source}")]
    Io {
        file: PathBuf,
        #[source]
        source: std::io::Error,
    },
}

impl GatherError {
    pub(crate) fn camera(name: &str, message: impl Into<String>) -> Self {
        GatherError::Camera {
            name: name.to_string(),
            message: message.into(),
        }
    }

    pub(crate) fn io(file: &std::path::Path, source: std::io::Error) -> Self {
        GatherError::Io {
            file: file.to_path_buf(),
            source,
        }
    }

    pub(crate) fn format(file: &std::path::Path, message: impl Into<String>) -> Self {
        GatherError::Format {
            file: file.to_path_buf(),
            message: message.into(),
        }
    }
}
