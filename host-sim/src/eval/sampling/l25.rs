//! The paper's Table I row "L = 25, data-driven prior" (Merali & Barfoot, Algorithm 1 / Eq. 1,
//! §III-A): a host-only Gibbs sampler over 5 × 5 patches with the *unconditioned* data-driven
//! prior p(a_k) of the committed L = 25 histogram ([`crate::eval::prior::L25::committed`]).
//!
//! `ogm_core::sampler::gibbs` keeps patch configurations in 16-bit words, so 5 × 5 (25-bit) patches do
//! not fit it; this module is the same algorithm in `std` code, built from ogm-core's public
//! pieces: the [`ogm_core::sampler::ray_store::RayStore`] and the fixed-point [`ForwardModel`], built by
//! `sampling::rays_and_model` as for the other samplers (Bresenham rays from the pose's
//! cell to the far end at maximum range, measured ranges as step indices, min-range and capacity
//! handling), and the store's `ray_geometry` ([`ogm_core::map::ray::Ray`] and the step length). What it does, per patch update (Algorithm 1):
//!
//! * **Patch**: a uniformly random 5 × 5 patch inside the map (centres two cells from the edge).
//! * **p_randPatch**: with probability [`SamplingConfig::p_rand_patch`] a uniformly random
//!   25-bit configuration is set instead of a draw.
//! * **Candidates**: the `K` = [`SamplingConfig::max_candidates`] most probable 5 × 5 windows of
//!   the prior (every window of an orbit under the 8 rotations/flips is its own entry, with the
//!   orbit's count), extended by the windows tied with the `K`-th so the set is invariant under
//!   the 8 transforms (`K` = 16 gives 18), plus the patch's current configuration when it is not
//!   among them. The paper names no `K` for L = 25; the existing variants' 16 is used. The
//!   current configuration keeps its histogram probability, or half a count if the corpus never
//!   showed it (below every seen window; the paper's prior would make it impossible).
//! * **Weights** (Eq. 1): `ln p(w)` plus Σ over the rays crossing the patch of
//!   `ln p(z_n | f_n(w))`, `f_n(w)` the ray's first occupied step given the patch takes `w`
//!   (the rest of the map as sampled). As in `ogm_core::sampler::gibbs`, a ray whose first occupied cell
//!   lies before the patch is the same for every candidate and skipped, and each ray's first
//!   occupied step in the current sample is cached and kept up to date.
//! * **Marginals**: after burn-in, every completed sweep (⌈K/25⌉ updates: one map sample) adds
//!   the sample to per-cell counts (`Estimator::Counts`, the paper's).
//!
//! The forward model evaluation is the same fixed-point arithmetic as `ogm_core::sampler::gibbs` (its
//! log-likelihood in LSB of [`ogm_core::types::fixed::LSB_NATS`]); the weights are then combined and
//! drawn in `f64`. Deterministic for a seed (`Xoshiro256PlusPlus`).

use std::collections::HashMap;
use std::sync::{Arc, OnceLock};

use anyhow::ensure;
use ogm_core::sampler::forward_model::ForwardModel;
use ogm_core::sampler::ray_store::NONE;
use ogm_core::types::fixed::LSB_NATS;
use ogm_core::wire::{SamplerReport, StoreReport};
use ogm_core::{GridGeometry, LogOdds, MapperConfig};
use rand::{RngExt, SeedableRng};
use rand_xoshiro::Xoshiro256PlusPlus;

use super::config::SamplingConfig;
use crate::eval::prior::L25;
use crate::sim::explore::ScanRecord;

/// Patch edge (cells).
pub const SIZE: i32 = 5;
/// Cells per patch (L).
pub const CELLS: u32 = 25;
/// The 25 bits of a patch configuration (the layout of [`ogm_core::sampler::patch`]: cell (row r,
/// column c) is bit 5r + c, row 0 at the bottom).
pub const MASK: u32 = (1 << CELLS) - 1;
const HALF: i32 = SIZE / 2;
/// "No occupied cell" in the first-occupied caches.
const NO_CELL: u32 = u32::MAX;

