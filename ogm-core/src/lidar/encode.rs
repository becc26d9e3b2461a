//! What the lidar encoders refuse: one error type for the LD06's ([`crate::lidar::ld06`]) and
//! the RPLIDAR's ([`crate::lidar::rplidar`]).

/// Why an encoder refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum EncodeError {
    /// LD06: the number of beams is not a multiple of 12.
    NotMultipleOf12,
    /// RPLIDAR: the output buffer needs this many bytes.
    BufferTooSmall {
        /// Bytes required.
        needed: usize,
    },
    /// RPLIDAR: a request payload longer than 255 bytes.
    PayloadTooLong,
}

impl core::error::Error for EncodeError {}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            EncodeError::NotMultipleOf12 => {
                f.write_str("LD06: a scan needs a multiple of 12 beams")
            }
            EncodeError::BufferTooSmall { needed } => {
                write!(
                    f,
                    "RPLIDAR: output buffer too small ({needed} bytes needed)"
                )
            }
            EncodeError::PayloadTooLong => f.write_str("RPLIDAR: request payload over 255 bytes"),
        }
    }
}
