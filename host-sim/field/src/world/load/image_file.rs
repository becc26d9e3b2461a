//! Decoding a map image: PNG or PGM (P2/P5), its content checked against its extension, its
//! size against [`MAX_SIDE`], every decoder failure (even a panic) a [`MapError`].

use std::io::{BufReader, Cursor, Read};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::Path;

use image::{DynamicImage, ImageFormat, ImageReader, Limits};

use super::file::{extension, open};
use crate::world::error::one_line;
use crate::world::{MapError, MAX_SIDE};

/// The image formats a map can be stored in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageKind {
    /// PNG (any bit depth and colour type the `image` crate reads).
    Png,
    /// PGM, plain (P2) or binary (P5).
    Pgm,
}

/// Decodes a `.png` (PNG) or `.pgm` (P2/P5) file, checking content against extension, size
/// against [`MAX_SIDE`], and turning every decoder failure (even a panic) into a [`MapError`].
pub(super) fn decode_image(path: &Path) -> Result<DynamicImage, MapError> {
    let ext = extension(path);
    let kind = match ext.as_str() {
        "png" => ImageKind::Png,
        "pgm" => ImageKind::Pgm,
        _ => {
            return Err(MapError::Format {
                path: path.to_path_buf(),
                detail: format!("image extension `.{ext}` not supported; use .png or .pgm"),
            })
        }
    };
    let (file, len) = open(path)?;
    let mut bytes = Vec::with_capacity(usize::try_from(len).unwrap_or(0));
    BufReader::new(file)
        .read_to_end(&mut bytes)
        .map_err(|e| MapError::Io {
            path: path.to_path_buf(),
            detail: one_line(e),
        })?;
    decode_image_bytes(path, &bytes, kind, MAX_SIDE)
}

/// The byte-level half of the image loader (what [`load_image`](super::load_image) runs on a file's contents, and
/// what the `map_loader` fuzz target drives): checks the content against `kind`, the size
/// against `max_side` pixels a side (at most [`MAX_SIDE`]), and turns every decoder failure
/// (even a panic) into a [`MapError`] naming `path`.
pub fn decode_image_bytes(
    path: &Path,
    bytes: &[u8],
    kind: ImageKind,
    max_side: usize,
) -> Result<DynamicImage, MapError> {
    let max_side = max_side.min(MAX_SIDE);
    let (format, expected) = match kind {
        ImageKind::Png => (ImageFormat::Png, "PNG"),
        ImageKind::Pgm => (ImageFormat::Pnm, "PGM"),
    };
    let len = bytes.len();
    if len == 0 {
        return Err(MapError::Empty {
            path: path.to_path_buf(),
        });
    }
    let head = &bytes[..len.min(8)];
    match sniff(head) {
        found if found == expected => {}
        "truncated PNG" if expected == "PNG" => {
            return Err(MapError::Corrupt {
                path: path.to_path_buf(),
                detail: format!("only {len} bytes"),
            })
        }
        found => {
            return Err(MapError::Format {
                path: path.to_path_buf(),
                detail: format!(
                    "expected {expected}{}, found {found}",
                    if expected == "PGM" { " (P2/P5)" } else { "" }
                ),
            })
        }
    }
    let mut reader = Cursor::new(bytes);
    let corrupt = |e: image::ImageError| match e {
        image::ImageError::Limits(l) => MapError::TooLarge {
            path: path.to_path_buf(),
            detail: one_line(l),
        },
        image::ImageError::IoError(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => {
            MapError::Corrupt {
                path: path.to_path_buf(),
                detail: "unexpected end of file".into(),
            }
        }
        e => MapError::Corrupt {
            path: path.to_path_buf(),
            detail: one_line(e),
        },
    };
    let panicked = |_| MapError::Corrupt {
        path: path.to_path_buf(),
        detail: "the image decoder failed unexpectedly".into(),
    };
    let (w, h) = catch_unwind(AssertUnwindSafe(|| {
        ImageReader::with_format(&mut reader, format).into_dimensions()
    }))
    .map_err(panicked)?
    .map_err(corrupt)?;
    if w as usize > max_side || h as usize > max_side {
        return Err(MapError::TooLarge {
            path: path.to_path_buf(),
            detail: format!("{w}x{h} px, the limit is {max_side} px a side"),
        });
    }
    if w == 0 || h == 0 {
        return Err(MapError::Corrupt {
            path: path.to_path_buf(),
            detail: format!("image is {w}x{h} px"),
        });
    }
    reader.set_position(0);
    let img = catch_unwind(AssertUnwindSafe(|| {
        let mut r = ImageReader::with_format(&mut reader, format);
        let mut limits = Limits::default();
        limits.max_image_width = Some(max_side as u32);
        limits.max_image_height = Some(max_side as u32);
        r.limits(limits);
        r.decode()
    }))
    .map_err(panicked)?
    .map_err(corrupt)?;
    Ok(img)
}

pub(super) const PNG_SIGNATURE: &[u8] = b"\x89PNG\r\n\x1a\n";

/// What the first bytes say a file is.
fn sniff(head: &[u8]) -> &'static str {
    if head.starts_with(PNG_SIGNATURE) {
        return "PNG";
    }
    if head.len() < PNG_SIGNATURE.len() && PNG_SIGNATURE.starts_with(head) {
        return "truncated PNG";
    }
    match head {
        [b'P', b'2' | b'5', ..] => "PGM",
        [b'P', b'1' | b'4', ..] => "PBM (bitmap)",
        [b'P', b'3' | b'6', ..] => "PPM (colour)",
        [b'P', b'7', ..] => "PAM",
        [0xFF, 0xD8, 0xFF, ..] => "JPEG",
        [b'G', b'I', b'F', b'8', ..] => "GIF",
        [b'B', b'M', ..] => "BMP",
        [b'R', b'I', b'F', b'F', ..] => "RIFF/WebP",
        [b'I', b'I', 42, 0, ..] | [b'M', b'M', 0, 42, ..] => "TIFF",
        _ if head.iter().all(|b| b.is_ascii()) => "text",
        _ => "unrecognised data",
    }
}