/// The unconditioned L = 25 prior: `ln p(window)` for every window the corpus showed, and the
/// candidate list.
#[derive(Clone, Debug)]
pub struct L25Prior {
    /// The top-K windows (ties with the K-th included), most probable first: (window, ln p).
    top: Vec<(u32, f64)>,
    /// ln p of every seen window.
    log_p: Arc<HashMap<u32, f64>>,
    /// ln p of a window the corpus never showed: half a count.
    floor: f64,
}

/// A histogram prepared for [`L25Prior`]: its windows by descending count (ties by window),
/// `ln p` of every window, and the total count.
struct Tables {
    by_count: Vec<(u32, u64)>,
    log_p: Arc<HashMap<u32, f64>>,
    total: u64,
}

/// The committed histogram's [`Tables`], built once per process.
fn committed_tables() -> &'static Tables {
    static T: OnceLock<Tables> = OnceLock::new();
    T.get_or_init(|| Tables::of(&L25::committed()))
}

impl Tables {
    fn of(h: &L25) -> Tables {
        let mut by_count: Vec<(u32, u64)> = h.windows().collect();
        by_count.sort_unstable_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
        Tables {
            by_count,
            log_p: Arc::new(h.log_probabilities()),
            total: h.total(),
        }
    }
}

impl L25Prior {
    /// The committed L = 25 histogram with the top `k` windows (at least 1) as candidates.
    pub fn committed(k: usize) -> L25Prior {
        let t = committed_tables();
        Self::build(&t.by_count, t.log_p.clone(), t.total, k)
    }

    /// A prior from any histogram (tests).
    pub fn from_histogram(h: &L25, k: usize) -> L25Prior {
        let t = Tables::of(h);
        Self::build(&t.by_count, t.log_p, t.total, k)
    }

    fn build(
        by_count: &[(u32, u64)],
        log_p: Arc<HashMap<u32, f64>>,
        total: u64,
        k: usize,
    ) -> L25Prior {
        let k = k.max(1).min(by_count.len());
        // Extend past the k-th window while counts tie: whole orbits, so no rotation of a
        // window is a candidate without the others.
        let last = by_count.get(k.wrapping_sub(1)).map_or(0, |w| w.1);
        let n = k + by_count.iter().skip(k).take_while(|w| w.1 == last).count();
        let top = by_count
            .iter()
            .take(n)
            .map(|&(w, _)| (w, log_p.get(&w).copied().unwrap_or(f64::NEG_INFINITY)))
            .collect();
        L25Prior {
            top,
            log_p,
            floor: (0.5 / total.max(1) as f64).ln(),
        }
    }

    /// The prior's own candidates (window, ln p), most probable first.
    pub fn top(&self) -> &[(u32, f64)] {
        &self.top
    }

    /// `ln p(window)`: the histogram's, or half a count for a window it never showed.
    pub fn log_prior(&self, window: u32) -> f64 {
        self.log_p
            .get(&(window & MASK))
            .copied()
            .unwrap_or(self.floor)
    }

    /// The candidates of a patch whose configuration is `current`: [`L25Prior::top`], then
    /// `current` (with [`L25Prior::log_prior`]) unless it is among them.
    pub fn candidates_into(&self, current: u32, out: &mut Vec<(u32, f64)>) {
        out.clear();
        out.extend_from_slice(&self.top);
        let current = current & MASK;
        if !self.top.iter().any(|&(w, _)| w == current) {
            out.push((current, self.log_prior(current)));
        }
    }
}

/// A stored ray as the sampler reads it.
#[derive(Clone, Copy, Debug)]
struct RayInfo {
    /// Measured range, 1/16 steps, or [`NONE`] (no return).
    z_q4: u16,
    /// Length of one step in cells, Q12.
    step_q12: u32,
    /// The far end's step (maximum range).
    n: u32,
    /// First in-map step.
    first_step: u32,
    /// Its in-map cells: `cells[off .. off + len]`, step `first_step + j` at `off + j`.
    off: u32,
    len: u32,
}

