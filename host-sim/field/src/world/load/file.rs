//! Opening a map file: one-line errors for a missing, unreadable or empty file.

use std::fs::File;
use std::path::Path;

use crate::world::error::one_line;
use crate::world::MapError;

pub(super) fn extension(path: &Path) -> String {
    path.extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase()
}

pub(super) fn check_exists(path: &Path) -> Result<(), MapError> {
    match std::fs::metadata(path) {
        Ok(m) if m.is_dir() => Err(MapError::Io {
            path: path.to_path_buf(),
            detail: "is a directory".into(),
        }),
        Ok(_) => Ok(()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Err(MapError::NotFound {
            path: path.to_path_buf(),
        }),
        Err(e) => Err(MapError::Io {
            path: path.to_path_buf(),
            detail: one_line(e),
        }),
    }
}

pub(super) fn open(path: &Path) -> Result<(File, u64), MapError> {
    check_exists(path)?;
    let io = |e: std::io::Error| match e.kind() {
        std::io::ErrorKind::NotFound => MapError::NotFound {
            path: path.to_path_buf(),
        },
        _ => MapError::Io {
            path: path.to_path_buf(),
            detail: one_line(e),
        },
    };
    let file = File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    if len == 0 {
        return Err(MapError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok((file, len))
}
