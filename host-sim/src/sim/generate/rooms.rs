//! The building's plan: the map split recursively (BSP) into rooms and corridors, each split
//! wall with its door, then extra doors between neighbouring rooms.

use std::collections::BTreeMap;

use ogm_field::world::Truth;

use super::{chance, pick, Door, Gen, Leaf, Rect, Side};

impl Gen {
    /// Recursively divides region `r` (free interior, walls around it) whose boundary has
    /// `doors`. Invariant: on return the free cells of `r` are connected and every door in
    /// `doors` opens onto them.
    pub(super) fn split(&mut self, r: Rect, doors: Vec<Door>, main: bool) {
        let (w, h) = (r.w(), r.h());
        let c = &self.c;
        let (t, minr) = (c.t, c.min_room);
        let (short, long) = (w.min(h), w.max(h));
        let along = w >= h; // a corridor along the longer axis runs along x iff w >= h
                            // (corridor width, runs along x)
        let corridor = if main && short >= 2 * minr + c.corridor + 2 * t {
            Some((c.corridor, along))
        } else if main {
            None
        } else if long >= 2 * c.corridor_split && long >= 2 * minr + c.corridor2 + 2 * t {
            // a very long block: a cross corridor cuts it in two
            Some((c.corridor2, !along))
        } else if short >= c.corridor_split && short >= 2 * minr + c.corridor2 + 2 * t {
            Some((c.corridor2, along))
        } else {
            None
        };
        if let Some((cw, horizontal)) = corridor {
            if self.split_corridor(r, &doors, horizontal, cw) {
                return;
            }
        }
        let long = w.max(h);
        let must = long > self.c.max_room;
        let may = long >= 2 * minr + t && chance(&mut self.rng, self.extra_split_prob);
        if must || may {
            // Try the wall across the longer side first.
            let order = if w >= h { [true, false] } else { [false, true] };
            for vertical in order {
                let len = if vertical { w } else { h };
                if len < 2 * minr + t {
                    continue;
                }
                if self.split_wall(r, &doors, vertical) {
                    return;
                }
            }
        }
        self.leaves.push(Leaf {
            rect: r,
            corridor: false,
        });
    }

    /// Splits `r` by one wall; `vertical` = the wall runs along y (splits x).
    fn split_wall(&mut self, r: Rect, doors: &[Door], vertical: bool) -> bool {
        let (t, minr) = (self.c.t, self.c.min_room);
        let (lo, len) = if vertical {
            (r.x0, r.w())
        } else {
            (r.y0, r.h())
        };
        let cross = if vertical {
            [Side::Bottom, Side::Top]
        } else {
            [Side::Left, Side::Right]
        };
        let blocked = Self::intervals(doors, &cross);
        let cands = self.clear_positions(lo + minr, lo + len - minr - t, t, &blocked);
        if cands.is_empty() {
            return false;
        }
        // Prefer the middle half of the admissible range for less sliver-like rooms.
        let n = cands.len();
        let i = pick(&mut self.rng, n / 4, n - 1 - n / 4);
        let s = cands[i];
        let (a, b, door_dir) = if vertical {
            let wall = Rect {
                x0: s,
                y0: r.y0,
                x1: s + t,
                y1: r.y1,
            };
            self.fill(wall, Truth::Occupied);
            let (d0, d1) = self.door_span(r.y0, r.y1);
            self.carve(
                Rect {
                    x0: s,
                    y0: d0,
                    x1: s + t,
                    y1: d1,
                },
                true,
            );
            (
                Rect { x1: s, ..r },
                Rect { x0: s + t, ..r },
                (Side::Right, Side::Left, d0, d1),
            )
        } else {
            let wall = Rect {
                x0: r.x0,
                y0: s,
                x1: r.x1,
                y1: s + t,
            };
            self.fill(wall, Truth::Occupied);
            let (d0, d1) = self.door_span(r.x0, r.x1);
            self.carve(
                Rect {
                    x0: d0,
                    y0: s,
                    x1: d1,
                    y1: s + t,
                },
                false,
            );
            (
                Rect { y1: s, ..r },
                Rect { y0: s + t, ..r },
                (Side::Top, Side::Bottom, d0, d1),
            )
        };
        let (side_a, side_b, d0, d1) = door_dir;
        let mut da = Self::inherit(doors, r, a);
        da.push(Door {
            side: side_a,
            lo: d0,
            hi: d1,
        });
        let mut db = Self::inherit(doors, r, b);
        db.push(Door {
            side: side_b,
            lo: d0,
            hi: d1,
        });
        self.split(a, da, false);
        self.split(b, db, false);
        true
    }