/// How one ray crosses the patch being updated.
#[derive(Clone, Copy, Debug, Default)]
struct Crossing {
    ray: u32,
    /// (step, patch bit), in ray order (at most 5: one per major coordinate).
    cells: [(u32, u32); SIZE as usize],
    n_cells: usize,
    /// The patch can change the ray's first occupied cell.
    affected: bool,
    /// First occupied step after the patch (unaffected by it), or [`NO_CELL`].
    f_after: u32,
}

impl Crossing {
    /// First step inside the patch occupied under `config`, else the first after it.
    #[inline]
    fn first_under(&self, config: u32) -> u32 {
        self.cells
            .iter()
            .take(self.n_cells)
            .find(|(_, bit)| config >> bit & 1 != 0)
            .map_or(self.f_after, |(s, _)| *s)
    }
}

/// The L = 25 Gibbs sampler on one dataset.
pub struct L25Sampler {
    geometry: GridGeometry,
    prior: L25Prior,
    forward: ForwardModel,
    rays: Vec<RayInfo>,
    /// In-map cell indices of every ray, in step order.
    ray_cells: Vec<u32>,
    /// Per cell, the (ray, step) visits: `visits[cell_start[i] .. cell_start[i + 1]]`.
    cell_start: Vec<u32>,
    visits: Vec<(u32, u32)>,
    /// Per ray, its first occupied step in the current sample, or [`NO_CELL`].
    first_occ: Vec<u32>,
    sample: Vec<u8>,
    counts: Vec<u32>,
    samples: u32,
    rng: Xoshiro256PlusPlus,
    p_rand: f64,
    burn_in: u32,
    sweep_len: u32,
    in_sweep: u32,
    stats: SamplerReport,
    store_stats: StoreReport,
    // Scratch, reused by every update.
    stamp: Vec<u32>,
    slot: Vec<u32>,
    epoch: u32,
    crossings: Vec<Crossing>,
    cands: Vec<(u32, f64)>,
    weights: Vec<f64>,
    lsb: Vec<i64>,
}

impl L25Sampler {
    /// Stores the dataset's rays (capacity as `cfg.bounds.rays` / `.scans`, unbounded by
    /// default), indexes them by cell and starts from `map` thresholded at
    /// `cfg.init_threshold`. `cfg.max_candidates` is K; the other bounds (local list, `u8`
    /// counts) belong to `ogm_core::sampler::gibbs` and do not apply.
    pub fn new(
        geometry: GridGeometry,
        mapper: &MapperConfig,
        scans: &[ScanRecord],
        map: &[LogOdds],
        cfg: &SamplingConfig,
        seed: u64,
    ) -> anyhow::Result<L25Sampler> {
        let (w, h) = (geometry.width(), geometry.height());
        ensure!(
            i32::from(w) >= SIZE && i32::from(h) >= SIZE,
            "L = 25 sampler: the map ({w} × {h}) is smaller than a 5 × 5 patch"
        );
        ensure!(
            map.len() == geometry.len(),
            "L = 25 sampler: map has {} cells, geometry {}",
            map.len(),
            geometry.len()
        );
        let (store, forward) = super::dataset::rays_and_model(geometry, mapper, scans, cfg)?;

        // Every ray's in-map cells, and per cell the rays visiting it.
        let mut rays = Vec::with_capacity(store.rays().len());
        let mut ray_cells: Vec<u32> = Vec::new();
        for scan in store.scans() {
            let Some(stored) = store
                .rays()
                .get(scan.first as usize..(scan.first + scan.len) as usize)
            else {
                continue;
            };
            for r in stored {
                let g = store.ray_geometry(&scan.pose, r.angle);
                let off = ray_cells.len() as u32;
                let first_step = match g.ray.clip(w, h) {
                    Some(steps) => {
                        g.ray
                            .for_each_index(steps, w, |_, idx| ray_cells.push(idx as u32));
                        steps.first as u32
                    }
                    None => 0,
                };
                rays.push(RayInfo {
                    z_q4: r.z_q4,
                    step_q12: g.step_q12,
                    n: g.ray.steps() as u32,
                    first_step,
                    off,
                    len: ray_cells.len() as u32 - off,
                });
            }
        }
        let mut cell_start = vec![0u32; geometry.len() + 1];
        for &c in &ray_cells {
            cell_start[c as usize + 1] += 1;
        }
        for i in 0..geometry.len() {
            cell_start[i + 1] += cell_start[i];
        }
        let mut fill = cell_start.clone();
        let mut visits = vec![(0u32, 0u32); ray_cells.len()];
        for (k, r) in rays.iter().enumerate() {
            let cells = &ray_cells[r.off as usize..(r.off + r.len) as usize];
            for (j, &c) in cells.iter().enumerate() {
                let at = &mut fill[c as usize];
                visits[*at as usize] = (k as u32, r.first_step + j as u32);
                *at += 1;
            }
        }
        let sample: Vec<u8> = map
            .iter()
            .map(|l| u8::from(*l > LogOdds(cfg.init_threshold)))
            .collect();
        let n_rays = rays.len();
        let mut s = L25Sampler {
            geometry,
            prior: L25Prior::committed(usize::from(cfg.max_candidates)),
            forward,
            rays,
            ray_cells,
            cell_start,
            visits,
            first_occ: vec![NO_CELL; n_rays],
            sample,
            counts: vec![0; geometry.len()],
            samples: 0,
            rng: Xoshiro256PlusPlus::seed_from_u64(seed),
            p_rand: f64::from(cfg.p_rand_patch).clamp(0.0, 1.0),
            burn_in: cfg.burn_in,
            sweep_len: (geometry.len() as u32).div_ceil(CELLS).max(1),
            in_sweep: 0,
            stats: SamplerReport::default(),
            store_stats: store.stats(),
            stamp: vec![0; n_rays],
            slot: vec![0; n_rays],
            epoch: 0,
            crossings: Vec::new(),
            cands: Vec::new(),
            weights: Vec::new(),
            lsb: Vec::new(),
        };
        for k in 0..n_rays {
            s.first_occ[k] = s.first_occupied_from(k, 0);
        }
        Ok(s)
    }

