//! Bit layout of 5×5 windows, 3×3 patches and their borders, shared by the prior trainer
//! (`host-sim train-prior`), the compiled prior table ([`crate::sampler::prior`]) and the patch sampler.
//!
//! # Layout
//! Rows grow with world *y* (row 0 is the **bottom** row, as in [`crate::map::grid`]) and columns with
//! world *x* (column 0 is the left column). A set bit means *occupied*.
//!
//! * **Window** (`u32`, 25 bits): the 5×5 cells around a patch; cell (row `r`, column `c`),
//!   `r, c ∈ 0..5`, is bit `5·r + c`.
//! * **Config** (`u16`, 9 bits): a 3×3 patch configuration, the window's rows and columns
//!   `1..=3`; window cell (`r`, `c`) is config bit `3·(r − 1) + (c − 1)`, so config bit 4 is the
//!   centre cell and the bits run row-major from the bottom-left.
//! * **Border** (`u16`, 16 bits): the 16 window cells around the patch:
//!   bits 0–4 = row 0 (`c = 0..=4`), bits 5–9 = row 4 (`c = 0..=4`),
//!   bits 10–12 = column 0 (`r = 1..=3`), bits 13–15 = column 4 (`r = 1..=3`).
//! * **Neighbours** (`u8`, L = 1): the 8 cells around the centre of a 3×3 config, in the
//!   config's row-major order skipping the centre: config bits 0–3 → bits 0–3, config bits 5–8
//!   → bits 4–7.
//!
//! ```text
//!   row 4:  b5  b6  b7  b8  b9          config (rows 1..=3, cols 1..=3):
//!   row 3: b12  p6  p7  p8 b15              p6 p7 p8
//!   row 2: b11  p3  p4  p5 b14              p3 p4 p5     (p4 = centre)
//!   row 1: b10  p0  p1  p2 b13              p0 p1 p2
//!   row 0:  b0  b1  b2  b3  b4
//! ```
//!
//! # Symmetries
//! [`Dihedral`] is one of the 8 rotations/reflections of the square about the centre cell. They
//! map the centre 3×3 onto itself and the 16-cell ring onto itself, so they act on windows,
//! configs, borders and neighbour bytes alike; the prior is trained on all 8 images of every
//! window, which makes the tables invariant under them.
//!
//! Everything here is a total `const fn` on plain integers: bits outside a layout's width are
//! ignored, never a panic.

/// The 25 bits of a 5×5 window.
pub const WINDOW_MASK: u32 = (1 << 25) - 1;
/// The 9 bits of a 3×3 config.
pub const CONFIG_MASK: u16 = (1 << 9) - 1;
/// Number of distinct 3×3 configs (2⁹).
pub const CONFIGS: usize = 1 << 9;
/// Number of distinct 16-cell borders (2¹⁶).
pub const BORDERS: usize = 1 << 16;
/// Config bit of the centre cell.
pub const CENTRE_BIT: u16 = 1 << 4;
/// The all-occupied 3×3 config.
pub const CONFIG_OCCUPIED: u16 = CONFIG_MASK;
/// The all-free 3×3 config.
pub const CONFIG_FREE: u16 = 0;

/// Whether window cell (`r`, `c`) is occupied (`false` outside `0..5`).
#[inline]
pub const fn window_cell(window: u32, r: u32, c: u32) -> bool {
    r < 5 && c < 5 && (window >> (5 * r + c)) & 1 == 1
}

/// `window` with cell (`r`, `c`) set to `occupied` (unchanged outside `0..5`).
#[inline]
pub const fn with_window_cell(window: u32, r: u32, c: u32, occupied: bool) -> u32 {
    if r >= 5 || c >= 5 {
        return window;
    }
    let bit = 1u32 << (5 * r + c);
    if occupied {
        window | bit
    } else {
        window & !bit
    }
}

/// The 3×3 config at the centre of a 5×5 window (rows and columns `1..=3`).
#[inline]
pub const fn patch_of(window: u32) -> u16 {
    let row1 = (window >> 6) & 0b111;
    let row2 = (window >> 11) & 0b111;
    let row3 = (window >> 16) & 0b111;
    (row1 | (row2 << 3) | (row3 << 6)) as u16
}

