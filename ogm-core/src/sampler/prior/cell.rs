//! The L = 1 prior: one cell given its 8 neighbours ([`cell_prior`]), and the unconditioned
//! occupancy prior `p(m_k)` it falls back to.

use super::{probability, table, Candidate, PriorSource, LOG_ZERO};
use crate::sampler::patch::config_from;
use crate::types::fixed::LogOdds;

/// The prior of one cell (L = 1): `ln p(free)` and `ln p(occupied)` in [`LSB_NATS`] units, either
/// of which may be [`LOG_ZERO`] when the data never showed that value.
///
/// [`LSB_NATS`]: crate::types::fixed::LSB_NATS
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct CellPrior {
    /// `ln p(free)`.
    pub log_p_free: i16,
    /// `ln p(occupied)`.
    pub log_p_occupied: i16,
    /// Which table it came from.
    pub source: PriorSource,
}

impl CellPrior {
    /// Log-odds `ln(p_occ / p_free)`, saturating at `±i16::MAX` (a certain cell).
    pub fn log_odds(&self) -> LogOdds {
        match (self.log_p_free, self.log_p_occupied) {
            (LOG_ZERO, LOG_ZERO) => LogOdds::ZERO,
            (LOG_ZERO, _) => LogOdds(i16::MAX),
            (_, LOG_ZERO) => LogOdds(-i16::MAX),
            (f, o) => {
                let d = i32::from(o) - i32::from(f);
                LogOdds(d.clamp(-i32::from(i16::MAX), i32::from(i16::MAX)) as i16)
            }
        }
    }

    /// `Some(occupied)` if the prior is certain (the other value has probability zero).
    pub fn certain(&self) -> Option<bool> {
        match (self.log_p_free, self.log_p_occupied) {
            (LOG_ZERO, o) if o != LOG_ZERO => Some(true),
            (f, LOG_ZERO) if f != LOG_ZERO => Some(false),
            _ => None,
        }
    }

    /// The probability of the cell being occupied.
    pub fn p_occupied(&self) -> f64 {
        let o = probability(self.log_p_occupied);
        let f = probability(self.log_p_free);
        if o + f > 0.0 {
            o / (o + f)
        } else {
            0.5
        }
    }
}

/// The unconditioned prior of one cell, `p(m_k)`.
pub fn occupancy_prior() -> CellPrior {
    let [f, o] = table::OCC_LOG_PRIOR;
    CellPrior {
        log_p_free: f,
        log_p_occupied: o,
        source: PriorSource::Unconditioned,
    }
}

/// The L = 1 prior of a cell given its 8 neighbours ([`crate::sampler::patch::neighbours_of`] layout),
/// falling back to [`occupancy_prior`] (flagged [`PriorSource::Fallback`]) for neighbour bytes
/// never seen in training.
pub fn cell_prior(neighbours: u8) -> CellPrior {
    match table::L1_LOG_PRIOR.get(usize::from(neighbours)) {
        Some(&[f, o]) if f != LOG_ZERO || o != LOG_ZERO => CellPrior {
            log_p_free: f,
            log_p_occupied: o,
            source: PriorSource::Border,
        },
        _ => CellPrior {
            source: PriorSource::Fallback,
            ..occupancy_prior()
        },
    }
}

/// The L = 1 prior of the centre of `config` given its neighbours, as a [`Candidates`]-like
/// pair: `(config with centre free, ln p), (config with centre occupied, ln p)`.
///
/// [`Candidates`]: super::Candidates
pub fn cell_prior_configs(config: u16) -> [Candidate; 2] {
    let n = crate::sampler::patch::neighbours_of(config);
    let p = cell_prior(n);
    [
        Candidate {
            config: config_from(n, false),
            log_prior: p.log_p_free,
        },
        Candidate {
            config: config_from(n, true),
            log_prior: p.log_p_occupied,
        },
    ]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampler::patch::{centre_of, neighbours_of};

    #[test]
    fn cell_prior_fallback_and_certainty() {
        let mut seen = 0;
        for n in 0..=255u8 {
            let p = cell_prior(n);
            match p.source {
                PriorSource::Border => seen += 1,
                PriorSource::Fallback => {
                    assert_eq!(
                        (p.log_p_free, p.log_p_occupied),
                        (
                            occupancy_prior().log_p_free,
                            occupancy_prior().log_p_occupied
                        )
                    );
                }
                PriorSource::Unconditioned
                | PriorSource::Nearby
                | PriorSource::Despeckled
                | PriorSource::RingMajority => unreachable!(),
            }
            match p.certain() {
                Some(true) => assert_eq!(p.log_odds(), LogOdds(i16::MAX)),
                Some(false) => assert_eq!(p.log_odds(), LogOdds(-i16::MAX)),
                None => assert!(p.p_occupied() > 0.0 && p.p_occupied() < 1.0),
            }
            let [a, b] = cell_prior_configs(config_from(n, true));
            assert!(!centre_of(a.config) && centre_of(b.config));
            assert_eq!(neighbours_of(a.config), n);
        }
        assert!(seen > 0);
        // All-free and all-occupied neighbourhoods are in any building corpus.
        assert_eq!(cell_prior(0).source, PriorSource::Border);
        assert_eq!(cell_prior(0xFF).source, PriorSource::Border);
        let p = occupancy_prior().p_occupied();
        assert!(p > 0.0 && p < 0.5, "p(m_k) = {p}");
    }
}