    /// Replaces the prior (tests, other K).
    pub fn with_prior(mut self, prior: L25Prior) -> Self {
        self.prior = prior;
        self
    }

    /// First occupied step of ray `k` at or after step `from`, or [`NO_CELL`].
    fn first_occupied_from(&self, k: usize, from: u32) -> u32 {
        let r = self.rays[k];
        let start = from.saturating_sub(r.first_step).min(r.len);
        let cells = &self.ray_cells[(r.off + start) as usize..(r.off + r.len) as usize];
        cells
            .iter()
            .position(|&c| self.sample[c as usize] != 0)
            .map_or(NO_CELL, |j| r.first_step + start + j as u32)
    }

    /// log p(z | f) of ray `k` (LSB): `ogm_core`'s fixed-point evaluation
    /// ([`ForwardModel::ray`]). Steps fit a `u16` (a ray never leaves the grid).
    fn log_lik(&self, k: usize, f: u32) -> i64 {
        let r = &self.rays[k];
        let as_step = |v: u32| u16::try_from(v).unwrap_or(NONE);
        let f = if f == NO_CELL { NONE } else { as_step(f) };
        let step = u16::try_from(r.step_q12).unwrap_or(u16::MAX);
        i64::from(self.forward.ray(r.z_q4, step, as_step(r.n), f))
    }

    /// The current configuration of the patch centred at (cx, cy) (inside the map).
    fn window(&self, cx: i32, cy: i32) -> u32 {
        let width = i32::from(self.geometry.width());
        let mut w = 0u32;
        for r in 0..SIZE {
            let row = ((cy - HALF + r) * width + cx - HALF) as usize;
            for c in 0..SIZE {
                if self.sample[row + c as usize] != 0 {
                    w |= 1 << (SIZE * r + c);
                }
            }
        }
        w
    }

