//! The beam model's insertion ([`insert_beam_model`]): mark every ray, apply the hits in beam
//! order, sweep the marks for the freed cells; and the cell update it applies ([`Update`]).

use super::band::{face_deltas, face_slot, Band, FACE_LOW};
use super::listener::{hears, Reports, UpdateListener};
use super::marks::{box_words, ScanBox};
use super::rays::{beam_extent, Rays};
use super::sweep::{free_words, free_words_lanes, LaneCount, LANE_SWEEP};
use super::update::Update;
use super::{MapperConfig, ScanStats};
use crate::types::fixed::LogOdds;
use crate::types::geometry::{CellCoord, GridGeometry, Pose};
use crate::types::scan::Beam;

/// The beam model's insertion, in three passes over the scan:
/// 1. **mark**: every used beam's ray, clipped to the grid and *including* a hit's end cell, sets
///    its cells' bits in `marks` (run by run where the ray is x-major, [`IndexWalk::mark_all`]);
///    the box of the marked cells is kept, and each hit's end cell is remembered;
/// 2. **hits**, in beam order: a hit cell's bit was set by its own ray, so the first beam that
///    hits it finds the bit set, clears it and applies the occupied update; later hits of the
///    same cell find it clear;
/// 3. **frees**: the bits still set are the cells the rays crossed that no beam hit (hits win),
///    found word by word over the box, each freed once and its word cleared, in increasing
///    index order, which walks the grid the way it is laid out in memory.
///
/// The cells and updates are exactly [`classify_scan`]'s (`tests::fast_insert_matches_
/// classification`); only the order of the free updates differs, which cannot change the map
/// since each cell changes at most once per scan. Marking no longer tests bits (a test per
/// walked cell, where rays overlap near the robot, was most of the old cost) and a cell is
/// updated where the sweep finds it rather than through a queue.
///
/// [`IndexWalk::mark_all`]: crate::map::ray::IndexWalk::mark_all
/// [`classify_scan`]: super::classify_scan
#[allow(clippy::too_many_arguments)]
pub(super) fn insert_beam_model<L: UpdateListener>(
    g: &GridGeometry,
    cfg: &MapperConfig,
    pose: &Pose,
    beams: &[Beam],
    marks: &mut [u32],
    cells: &mut [LogOdds],
    update: Update,
    listener: &mut L,
) -> ScanStats {
    let mut stats = ScanStats::default();
    let rays = Rays::new(g, pose);
    let (width, height) = (g.width(), g.height());
    let mut hits = [NO_CELL; HIT_TABLE];
    let mut n_hits = 0usize;
    let mut area = ScanBox::empty();
    let band = Band::of(cfg);
    // Pass 1: mark every ray (with the face band, through its band).
    for beam in beams {
        let Some((range, hit)) = beam_extent(cfg, beam) else {
            stats.beams_dropped += 1;
            continue;
        };
        stats.beams_used += 1;
        let end = rays.end(Band::traced(band, range, hit), beam.angle);
        if hit {
            if let Some(slot) = hits.get_mut(n_hits) {
                *slot = if band.is_some() {
                    // The band's set-up in pass 2 starts from the same end cell.
                    pack_end(end)
                } else {
                    // In-grid indices are < 2^32 − 1 (see NO_CELL).
                    g.index(end).map_or(NO_CELL, |i| i as u32)
                };
            }
            n_hits += 1;
        }
        if let Some(ray) = rays.grid_ray(end) {
            ray.walk().mark_all(marks);
        } else {
            let Some((ray, steps)) = rays.in_grid(end) else {
                continue;
            };
            match ray.index_walk(steps, width) {
                Some(walk) => walk.mark_all(marks),
                None => ray.for_each_index(steps, width, |_, i| {
                    if let Some(word) = marks.get_mut(i / 32) {
                        *word |= 1 << (i % 32);
                    }
                }),
            }
        }
        area.cover(rays.origin, end);
    }
    // The listener learns which cells will change from the marks, before passes 2-3 clear them.
    if L::REPORTS == Reports::Notable {
        box_words(&area, width, height, |first, last| {
            listener.marked_words(first, marks.get(first..=last).unwrap_or(&[]));
        });
    }
    // Pass 2: hits, in beam order; each in-grid hit cell's bit was set by its own ray. With the
    // face band, each hit's band cells, in beam order (set by its own ray too), each band from
    // its ray's end where it can (`Rays::band_back`).
    if let Some(b) = band {
        let face = face_deltas(&update);
        let mut k = 0usize;
        for beam in beams {
            let Some((range, true)) = beam_extent(cfg, beam) else {
                continue;
            };
            let end = hits.get(k).and_then(|&v| unpack_end(v));
            k += 1;
            // Claims band cell `i` at face slot `slot` (its offset in eighths of σ, + FACE_LOW).
            let mut claim = |i: usize, slot: usize| {
                let (w, bit) = (i / 32, 1u32 << (i % 32));
                if let (Some(word), Some(cell)) = (marks.get_mut(w), cells.get_mut(i)) {
                    if *word & bit != 0 {
                        *word &= !bit;
                        let before = *cell;
                        *cell = update.apply(before, face.get(slot).copied().unwrap_or(0));
                        stats.cells_hit += 1;
                        if hears::<L>(before, *cell) {
                            listener.changed(i, before, *cell);
                        }
                    }
                }
            };
            // Backwards from the ray's end where it is in the grid, else forwards from the
            // band's first cell in the grid.
            let (mut walk, (mut t, dt)) = match rays.band_back(b, range, end) {
                Some(back) => back,
                None => {
                    let Some(band) = rays.band(b, range, beam.angle, end) else {
                        continue;
                    };
                    match band.ray.index_walk(band.steps, width) {
                        Some(walk) => (walk, band.offsets()),
                        None => {
                            band.ray.for_each_index(band.steps, width, |k, i| {
                                claim(i, (i32::from(band.eighths(k)) + FACE_LOW) as usize)
                            });
                            continue;
                        }
                    }
                }
            };
            // The offset by one addition per step (no multiply), in registers.
            loop {
                claim(walk.index(), face_slot(t));
                if walk.left() <= 1 {
                    break;
                }
                walk.take(1);
                walk.advance();
                t = t.saturating_add(dt);
            }
        }
    }
    let mut k = 0usize;
    for beam in beams.iter().filter(|_| band.is_none()) {
        let Some((range, true)) = beam_extent(cfg, beam) else {
            continue;
        };
        let index = match hits.get(k) {
            Some(&NO_CELL) => None,
            Some(&i) => Some(i as usize),
            None => g.index(rays.end(range, beam.angle)),
        };
        k += 1;
        let Some(i) = index else { continue };
        let (w, bit) = (i / 32, 1u32 << (i % 32));
        if let (Some(word), Some(cell)) = (marks.get_mut(w), cells.get_mut(i)) {
            if *word & bit != 0 {
                *word &= !bit;
                let before = *cell;
                *cell = update.apply(before, update.occ);
                stats.cells_hit += 1;
                if hears::<L>(before, *cell) {
                    listener.changed(i, before, *cell);
                }
            }
        }
    }
    // Pass 3: free what is left, clearing the marks.
    if LANE_SWEEP && L::REPORTS == Reports::Nothing {
        let mut count = LaneCount::default();
        box_words(&area, width, height, |first, last| {
            free_words_lanes(marks, first, last, cells, update, &mut count);
        });
        stats.cells_freed += count.total();
    } else {
        box_words(&area, width, height, |first, last| {
            stats.cells_freed += free_words(marks, first, last, cells, update, listener);
        });
    }
    stats
}