/// The 16-cell border of a 5×5 window (layout in the [module docs](self)).
#[inline]
pub const fn border_of(window: u32) -> u16 {
    let row0 = window & 0x1F;
    let row4 = (window >> 20) & 0x1F;
    let col0 = ((window >> 5) & 1) | (((window >> 10) & 1) << 1) | (((window >> 15) & 1) << 2);
    let col4 = ((window >> 9) & 1) | (((window >> 14) & 1) << 1) | (((window >> 19) & 1) << 2);
    (row0 | (row4 << 5) | (col0 << 10) | (col4 << 13)) as u16
}

/// The 5×5 window with the given centre config and border: the inverse of
/// ([`patch_of`], [`border_of`]). Config bits above bit 8 are ignored.
#[inline]
pub const fn window_from(config: u16, border: u16) -> u32 {
    let p = config as u32;
    let b = border as u32;
    let mut w = b & 0x1F; // row 0
    w |= ((b >> 5) & 0x1F) << 20; // row 4
    w |= (b >> 10 & 1) << 5 | (b >> 11 & 1) << 10 | (b >> 12 & 1) << 15; // column 0
    w |= (b >> 13 & 1) << 9 | (b >> 14 & 1) << 14 | (b >> 15 & 1) << 19; // column 4
    w |= (p & 0b111) << 6 | ((p >> 3) & 0b111) << 11 | ((p >> 6) & 0b111) << 16;
    w
}

/// Whether the centre cell of a 3×3 config is occupied.
#[inline]
pub const fn centre_of(config: u16) -> bool {
    config & CENTRE_BIT != 0
}

/// The border's cells in order around the ring (anticlockwise from the bottom-left corner):
/// row 0 left to right, column 4 upwards, row 4 right to left, column 0 downwards.
pub const RING: [u8; 16] = [0, 1, 2, 3, 4, 13, 14, 15, 9, 8, 7, 6, 5, 12, 11, 10];

/// The border with every *speck* flipped: a ring cell whose state differs from both of its
/// neighbours along the ring ([`RING`]). The nearest "smooth" border, which the prior's
/// back-off looks up first when a border is not stored: a lone occupied cell on a free ring (or
/// a lone gap in a wall) is what a random patch or one noisy cell leaves, and the table knows the
/// border without it. Commutes with the eight [`Dihedral`] transforms (they map the ring onto
/// itself, keeping each cell's two ring neighbours). Branch-free: each ring neighbour's state is
/// gathered with masks and shifts.
#[inline]
pub const fn despeckle(border: u16) -> u16 {
    let x = border as u32;
    // Bit i of `next` / `prev` holds the state of cell i's successor / predecessor on the ring.
    let next = (x >> 1) & 0x000F // b0..b3 ← b1..b4
        | (x >> 9) & 0x0010 // b4 ← b13
        | (x >> 1) & 0x6000 // b13, b14 ← b14, b15
        | (x << 6) & 0x8000 // b15 ← b9
        | (x << 1) & 0x03C0 // b6..b9 ← b5..b8
        | (x >> 7) & 0x0020 // b5 ← b12
        | (x << 1) & 0x1800 // b11, b12 ← b10, b11
        | (x << 10) & 0x0400; // b10 ← b0
    let prev = (x << 1) & 0x001E // b1..b4 ← b0..b3
        | (x << 9) & 0x2000 // b13 ← b4
        | (x << 1) & 0xC000 // b14, b15 ← b13, b14
        | (x >> 6) & 0x0200 // b9 ← b15
        | (x >> 1) & 0x01E0 // b5..b8 ← b6..b9
        | (x << 7) & 0x1000 // b12 ← b5
        | (x >> 1) & 0x0C00 // b10, b11 ← b11, b12
        | (x >> 10) & 0x0001; // b0 ← b10
    (x ^ ((x ^ next) & (x ^ prev))) as u16
}