    /// Collects the rays crossing the patch at (cx, cy) into `self.crossings`: their patch
    /// cells in ray order, whether the patch can change their first occupied cell, and the first
    /// occupied cell after the patch.
    fn gather(&mut self, cx: i32, cy: i32) {
        self.epoch = self.epoch.wrapping_add(1);
        if self.epoch == 0 {
            self.stamp.fill(0);
            self.epoch = 1;
        }
        self.crossings.clear();
        let width = i32::from(self.geometry.width());
        for r in 0..SIZE {
            for c in 0..SIZE {
                let idx = ((cy - HALF + r) * width + cx - HALF + c) as usize;
                let bit = (SIZE * r + c) as u32;
                let (a, b) = (self.cell_start[idx], self.cell_start[idx + 1]);
                for &(ray, step) in &self.visits[a as usize..b as usize] {
                    let k = ray as usize;
                    let j = if self.stamp[k] == self.epoch {
                        self.slot[k] as usize
                    } else {
                        self.stamp[k] = self.epoch;
                        self.slot[k] = self.crossings.len() as u32;
                        self.crossings.push(Crossing {
                            ray,
                            ..Crossing::default()
                        });
                        self.crossings.len() - 1
                    };
                    let x = &mut self.crossings[j];
                    if x.n_cells < x.cells.len() {
                        x.cells[x.n_cells] = (step, bit);
                        x.n_cells += 1;
                    }
                }
            }
        }
        for j in 0..self.crossings.len() {
            let mut x = self.crossings[j];
            x.cells[..x.n_cells].sort_unstable();
            let (first, last) = (x.cells[0].0, x.cells[x.n_cells - 1].0);
            let f = self.first_occ[x.ray as usize];
            // A Bresenham ray meets a box in consecutive steps: f in first..=last is a patch
            // cell, and only then is the rest of the ray walked.
            x.affected = f == NO_CELL || f >= first;
            x.f_after = if f == NO_CELL || f > last {
                f
            } else if f >= first {
                self.first_occupied_from(x.ray as usize, last + 1)
            } else {
                f
            };
            self.crossings[j] = x;
        }
    }

    /// Eq. 1 in the log domain for the candidates in `self.cands` into `self.weights` (nats).
    fn weigh(&mut self) {
        let mut lsb = std::mem::take(&mut self.lsb);
        lsb.clear();
        lsb.resize(self.cands.len(), 0);
        let mut evaluated = 0u64;
        for x in self.crossings.iter().filter(|x| x.affected) {
            evaluated += 1;
            let k = x.ray as usize;
            // The at most six first-occupied steps a candidate can give this ray.
            let mut ll = [0i64; SIZE as usize];
            for (l, (s, _)) in ll.iter_mut().zip(&x.cells).take(x.n_cells) {
                *l = self.log_lik(k, *s);
            }
            let after = self.log_lik(k, x.f_after);
            for (acc, &(config, _)) in lsb.iter_mut().zip(&self.cands) {
                let v = x
                    .cells
                    .iter()
                    .take(x.n_cells)
                    .position(|(_, bit)| config >> bit & 1 != 0)
                    .map_or(after, |j| ll[j]);
                *acc += v;
            }
        }
        self.stats.rays_evaluated += evaluated;
        self.weights.clear();
        self.weights.extend(
            self.cands
                .iter()
                .zip(&lsb)
                .map(|(&(_, lp), &l)| lp + l as f64 * LSB_NATS),
        );
        self.lsb = lsb;
    }

    /// Draws an index with probability ∝ exp(weights).
    fn draw(&mut self) -> usize {
        let best = self
            .weights
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        for w in &mut self.weights {
            *w = (*w - best).exp();
        }
        let total: f64 = self.weights.iter().sum();
        let mut u = self.rng.random::<f64>() * total;
        for (j, &q) in self.weights.iter().enumerate() {
            if u < q {
                return j;
            }
            u -= q;
        }
        // Rounding: the last candidate with any weight.
        self.weights.iter().rposition(|&q| q > 0.0).unwrap_or(0)
    }

    /// Writes `config` into the patch at (cx, cy) and updates the crossing rays' caches.
    fn apply(&mut self, cx: i32, cy: i32, config: u32) {
        for x in self.crossings.iter().filter(|x| x.affected) {
            self.first_occ[x.ray as usize] = x.first_under(config);
        }
        self.apply_cells(cx, cy, config);
    }

