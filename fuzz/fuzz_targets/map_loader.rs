//! The map loader's byte-level decode path (`ogm_field::world::load`): the first byte picks PNG,
//! PGM or a map_server YAML; the rest is the file's content. A decoded image becomes a `World`
//! (map_server semantics) and is resampled to 5 cm like `host-sim firmware --map` does.
//! Invariants: nothing panics (the decoders' own panics are caught and reported as errors);
//! the error message is one line and names the file; a `World` has width × height cells.
#![no_main]

use std::path::Path;

use libfuzzer_sys::fuzz_target;
use ogm_field::world::load::{decode_image_bytes, parse_ros_yaml, ImageKind, ImageParams};
use ogm_field::world::World;

/// Small enough that a huge declared size cannot exhaust the fuzzer's memory.
const MAX_SIDE: usize = 1024;

fuzz_target!(|data: &[u8]| {
    let Some((&sel, bytes)) = data.split_first() else {
        return;
    };
    let (name, kind) = match sel % 3 {
        0 => ("fuzz.png", Some(ImageKind::Png)),
        1 => ("fuzz.pgm", Some(ImageKind::Pgm)),
        _ => ("fuzz.yaml", None),
    };
    let path = Path::new(name);
    let result = match kind {
        Some(kind) => decode_image_bytes(path, bytes, kind, MAX_SIDE).map(|img| {
            let params = ImageParams {
                resolution_m: 0.02 + f64::from(sel % 7) * 0.01,
                ..ImageParams::default()
            };
            let w = World::from_image(&img, &params);
            assert_eq!(w.cells.len(), w.width * w.height);
            let r = w.resample(0.05);
            assert_eq!(r.cells.len(), r.width * r.height);
        }),
        None => parse_ros_yaml(path, bytes).map(|m| {
            assert!(m.params.resolution_m.is_finite() && m.params.resolution_m > 0.0);
            assert!(m.params.free_thresh < m.params.occupied_thresh);
        }),
    };
    if let Err(e) = result {
        let msg = e.to_string();
        assert!(!msg.contains('\n'), "multi-line error: {msg:?}");
        assert!(
            msg.starts_with(name),
            "error does not name the file: {msg:?}"
        );
    }
});