/// Hit cells remembered between marking and applying the hits, so that their end points are
/// computed once per scan; hits beyond this many are computed again.
const HIT_TABLE: usize = if cfg!(target_pointer_width = "64") {
    1024
} else {
    480
};

/// "No cell": a hit whose end cell is outside the grid. Grid indices are < 2^32 − 1 (a grid
/// has at most 65535² cells).
const NO_CELL: u32 = u32::MAX;

/// A band ray's end cell in a hit table slot, `x` and `y` as `i16`s, or [`NO_CELL`] (then
/// pass 2 computes it again) if they do not fit or pack to [`NO_CELL`] itself.
#[inline]
fn pack_end(c: CellCoord) -> u32 {
    match (i16::try_from(c.x), i16::try_from(c.y)) {
        (Ok(x), Ok(y)) => u32::from(x as u16) << 16 | u32::from(y as u16),
        _ => NO_CELL,
    }
}

/// [`pack_end`]'s cell, if it packed one.
#[inline]
fn unpack_end(v: u32) -> Option<CellCoord> {
    (v != NO_CELL).then(|| CellCoord {
        x: i32::from((v >> 16) as u16 as i16),
        y: i32::from(v as u16 as i16),
    })
}

#[cfg(test)]
mod tests {
    use super::super::strategies::{beams, geometry, mm};
    use super::super::{classify_scan, marks_len, notable, CellUpdate, Mapper};
    use super::*;
    use crate::map::grid::LogOddsGrid;
    use crate::map::sensor_model::{InverseModelKind, InverseSensorModel};
    use crate::types::angle::Angle;
    use crate::types::fixed::Clamp;
    use crate::types::scan::Range;
    use proptest::prelude::*;

