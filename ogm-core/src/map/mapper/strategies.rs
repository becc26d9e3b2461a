//! Proptest strategies shared by the mapper's tests.

use crate::types::angle::Angle;
use crate::types::geometry::GridGeometry;
use crate::types::scan::{Beam, Range};
use proptest::prelude::*;

/// Any coordinate, mostly near the grid, sometimes anywhere in the i32 range.
pub(super) fn mm() -> impl Strategy<Value = i32> {
    prop_oneof![4 => -6_000i32..6_000, 1 => any::<i32>()]
}

pub(super) fn geometry() -> impl Strategy<Value = GridGeometry> {
    (
        1u16..50,
        1u16..50,
        prop_oneof![1u32..200, Just(1), any::<u32>().prop_map(|s| s.max(1))],
        -3_000i32..3_000,
        -3_000i32..3_000,
    )
        .prop_map(|(w, h, s, ox, oy)| GridGeometry::new(w, h, s, ox, oy).unwrap())
}

pub(super) fn beams() -> impl Strategy<Value = Vec<Beam>> {
    let range = prop_oneof![
        4 => (0u32..8_000).prop_map(Range::Hit),
        1 => any::<u32>().prop_map(Range::Hit),
        1 => Just(Range::NoReturn),
    ];
    prop::collection::vec(
        (any::<u16>(), range).prop_map(|(a, range)| Beam {
            angle: Angle(a),
            range,
        }),
        0..40,
    )
}
