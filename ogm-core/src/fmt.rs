//! A tiny logging shim (after embassy's `fmt.rs`), the one copy: ogm-core's own `debug!` and
//! `warn!`, and the firmware's log macros, all expand [`__log!`](crate::__log).
#![allow(unused_macros)]

/// Logs at defmt level `$level` (`debug`, `info`, `warn`, `error`): with the *calling* crate's
/// `defmt` feature the call forwards to defmt, without it the arguments are only evaluated (and
/// so "used"), so host builds need no logger and no `unused` warnings appear. The `cfg` is
/// expanded in the caller, so each crate logs by its own feature (ogm-core's and the
/// firmware's are both named `defmt`).
#[doc(hidden)]
#[macro_export]
macro_rules! __log {
    ($level:ident, $s:literal $(, $x:expr)* $(,)?) => {{
        #[cfg(feature = "defmt")]
        ::defmt::$level!($s $(, $x)*);
        #[cfg(not(feature = "defmt"))]
        let _ = ($( & $x ),*);
    }};
}

macro_rules! debug {
    ($($t:tt)*) => { $crate::__log!(debug, $($t)*) };
}

macro_rules! warn {
    ($($t:tt)*) => { $crate::__log!(warn, $($t)*) };
}