    /// A [`Reports::Notable`] listener that records what it hears.
    #[derive(Default)]
    struct Heard {
        marked: Vec<usize>,
        words: std::collections::HashSet<usize>,
        notable: Vec<(usize, LogOdds, LogOdds)>,
    }

    impl UpdateListener for Heard {
        const REPORTS: Reports = Reports::Notable;
        fn changed(&mut self, index: usize, before: LogOdds, after: LogOdds) {
            self.notable.push((index, before, after));
        }
        fn fresh_word(&mut self, word: usize, bits: u32, after: LogOdds) {
            assert_ne!(bits, 0, "word {word}");
            self.notable.extend(
                (0..32)
                    .filter(|b| bits & (1 << b) != 0)
                    .map(|b| (32 * word + b, LogOdds(0), after)),
            );
        }
        fn marked_words(&mut self, first: usize, words: &[u32]) {
            for (k, &bits) in words.iter().enumerate() {
                let word = first + k;
                assert!(self.words.insert(word), "word {word} passed twice");
                self.marked.extend(
                    (0..32)
                        .filter(|b| bits & (1 << b) != 0)
                        .map(|b| 32 * word + b),
                );
            }
        }
    }

    /// Inserts `scans` (the pose moving a little between them) with `insert_scan_with`,
    /// `insert_scan_into` (a [`Reports::Notable`] listener) and `insert_scan` into maps that start
    /// from `start` repeated (values outside the clamp included) and checks them against `classify_scan` applied with `Clamp::apply`: the same
    /// hits in the same order, the same freed cells in increasing index order, the same
    /// statistics, the same map, bit for bit, scan after scan; and the marks left zeroed.
    fn check_against_classification(
        g: GridGeometry,
        cfg: MapperConfig,
        (x, y, heading): (i32, i32, u16),
        scans: &[Vec<Beam>],
        start: &[i16],
    ) -> std::result::Result<(), TestCaseError> {
        let cells: Vec<LogOdds> = (0..g.len())
            .map(|i| LogOdds(start[i % start.len()]))
            .collect();
        let grid = LogOddsGrid::new(g, cells.clone()).unwrap();
        let mut mapper =
            Mapper::new(grid.clone(), vec![0u32; marks_len(g.len()) + 1], cfg).unwrap();
        // `insert_scan` takes the lane-wise sweep on 64-bit hosts.
        let mut quiet = Mapper::new(grid.clone(), vec![0u32; marks_len(g.len())], cfg).unwrap();
        let mut listened = Mapper::new(grid, vec![0u32; marks_len(g.len())], cfg).unwrap();
        let mut want = cells;
        let mut marks = vec![0u32; marks_len(g.len())];
        for (k, beams) in scans.iter().enumerate() {
            let pose = Pose {
                x_mm: x.wrapping_add(k as i32 * 37),
                y_mm: y,
                heading: Angle(heading),
            };
            let mut got = Vec::new();
            let stats = mapper
                .insert_scan_with(&pose, beams, |i, before, after| {
                    got.push((i, before, after))
                })
                .unwrap();
            let mut expected = Vec::new();
            let want_stats = classify_scan(&g, &cfg, &pose, beams, &mut marks, |i, u| {
                let before = want[i];
                let delta = match u {
                    CellUpdate::Hit => cfg.model.occ_increment(),
                    CellUpdate::Free => cfg.model.free_increment(),
                    CellUpdate::Face(t8) => LogOdds(crate::map::sensor_model::face_band_delta(
                        i32::from(cfg.model.occ_increment().0),
                        i32::from(cfg.model.free_increment().0),
                        t8,
                    ) as i16),
                };
                want[i] = cfg.clamp.apply(before, delta);
                expected.push((i, before, want[i], u));
            })
            .unwrap();
            prop_assert_eq!(stats, want_stats);
            prop_assert_eq!(quiet.insert_scan(&pose, beams).unwrap(), want_stats);
            let mut heard = Heard::default();
            prop_assert_eq!(
                listened.insert_scan_into(&pose, beams, &mut heard).unwrap(),
                want_stats
            );
            // `Reports::Notable`: the mark words name exactly the changed cells, each once,
            // and only the notable changes are heard.
            let mut changed: Vec<usize> = got.iter().map(|c| c.0).collect();
            changed.sort_unstable();
            heard.marked.sort_unstable();
            prop_assert_eq!(&heard.marked, &changed);
            // The hits' in beam order, then the sweep's (the fresh ones a word at a time).
            let notables = |c: &[(usize, LogOdds, LogOdds)]| -> Vec<_> {
                c.iter()
                    .copied()
                    .filter(|&(_, before, after)| notable(before, after))
                    .collect()
            };
            let hits = (stats.cells_hit as usize).min(got.len());
            let (hit_notables, freed_notables) = (notables(&got[..hits]), notables(&got[hits..]));
            let n = hit_notables.len().min(heard.notable.len());
            heard.notable[n..].sort_unstable();
            prop_assert_eq!(&heard.notable[..n], &hit_notables[..]);
            prop_assert_eq!(&heard.notable[n..], &freed_notables[..]);
            prop_assert_eq!(listened.grid().cells(), &want[..]);
            prop_assert!(listened.marks.iter().all(|&w| w == 0));
            let hits = (stats.cells_hit as usize).min(got.len());
            let want_hits: Vec<_> = expected
                .iter()
                .filter(|c| c.3 != CellUpdate::Free)
                .map(|c| (c.0, c.1, c.2))
                .collect();
            let mut want_frees: Vec<_> = expected
                .iter()
                .filter(|c| c.3 == CellUpdate::Free)
                .map(|c| (c.0, c.1, c.2))
                .collect();
            want_frees.sort_unstable();
            if matches!(cfg.model.kind(), InverseModelKind::FaceBand { .. }) {
                // A band is walked backwards from its ray's end where that is in the grid
                // (`Rays::band_back`): the same cells and values, each beam's in either order.
                let mut got_hits = got[..hits].to_vec();
                got_hits.sort_unstable();
                let mut want_hits = want_hits;
                want_hits.sort_unstable();
                prop_assert_eq!(got_hits, want_hits);
            } else {
                prop_assert_eq!(&got[..hits], &want_hits[..]);
            }
            prop_assert_eq!(&got[hits..], &want_frees[..]);
            prop_assert_eq!(mapper.grid().cells(), &want[..]);
            prop_assert_eq!(quiet.grid().cells(), &want[..]);
            prop_assert!(mapper.marks.iter().all(|&w| w == 0));
            prop_assert!(quiet.marks.iter().all(|&w| w == 0));
        }
        Ok(())
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(1000))]

        /// A packed end cell unpacks to itself, or to nothing (then it is computed again).
        #[test]
        fn end_cells_pack(x in prop_oneof![-40_000i32..40_000, any::<i32>()],
                          y in prop_oneof![-40_000i32..40_000, any::<i32>()]) {
            let c = CellCoord { x, y };
            match unpack_end(pack_end(c)) {
                Some(u) => prop_assert_eq!(u, c),
                None => prop_assert!(i16::try_from(x).is_err() || i16::try_from(y).is_err()
                    || (x, y) == (-1, -1)),
            }
        }

        /// The mapper's beam-model insertion makes exactly the updates of the classification
        /// (the algorithm it replaced, which the f64 reference still runs): see
        /// [`check_against_classification`].
        #[test]
        fn fast_insert_matches_classification(g in geometry(), x in mm(), y in mm(), heading in any::<u16>(),
                                              scans in prop::collection::vec(beams(), 1..4),
                                              max_range in 1u32..10_000, min_range in 0u32..300,
                                              start in prop::collection::vec(any::<i16>(), 16),
                                              p_occ in 0.55f64..0.97, p_free in 0.03f64..0.45,
                                              wide_clamp in any::<bool>(),
                                              band in prop::option::of((1u32..400, 1u16..=256, 0u16..=256))) {
            let mut cfg = MapperConfig::new(max_range.max(min_range + 1));
            cfg.min_range_mm = min_range;
            cfg.model = match band {
                Some((sigma, q8, far)) => InverseSensorModel::hahnel_face_band(sigma).unwrap()
                    .with_far_edge(far).unwrap().with_free_scale(q8).unwrap(),
                None => InverseSensorModel::beam(p_occ, p_free, 0.5).unwrap(),
            };
            if wide_clamp {
                cfg.clamp = Clamp::new(LogOdds(-i16::MAX), LogOdds(i16::MAX)).unwrap();
            }
            check_against_classification(g, cfg, (x, y, heading), &scans, &start)?;
        }

        /// The same with what skipping the cells shared with the previous ray is for: dense,
        /// sorted scans from a pose on the map, many beams per octant and long rays.
        #[test]
        fn dense_scans_match_classification(w in 3u16..90, h in 1u16..90, cell in 10u32..120,
                                            fx in 0.0f64..1.0, fy in 0.0f64..1.0, heading in any::<u16>(),
                                            n in 8usize..400, jitter in prop::collection::vec(0u16..200, 400),
                                            ranges in prop::collection::vec(prop_oneof![6 => 0u32..12_000, 1 => Just(u32::MAX)], 400),
                                            max_range in 500u32..10_000,
                                            band in prop::option::of((1u32..300, 0u16..=256))) {
            let g = GridGeometry::new(w, h, cell, -1_000, 2_000).unwrap();
            let x = -1_000 + (fx * f64::from(w) * f64::from(cell)) as i32;
            let y = 2_000 + (fy * f64::from(h) * f64::from(cell)) as i32;
            let mut beams: Vec<Beam> = (0..n)
                .map(|k| Beam {
                    angle: Angle(((k * 65_536 / n) as u16).wrapping_add(jitter[k])),
                    range: match ranges[k] { u32::MAX => Range::NoReturn, r => Range::Hit(r) },
                })
                .collect();
            beams.sort_by_key(|b| b.angle.0);
            let mut cfg = MapperConfig::new(max_range);
            if let Some((sigma, far)) = band {
                cfg.model = InverseSensorModel::hahnel_face_band(sigma).unwrap().with_far_edge(far).unwrap();
            }
            check_against_classification(g, cfg, (x, y, heading), &[beams.clone(), beams], &[3, -2000, 7000, 0])?;
        }
    }
}
