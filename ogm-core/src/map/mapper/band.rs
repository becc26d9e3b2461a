//! The face band ([`InverseModelKind::FaceBand`]): the cells around a reading, on its ray, that get
//! an update between the occupied and the free one by their offset past the reading in eighths
//! of σ; its geometry, its cells on a ray, and its table of updates.

use super::update::Update;
use super::MapperConfig;
use crate::map::ray::{Ray, Steps};
use crate::map::sensor_model::{
    face_band_delta, InverseModelKind, FACE_BAND_FAR_EIGHTHS, FACE_BAND_REACH_EIGHTHS,
};
use crate::types::geometry::CellCoord;

/// The face band's geometry: σ and the band's half-width in mm, the half-width in eighths
/// of σ, Q16, and the model's far-edge share (Q8, ≤ 256).
#[derive(Clone, Copy)]
pub(super) struct Band {
    sigma_mm: u32,
    pub(super) reach_mm: u32,
    pub(super) reach_t: i64,
    far_edge_q8: u64,
}

impl Band {
    pub(super) fn of(cfg: &MapperConfig) -> Option<Band> {
        match cfg.model.kind() {
            InverseModelKind::FaceBand { sigma_mm } => {
                let sigma_mm = sigma_mm.max(1);
                let reach_mm = sigma_mm.saturating_mul(u32::from(FACE_BAND_REACH_EIGHTHS)) / 8;
                Some(Band {
                    sigma_mm,
                    reach_mm,
                    // 8·reach/σ ≤ 12, in Q16.
                    reach_t: ((u64::from(reach_mm) << 19) / u64::from(sigma_mm)) as i64,
                    far_edge_q8: u64::from(cfg.model.far_edge_q8().min(256)),
                })
            }
            _ => None,
        }
    }

    /// How far a beam's ray is traced: a hit's reading plus the band beyond it.
    pub(super) fn traced(band: Option<Band>, range: u32, hit: bool) -> u32 {
        match band {
            Some(b) if hit => range.saturating_add(b.reach_mm),
            _ => range,
        }
    }

    /// The first step of the band on a ray of `n` steps traced to `traced` mm for a reading at
    /// `range` mm: the first step at least `reach` before the reading (step k lies k/n of the
    /// way, which is exact along the ray's major axis) or, with a far edge, the step before it
    /// if its offset as the band takes it (shifted, [`Band::far_shift`]) lies within the reach.
    ///
    /// Why the shifted offset decides with a far edge: a band narrower than a step holds only
    /// the end cell, the one the reading plus `reach` falls in (anywhere in it); where that is
    /// the cell after the reading's (about reach/step of the readings) the reading's own cell
    /// was freed whole, though its offset at its far edge lies within the band: the textbook
    /// model shifted 1.5 σ deeper (on real logs with σ ≈ 1.3 cells, σ_b ≈ 0.3 cell: −0.03 of
    /// max F1 against the textbook model). Without a far edge (the firmware's default) nothing
    /// changes; as σ → 0 the step before the end lies ever further below the reach: the
    /// textbook model.
    #[inline]
    pub(super) fn first_step(&self, range: u32, traced: u32, n: u64) -> u64 {
        let before = range.saturating_sub(self.reach_mm);
        // In 32 bits when the product fits (a robot's readings on a grid of under 2^16 cells a
        // side), else saturating in 64: only absurd rays come near the u64 range.
        let first = match u32::try_from(n).ok().and_then(|n| before.checked_mul(n)) {
            Some(p) => u64::from(p.div_ceil(traced.max(1))),
            None => div_u64(
                u64::from(before).saturating_mul(n),
                u64::from(traced.max(1)),
                true,
            ),
        };
        if self.far_edge_q8 == 0 || first == 0 {
            first
        } else {
            self.far_edge_first(first, traced, n)
        }
    }

    /// [`Band::first_step`] with a far edge: `first`, or `first − 1` (`first ≥ 1`) if that
    /// step's shifted offset lies within the reach. Out of line: the firmware's default has no
    /// far edge and never calls it.
    #[inline(never)]
    fn far_edge_first(&self, first: u64, traced: u32, n: u64) -> u64 {
        // Step first − 1 lies (n − first + 1)·traced/n mm before the end, which is reach past
        // the reading, and the far edge takes it q/512 of a step further on: within the reach
        // iff 512·(n − first + 1)·traced ≤ 1024·reach·n + q·traced (exact, in mm). With n ≤
        // 2^20 (a ray on a grid under 2^16 cells a side; longer ones are left as they were),
        // traced and reach < 2^32 and q ≤ 256 every term is below 2^62: no overflow.
        if n > 1 << 20 {
            return first;
        }
        let (k, traced) = (n.saturating_sub(first) + 1, u64::from(traced));
        if 512 * k * traced <= 1024 * u64::from(self.reach_mm) * n + self.far_edge_q8 * traced {
            first.saturating_sub(1)
        } else {
            first
        }
    }