    /// Writes `config` into the patch at (cx, cy) of the sample (nothing else).
    fn apply_cells(&mut self, cx: i32, cy: i32, config: u32) {
        let width = i32::from(self.geometry.width());
        for r in 0..SIZE {
            let row = ((cy - HALF + r) * width + cx - HALF) as usize;
            for c in 0..SIZE {
                self.sample[row + c as usize] = u8::from(config >> (SIZE * r + c) & 1 != 0);
            }
        }
    }

    /// The candidates and their normalised conditional probabilities (Eq. 1) for the patch
    /// centred at (cx, cy), without changing anything but the scratch space and the counters.
    /// Diagnostic and test API.
    pub fn conditional(&mut self, cx: i32, cy: i32) -> Vec<(u32, f64)> {
        let current = self.window(cx, cy);
        self.gather(cx, cy);
        let mut cands = std::mem::take(&mut self.cands);
        self.prior.candidates_into(current, &mut cands);
        self.cands = cands;
        self.weigh();
        let best = self
            .weights
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        let q: Vec<f64> = self.weights.iter().map(|w| (w - best).exp()).collect();
        let total: f64 = q.iter().sum();
        self.cands
            .iter()
            .zip(q)
            .map(|(&(c, _), q)| (c, q / total))
            .collect()
    }

    /// One patch update (Algorithm 1's inner loop).
    fn update(&mut self) {
        self.stats.updates += 1;
        let (w, h) = (
            i32::from(self.geometry.width()),
            i32::from(self.geometry.height()),
        );
        let cx = self.rng.random_range(HALF..w - HALF);
        let cy = self.rng.random_range(HALF..h - HALF);
        let current = self.window(cx, cy);
        let new = if self.rng.random::<f64>() < self.p_rand {
            self.stats.random_patches += 1;
            self.gather(cx, cy);
            self.rng.random::<u32>() & MASK
        } else {
            self.gather(cx, cy);
            let mut cands = std::mem::take(&mut self.cands);
            self.prior.candidates_into(current, &mut cands);
            self.cands = cands;
            self.weigh();
            let j = self.draw();
            self.cands.get(j).map_or(current, |c| c.0)
        };
        if new != current {
            self.stats.changed += 1;
            self.apply(cx, cy, new);
        }
    }

    /// Runs `n` sweeps (⌈K/25⌉ patch updates each); after burn-in every completed sweep is
    /// counted into the marginals.
    pub fn sweeps(&mut self, n: u32) {
        for _ in 0..n {
            for _ in self.in_sweep..self.sweep_len {
                self.update();
            }
            self.in_sweep = 0;
            self.stats.sweeps = self.stats.sweeps.saturating_add(1);
            if self.stats.sweeps > self.burn_in {
                for (c, &s) in self.counts.iter_mut().zip(&self.sample) {
                    *c += u32::from(s);
                }
                self.samples += 1;
            }
        }
    }

    /// Marginal p(occupied) per cell (0.5 before the first counted sweep).
    pub fn marginals(&self) -> Vec<f64> {
        if self.samples == 0 {
            return vec![0.5; self.counts.len()];
        }
        let n = f64::from(self.samples);
        self.counts.iter().map(|&c| f64::from(c) / n).collect()
    }

    /// The current sample (0/1 per cell).
    pub fn sample(&self) -> &[u8] {
        &self.sample
    }

    /// Counters (`single_candidate`, `tile_visits` and `local_overflow` are
    /// `ogm_core::sampler::gibbs`'s and stay 0, as do `samples` and `store`).
    pub fn stats(&self) -> SamplerReport {
        self.stats
    }

    /// The ray store's counters.
    pub fn store_stats(&self) -> StoreReport {
        self.store_stats
    }

