//! An f64 reference of the Gibbs sampler's conditional (Eq. 1), written for obviousness, not
//! speed: every update looks at *every* stored ray, recomputes first occupied cells from scratch
//! for each candidate, evaluates the sensor model with `libm` in f64 and draws with f64 weights.
//! It shares only the discrete model with [`crate::sampler::gibbs::Gibbs`]: the ray store's Bresenham
//! rays, the patch bit layout, and the [`PatchPrior`]. Tests compare the two samplers' marginals.

use rand_core::{Rng, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

use crate::error::{Error, Result};
use crate::sampler::gibbs::{PatchCandidate, PatchPrior, MAX_CANDIDATES};
use crate::sampler::ray_store::{RayStore, StoredRay, StoredScan, NONE};
use crate::types::fixed::{LogOdds, LSB_NATS};
use crate::types::geometry::{CellCoord, GridGeometry};

/// The forward model in f64.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ReferenceModel {
    /// N(f, σ²) mixed with w/F (cells).
    Gaussian {
        /// σ in cells.
        sigma: f64,
        /// Outlier weight w.
        w: f64,
        /// Max range F in cells.
        max_range: f64,
    },
    /// Dhiman's piecewise-constant model.
    Pcsm,
}

impl ReferenceModel {
    /// log p(z | f) with distances in cells; `f = None` means no occupied cell within range.
    /// `z = None` is a no-return reading and `range_minus_f` is F − f in cells.
    pub fn log_lik(
        &self,
        z_minus_f: Option<f64>,
        range_minus_f: Option<f64>,
        no_return: bool,
    ) -> f64 {
        match *self {
            ReferenceModel::Gaussian {
                sigma,
                w,
                max_range,
            } => {
                let u = w / max_range;
                if no_return {
                    match range_minus_f {
                        None => libm::log(1.0 - w + u),
                        Some(d) => {
                            let tail =
                                0.5 * libm::erfc(d.max(0.0) / sigma / core::f64::consts::SQRT_2);
                            libm::log((1.0 - w) * tail + u)
                        }
                    }
                } else {
                    match z_minus_f {
                        None => libm::log(u),
                        Some(d) => {
                            let g = libm::exp(-d * d / (2.0 * sigma * sigma))
                                / (sigma * libm::sqrt(2.0 * core::f64::consts::PI));
                            libm::log((1.0 - w) * g + u)
                        }
                    }
                }
            }
            ReferenceModel::Pcsm => match (no_return, z_minus_f, range_minus_f) {
                (true, _, None) => 0.0,
                (true, _, Some(_)) => -1000.0,
                (false, None, _) => -900.0,
                (false, Some(d), _) if d.abs() <= 0.5 => 0.0,
                (false, Some(d), _) if d > 0.0 => -1000.0,
                (false, Some(_), _) => -900.0,
            },
        }
    }
}

/// The f64 reference sampler over caller buffers: `sample` (K cells, 0/1) and `counts` (K).
pub struct ReferenceGibbs<'a, P> {
    geometry: GridGeometry,
    prior: P,
    model: ReferenceModel,
    p_rand: f64,
    sample: &'a mut [u8],
    counts: &'a mut [u64],
    samples: u64,
    rng: Xoshiro256PlusPlus,
}