    /// The offset of one step past the one before, in eighths of σ, Q16 (≤ 2^22: the step
    /// before a narrow band's end can be up to 6 σ, [`Band::first_step`]), on a ray of `n`
    /// steps traced to `traced` mm: each step lies `8·traced/(σ·n)` eighths further on.
    pub(super) fn step_t(&self, traced: u32, n: u64) -> u64 {
        let den = u64::from(self.sigma_mm).saturating_mul(n.max(1));
        div_u64(u64::from(traced) << 19, den.max(1), false).min(1 << 22)
    }

    /// How much further on than its sample point every cell's offset is taken, in eighths of
    /// σ, Q16, on a ray whose steps are `dt` apart: the model's far-edge share of half a step
    /// (`InverseSensorModel::with_far_edge`) of a step of at most 4 σ (a longer one only
    /// before a narrow band's end, whose offset then lies below the reach and is clamped to
    /// it); ≤ 2^20 (share ≤ 1). 0 without a far edge, so the offsets are the band's as before.
    #[inline]
    pub(super) fn far_shift(&self, dt: u64) -> i64 {
        (dt.min(1 << 21) * self.far_edge_q8 / 512) as i64
    }
}

/// One reading's face band on its ray: the band's steps in the grid, and the offset past the
/// reading, in eighths of σ, of each.
pub(super) struct BandRay {
    pub(super) ray: Ray,
    pub(super) end: CellCoord,
    pub(super) steps: Steps,
    /// Offset of `steps.first` in eighths of σ, Q16.
    pub(super) t0: i64,
    /// Offset of one step in eighths of σ, Q16 (≤ 2^22).
    pub(super) dt: i64,
}

impl BandRay {
    /// The offset of `steps.first` and of one step, in eighths of σ, Q16, as `i32`s: a walk over
    /// the band adds `dt` per step. On a band `|t0| ≤ 36·2^16` and every step's offset lies in
    /// `t0 ..= 12·2^16` (`Rays::band`), far inside the `i32` range.
    #[inline]
    pub(super) fn offsets(&self) -> (i32, i32) {
        let to_i32 = |v: i64| v.clamp(i64::from(i32::MIN), i64::from(i32::MAX)) as i32;
        (to_i32(self.t0), to_i32(self.dt))
    }

    /// Step `k`'s (`k ≥ steps.first`) offset past the reading in eighths of σ, rounded half
    /// away from zero, clamped to `−R ..= F` (R = [`FACE_BAND_REACH_EIGHTHS`], F =
    /// [`FACE_BAND_FAR_EIGHTHS`]; only a far edge's shift takes an offset past R): one
    /// multiply-add per cell, no division.
    #[inline]
    pub(super) fn eighths(&self, k: u64) -> i8 {
        // Fewer than 2^20 in-grid steps (the grid is under 2^16 cells a side), dt ≤ 2^22 and
        // |t0| ≤ 2^41: no overflow.
        let j = k.saturating_sub(self.steps.first).min(1 << 20) as i64;
        let t = self.t0 + j * self.dt;
        let cap = if t < 0 {
            FACE_BAND_REACH_EIGHTHS
        } else {
            FACE_BAND_FAR_EIGHTHS
        };
        let r = ((t.unsigned_abs() + (1 << 15)) >> 16).min(u64::from(cap));
        // r ≤ 28.
        if t < 0 {
            -(r as i8)
        } else {
            r as i8
        }
    }
}

/// The face table slot ([`face_deltas`]) of an offset `t` in eighths of σ, Q16, on a band
/// (`−36·2^16 ≤ t ≤ 28·2^16`, [`Rays::band`]): [`BandRay::eighths`]'s rounding half away from
/// zero, + [`FACE_LOW`]; the table holds the clamp, so none is needed here.
///
/// [`Rays::band`]: super::rays::Rays::band
#[inline(always)]
pub(super) fn face_slot(t: i32) -> usize {
    // Half away from zero: ⌊(t + 2^15)/2^16⌋ for t ≥ 0, and for t < 0 ⌈(t − 2^15)/2^16⌉, which
    // is ⌊(t + 2^15 − 1)/2^16⌋. Saturating: outside a band's range the slot is past the table.
    let r = t.saturating_add((1 << 15) + (t >> 31)) >> 16;
    r.wrapping_add(FACE_LOW) as usize
}

/// [`FACE_BAND_REACH_EIGHTHS`] as an `i32`.
const FACE_REACH: i32 = FACE_BAND_REACH_EIGHTHS as i32;

/// [`FACE_BAND_FAR_EIGHTHS`] as an `i32`.
const FACE_FAR: i32 = FACE_BAND_FAR_EIGHTHS as i32;