/// The border with every ring cell set to the majority of the five ring cells around it (itself
/// and two on each side along [`RING`]): smoother than [`despeckle`]'s, it also fills or clears
/// two-cell features. The prior's back-off looks it up after the despeckled border. Commutes
/// with the eight [`Dihedral`] transforms. Bit-parallel: the border is gathered into ring order,
/// the five neighbours are rotations of that word, and two full adders count their votes.
#[inline]
pub const fn ring_majority(border: u16) -> u16 {
    let r = to_ring(border);
    let (a, b, c, d, e) = (
        r.rotate_left(2),
        r.rotate_left(1),
        r,
        r.rotate_right(1),
        r.rotate_right(2),
    );
    // votes = 2 (c1 + c2) + s2, per bit.
    let (s1, c1) = (a ^ b ^ c, (a & b) | (a & c) | (b & c));
    let (s2, c2) = (s1 ^ d ^ e, (s1 & d) | (s1 & e) | (d & e));
    from_ring((c1 & c2) | ((c1 | c2) & s2))
}

/// The border's cells in [`RING`] order: bit `i` is border bit `RING[i]`.
#[inline]
const fn to_ring(b: u16) -> u16 {
    (b & 0x001F) // ring 0..4 ← border 0..4
        | (b >> 8) & 0x00E0 // ring 5..7 ← border 13..15
        | (b >> 1) & 0x0100 // ring 8 ← border 9
        | (b << 1) & 0x0200 // ring 9 ← border 8
        | (b << 3) & 0x0400 // ring 10 ← border 7
        | (b << 5) & 0x0800 // ring 11 ← border 6
        | (b << 7) & 0x1000 // ring 12 ← border 5
        | (b << 1) & 0x2000 // ring 13 ← border 12
        | (b << 3) & 0x4000 // ring 14 ← border 11
        | (b << 5) & 0x8000 // ring 15 ← border 10
}

/// The inverse of [`to_ring`].
#[inline]
const fn from_ring(r: u16) -> u16 {
    (r & 0x001F)
        | (r << 8) & 0xE000
        | (r << 1) & 0x0200
        | (r >> 1) & 0x0100
        | (r >> 3) & 0x0080
        | (r >> 5) & 0x0040
        | (r >> 7) & 0x0020
        | (r >> 1) & 0x1000
        | (r >> 3) & 0x0800
        | (r >> 5) & 0x0400
}

/// The 8 neighbours of a 3×3 config's centre (L = 1 border), row-major skipping the centre.
#[inline]
pub const fn neighbours_of(config: u16) -> u8 {
    ((config & 0x0F) | ((config >> 1) & 0xF0)) as u8
}

/// The 3×3 config with the given neighbours and centre: the inverse of
/// ([`neighbours_of`], [`centre_of`]).
#[inline]
pub const fn config_from(neighbours: u8, centre: bool) -> u16 {
    let n = neighbours as u16;
    let c = if centre { CENTRE_BIT } else { 0 };
    (n & 0x0F) | ((n & 0xF0) << 1) | c
}

/// One of the 8 symmetries of the square (the dihedral group D4) acting about the centre cell.
///
/// Index `i ∈ 0..8`: first a reflection `x ↦ −x` (mirror left ↔ right) if `i ≥ 4`, then a
/// counter-clockwise rotation by `(i mod 4) · 90°`, in centred cell coordinates
/// `x = c − 2`, `y = r − 2` (a rotation by 90° maps `(x, y)` to `(−y, x)`). Index 0 is the
/// identity. Applying a transform to a window moves the occupancy of cell `p` to cell `T(p)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Dihedral(u8);

impl Dihedral {
    /// The identity.
    pub const IDENTITY: Dihedral = Dihedral(0);
    /// All 8 transforms, identity first.
    pub const ALL: [Dihedral; 8] = [
        Dihedral(0),
        Dihedral(1),
        Dihedral(2),
        Dihedral(3),
        Dihedral(4),
        Dihedral(5),
        Dihedral(6),
        Dihedral(7),
    ];

    /// The transform with index `index mod 8` (see the type docs).
    #[inline]
    pub const fn new(index: u8) -> Dihedral {
        Dihedral(index % 8)
    }

    /// The index in `0..8`.
    #[inline]
    pub const fn index(self) -> u8 {
        self.0
    }

    /// Number of counter-clockwise quarter turns (after the optional reflection).
    #[inline]
    pub const fn quarter_turns(self) -> u8 {
        self.0 % 4
    }

