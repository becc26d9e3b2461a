//! The crate's single, flat error type (in the style of heapless/postcard).

/// Everything that can go wrong in `ogm-core`. No function in this crate panics on bad input; it
/// returns one of these instead.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum Error {
    /// A grid dimension or the cell size is zero, or the grid has more cells than `u32` indexes.
    InvalidGeometry,
    /// A caller-provided buffer has the wrong length for the geometry it is used with.
    BufferSize {
        /// Length the geometry requires.
        expected: usize,
        /// Length that was provided.
        actual: usize,
    },
    /// A probability outside the open interval (0, 1), or NaN.
    InvalidProbability,
    /// A sensor-model parameter is out of range (e.g. an occupied increment that is not positive,
    /// a free increment that is not negative, or an increment larger than the clamp range).
    InvalidModel,
    /// Clamp bounds that are not `min < 0 < max`.
    InvalidClamp,
    /// The cone model needs a scan sorted by beam angle.
    UnsortedScan,
    /// A capacity-bounded buffer is full.
    Full,
}

impl core::fmt::Display for Error {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Error::InvalidGeometry => {
                f.write_str("invalid grid geometry (zero size or too many cells)")
            }
            Error::BufferSize { expected, actual } => {
                write!(f, "buffer has {actual} elements, geometry needs {expected}")
            }
            Error::InvalidProbability => {
                f.write_str("probability must be in the open interval (0, 1)")
            }
            Error::InvalidModel => f.write_str("invalid sensor model parameters"),
            Error::InvalidClamp => f.write_str("clamp bounds must satisfy min < 0 < max"),
            Error::UnsortedScan => f.write_str("scan beams must be sorted by angle for this model"),
            Error::Full => f.write_str("bounded buffer is full"),
        }
    }
}

impl core::error::Error for Error {}

/// Shorthand for `core::result::Result<T, ogm_core::Error>`.
pub type Result<T> = core::result::Result<T, Error>;
