//! Why a map could not be loaded or written: [`MapError`], one line naming the file.

use std::path::PathBuf;

/// Why a map could not be loaded (or written). Messages are one line and name the file.
#[derive(Debug, thiserror::Error)]
pub enum MapError {
    /// The file does not exist.
    #[error("{path}: file not found")]
    NotFound {
        /// The missing file.
        path: PathBuf,
    },
    /// The file exists but could not be read (permissions, a directory, I/O error).
    #[error("{path}: cannot read: {detail}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        detail: String,
    },
    /// The file has no content.
    #[error("{path}: file is empty")]
    Empty {
        /// The file.
        path: PathBuf,
    },
    /// Unknown extension, or content that is not what the extension says.
    #[error("{path}: wrong or unsupported format: {detail}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What was expected and found.
        detail: String,
    },
    /// The image could not be decoded (truncated, corrupt, bad header).
    #[error("{path}: truncated or corrupt image: {detail}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// The decoder's complaint.
        detail: String,
    },
    /// The image is larger than [`MAX_SIDE`](super::MAX_SIDE) pixels a side or needs too much memory.
    #[error("{path}: image too large: {detail}")]
    TooLarge {
        /// The file.
        path: PathBuf,
        /// Size and limit.
        detail: String,
    },
    /// The YAML could not be parsed or is not a mapping.
    #[error("{path}: invalid map YAML: {detail}")]
    Yaml {
        /// The YAML file.
        path: PathBuf,
        /// The parser's complaint.
        detail: String,
    },
    /// A required key is missing from the map YAML.
    #[error("{path}: map YAML has no `{key}` key")]
    MissingKey {
        /// The YAML file.
        path: PathBuf,
        /// The key.
        key: &'static str,
    },
    /// A value is of the wrong type or out of range (in a YAML, or a caller's parameter).
    #[error("{path}: bad `{key}`: {detail}")]
    BadValue {
        /// The file the value belongs to.
        path: PathBuf,
        /// The key or parameter.
        key: &'static str,
        /// What is wrong with it.
        detail: String,
    },
    /// The image named in a map YAML does not exist.
    #[error("{path}: image `{}` not found", clip(&.image.display().to_string()))]
    ImageMissing {
        /// The YAML file.
        path: PathBuf,
        /// The resolved image path.
        image: PathBuf,
    },
    /// Writing failed (export).
    #[error("{path}: cannot write: {detail}")]
    Write {
        /// The file being written.
        path: PathBuf,
        /// The OS or encoder error.
        detail: String,
    },
}

/// Flattens a message to one line.
pub(crate) fn one_line(s: impl std::fmt::Display) -> String {
    s.to_string()
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
}

/// A value from a file quoted in a message: one line, at most 60 characters.
pub(crate) fn clip(s: &str) -> String {
    let s = one_line(s);
    match s.char_indices().nth(60) {
        Some((i, _)) => format!("{}…", &s[..i]),
        None => s,
    }
}
