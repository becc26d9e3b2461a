//! The patch priors p(a_k | border) the sampler can use (Eq. 1's first factor): the interface
//! ([`PatchPrior`]) and the three variants of the paper's Table II.

use crate::error::{Error, Result};
use crate::types::fixed::LogOdds;

/// A candidate configuration with its log-prior (LSB units of [`crate::types::fixed::LSB_NATS`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct PatchCandidate {
    /// Bit `size·r + c` = cell (column c, row r) of the patch, row 0 at the bottom.
    pub config: u16,
    /// log p(config | border) in LSB; only differences between candidates matter.
    pub log_prior: i32,
}

/// The patch prior p(a_k | border) of Eq. 1.
pub trait PatchPrior {
    /// Patch edge: 1 (L = 1) or 3 (L = 9).
    fn size(&self) -> u8;
    /// Cells around patch centres that must lie inside the map so the border can be read:
    /// 2 for a 3×3 patch with a 16-cell border, 1 for a cell with 8 neighbours, 0 if the prior
    /// ignores the border.
    fn margin(&self) -> u8;
    /// Writes candidates for `border` (the 16-cell border of a 3×3 patch, or the 8-neighbour byte
    /// of a cell, in [`crate::sampler::patch`]'s bit order) into `out`, most probable first, and returns
    /// how many were written: at least 1 whenever `out` is not empty.
    fn candidates(&self, border: u16, out: &mut [PatchCandidate]) -> usize;
    /// [`PatchPrior::candidates`] for the sampler, which may remember results (the default does
    /// not): the same candidates for the same `border` and `out.len()`.
    #[inline]
    fn candidates_cached(&mut self, border: u16, out: &mut [PatchCandidate]) -> usize {
        self.candidates(border, out)
    }
    /// The candidates of `border` as static tables (configurations, log-priors; most probable
    /// first), when the prior stores them that way: lets the sampler's hot path read flash
    /// directly instead of copying. `None` (the default): use [`PatchPrior::candidates`].
    #[inline]
    fn table(&mut self, _border: u16) -> Option<(&'static [u16], &'static [i16])> {
        None
    }
}

/// L = 1 with a constant prior p(m_k) (merali-barfoot-mcmc-gibbs-ogm).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConstantCellPrior {
    log_free: i32,
    log_occ: i32,
}

impl ConstantCellPrior {
    /// A prior with p(occupied) = `p`, in (0, 1).
    pub fn new(p: f64) -> Result<Self> {
        if !(p > 0.0 && p < 1.0) {
            return Err(Error::InvalidProbability);
        }
        let l = |q: f64| {
            i32::from(
                LogOdds::from_nats(libm::log(q))
                    .map(|l| l.0)
                    .unwrap_or(i16::MIN),
            )
        };
        Ok(ConstantCellPrior {
            log_free: l(1.0 - p),
            log_occ: l(p),
        })
    }
}

impl PatchPrior for ConstantCellPrior {
    fn size(&self) -> u8 {
        1
    }
    fn margin(&self) -> u8 {
        0
    }
    fn candidates(&self, _border: u16, out: &mut [PatchCandidate]) -> usize {
        let c = [
            PatchCandidate {
                config: 0,
                log_prior: self.log_free,
            },
            PatchCandidate {
                config: 1,
                log_prior: self.log_occ,
            },
        ];
        let n = out.len().min(2);
        for (o, c) in out.iter_mut().zip(c) {
            *o = c;
        }
        n
    }
}

/// L = 1 with the data-driven prior conditioned on the 8 neighbours (the paper's Table I, "L = 1,
/// data-driven prior with border"): [`crate::sampler::prior::cell_prior`], which falls back to the
/// constant p(m_k) for neighbourhoods the corpus never showed.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct NeighbourPrior;

impl PatchPrior for NeighbourPrior {
    fn size(&self) -> u8 {
        1
    }
    fn margin(&self) -> u8 {
        1
    }
    fn candidates(&self, border: u16, out: &mut [PatchCandidate]) -> usize {
        let p = crate::sampler::prior::cell_prior(border as u8);
        let c = [
            PatchCandidate {
                config: 0,
                log_prior: i32::from(p.log_p_free),
            },
            PatchCandidate {
                config: 1,
                log_prior: i32::from(p.log_p_occupied),
            },
        ];
        let n = out.len().min(2);
        for (o, c) in out.iter_mut().zip(c) {
            *o = c;
        }
        n
    }
}