    /// Whether the transform includes the reflection `x ↦ −x`.
    #[inline]
    pub const fn is_reflection(self) -> bool {
        self.0 >= 4
    }

    /// Maps centred coordinates `(x, y)` (any integers) to their image.
    #[inline]
    pub const fn map_xy(self, x: i32, y: i32) -> (i32, i32) {
        let (mut x, mut y) = if self.is_reflection() {
            (-x, y)
        } else {
            (x, y)
        };
        let mut k = 0;
        while k < self.quarter_turns() {
            let nx = -y;
            y = x;
            x = nx;
            k += 1;
        }
        (x, y)
    }

    /// Maps window cell (`r`, `c`), both in `0..5`, to its image (also in `0..5`).
    /// Out-of-range inputs are returned unchanged.
    #[inline]
    pub const fn map_cell(self, r: u32, c: u32) -> (u32, u32) {
        if r >= 5 || c >= 5 {
            return (r, c);
        }
        let (x, y) = self.map_xy(c as i32 - 2, r as i32 - 2);
        ((y + 2) as u32, (x + 2) as u32)
    }

    /// `self ∘ other`: first `other`, then `self`.
    pub const fn compose(self, other: Dihedral) -> Dihedral {
        // Identify the composition by where it sends two non-symmetric probe points.
        let (ax, ay) = other.map_xy(1, 0);
        let (bx, by) = other.map_xy(0, 2);
        let (ax, ay) = self.map_xy(ax, ay);
        let (bx, by) = self.map_xy(bx, by);
        let mut i = 0;
        while i < 8 {
            let t = Dihedral(i);
            let (px, py) = t.map_xy(1, 0);
            let (qx, qy) = t.map_xy(0, 2);
            if px == ax && py == ay && qx == bx && qy == by {
                return t;
            }
            i += 1;
        }
        // Unreachable: D4 is closed under composition (tested exhaustively).
        Dihedral::IDENTITY
    }

    /// The inverse transform.
    pub const fn inverse(self) -> Dihedral {
        let mut i = 0;
        while i < 8 {
            let t = Dihedral(i);
            if t.compose(self).0 == 0 {
                return t;
            }
            i += 1;
        }
        Dihedral::IDENTITY
    }

    /// The image of a 5×5 window (bits above bit 24 are dropped).
    pub const fn window(self, window: u32) -> u32 {
        if self.0 == 0 {
            return window & WINDOW_MASK;
        }
        let mut out = 0u32;
        let mut r = 0;
        while r < 5 {
            let mut c = 0;
            while c < 5 {
                if window_cell(window, r, c) {
                    let (r2, c2) = self.map_cell(r, c);
                    out = with_window_cell(out, r2, c2, true);
                }
                c += 1;
            }
            r += 1;
        }
        out
    }

    /// The image of a 3×3 config.
    #[inline]
    pub const fn config(self, config: u16) -> u16 {
        patch_of(self.window(window_from(config, 0)))
    }

    /// The image of a 16-cell border.
    #[inline]
    pub const fn border(self, border: u16) -> u16 {
        border_of(self.window(window_from(0, border)))
    }

    /// The image of an 8-neighbour byte.
    #[inline]
    pub const fn neighbours(self, neighbours: u8) -> u8 {
        neighbours_of(self.config(config_from(neighbours, false)))
    }
}

