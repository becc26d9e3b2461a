//! Furnishing the rooms: rectangular and round obstacles clear of the door approaches, free
//! standing with a clearance ring or flush against one wall.

use ogm_field::world::{Truth, MAX_SIDE};

use super::{chance, pick, uniform, Gen, GenParams, Rect};

impl Gen {
    /// Places clutter in the rooms (not in corridors).
    pub(super) fn furnish(&mut self, params: &GenParams) {
        let density = params.clutter_density;
        if density.is_nan() || density <= 0.0 {
            return;
        }
        let density = density.min(0.5);
        let (w, h) = (self.w, self.h);
        let mut keepout = vec![false; w * h];
        let (ap, dc) = (self.c.approach, self.c.door_clear);
        for &(r, vertical_wall) in &self.doors {
            let (mx, my) = if vertical_wall { (ap, dc) } else { (dc, ap) };
            for y in r.y0.saturating_sub(my)..(r.y1 + my).min(h) {
                for x in r.x0.saturating_sub(mx)..(r.x1 + mx).min(w) {
                    keepout[y * w + x] = true;
                }
            }
        }
        let res = if params.resolution_m.is_finite() && params.resolution_m > 0.0 {
            params.resolution_m
        } else {
            0.05
        };
        let cells = |m: f64| ((m / res).round().max(1.0) as usize).min(MAX_SIDE);
        let clear = self.c.clear;
        let rooms: Vec<Rect> = self
            .leaves
            .iter()
            .filter(|l| !l.corridor)
            .map(|l| l.rect)
            .collect();
        for room in rooms {
            let target = (density * room.area() as f64) as usize;
            let mut placed = 0usize;
            let mut attempts = 0;
            while placed < target && attempts < 80 {
                attempts += 1;
                let free_of_keepout =
                    |r: Rect| (r.y0..r.y1).all(|y| (r.x0..r.x1).all(|x| !keepout[y * w + x]));
                if chance(&mut self.rng, params.round_clutter_fraction) {
                    // round: pillar, bin, plant
                    let rc = cells(uniform(&mut self.rng, 0.15, 0.45));
                    let m = clear + rc;
                    if room.w() < 2 * m + 1 || room.h() < 2 * m + 1 {
                        continue;
                    }
                    let cx = pick(&mut self.rng, room.x0 + m, room.x1 - 1 - m);
                    let cy = pick(&mut self.rng, room.y0 + m, room.y1 - 1 - m);
                    let bbox = Rect {
                        x0: cx - rc,
                        y0: cy - rc,
                        x1: cx + rc + 1,
                        y1: cy + rc + 1,
                    };
                    let ring = Rect {
                        x0: bbox.x0 - clear,
                        y0: bbox.y0 - clear,
                        x1: bbox.x1 + clear,
                        y1: bbox.y1 + clear,
                    };
                    if self.any_occupied(ring) || !free_of_keepout(bbox) {
                        continue;
                    }
                    let r2 = (rc * rc + rc) as i64;
                    for y in bbox.y0..bbox.y1 {
                        for x in bbox.x0..bbox.x1 {
                            let (dx, dy) = (x as i64 - cx as i64, y as i64 - cy as i64);
                            if dx * dx + dy * dy <= r2 {
                                self.cells[y * w + x] = Truth::Occupied;
                                placed += 1;
                            }
                        }
                    }
                    continue;
                }
                let flush = chance(&mut self.rng, 0.5);
                let (obj, ring) = if flush {
                    // shelf, desk or sofa against one wall
                    let len = cells(uniform(&mut self.rng, 0.6, 2.0));
                    let depth = cells(uniform(&mut self.rng, 0.3, 0.7));
                    let side = pick(&mut self.rng, 0, 3);
                    let along_x = side < 2;
                    let (span, across) = if along_x {
                        (room.w(), room.h())
                    } else {
                        (room.h(), room.w())
                    };
                    if span < len + 2 * clear || across < depth + 2 * clear {
                        continue;
                    }
                    let a = pick(&mut self.rng, clear, span - clear - len);
                    let (obj, ring) = match side {
                        0 => {
                            let o = Rect {
                                x0: room.x0 + a,
                                y0: room.y0,
                                x1: room.x0 + a + len,
                                y1: room.y0 + depth,
                            };
                            (
                                o,
                                Rect {
                                    x0: o.x0 - clear,
                                    y0: o.y0,
                                    x1: o.x1 + clear,
                                    y1: o.y1 + clear,
                                },
                            )
                        }
                        1 => {
                            let o = Rect {
                                x0: room.x0 + a,
                                y0: room.y1 - depth,
                                x1: room.x0 + a + len,
                                y1: room.y1,
                            };
                            (
                                o,
                                Rect {
                                    x0: o.x0 - clear,
                                    y0: o.y0 - clear,
                                    x1: o.x1 + clear,
                                    y1: o.y1,
                                },
                            )
                        }
                        2 => {
                            let o = Rect {
                                x0: room.x0,
                                y0: room.y0 + a,
                                x1: room.x0 + depth,
                                y1: room.y0 + a + len,
                            };
                            (
                                o,
                                Rect {
                                    x0: o.x0,
                                    y0: o.y0 - clear,
                                    x1: o.x1 + clear,
                                    y1: o.y1 + clear,
                                },
                            )
                        }
                        _ => {
                            let o = Rect {
                                x0: room.x1 - depth,
                                y0: room.y0 + a,
                                x1: room.x1,
                                y1: room.y0 + a + len,
                            };
                            (
                                o,
                                Rect {
                                    x0: o.x0 - clear,
                                    y0: o.y0 - clear,
                                    x1: o.x1,
                                    y1: o.y1 + clear,
                                },
                            )
                        }
                    };
                    (obj, ring)
                } else {
                    // table, cabinet
                    let ow = cells(uniform(&mut self.rng, 0.4, 1.6));
                    let oh = cells(uniform(&mut self.rng, 0.4, 1.6));
                    if room.w() < ow + 2 * clear || room.h() < oh + 2 * clear {
                        continue;
                    }
                    let x0 = pick(&mut self.rng, room.x0 + clear, room.x1 - clear - ow);
                    let y0 = pick(&mut self.rng, room.y0 + clear, room.y1 - clear - oh);
                    let o = Rect {
                        x0,
                        y0,
                        x1: x0 + ow,
                        y1: y0 + oh,
                    };
                    (
                        o,
                        Rect {
                            x0: x0 - clear,
                            y0: y0 - clear,
                            x1: o.x1 + clear,
                            y1: o.y1 + clear,
                        },
                    )
                };
                if self.any_occupied(ring) || !free_of_keepout(obj) {
                    continue;
                }
                self.fill(obj, Truth::Occupied);
                placed += obj.area();
            }
        }
    }
}