    /// Splits `r` by a corridor of width `cw` with a wall on each side.
    fn split_corridor(&mut self, r: Rect, doors: &[Door], horizontal: bool, cw: usize) -> bool {
        let (t, minr) = (self.c.t, self.c.min_room);
        // Along the split axis (y for a horizontal corridor).
        let (lo, len) = if horizontal {
            (r.y0, r.h())
        } else {
            (r.x0, r.w())
        };
        let band = 2 * t + cw;
        let cross = if horizontal {
            [Side::Left, Side::Right]
        } else {
            [Side::Bottom, Side::Top]
        };
        let blocked = Self::intervals(doors, &cross);
        // Both walls must keep clear of doors; the corridor itself may take one.
        let dc = self.c.door_clear;
        let cands: Vec<usize> = (lo + minr..=(lo + len).saturating_sub(minr + band))
            .filter(|&s| {
                let w1 = (s, s + t);
                let w2 = (s + t + cw, s + band);
                blocked.iter().all(|&(a, b)| {
                    (w1.0 >= b + dc || w1.1 + dc <= a) && (w2.0 >= b + dc || w2.1 + dc <= a)
                })
            })
            .collect();
        if cands.is_empty() {
            return false;
        }
        // Keep the corridor near the middle (the middle third of the admissible positions).
        let n = cands.len();
        let s = cands[pick(&mut self.rng, n / 3, n - 1 - n / 3)];
        let (a, corr, b);
        if horizontal {
            a = Rect { y1: s, ..r };
            corr = Rect {
                y0: s + t,
                y1: s + t + cw,
                ..r
            };
            b = Rect { y0: s + band, ..r };
            self.fill(
                Rect {
                    y0: s,
                    y1: s + t,
                    ..r
                },
                Truth::Occupied,
            );
            self.fill(
                Rect {
                    y0: s + t + cw,
                    y1: s + band,
                    ..r
                },
                Truth::Occupied,
            );
        } else {
            a = Rect { x1: s, ..r };
            corr = Rect {
                x0: s + t,
                x1: s + t + cw,
                ..r
            };
            b = Rect { x0: s + band, ..r };
            self.fill(
                Rect {
                    x0: s,
                    x1: s + t,
                    ..r
                },
                Truth::Occupied,
            );
            self.fill(
                Rect {
                    x0: s + t + cw,
                    x1: s + band,
                    ..r
                },
                Truth::Occupied,
            );
        }
        self.leaves.push(Leaf {
            rect: corr,
            corridor: true,
        });
        // One door from each side onto the corridor (more are added for every room later).
        let mut children = Vec::new();
        for (child, wall_lo, side) in [
            (a, s, if horizontal { Side::Top } else { Side::Right }),
            (
                b,
                s + t + cw,
                if horizontal { Side::Bottom } else { Side::Left },
            ),
        ] {
            let (d0, d1) = if horizontal {
                self.door_span(r.x0, r.x1)
            } else {
                self.door_span(r.y0, r.y1)
            };
            let door = if horizontal {
                Rect {
                    x0: d0,
                    y0: wall_lo,
                    x1: d1,
                    y1: wall_lo + t,
                }
            } else {
                Rect {
                    x0: wall_lo,
                    y0: d0,
                    x1: wall_lo + t,
                    y1: d1,
                }
            };
            self.carve(door, !horizontal);
            let mut dd = Self::inherit(doors, r, child);
            dd.push(Door {
                side,
                lo: d0,
                hi: d1,
            });
            children.push((child, dd));
        }
        for (child, dd) in children {
            self.split(child, dd, false);
        }
        true
    }

    /// The doors of parent `p` that lie on the boundary of its child `c`.
    fn inherit(doors: &[Door], p: Rect, c: Rect) -> Vec<Door> {
        doors
            .iter()
            .filter(|d| {
                let (on_side, lo, hi) = match d.side {
                    Side::Left => (c.x0 == p.x0, c.y0, c.y1),
                    Side::Right => (c.x1 == p.x1, c.y0, c.y1),
                    Side::Bottom => (c.y0 == p.y0, c.x0, c.x1),
                    Side::Top => (c.y1 == p.y1, c.x0, c.x1),
                };
                on_side && d.lo >= lo && d.hi <= hi
            })
            .copied()
            .collect()
    }

