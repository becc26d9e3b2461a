//! Procedural building-like worlds, seeded and reproducible.
//!
//! The building fills the map: an outer wall along the border, a main corridor across the
//! longer axis, and both sides split recursively (BSP) into rooms by thinner walls. Large
//! blocks get secondary corridors (opened onto the corridor they end at, like a T junction). Every split wall gets
//! a door as it is made and later splits keep clear of existing doors, so every room is
//! reachable; then every room bordering a corridor gets a door onto it, and some neighbouring
//! rooms get an extra door (loops). Finally rooms are furnished with rectangular and round
//! obstacles that keep clear of door approaches, and either stand free with a clearance ring or
//! stand flush against one wall, so the free space stays one 4-connected region. The same
//! `(params, seed)` always gives the same world.
//!
//! Files: the parameters, the entry points and the generator's state here; `rooms` (the BSP
//! split into rooms and corridors, and their doors), `furnish` (the obstacles).

mod furnish;
mod rooms;

use ogm_field::world::{Truth, World, MAX_SIDE};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

/// Parameters of [`generate()`]. Lengths in metres are rounded to whole cells.
#[derive(Clone, Debug, PartialEq)]
pub struct GenParams {
    /// Columns (clamped to 1..=[`MAX_SIDE`]).
    pub width: usize,
    /// Rows (clamped to 1..=[`MAX_SIDE`]).
    pub height: usize,
    /// Cell edge (m); non-finite or non-positive values fall back to 0.05.
    pub resolution_m: f64,
    /// Interior wall thickness in cells (realistic: 2–4 at 5 cm; at least 1).
    pub wall_thickness: usize,
    /// Outer wall thickness in cells (at least 1).
    pub outer_wall_thickness: usize,
    /// Width of the main corridor (m).
    pub corridor_width_m: f64,
    /// Width of secondary corridors (m).
    pub secondary_corridor_width_m: f64,
    /// A block whose sides both exceed this (m) is split lengthwise by a secondary corridor
    /// instead of a wall; one longer than twice this gets a cross corridor.
    pub corridor_split_m: f64,
    /// Smallest room side (m); raised if needed to fit a door with its clearances.
    pub min_room_m: f64,
    /// Rooms with a side longer than this (m) are always split further.
    pub max_room_m: f64,
    /// Chance that a room which could be split although small enough is split anyway.
    pub extra_split_prob: f64,
    /// Door width (m).
    pub door_width_m: f64,
    /// Chance that two neighbouring rooms get a door between them beyond the ones needed.
    pub extra_door_prob: f64,
    /// Fraction of each room's floor to cover with clutter (0 = empty rooms).
    pub clutter_density: f64,
    /// Share of clutter items that are round (pillars, bins, plants).
    pub round_clutter_fraction: f64,
    /// Free gap kept around clutter (m), so a robot can pass.
    pub clutter_clearance_m: f64,
}

impl Default for GenParams {
    /// 500 × 500 cells of 5 cm (25 m square), 3-cell walls, 4-cell outer wall, 1.8 m main
    /// corridor, 0.9 m doors, rooms 2.5–7 m, 5 % clutter.
    fn default() -> Self {
        GenParams {
            width: 500,
            height: 500,
            resolution_m: 0.05,
            wall_thickness: 3,
            outer_wall_thickness: 4,
            corridor_width_m: 1.8,
            secondary_corridor_width_m: 1.5,
            corridor_split_m: 18.0,
            min_room_m: 2.5,
            max_room_m: 7.0,
            extra_split_prob: 0.25,
            door_width_m: 0.9,
            extra_door_prob: 0.25,
            clutter_density: 0.05,
            round_clutter_fraction: 0.3,
            clutter_clearance_m: 0.5,
        }
    }
}

/// The embedded default world of the demo: `generate(&GenParams::default(), 1)`.
pub fn default_world() -> World {
    generate(&GenParams::default(), 1)
}

/// Generates a building-like world (see the module docs). Deterministic in `(params, seed)`;
/// never panics, whatever the parameters (degenerate ones give degenerate but valid worlds).
/// The free space is always a single 4-connected region (if there is any).
pub fn generate(params: &GenParams, seed: u64) -> World {
    let mut world = generate_unsealed(params, seed);
    // Safety net; the construction already guarantees this (tested without the net).
    seal_pockets(&mut world);
    world
}