/// The canonical representative of a window's orbit under [`Dihedral`]: the smallest of its 8
/// images.
pub const fn canonical_window(window: u32) -> u32 {
    let mut best = window & WINDOW_MASK;
    let mut i = 1;
    while i < 8 {
        let w = Dihedral(i).window(window);
        if w < best {
            best = w;
        }
        i += 1;
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A small deterministic generator for sampled exhaustive-ish tests.
    fn lcg(state: &mut u64) -> u32 {
        *state = state
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*state >> 33) as u32
    }

    #[test]
    fn despeckle_flips_exactly_the_lone_ring_cells() {
        for border in 0..=u16::MAX {
            let cell = |i: usize| border >> RING[i % 16] & 1;
            let mut want = border;
            for (i, &b) in RING.iter().enumerate() {
                if cell(i) != cell(i + 1) && cell(i) != cell(i + 15) {
                    want ^= 1 << b;
                }
            }
            assert_eq!(despeckle(border), want, "border {border:#06x}");
            for d in Dihedral::ALL {
                assert_eq!(despeckle(d.border(border)), d.border(want));
            }
        }
        // A lone occupied cell on a free ring, a lone gap in a full one.
        assert_eq!(despeckle(1 << 7), 0);
        assert_eq!(despeckle(!(1 << 12)), u16::MAX);
        // RING is a permutation of the 16 border bits, consecutive cells adjacent in the window.
        assert_eq!(RING.iter().fold(0u32, |m, &b| m | 1 << b), 0xFFFF);
        let at = |i: usize| {
            let w = window_from(0, 1 << RING[i % 16]).trailing_zeros() as i32;
            (w / 5, w % 5)
        };
        for i in 0..16 {
            let ((r0, c0), (r1, c1)) = (at(i), at(i + 1));
            assert_eq!(
                (r0 - r1).abs() + (c0 - c1).abs(),
                1,
                "ring cells {i}, {}",
                i + 1
            );
        }
    }

    #[test]
    fn ring_majority_is_the_five_cell_vote_along_the_ring() {
        for border in 0..=u16::MAX {
            let cell = |i: usize| border >> RING[i % 16] & 1;
            let mut want = 0u16;
            for (i, &b) in RING.iter().enumerate() {
                let votes: u16 = (0..5).map(|j| cell(i + 14 + j)).sum();
                if votes >= 3 {
                    want |= 1 << b;
                }
            }
            assert_eq!(ring_majority(border), want, "border {border:#06x}");
            assert_eq!(from_ring(to_ring(border)), border);
            for d in Dihedral::ALL {
                assert_eq!(ring_majority(d.border(border)), d.border(want));
            }
        }
        // A two-cell gap in a full ring closes; a two-cell run on a free one goes.
        assert_eq!(ring_majority(!(1 << 1 | 1 << 2)), u16::MAX);
        assert_eq!(ring_majority(1 << 13 | 1 << 14), 0);
    }

    #[test]
    fn border_and_patch_round_trip_exhaustively() {
        for border in 0..=u16::MAX {
            for config in [0u16, 1, 0x10, 0x155, 0xAA, 0x1FF] {
                let w = window_from(config, border);
                assert_eq!(w & !WINDOW_MASK, 0);
                assert_eq!(border_of(w), border);
                assert_eq!(patch_of(w), config);
            }
        }
        for config in 0..CONFIGS as u16 {
            let w = window_from(config, 0xA5C3);
            assert_eq!(patch_of(w), config);
            assert_eq!(border_of(w), 0xA5C3);
        }
        let mut s = 7;
        for _ in 0..100_000 {
            let w = lcg(&mut s) & WINDOW_MASK;
            assert_eq!(window_from(patch_of(w), border_of(w)), w);
        }
    }

    #[test]
    fn layout_matches_the_documented_bits() {
        // Border bit order, cell by cell.
        let expected: [(u32, u32); 16] = [
            (0, 0),
            (0, 1),
            (0, 2),
            (0, 3),
            (0, 4),
            (4, 0),
            (4, 1),
            (4, 2),
            (4, 3),
            (4, 4),
            (1, 0),
            (2, 0),
            (3, 0),
            (1, 4),
            (2, 4),
            (3, 4),
        ];
        for (bit, &(r, c)) in expected.iter().enumerate() {
            let w = with_window_cell(0, r, c, true);
            assert_eq!(border_of(w), 1 << bit, "border bit {bit}");
            assert_eq!(patch_of(w), 0);
        }
        for r in 1..=3 {
            for c in 1..=3 {
                let w = with_window_cell(0, r, c, true);
                assert_eq!(patch_of(w), 1 << (3 * (r - 1) + (c - 1)));
                assert_eq!(border_of(w), 0);
            }
        }
        assert!(centre_of(patch_of(with_window_cell(0, 2, 2, true))));
        assert!(window_cell(1 << 7, 1, 2));
        assert!(!window_cell(u32::MAX, 5, 0));
        assert_eq!(with_window_cell(0, 0, 7, true), 0);
    }

    #[test]
    fn neighbours_round_trip() {
        for config in 0..CONFIGS as u16 {
            let n = neighbours_of(config);
            assert_eq!(config_from(n, centre_of(config)), config);
        }
        for n in 0..=u8::MAX {
            for centre in [false, true] {
                let c = config_from(n, centre);
                assert_eq!(neighbours_of(c), n);
                assert_eq!(centre_of(c), centre);
            }
        }
    }

    #[test]
    fn transforms_form_the_dihedral_group() {
        let all = Dihedral::ALL;
        // Distinct on a generic window.
        let generic = with_window_cell(with_window_cell(0, 0, 1, true), 0, 2, true) | (1 << 12);
        for (i, a) in all.iter().enumerate() {
            for b in all.iter().skip(i + 1) {
                assert_ne!(a.window(generic), b.window(generic));
            }
        }
        // Closure, identity, inverse, associativity, and compose agrees with application.
        let mut s = 11;
        let samples: Vec<u32> = (0..200).map(|_| lcg(&mut s) & WINDOW_MASK).collect();
        for a in all {
            assert_eq!(a.compose(Dihedral::IDENTITY), a);
            assert_eq!(Dihedral::IDENTITY.compose(a), a);
            assert_eq!(a.inverse().compose(a), Dihedral::IDENTITY);
            assert_eq!(a.compose(a.inverse()), Dihedral::IDENTITY);
            for b in all {
                let ab = a.compose(b);
                for &w in &samples {
                    assert_eq!(ab.window(w), a.window(b.window(w)));
                }
                for c in all {
                    assert_eq!(a.compose(b).compose(c), a.compose(b.compose(c)));
                }
            }
        }
        // Quarter turn: four of them are the identity, and (x, y) -> (-y, x).
        let r = Dihedral::new(1);
        assert_eq!(r.map_xy(1, 0), (0, 1));
        assert_eq!(r.compose(r).compose(r).compose(r), Dihedral::IDENTITY);
        assert_eq!(Dihedral::new(4).map_xy(1, 1), (-1, 1));
        assert!(Dihedral::new(12).is_reflection());
        assert_eq!(Dihedral::new(12).index(), 4);
    }

    #[test]
    fn transforms_preserve_centre_ring_and_popcount() {
        for t in Dihedral::ALL {
            assert_eq!(t.map_cell(2, 2), (2, 2));
            for r in 0..5 {
                for c in 0..5 {
                    let (r2, c2) = t.map_cell(r, c);
                    let ring = |r: u32, c: u32| r == 0 || r == 4 || c == 0 || c == 4;
                    assert_eq!(ring(r, c), ring(r2, c2));
                }
            }
            for config in 0..CONFIGS as u16 {
                let img = t.config(config);
                assert_eq!(img.count_ones(), config.count_ones());
                assert_eq!(centre_of(img), centre_of(config));
                assert_eq!(t.inverse().config(img), config);
                assert_eq!(
                    t.neighbours(neighbours_of(config)),
                    neighbours_of(img),
                    "neighbours commute with the transform"
                );
            }
            for border in (0..=u16::MAX).step_by(7) {
                let img = t.border(border);
                assert_eq!(img.count_ones(), border.count_ones());
                assert_eq!(t.inverse().border(img), border);
                // Transforming the window = transforming its parts.
                let w = window_from(0x0B3, border);
                assert_eq!(t.window(w), window_from(t.config(0x0B3), t.border(border)));
            }
            assert_eq!(t.config(CONFIG_FREE), CONFIG_FREE);
            assert_eq!(t.config(CONFIG_OCCUPIED), CONFIG_OCCUPIED);
            assert_eq!(t.map_cell(9, 1), (9, 1));
        }
    }

    #[test]
    fn canonical_window_is_orbit_invariant() {
        let mut s = 3;
        for _ in 0..2000 {
            let w = lcg(&mut s) & WINDOW_MASK;
            let c = canonical_window(w);
            assert!(c <= w);
            for t in Dihedral::ALL {
                assert_eq!(canonical_window(t.window(w)), c);
            }
        }
    }
}