    /// The prior in use.
    pub fn prior(&self) -> &L25Prior {
        &self.prior
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::eval::sampling::{run_sampler, Variant};
    use ogm_core::sampler::patch::Dihedral;
    use ogm_core::{Angle, Beam, Pose, Range};

    const CELL: u32 = 100;
    const W: u16 = 40;
    const H: u16 = 30;
    /// The wall: column 30 (its face at x = 3000 mm).
    const WALL_X: i32 = 30;

    /// Noise-free scans from three poses left of a vertical wall at column [`WALL_X`] (beams
    /// within ±60° of +x that reach it hit its face, the others see nothing).
    /// A 4 m × 3 m room at 10 cm with one wall, seen from four poses (shared with the
    /// `sampling` tests).
    pub(crate) fn wall_dataset() -> (GridGeometry, MapperConfig, Vec<ScanRecord>, Vec<LogOdds>) {
        let g = GridGeometry::new(W, H, CELL, 0, 0).unwrap();
        let mapper = MapperConfig::new(25 * CELL);
        let face = f64::from(WALL_X as u32 * CELL);
        let mut scans = Vec::new();
        for (x, y) in [(12, 15), (14, 9), (14, 21), (18, 15)] {
            let pose = Pose::new(x * CELL as i32 + 50, y * CELL as i32 + 50, Angle::ZERO);
            let beams = (0..360)
                .map(|i| {
                    let deg = f64::from(i) - 180.0;
                    let a = deg.to_radians();
                    let range = if deg.abs() < 60.0 {
                        let d = (face - f64::from(pose.x_mm)) / a.cos();
                        let hit_y = f64::from(pose.y_mm) + d * a.sin();
                        if d < f64::from(mapper.max_range_mm)
                            && (0.0..f64::from(u32::from(H) * CELL)).contains(&hit_y)
                        {
                            Range::Hit(d.round() as u32)
                        } else {
                            Range::NoReturn
                        }
                    } else {
                        Range::NoReturn
                    };
                    Beam {
                        angle: Angle::from_radians(a),
                        range,
                    }
                })
                .collect();
            scans.push(ScanRecord { pose, beams });
        }
        let mut m = crate::sim::new_mapper(g, mapper).unwrap();
        for s in &scans {
            m.insert_scan(&s.pose, &s.beams).unwrap();
        }
        let map = m.grid().cells().to_vec();
        (g, mapper, scans, map)
    }

    fn cfg() -> SamplingConfig {
        SamplingConfig {
            burn_in: 10,
            sweeps: 60,
            ..SamplingConfig::default()
        }
    }

    #[test]
    fn candidates_are_symmetric_and_include_the_current_configuration() {
        let p = L25Prior::committed(16);
        let top: Vec<u32> = p.top().iter().map(|c| c.0).collect();
        // Most probable first: all free, then all occupied.
        assert_eq!(top[0], 0);
        assert_eq!(top[1], MASK);
        assert!(top.len() >= 16, "{}", top.len());
        // Invariant under the 8 rotations/flips.
        for &w in &top {
            for t in Dihedral::ALL {
                assert!(top.contains(&t.window(w)), "{w:#x} under {t:?}");
            }
        }
        let mut out = Vec::new();
        // A window the corpus never showed: added, below every seen window.
        let checker = 0x155_5555 & MASK;
        p.candidates_into(checker, &mut out);
        assert_eq!(out.len(), top.len() + 1);
        let last = *out.last().unwrap();
        assert_eq!(last.0, checker);
        assert!(out.iter().take(top.len()).all(|c| c.1 > last.1));
        // A top window: not duplicated.
        p.candidates_into(MASK, &mut out);
        assert_eq!(out.len(), top.len());
        assert_eq!(out.iter().filter(|c| c.0 == MASK).count(), 1);
        // A seen window outside the top: its histogram probability.
        let corner = 0x18c_0000;
        p.candidates_into(corner, &mut out);
        assert_eq!(out.last().unwrap().0, corner);
        let lp = out.last().unwrap().1;
        assert!(lp < p.top().last().unwrap().1 && lp > p.log_prior(checker));
    }

    #[test]
    fn conditional_offers_the_current_configuration() {
        let (g, mapper, scans, map) = wall_dataset();
        let mut s = L25Sampler::new(g, &mapper, &scans, &map, &cfg(), 1).unwrap();
        for (cx, cy) in [(5, 5), (20, 15), (30, 15), (35, 20)] {
            let current = s.window(cx, cy);
            let c = s.conditional(cx, cy);
            assert!(c.iter().any(|x| x.0 == current), "({cx}, {cy})");
            let total: f64 = c.iter().map(|x| x.1).sum();
            assert!((total - 1.0).abs() < 1e-9);
        }
        // In the open, seen by many rays: all free dominates.
        let c = s.conditional(22, 15);
        let free = c.iter().find(|x| x.0 == 0).unwrap().1;
        assert!(free > 0.9, "{c:?}");
    }

    #[test]
    fn conditional_matches_brute_force_and_caches_stay_exact() {
        let (g, mapper, scans, map) = wall_dataset();
        let mut s = L25Sampler::new(g, &mapper, &scans, &map, &cfg(), 3).unwrap();
        s.sweeps(15);
        // Every ray's cached first occupied step is the sample's.
        for k in 0..s.rays.len() {
            assert_eq!(s.first_occ[k], s.first_occupied_from(k, 0), "ray {k}");
        }
        // Eq. 1 from scratch: set the patch to each candidate, walk every ray of the dataset.
        for (cx, cy) in [(29, 15), (31, 12), (22, 18), (16, 9), (2, 27)] {
            let current = s.window(cx, cy);
            let fast = s.conditional(cx, cy);
            let mut slow: Vec<f64> = fast
                .iter()
                .map(|&(w, _)| {
                    s.apply_cells(cx, cy, w);
                    let ll: i64 = (0..s.rays.len())
                        .map(|k| s.log_lik(k, s.first_occupied_from(k, 0)))
                        .sum();
                    s.prior.log_prior(w) + ll as f64 * LSB_NATS
                })
                .collect();
            s.apply_cells(cx, cy, current);
            let best = slow.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let total: f64 = slow.iter().map(|w| (w - best).exp()).sum();
            for w in &mut slow {
                *w = (*w - best).exp() / total;
            }
            for ((w, p), q) in fast.iter().zip(&slow) {
                assert!((p - q).abs() < 1e-9, "({cx}, {cy}) {w:#x}: {p} vs {q}");
            }
        }
    }

    #[test]
    fn l25_sampler_finds_the_wall_and_is_deterministic() {
        let (g, mapper, scans, map) = wall_dataset();
        let run = |map: &[LogOdds], init_threshold: i16, seed| {
            let cfg = SamplingConfig {
                init_threshold,
                ..cfg()
            };
            run_sampler(g, &mapper, &scans, map, Variant::L25, &cfg, seed).unwrap()
        };
        let a = run(&map, -1, 7);
        let b = run(&map, -1, 7);
        assert_eq!(a.marginals, b.marginals, "same seed, same marginals");
        assert_eq!(a.stats, b.stats);
        assert_eq!(a.stats.sweeps, 70);
        assert_eq!(
            a.stats.updates,
            70 * u64::from((u32::from(W) * u32::from(H)).div_ceil(25))
        );
        assert!(a.stats.rays_evaluated > 0 && a.stats.changed > 0);
        let c = run(&map, -1, 8);
        assert_ne!(a.marginals, c.marginals, "another seed, another chain");
        // From the mapper's map, and from no map at all: everything occupied (the default
        // threshold takes unobserved cells as occupied) and everything free, so that the rays
        // must carve the free space, or raise the wall, themselves.
        let blank = vec![LogOdds::ZERO; g.len()];
        for (name, o) in [
            ("mapped", a),
            ("all occupied", run(&blank, -1, 7)),
            ("all free", run(&blank, i16::MAX, 7)),
        ] {
            let p = |x: i32, y: i32| o.marginals[(y * i32::from(W) + x) as usize];
            // The wall face where the rays hit it, and the free space in front of it.
            for y in 8..=22 {
                assert!(
                    p(WALL_X, y) > 0.5,
                    "{name}: wall ({WALL_X}, {y}): {}",
                    p(WALL_X, y)
                );
                for x in 20..=27 {
                    assert!(p(x, y) < 0.5, "{name}: free ({x}, {y}): {}", p(x, y));
                }
            }
        }
    }
}
