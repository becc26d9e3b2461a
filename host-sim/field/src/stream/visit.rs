//! A region the robot comes back to: a building tile that enters the rolling window again.
//!
//! * **Sent back.** When a `Window` announces that stored tiles entered, a host sends them back
//!   ([`BuildingMap::restore_msgs`], docs/wire.md "Restoring stored tiles"); the robot restores
//!   a tile only while it has not mapped there on this visit, so its later tiles contain the
//!   stored evidence, and they **replace** it (newest wins), as with a fixed grid.
//! * **Not sent back** (no host then, or the robot refused): the robot restarted the region
//!   from unknown, so its tiles hold only this visit's evidence; they are **merged** with the
//!   earlier visits': log-odds add, saturating at the robot's clamp (±5·1024); estimates and the
//!   sample bit are this visit's where this visit observed the cell (log-odds ≠ 0), else the
//!   earlier visits'.
//! * **Which.** A tile that enters with something stored keeps its earlier visits apart
//!   ([`Older`]) until the next `Window`, whose `tiles_restored` counter says how many stored
//!   tiles the robot restored meanwhile: none → merged; as many as were sent back (a host that
//!   sends every entered tile: as many as entered) → replaced; any other number (some refused,
//!   which the counters do not name; counted in [`Revisits::unsure`]) → each tile by its data:
//!   a restored tile keeps every cell the older visits knew, so a cell known before but
//!   unknown in this visit's tile means the robot started from unknown (merged), none means
//!   replaced. Until then a tile the host says it sent back renders as replaced, another as
//!   merged.
//!
//! The decision needs only the stream (the counters and the order of tiles), so `listen`,
//! `export --stream` and `host-sim firmware --log` stitch the same building from the same bytes.

use ogm_core::wire::{self, HostMsg, Layer, WindowReport};

use super::building::Stored;
use super::BuildingMap;

/// A revisited tile's earlier visits, merged.
#[derive(Clone, Debug, PartialEq, Eq)]
pub(crate) struct Older {
    /// `LogOdds`, `Counts`, `Sample` of the earlier visits.
    layers: [Option<Vec<u8>>; 3],
    /// Whether the robot holds them (sent back): this visit's tiles then replace them.
    sent: bool,
    /// The counters could not tell (some of a batch refused): decided by this visit's
    /// log-odds tile, once it arrives — a cell unknown there but known before means the robot
    /// started from unknown (refused: merge); none means it holds the older evidence.
    by_data: bool,
}

/// What the revisits did, and the tiles that entered at the last `Window`.
#[derive(Clone, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct Revisits {
    /// Tiles that entered at the last `Window` with something to send back, and the robot's
    /// `tiles_restored` then.
    #[serde(skip)]
    entered: Vec<(i32, i32)>,
    #[serde(skip)]
    restored_before: u32,
    /// Stored tiles that entered the window again (with log-odds and estimates).
    pub tiles_entered: u64,
    /// Of those, the robot restored (its tiles replace the stored ones).
    pub restored: u64,
    /// Of those, the robot did not restore (its tiles are merged with the stored ones).
    pub merged: u64,
    /// Of those, the counters could not tell (decided by each tile's data).
    pub unsure: u64,
}

/// The robot's log-odds clamp: merged log-odds saturate here.
fn clamp() -> i32 {
    i32::from(ogm_core::Clamp::default().max().raw())
}