    /// Positions `s` in `lo..=hi` where a band `[s, s + band)` keeps `door_clear` cells away
    /// from every door interval in `doors`.
    fn clear_positions(
        &self,
        lo: usize,
        hi: usize,
        band: usize,
        doors: &[(usize, usize)],
    ) -> Vec<usize> {
        let dc = self.c.door_clear;
        (lo..=hi)
            .filter(|&s| {
                doors
                    .iter()
                    .all(|&(a, b)| s >= b + dc || s + band + dc <= a)
            })
            .collect()
    }

    /// Door intervals of `doors` on the given sides.
    fn intervals(doors: &[Door], sides: &[Side]) -> Vec<(usize, usize)> {
        doors
            .iter()
            .filter(|d| sides.contains(&d.side))
            .map(|d| (d.lo, d.hi))
            .collect()
    }

    /// A door interval of `self.c.door` cells within `[lo, hi)`, with clearance if possible.
    fn door_span(&mut self, lo: usize, hi: usize) -> (usize, usize) {
        let (d, dc) = (self.c.door, self.c.door_clear);
        let len = hi.saturating_sub(lo);
        if len <= d {
            return (lo, hi);
        }
        let (a, b) = if len >= d + 2 * dc {
            (lo + dc, hi - dc - d)
        } else {
            (lo, hi - d)
        };
        let s = pick(&mut self.rng, a, b);
        (s, s + d)
    }

    /// Adds doors between neighbouring leaves: every room onto each corridor it borders,
    /// corridors onto corridors (full width), rooms onto rooms with `extra_prob`.
    pub(super) fn connect_neighbours(&mut self, extra_prob: f64) {
        let t = self.c.t;
        for vertical in [true, false] {
            // key: the coordinate where the far side of a wall starts.
            let mut near: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
            let mut far: BTreeMap<usize, Vec<usize>> = BTreeMap::new();
            for (i, l) in self.leaves.iter().enumerate() {
                let (end, start) = if vertical {
                    (l.rect.x1, l.rect.x0)
                } else {
                    (l.rect.y1, l.rect.y0)
                };
                near.entry(end + t).or_default().push(i);
                far.entry(start).or_default().push(i);
            }
            for (k, ns) in &near {
                let Some(fs) = far.get(k) else { continue };
                for &i in ns {
                    for &j in fs {
                        let (a, b) = (self.leaves[i], self.leaves[j]);
                        let (lo, hi) = if vertical {
                            (a.rect.y0.max(b.rect.y0), a.rect.y1.min(b.rect.y1))
                        } else {
                            (a.rect.x0.max(b.rect.x0), a.rect.x1.min(b.rect.x1))
                        };
                        if hi <= lo || self.has_opening(vertical, *k, lo, hi) {
                            continue;
                        }
                        let (d0, d1) = match (a.corridor, b.corridor) {
                            (true, true) => (lo, hi),
                            (true, false) | (false, true) if hi - lo >= self.c.door => {
                                self.door_span(lo, hi)
                            }
                            (false, false)
                                if hi - lo >= self.c.door + 2 * self.c.door_clear
                                    && chance(&mut self.rng, extra_prob) =>
                            {
                                self.door_span(lo, hi)
                            }
                            _ => continue,
                        };
                        let r = if vertical {
                            Rect {
                                x0: k - t,
                                y0: d0,
                                x1: *k,
                                y1: d1,
                            }
                        } else {
                            Rect {
                                x0: d0,
                                y0: k - t,
                                x1: d1,
                                y1: *k,
                            }
                        };
                        self.carve(r, vertical);
                    }
                }
            }
        }
    }

    /// Whether the wall between two leaves already has an opening. `vertical`: the wall spans
    /// x in `[k - t, k)` and the overlap runs along y; otherwise transposed.
    fn has_opening(&self, vertical: bool, k: usize, lo: usize, hi: usize) -> bool {
        let t = self.c.t;
        (lo..hi).any(|u| {
            (k - t..k).all(|v| {
                let (x, y) = if vertical { (v, u) } else { (u, v) };
                self.at(x, y) == Truth::Free
            })
        })
    }
}