/// How far before the reading, in eighths of σ, the face table reaches: a band's offsets lie
/// within `−36 ..= R` eighths ([`Rays::band`]); those before `−R` get the update of `−R`.
///
/// [`Rays::band`]: super::rays::Rays::band
pub(super) const FACE_LOW: i32 = 40;

/// The face band's updates by eighths of σ past the reading, `−FACE_LOW ..= F` (clamped to
/// `−R ..= F`; past R only with a far edge), once per scan: a band walk looks each cell's up
/// without a clamp.
pub(super) fn face_deltas(update: &Update) -> [i32; (FACE_LOW + FACE_FAR + 1) as usize] {
    core::array::from_fn(|j| {
        // |j − FACE_LOW| ≤ 40 and then within −12 ..= 28: fits an i8.
        let t8 = (j as i32 - FACE_LOW).clamp(-FACE_REACH, FACE_FAR);
        face_band_delta(update.occ, update.free, t8 as i8)
    })
}

/// `a / b` (`b ≥ 1`), rounded up if `ceil`: one hardware division when both fit a `u32` (a
/// band's set-up on a robot's ranges), else the `u64` routine a 32-bit core calls.
#[inline]
fn div_u64(a: u64, b: u64, ceil: bool) -> u64 {
    let b = b.max(1);
    match (u32::try_from(a), u32::try_from(b)) {
        (Ok(a), Ok(b)) if ceil => u64::from(a.div_ceil(b)),
        (Ok(a), Ok(b)) => u64::from(a / b),
        _ if ceil => a.div_ceil(b),
        _ => a / b,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::map::sensor_model::InverseSensorModel;
    use proptest::prelude::*;

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]

        /// The band walk's 32-bit face slot finds the update of `BandRay::eighths`'s rounded
        /// and clamped offset, over a band's range of offsets.
        #[test]
        fn face_slot_matches_eighths(t in prop_oneof![(-72i32..=56).prop_map(|k| k << 15),
                -(36i32 << 16)..=(28 << 16)], occ in 1i32..2000, free in -2000i32..0) {
            let cap = if t < 0 { 12 } else { 28 };
            let r = ((u64::from(t.unsigned_abs()) + (1 << 15)) >> 16).min(cap) as i8;
            let want = face_band_delta(occ, free, if t < 0 { -r } else { r });
            let update = Update { occ, free, min: -30_000, max: 30_000 };
            prop_assert_eq!(face_deltas(&update).get(face_slot(t)).copied(), Some(want));
        }

        /// The band's first step in 32 bits equals the 64-bit formula.
        #[test]
        fn band_first_step_matches_u64(sigma in 1u32..200, range in prop_oneof![0u32..20_000, any::<u32>()],
                                       n in prop_oneof![0u64..70_000, any::<u64>()], far in 1u16..=256) {
            let cfg = MapperConfig {
                model: InverseSensorModel::hahnel_face_band(sigma).unwrap(),
                ..MapperConfig::new(20_000)
            };
            let b = Band::of(&cfg).unwrap();
            let traced = range.saturating_add(b.reach_mm);
            let before = u64::from(range.saturating_sub(b.reach_mm));
            let want = before.saturating_mul(n).div_ceil(u64::from(traced.max(1)));
            prop_assert_eq!(b.first_step(range, traced, n), want);
            // With a far edge: that step, or the one before if its shifted offset is within
            // the reach.
            let cfg = MapperConfig {
                model: InverseSensorModel::hahnel_face_band(sigma).unwrap().with_far_edge(far).unwrap(),
                ..cfg
            };
            let f = Band::of(&cfg).unwrap();
            let got = f.first_step(range, traced, n);
            if want == 0 || got == want {
                prop_assert_eq!(got, want);
            } else {
                // In f64: that step's distance before the reading, less the far edge's share
                // of half a step, is within the reach.
                prop_assert_eq!(got, want - 1);
                let step = f64::from(traced) / n as f64;
                let before = (n - want + 1) as f64 * step - f64::from(b.reach_mm);
                let shift = f64::from(far) / 512.0 * step;
                prop_assert!(before - shift <= f64::from(b.reach_mm) + 1e-6 * before.abs().max(1.0));
            }
        }

        /// The narrow division equals the `u64` one.
        #[test]
        fn narrow_division_matches_u64(a in prop_oneof![any::<u32>().prop_map(u64::from), any::<u64>()],
                b in prop_oneof![1u64..1000, 1..=u64::from(u32::MAX), 1..=u64::MAX], ceil in any::<bool>()) {
            let want = if ceil { a.div_ceil(b) } else { a / b };
            prop_assert_eq!(div_u64(a, b, ceil), want);
        }
    }
}