/// The data-driven L = 9 prior conditioned on the 16-cell border (the paper's "MCMC + border",
/// the default): [`crate::sampler::prior::candidates_into`], with its documented back-off for unseen
/// borders (the despeckled border, its ring majority, nearby borders, then the unconditioned
/// prior).
///
/// Keeps a 256-entry direct-mapped cache (1 KiB) of border → candidate slice (of the border, of
/// its despeckled image or of its ring majority, [`crate::sampler::prior::smooth_slot`]), because the
/// borders of a map repeat (straight walls, open space): a hit replaces the table's bucket,
/// binary search and slice bounds by a load and a compare. The union of nearby borders is not
/// cached: the borders that still need it are diverse, so their lookup is made cheap instead
/// (the table's bit filter, [`crate::sampler::prior`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct BorderPrior {
    /// Entry `h` for a border `b` with `(b ^ (b >> 8) · 0x9E37_79B9 >> 24) & 0xFF == h`
    /// ([`PatchPrior::table`]'s hash): `tag | stored << 8 |
    /// (len − 1) << 9 | start << 13`, where `tag = b >> 8` (with `h` it identifies `b`) and
    /// `start`, `len` are the candidates' [`crate::sampler::prior::slot_span`]; or [`EMPTY`].
    cache: [u32; 256],
}

const EMPTY: u32 = 1 << 31;
const STORED: u32 = 1 << 8;
// The packing: a 13-bit start from bit 13 ends below the EMPTY bit.
const _: () = assert!(13 + crate::sampler::prior::SPAN_START_BITS <= 31);

impl Default for BorderPrior {
    fn default() -> Self {
        BorderPrior {
            cache: [EMPTY; 256],
        }
    }
}

impl BorderPrior {
    /// The prior, with an empty cache.
    pub fn new() -> Self {
        Self::default()
    }
}

impl PatchPrior for BorderPrior {
    fn size(&self) -> u8 {
        3
    }
    fn margin(&self) -> u8 {
        2
    }
    fn candidates(&self, border: u16, out: &mut [PatchCandidate]) -> usize {
        let mut buf = [crate::sampler::prior::Candidate {
            config: 0,
            log_prior: 0,
        }; super::MAX_CANDIDATES];
        let k = out.len().min(buf.len());
        let (n, _) =
            crate::sampler::prior::candidates_into(border, buf.get_mut(..k).unwrap_or(&mut []));
        for (o, c) in out.iter_mut().zip(buf.iter().take(n)) {
            *o = PatchCandidate {
                config: c.config,
                log_prior: i32::from(c.log_prior),
            };
        }
        n.min(out.len())
    }

    #[inline]
    fn table(&mut self, border: u16) -> Option<(&'static [u16], &'static [i16])> {
        let tag = u32::from(border >> 8);
        // The low byte xor a hash of the high byte (the tag): with the tag it gives back the
        // border, and the rows of open space and walls spread over the entries.
        let h = (u32::from(border) ^ tag.wrapping_mul(0x9E37_79B9) >> 24) as usize & 0xFF;
        let mut e = self.cache.get(h).copied().unwrap_or(EMPTY);
        if e & (EMPTY | 0xFF) != tag {
            // A stored border, its despeckled image or its ring majority: the back-off's first
            // three steps, which take one border's flash tables whole (the hot path).
            e = match crate::sampler::prior::smooth_slot(border)
                .and_then(|(s, _)| crate::sampler::prior::slot_span(s))
            {
                Some((start, len)) => {
                    tag | STORED | u32::from(len.saturating_sub(1)) << 9 | u32::from(start) << 13
                }
                None => tag,
            };
            if let Some(c) = self.cache.get_mut(h) {
                *c = e;
            }
        }
        if e & STORED == 0 {
            return None;
        }
        crate::sampler::prior::span_tables((e >> 13) as u16, ((e >> 9 & 15) + 1) as u8)
    }
}

/// The data-driven L = 9 prior without border (the paper's "MCMC, L = 9"): the most likely
/// unconditioned configurations, top-k by mass.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UnconditionedPrior;

impl PatchPrior for UnconditionedPrior {
    fn size(&self) -> u8 {
        3
    }
    fn margin(&self) -> u8 {
        1
    }
    fn candidates(&self, _border: u16, out: &mut [PatchCandidate]) -> usize {
        copy_candidates(crate::sampler::prior::unconditioned(out.len()), out)
    }
}

fn copy_candidates(c: crate::sampler::prior::Candidates, out: &mut [PatchCandidate]) -> usize {
    let mut n = 0;
    for (o, (config, lp)) in out.iter_mut().zip(c.configs().iter().zip(c.log_priors())) {
        *o = PatchCandidate {
            config: *config,
            log_prior: i32::from(*lp),
        };
        n += 1;
    }
    n
}