/// `s` as one tile: its earlier visits merged with this one (see the module docs).
pub(super) fn merge(s: &Stored) -> Stored {
    let Some(older) = &s.older else {
        return s.clone();
    };
    let [lo, counts, sample] = &s.layers;
    let [old_lo, old_counts, old_sample] = &older.layers;
    let sent = if older.by_data {
        match (lo, old_lo) {
            (Some(n), Some(o)) => !n
                .chunks_exact(2)
                .zip(o.chunks_exact(2))
                .any(|(n, o)| n == [0, 0] && o != [0, 0]),
            _ => true,
        }
    } else {
        older.sent
    };
    let layers = if sent {
        [
            lo.clone().or_else(|| old_lo.clone()),
            counts.clone().or_else(|| old_counts.clone()),
            sample.clone().or_else(|| old_sample.clone()),
        ]
    } else {
        let cells = s.w * s.h;
        let lo_at = |d: &Option<Vec<u8>>, k: usize| -> i16 {
            d.as_ref()
                .and_then(|d| d.get(2 * k..2 * k + 2))
                .map_or(0, |c| i16::from_le_bytes([c[0], c[1]]))
        };
        let c = clamp();
        let added: Vec<u8> = (0..cells)
            .flat_map(|k| {
                let v = (i32::from(lo_at(lo, k)) + i32::from(lo_at(old_lo, k))).clamp(-c, c);
                (v as i16).to_le_bytes()
            })
            .collect();
        // This visit's estimate where it observed the cell, else the older one.
        let seen = |k: usize| lo_at(lo, k) != 0;
        let estimates = match (counts, old_counts) {
            (Some(n), Some(o)) => Some(
                (0..cells)
                    .map(|k| {
                        let d = if seen(k) { n } else { o };
                        d.get(k).copied().unwrap_or(0)
                    })
                    .collect(),
            ),
            (n, o) => n.clone().or_else(|| o.clone()),
        };
        let bits = match (sample, old_sample) {
            (Some(n), Some(o)) => {
                let mut out = vec![0u8; cells.div_ceil(8)];
                for (k, byte) in (0..cells).map(|k| (k, k / 8)) {
                    let d = if seen(k) { n } else { o };
                    if d.get(byte).is_some_and(|b| b >> (k % 8) & 1 != 0) {
                        out[byte] |= 1 << (k % 8);
                    }
                }
                Some(out)
            }
            (n, o) => n.clone().or_else(|| o.clone()),
        };
        [
            (lo.is_some() || old_lo.is_some()).then_some(added),
            estimates,
            bits,
        ]
    };
    Stored {
        w: s.w,
        h: s.h,
        layers,
        older: None,
    }
}

/// Whether `s` holds log-odds that are not all unknown.
fn known(s: &Stored) -> bool {
    s.layers[0]
        .as_ref()
        .is_some_and(|d| d.iter().any(|&b| b != 0))
}

impl BuildingMap {
    /// Records a `Window` report: settles the tiles that entered at the previous `Window` by the
    /// robot's restore counter, and notes those that enter now (module docs;
    /// [`BuildingMap::entered`]).
    pub fn note_window(&mut self, w: WindowReport) {
        let before = self.set_window(w);
        self.settle(&w);
        let (width, height, edge) = self.grid();
        let tiles = |r: &WindowReport| {
            let e = edge.max(1) as i64;
            let (x0, y0) = (
                i64::from(r.origin_x).div_euclid(e),
                i64::from(r.origin_y).div_euclid(e),
            );
            (
                x0,
                y0,
                x0 + (width / edge.max(1)) as i64,
                y0 + (height / edge.max(1)) as i64,
            )
        };
        let (ox0, oy0, ox1, oy1) = tiles(&before);
        let (nx0, ny0, nx1, ny1) = tiles(&w);
        let was_inside = |x: i64, y: i64| (ox0..ox1).contains(&x) && (oy0..oy1).contains(&y);
        let mut entered = Vec::new();
        let stored: Vec<(i32, i32)> = self
            .tiles
            .range((nx0.max(i64::from(i32::MIN)) as i32, i32::MIN)..)
            .map(|(k, _)| *k)
            .take_while(|&(x, _)| i64::from(x) < nx1)
            .filter(|&(x, y)| {
                let (x, y) = (i64::from(x), i64::from(y));
                (ny0..ny1).contains(&y) && !was_inside(x, y)
            })
            .collect();
        for key in stored {
            let Some(s) = self.tiles.get_mut(&key) else {
                continue;
            };
            let one = merge(s);
            if !known(&one) {
                continue;
            }
            let full = one.w == edge && one.h == edge;
            if full && one.layers[1].is_some() {
                entered.push(key);
            }
            s.older = Some(Older {
                layers: one.layers,
                sent: false,
                by_data: false,
            });
            s.layers = [None, None, None];
        }
        let r = &mut self.revisits;
        r.tiles_entered += entered.len() as u64;
        r.entered.clone_from(&entered);
        r.restored_before = w.tiles_restored;
    }

    /// The building tiles that entered the window at the last `Window` with stored log-odds
    /// and estimates: the tiles a host sends back ([`BuildingMap::restore_msgs`]).
    pub fn entered(&self) -> &[(i32, i32)] {
        &self.revisits.entered
    }