/// Fills every free region but the largest.
fn seal_pockets(world: &mut World) {
    let comps = world.free_components();
    if comps.count() <= 1 {
        return;
    }
    let keep = comps.largest();
    for (c, &l) in world.cells.iter_mut().zip(&comps.labels) {
        if l != ogm_field::world::FreeComponents::NONE && Some(l) != keep {
            *c = Truth::Occupied;
        }
    }
}

fn generate_unsealed(params: &GenParams, seed: u64) -> World {
    let width = params.width.clamp(1, MAX_SIDE);
    let height = params.height.clamp(1, MAX_SIDE);
    let res = if params.resolution_m.is_finite() && params.resolution_m > 0.0 {
        params.resolution_m
    } else {
        0.05
    };
    let m = |v: f64, min: usize| -> usize {
        let c = (v / res).round();
        if c.is_finite() && c >= min as f64 {
            (c as usize).min(MAX_SIDE)
        } else {
            min
        }
    };
    let t = params.wall_thickness.clamp(1, MAX_SIDE);
    let door = m(params.door_width_m, 2);
    let door_clear = m(0.3, 1);
    let c = Cells {
        t,
        corridor: m(params.corridor_width_m, 2),
        corridor2: m(params.secondary_corridor_width_m, 2),
        corridor_split: m(params.corridor_split_m, 1),
        min_room: m(params.min_room_m, 1).max(door + 2 * door_clear + 1),
        max_room: m(params.max_room_m, 1),
        door,
        door_clear,
        approach: m(0.8, 1).max(door),
        clear: m(params.clutter_clearance_m, 1),
    };
    let mut g = Gen {
        w: width,
        h: height,
        cells: vec![Truth::Free; width * height],
        rng: Xoshiro256PlusPlus::seed_from_u64(seed),
        c,
        leaves: Vec::new(),
        doors: Vec::new(),
        extra_split_prob: params.extra_split_prob,
    };
    let to = params.outer_wall_thickness.clamp(1, MAX_SIDE);
    g.fill(
        Rect {
            x0: 0,
            y0: 0,
            x1: width,
            y1: height,
        },
        Truth::Occupied,
    );
    if width > 2 * to && height > 2 * to {
        let inner = Rect {
            x0: to,
            y0: to,
            x1: width - to,
            y1: height - to,
        };
        g.fill(inner, Truth::Free);
        g.split(inner, Vec::new(), true);
        g.connect_neighbours(params.extra_door_prob);
        g.furnish(params);
    }
    World {
        width,
        height,
        resolution_m: res,
        origin_m: (0.0, 0.0),
        cells: g.cells,
    }
}

struct Gen {
    w: usize,
    h: usize,
    cells: Vec<Truth>,
    rng: Xoshiro256PlusPlus,
    c: Cells,
    leaves: Vec<Leaf>,
    /// Carved door rectangles (for the clutter keep-out).
    doors: Vec<(Rect, bool)>,
    extra_split_prob: f64,
}

/// Parameters in cells.
struct Cells {
    t: usize,
    corridor: usize,
    corridor2: usize,
    corridor_split: usize,
    min_room: usize,
    max_room: usize,
    door: usize,
    door_clear: usize,
    approach: usize,
    clear: usize,
}

/// Half-open cell rectangle `[x0, x1) × [y0, y1)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Rect {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

impl Rect {
    fn w(&self) -> usize {
        self.x1.saturating_sub(self.x0)
    }

    fn h(&self) -> usize {
        self.y1.saturating_sub(self.y0)
    }

