//! The patch priors p(a_k | border) the sampler can use (Eq. 1's first factor): the three
//! variants of the paper's Table II.

use super::{PatchCandidate, PatchPrior};
use crate::error::{Error, Result};
use crate::fixed::LogOdds;

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

/// The data-driven L = 9 prior conditioned on the 16-cell border (the paper's "MCMC + border",
/// the default): [`crate::prior::candidates_into`], with its documented back-off for unseen
/// borders (nearby borders, then the unconditioned prior).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BorderPrior;

impl PatchPrior for BorderPrior {
    fn size(&self) -> u8 {
        3
    }
    fn margin(&self) -> u8 {
        2
    }
    fn candidates(&self, border: u16, out: &mut [PatchCandidate]) -> usize {
        // The common case, a stored border: straight from the flash table.
        if let Some(c) = crate::prior::border_candidates(border) {
            return copy_candidates(c, out);
        }
        let mut buf = [crate::prior::Candidate {
            config: 0,
            log_prior: 0,
        }; super::MAX_CANDIDATES];
        let k = out.len().min(buf.len());
        let (n, _) = crate::prior::candidates_into(border, buf.get_mut(..k).unwrap_or(&mut []));
        for (o, c) in out.iter_mut().zip(buf.iter().take(n)) {
            *o = PatchCandidate {
                config: c.config,
                log_prior: i32::from(c.log_prior),
            };
        }
        n.min(out.len())
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
        copy_candidates(crate::prior::unconditioned(out.len()), out)
    }
}

fn copy_candidates(c: crate::prior::Candidates, out: &mut [PatchCandidate]) -> usize {
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