impl<'a, P: PatchPrior> ReferenceGibbs<'a, P> {
    /// A reference sampler starting from the thresholded `map` (occupied iff l > `threshold`).
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        geometry: GridGeometry,
        prior: P,
        model: ReferenceModel,
        p_rand: f64,
        map: &[LogOdds],
        threshold: LogOdds,
        sample: &'a mut [u8],
        counts: &'a mut [u64],
        seed: u64,
    ) -> Result<Self> {
        let k = geometry.len();
        if map.len() != k || sample.len() != k || counts.len() != k {
            return Err(Error::BufferSize {
                expected: k,
                actual: map.len().min(sample.len()).min(counts.len()),
            });
        }
        for (s, l) in sample.iter_mut().zip(map) {
            *s = u8::from(*l > threshold);
        }
        counts.fill(0);
        Ok(ReferenceGibbs {
            geometry,
            prior,
            model,
            p_rand,
            sample,
            counts,
            samples: 0,
            rng: Xoshiro256PlusPlus::seed_from_u64(seed),
        })
    }

    fn uniform(&mut self) -> f64 {
        (self.rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    fn occ(&self, c: CellCoord) -> bool {
        self.geometry
            .index(c)
            .and_then(|i| self.sample.get(i))
            .is_some_and(|&v| v != 0)
    }

    /// One sweep: K/L updates at uniformly random patch centres; then accumulates marginals if
    /// `count` is set.
    pub fn sweep<S, R>(&mut self, store: &RayStore<S, R>, count: bool)
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let size = i32::from(self.prior.size());
        let h = size / 2;
        let m = i32::from(self.prior.margin()).max(h);
        let (w, hh) = (
            i32::from(self.geometry.width()),
            i32::from(self.geometry.height()),
        );
        let updates = self.geometry.len().div_ceil((size * size) as usize);
        for _ in 0..updates {
            let cx = m + (self.uniform() * f64::from(w - 2 * m)) as i32;
            let cy = m + (self.uniform() * f64::from(hh - 2 * m)) as i32;
            let centre = CellCoord {
                x: cx.min(w - 1 - m),
                y: cy.min(hh - 1 - m),
            };
            let config = if self.uniform() < self.p_rand {
                (self.rng.next_u32() & ((1 << (size * size)) - 1)) as u16
            } else {
                self.draw(store, centre)
            };
            self.write(centre, config);
        }
        if count {
            for (c, s) in self.counts.iter_mut().zip(self.sample.iter()) {
                *c += u64::from(*s);
            }
            self.samples += 1;
        }
    }

    fn border(&self, centre: CellCoord) -> u16 {
        let size = self.prior.size();
        let r = if size == 3 { 2 } else { 1 };
        if size == 1 && self.prior.margin() == 0 {
            return 0;
        }
        let side = 2 * r + 1;
        let mut win = 0u32;
        for dy in 0..side {
            for dx in 0..side {
                if self.occ(CellCoord {
                    x: centre.x - r + dx,
                    y: centre.y - r + dy,
                }) {
                    win |= 1 << (dy * side + dx);
                }
            }
        }
        if size == 3 {
            crate::sampler::patch::border_of(win)
        } else {
            u16::from(crate::sampler::patch::neighbours_of(win as u16))
        }
    }

    fn write(&mut self, centre: CellCoord, config: u16) {
        let size = i32::from(self.prior.size());
        let h = size / 2;
        for py in 0..size {
            for px in 0..size {
                let c = CellCoord {
                    x: centre.x - h + px,
                    y: centre.y - h + py,
                };
                if let Some(i) = self.geometry.index(c) {
                    if let Some(s) = self.sample.get_mut(i) {
                        *s = u8::from(config & (1 << (py * size + px)) != 0);
                    }
                }
            }
        }
    }

    /// The normalised conditional of Eq. 1 at `centre`: fills `out` with (config, probability).
    pub fn conditional<S, R>(
        &mut self,
        store: &RayStore<S, R>,
        centre: CellCoord,
        out: &mut [(u16, f64)],
    ) -> usize
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let mut cands = [PatchCandidate::default(); MAX_CANDIDATES];
        let n = self
            .prior
            .candidates(self.border(centre), &mut cands)
            .min(out.len());
        let saved = self.current(centre);
        let mut logw = [0f64; MAX_CANDIDATES];
        for (lw, c) in logw.iter_mut().zip(cands.iter()).take(n) {
            self.write(centre, c.config);
            *lw = f64::from(c.log_prior) * LSB_NATS + self.log_likelihood(store, centre);
        }
        self.write(centre, saved);
        let best = logw
            .iter()
            .take(n)
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        let total: f64 = logw.iter().take(n).map(|l| libm::exp(l - best)).sum();
        for ((o, c), lw) in out.iter_mut().zip(cands.iter()).zip(logw.iter()).take(n) {
            *o = (c.config, libm::exp(lw - best) / total);
        }
        n
    }

    fn current(&self, centre: CellCoord) -> u16 {
        let size = i32::from(self.prior.size());
        let h = size / 2;
        let mut c = 0u16;
        for py in 0..size {
            for px in 0..size {
                if self.occ(CellCoord {
                    x: centre.x - h + px,
                    y: centre.y - h + py,
                }) {
                    c |= 1 << (py * size + px);
                }
            }
        }
        c
    }

    fn draw<S, R>(&mut self, store: &RayStore<S, R>, centre: CellCoord) -> u16
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let mut probs = [(0u16, 0f64); MAX_CANDIDATES];
        let n = self.conditional(store, centre, &mut probs);
        let mut u = self.uniform();
        for (c, p) in probs.iter().take(n) {
            if u < *p {
                return *c;
            }
            u -= p;
        }
        probs.first().map_or(0, |p| p.0)
    }

    /// Σ over rays crossing the patch of log p(z | f), from scratch.
    fn log_likelihood<S, R>(&self, store: &RayStore<S, R>, centre: CellCoord) -> f64
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let h = i32::from(self.prior.size()) / 2;
        let g = &self.geometry;
        let mut sum = 0.0;
        for scan in store.scans() {
            for k in 0..scan.len as usize {
                let Some(r) = store.rays().get(scan.first as usize + k) else {
                    continue;
                };
                let geom = store.ray_geometry(&scan.pose, r.angle);
                let ray = geom.ray;
                let crosses = (0..=ray.steps()).any(|i| {
                    let c = ray.cell_at(i);
                    (c.x - centre.x).abs() <= h && (c.y - centre.y).abs() <= h
                });
                if !crosses {
                    continue;
                }
                let step = f64::from(geom.step_q12) / 4096.0;
                let f = (0..=ray.steps())
                    .find(|&i| g.index(ray.cell_at(i)).is_some() && self.occ(ray.cell_at(i)));
                let n = ray.steps() as f64;
                let no_return = r.z_q4 == NONE;
                let z = f64::from(r.z_q4) / 16.0;
                let f = f.map(|f| f as f64);
                sum += self.model.log_lik(
                    f.map(|f| (z - f) * step),
                    f.map(|f| (n - f) * step),
                    no_return,
                );
            }
        }
        sum
    }

    /// Marginal of cell `index` over the accumulated sweeps.
    pub fn marginal(&self, index: usize) -> Option<f64> {
        (self.samples > 0)
            .then(|| {
                self.counts
                    .get(index)
                    .map(|&c| c as f64 / self.samples as f64)
            })
            .flatten()
    }
}