    fn area(&self) -> usize {
        self.w() * self.h()
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Side {
    Left,
    Right,
    Bottom,
    Top,
}

/// An opening in the wall on `side` of a region, spanning `[lo, hi)` along that side.
#[derive(Clone, Copy, Debug)]
struct Door {
    side: Side,
    lo: usize,
    hi: usize,
}

#[derive(Clone, Copy, Debug)]
struct Leaf {
    rect: Rect,
    corridor: bool,
}

fn chance(rng: &mut Xoshiro256PlusPlus, p: f64) -> bool {
    rng.random::<f64>() < p
}

/// Uniform in `lo..=hi` (`lo` if the range is empty).
fn pick(rng: &mut Xoshiro256PlusPlus, lo: usize, hi: usize) -> usize {
    if hi <= lo {
        lo
    } else {
        rng.random_range(lo..=hi)
    }
}

fn uniform(rng: &mut Xoshiro256PlusPlus, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

impl Gen {
    fn fill(&mut self, r: Rect, v: Truth) {
        for y in r.y0..r.y1.min(self.h) {
            let row = y * self.w;
            if let Some(s) = self
                .cells
                .get_mut(row + r.x0.min(self.w)..row + r.x1.min(self.w))
            {
                s.fill(v);
            }
        }
    }

    fn at(&self, x: usize, y: usize) -> Truth {
        self.cells
            .get(y * self.w + x)
            .copied()
            .unwrap_or(Truth::Occupied)
    }

    fn any_occupied(&self, r: Rect) -> bool {
        (r.y0..r.y1).any(|y| (r.x0..r.x1).any(|x| self.at(x, y) == Truth::Occupied))
    }

    /// Carves a door (free cells) and remembers it; `vertical_wall` tells its orientation.
    fn carve(&mut self, r: Rect, vertical_wall: bool) {
        self.fill(r, Truth::Free);
        self.doors.push((r, vertical_wall));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn check(world: &World, what: &str) {
        assert_eq!(world.cells.len(), world.width * world.height, "{what}");
        let comps = world.free_components();
        assert_eq!(
            comps.count(),
            1,
            "{what}: free space in {} pieces {:?}",
            comps.count(),
            comps.sizes
        );
        let occ = world.occupied_fraction();
        assert!(
            (0.10..=0.35).contains(&occ),
            "{what}: occupied fraction {occ:.3}"
        );
        assert_eq!(world.counts().unknown, 0, "{what}");
    }

    #[test]
    fn default_worlds_are_connected_and_plausible() {
        let p = GenParams::default();
        for seed in 0..12 {
            let w = generate_unsealed(&p, seed);
            assert_eq!((w.width, w.height, w.resolution_m), (500, 500, 0.05));
            check(&w, &format!("seed {seed}"));
        }
    }

    #[test]
    fn other_shapes_are_connected_and_plausible() {
        let cases = [
            GenParams {
                width: 900,
                height: 300,
                ..GenParams::default()
            },
            GenParams {
                width: 160,
                height: 700,
                wall_thickness: 2,
                ..GenParams::default()
            },
            GenParams {
                width: 1000,
                height: 1000,
                clutter_density: 0.1,
                ..GenParams::default()
            },
            GenParams {
                width: 250,
                height: 250,
                resolution_m: 0.1,
                wall_thickness: 2,
                outer_wall_thickness: 2,
                ..GenParams::default()
            },
            GenParams {
                width: 400,
                height: 400,
                wall_thickness: 4,
                extra_door_prob: 1.0,
                ..GenParams::default()
            },
        ];
        for (i, p) in cases.iter().enumerate() {
            for seed in 0..3 {
                check(
                    &generate_unsealed(p, seed),
                    &format!("case {i} seed {seed}"),
                );
            }
        }
    }

    #[test]
    fn reproducible_and_seed_dependent() {
        let p = GenParams {
            width: 300,
            height: 200,
            ..GenParams::default()
        };
        assert_eq!(generate(&p, 7), generate(&p, 7));
        assert_ne!(generate(&p, 7), generate(&p, 8));
        assert_eq!(default_world(), generate(&GenParams::default(), 1));
    }

    #[test]
    fn has_outer_wall_main_corridor_and_rooms() {
        let w = default_world();
        for i in 0..500 {
            for d in 0..4 {
                for (x, y) in [(i, d), (d, i), (i, 499 - d), (499 - d, i)] {
                    assert_eq!(w.get(x, y), Some(Truth::Occupied), "outer wall at {x},{y}");
                }
            }
        }
        // A main corridor: a band of at least 1.5 m free across most of the building.
        let band = 30;
        let free_run = |cell: &dyn Fn(i64, i64) -> Option<Truth>, k0: i64| {
            (4..496)
                .filter(|&u| (k0..k0 + band).all(|k| cell(u, k) == Some(Truth::Free)))
                .count()
        };
        let rows = (4..496 - band).any(|y0| free_run(&|u, k| w.get(u, k), y0) > 420);
        let cols = (4..496 - band).any(|x0| free_run(&|u, k| w.get(k, u), x0) > 420);
        assert!(rows || cols, "no main corridor");
        // Rooms: closing every door opening (done by flooding only through cells whose
        // 3-neighbourhood is free) is not needed; count generator leaves instead.
        let g = GenParams {
            clutter_density: 0.0,
            ..GenParams::default()
        };
        let bare = generate(&g, 1);
        let occ = bare.occupied_fraction();
        assert!(occ > 0.05, "hardly any walls: {occ}");
        assert!(w.occupied_fraction() > occ, "no clutter");
    }

    #[test]
    fn degenerate_parameters_do_not_panic() {
        let d = GenParams::default();
        let cases = [
            GenParams {
                width: 0,
                height: 0,
                ..d.clone()
            },
            GenParams {
                width: 1,
                height: 1,
                ..d.clone()
            },
            GenParams {
                width: 9,
                height: 9,
                ..d.clone()
            },
            GenParams {
                width: 30,
                height: 12,
                ..d.clone()
            },
            GenParams {
                resolution_m: f64::NAN,
                width: 100,
                height: 100,
                ..d.clone()
            },
            GenParams {
                resolution_m: 1e-9,
                width: 100,
                height: 100,
                ..d.clone()
            },
            GenParams {
                resolution_m: 10.0,
                width: 100,
                height: 100,
                ..d.clone()
            },
            GenParams {
                wall_thickness: 0,
                outer_wall_thickness: 0,
                width: 120,
                height: 90,
                ..d.clone()
            },
            GenParams {
                wall_thickness: 1000,
                width: 120,
                height: 90,
                ..d.clone()
            },
            GenParams {
                door_width_m: 100.0,
                min_room_m: -1.0,
                max_room_m: f64::NAN,
                ..d.clone()
            },
            GenParams {
                corridor_width_m: f64::INFINITY,
                clutter_density: 5.0,
                round_clutter_fraction: 2.0,
                ..d.clone()
            },
            GenParams {
                clutter_density: f64::NAN,
                extra_door_prob: -3.0,
                extra_split_prob: 9.0,
                clutter_clearance_m: 0.0,
                ..d.clone()
            },
            GenParams {
                min_room_m: 0.0,
                max_room_m: 0.0,
                width: 200,
                height: 200,
                ..d.clone()
            },
        ];
        for (i, p) in cases.iter().enumerate() {
            let w = generate(p, i as u64);
            assert_eq!(w.cells.len(), w.width * w.height, "case {i}");
            assert!(w.width >= 1 && w.height >= 1);
            assert!(w.free_components().count() <= 1, "case {i}");
        }
    }

    /// A generated world survives a round trip through the map_server files (the writer's own
    /// round-trip test in `ogm_field::world::export` uses hand-made patterns).
    #[test]
    fn generated_world_round_trips_through_ros_map_files() {
        use ogm_field::world::{load_world, write_png, write_ros_map};
        let dir = tempfile::tempdir().unwrap();
        let w = &generate(
            &GenParams {
                width: 230,
                height: 170,
                ..GenParams::default()
            },
            3,
        );
        let i = 3;
        let y = dir.path().join(format!("m{i}.yaml"));
        let pgm = write_ros_map(&y, w).unwrap();
        assert_eq!(pgm, dir.path().join(format!("m{i}.pgm")));
        let text = std::fs::read_to_string(&y).unwrap();
        assert!(text.starts_with(&format!("image: m{i}.pgm\n")), "{text}");
        assert!(text.contains("mode: trinary"));
        let back = load_world(&y, None).unwrap();
        assert_eq!(&back, w, "world {i}");
        // the PGM alone and a PNG give the same cells
        let alone = load_world(&pgm, Some(w.resolution_m)).unwrap();
        assert_eq!(alone.cells, w.cells);
        let png = dir.path().join(format!("m{i}.png"));
        write_png(&png, w).unwrap();
        assert_eq!(load_world(&png, None).unwrap().cells, w.cells);
    }
}