    /// The `Restore` parts that send `tiles` back (each: its merged log-odds, then estimates,
    /// `wire::restore_msgs`), and marks them sent. Tiles without both layers are skipped.
    pub fn restore_msgs(&mut self, tiles: &[(i32, i32)]) -> Vec<HostMsg> {
        let edge = u16::try_from(self.edge()).unwrap_or(u16::MAX);
        let mut out = Vec::new();
        for key in tiles {
            let Some(s) = self.tiles.get_mut(key) else {
                continue;
            };
            let one = merge(s);
            let (Some(lo), Some(est)) = (&one.layers[0], &one.layers[1]) else {
                continue;
            };
            let before = out.len();
            out.extend(wire::restore_msgs(key.0, key.1, Layer::LogOdds, edge, lo));
            out.extend(wire::restore_msgs(key.0, key.1, Layer::Counts, edge, est));
            if out.len() > before {
                if let Some(o) = &mut s.older {
                    o.sent = true;
                }
            }
        }
        out
    }

    /// What revisited regions did so far.
    pub fn revisits(&self) -> &Revisits {
        &self.revisits
    }

    /// Settles the tiles that entered at the previous `Window` (module docs).
    fn settle(&mut self, w: &WindowReport) {
        let entered = std::mem::take(&mut self.revisits.entered);
        if entered.is_empty() {
            return;
        }
        let done = u64::from(
            w.tiles_restored
                .saturating_sub(self.revisits.restored_before),
        );
        let sent = |m: &Self, k: &(i32, i32)| {
            m.tiles
                .get(k)
                .and_then(|s| s.older.as_ref())
                .is_some_and(|o| o.sent)
        };
        let n_sent = entered.iter().filter(|k| sent(self, k)).count() as u64;
        // A host that says nothing (a recorded stream): it sent every entered tile.
        let expected = if n_sent > 0 {
            n_sent
        } else {
            entered.len() as u64
        };
        let unsure = done != 0 && done != expected;
        for k in &entered {
            let was_sent = sent(self, k);
            let restored = if done == 0 {
                false
            } else {
                n_sent == 0 || was_sent
            };
            let Some(s) = self.tiles.get_mut(k) else {
                continue;
            };
            if unsure {
                if let Some(o) = &mut s.older {
                    o.by_data = true;
                }
            } else if restored {
                // The robot holds the older visits: its tiles replace them.
                if let Some(o) = &mut s.older {
                    o.sent = true;
                }
                *s = merge(s);
            } else if let Some(o) = &mut s.older {
                o.sent = false;
            }
            let r = &mut self.revisits;
            if unsure {
                r.unsure += 1;
            } else if restored {
                r.restored += 1;
            } else {
                r.merged += 1;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::stream::OwnedTile;

    /// A 4 × 4 tile of `layer` whose every cell is `v` (log-odds `i16`, else a byte).
    fn tile(layer: Layer, tx: i32, ty: i32, v: i16) -> OwnedTile {
        let data = match layer {
            Layer::LogOdds => v.to_le_bytes().repeat(16),
            Layer::Counts => vec![v as u8; 16],
            Layer::Sample => vec![v as u8; 2],
        };
        OwnedTile {
            layer,
            tx,
            ty,
            data,
        }
    }

    fn window(origin_x: i32, tiles_restored: u32) -> WindowReport {
        WindowReport {
            origin_x,
            tiles_restored,
            ..WindowReport::default()
        }
    }

    /// Cell `(x, 0)`'s log-odds and count.
    fn at(b: &BuildingMap, x: i64) -> (i16, u8) {
        let r = b.render();
        let i = (x - r.x0) as usize;
        (r.map.log_odds[i], r.map.counts[i])
    }

    /// An 8 × 8 window of 4-cell tiles: tile (0, 0) mapped (log-odds 100, count 50), the window
    /// moves east so that it leaves, and back: it enters again.
    fn revisit() -> BuildingMap {
        let mut b = BuildingMap::new(8, 8, 4);
        b.apply(&tile(Layer::LogOdds, 0, 0, 100)).unwrap();
        b.apply(&tile(Layer::Counts, 0, 0, 50)).unwrap();
        b.note_window(window(8, 0));
        assert!(b.entered().is_empty());
        b.note_window(window(0, 0));
        assert_eq!(b.entered(), &[(0, 0)]);
        b
    }

    #[test]
    fn a_region_not_sent_back_adds_its_visits_and_keeps_older_estimates_where_unseen() {
        let mut b = revisit();
        // This visit's evidence only (the robot restarted the tile from unknown): one cell
        // unseen on this visit.
        let mut lo = tile(Layer::LogOdds, 0, 0, 30);
        lo.data[2..4].copy_from_slice(&0i16.to_le_bytes());
        b.apply(&lo).unwrap();
        b.apply(&tile(Layer::Counts, 0, 0, 200)).unwrap();
        assert_eq!((at(&b, 0), at(&b, 1)), ((130, 200), (100, 50)));
        // The next Window: nothing was restored meanwhile, so the tile stays merged.
        b.note_window(window(8, 0));
        assert_eq!((at(&b, 0), at(&b, 1)), ((130, 200), (100, 50)));
        let v = b.revisits();
        assert_eq!(
            (v.tiles_entered, v.restored, v.merged, v.unsure),
            (1, 0, 1, 0)
        );
        // Merged log-odds saturate at the robot's clamp; a third visit adds to both.
        b.note_window(window(0, 0));
        b.apply(&tile(Layer::LogOdds, 0, 0, 5100)).unwrap();
        assert_eq!(at(&b, 0).0, 5120);
        b.apply(&tile(Layer::LogOdds, 0, 0, -5200)).unwrap();
        assert_eq!(at(&b, 0).0, 130 - 5200);
    }

    #[test]
    fn a_region_sent_back_is_replaced_by_the_robots_newer_tiles() {
        let mut b = revisit();
        let msgs = b.restore_msgs(&[(0, 0)]);
        // A 4-cell tile: one part per layer, the stored cells.
        assert_eq!(msgs.len(), 2);
        let HostMsg::Restore { layer, data, .. } = &msgs[0] else {
            panic!("{:?}", msgs[0]);
        };
        assert_eq!(*layer, Layer::LogOdds);
        assert_eq!(data.as_slice(), 100i16.to_le_bytes().repeat(16).as_slice());
        // The robot restored it: its tiles hold the stored evidence and this visit's.
        b.apply(&tile(Layer::LogOdds, 0, 0, 130)).unwrap();
        assert_eq!(at(&b, 0), (130, 50));
        b.note_window(window(8, 1));
        assert_eq!(at(&b, 0), (130, 50));
        assert_eq!(b.revisits().restored, 1);
        // The robot refused it (restored 0): merged after all.
        let mut b = revisit();
        b.restore_msgs(&[(0, 0)]);
        b.apply(&tile(Layer::LogOdds, 0, 0, 30)).unwrap();
        b.note_window(window(8, 0));
        assert_eq!(at(&b, 0).0, 130);
        assert_eq!(b.revisits().merged, 1);
    }

    #[test]
    fn a_recorded_stream_tells_restored_tiles_by_the_robots_counter() {
        // No host knowledge (export --stream): the counter alone decides.
        for (restored, want) in [(1, 130), (0, 230)] {
            let mut b = revisit();
            b.apply(&tile(Layer::LogOdds, 0, 0, 130)).unwrap();
            b.note_window(window(8, restored));
            assert_eq!(at(&b, 0).0, want, "restored {restored}");
        }
        // Two tiles entered, one restored: unsure; each decided by its data. Tile (0, 0) holds
        // every cell known before (restored: replaced), tile (1, 0) only what this visit saw
        // (refused: merged).
        let mut b = BuildingMap::new(8, 8, 4);
        for tx in 0..2 {
            b.apply(&tile(Layer::LogOdds, tx, 0, 100)).unwrap();
            b.apply(&tile(Layer::Counts, tx, 0, 50)).unwrap();
        }
        b.note_window(window(8, 0));
        b.note_window(window(0, 0));
        assert_eq!(b.entered().len(), 2);
        b.apply(&tile(Layer::LogOdds, 0, 0, 130)).unwrap();
        let mut fresh = tile(Layer::LogOdds, 1, 0, 0);
        fresh.data[..2].copy_from_slice(&30i16.to_le_bytes());
        b.apply(&fresh).unwrap();
        b.note_window(window(8, 1));
        assert_eq!(b.revisits().unsure, 2);
        assert_eq!((at(&b, 0).0, at(&b, 1).0), (130, 130));
        assert_eq!((at(&b, 4).0, at(&b, 5).0), (130, 100));
        assert_eq!(at(&b, 0).0, 130);
    }
}
