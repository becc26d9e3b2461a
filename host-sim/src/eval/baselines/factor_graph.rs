//! The factor graph of dhiman-modern-map-inference-ogm §III-C with the pattern-based factors of
//! §VI, built from `ogm_core`'s ray store and evaluated with `ogm_core::reference::ReferenceModel`
//! — the f64 forward model of the reference Gibbs sampler — so every baseline works on exactly the
//! posterior the samplers sample.
//!
//! * **Variables** are the map's cells (row-major indices), labels 0 = free, 1 = occupied.
//! * **Factors** are rays: ray `n` of the store is traced (Bresenham, [`ogm_core::map::ray::Ray`]) from
//!   its pose's cell to the far end at maximum range, clipped to the map; its in-map cells, in ray
//!   order, are the factor's neighbourhood `n(f)`. Its value depends only on the first occupied
//!   cell (Eq. 28–31): `ψ_m` if the m-th cell is the first occupied one, `ψ_clear` if none is.
//!   `ln ψ_m` is `ReferenceModel::log_lik` with the distances of `ReferenceGibbs` (steps × step
//!   length), so the factor is exactly the reference sampler's `p(z_n | f_n)`.
//! * **Unary factors**: an optional constant cell prior `p(m_k = 1) = p` (Merali & Barfoot's
//!   user-defined constant; Dhiman et al. use none, the [`FactorGraph::new`] `prior = None`).
//!
//! The **energy** of a labelling is the negative log-posterior up to a constant,
//! `E(x) = −Σ_f ln ψ_f(x_f) − Σ_i ln p(x_i)`; [`Energy::nll`] is the first (data) term alone.

use anyhow::{anyhow, ensure};
use ogm_core::reference::ReferenceModel;
use ogm_core::sampler::ray_store::{RayStore, StoredRay, StoredScan, NONE};
use ogm_core::{GridGeometry, MapperConfig};
use serde::{Deserialize, Serialize};

use crate::sim::explore::ScanRecord;

/// A constant cell prior as unary energies.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct UnaryPrior {
    /// p(m_k = 1).
    pub p_occupied: f64,
}

impl UnaryPrior {
    /// `−ln p(x)` for label `x`.
    #[inline]
    pub fn energy(&self, occupied: bool) -> f64 {
        if occupied {
            -self.p_occupied.ln()
        } else {
            -(1.0 - self.p_occupied).ln()
        }
    }

    /// Prior log-odds `ln(p / (1 − p))`.
    #[inline]
    pub fn log_odds(&self) -> f64 {
        (self.p_occupied / (1.0 - self.p_occupied)).ln()
    }
}

/// One factor given explicitly (for tests and toy problems): its cells in ray order, `ln ψ_m`
/// per cell, and `ln ψ_clear`.
#[derive(Clone, Debug, PartialEq)]
pub struct FactorSpec {
    /// Cell indices in ray order (distinct).
    pub cells: Vec<u32>,
    /// `ln ψ_m`: log-likelihood if `cells[m]` is the first occupied cell.
    pub log_psi: Vec<f64>,
    /// `ln ψ_clear`: log-likelihood if no cell is occupied.
    pub log_psi_clear: f64,
}

/// Energy of a labelling.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Energy {
    /// `−Σ_f ln ψ_f(x_f)`: negative log-likelihood of the data.
    pub nll: f64,
    /// `−Σ_i ln p(x_i)` (0 without a prior).
    pub prior: f64,
}

impl Energy {
    /// The total, `nll + prior`.
    pub fn total(&self) -> f64 {
        self.nll + self.prior
    }
}

/// The occupancy grid factor graph (bipartite cells ↔ rays), in compressed sparse rows.
#[derive(Clone, Debug)]
pub struct FactorGraph {
    n_cells: usize,
    /// Factor f owns edges `factor_start[f] .. factor_start[f + 1]`.
    factor_start: Vec<u32>,
    /// `ln ψ_clear` per factor.
    factor_clear: Vec<f64>,
    /// Cell of each edge.
    edge_cell: Vec<u32>,
    /// `ln ψ_m` of each edge (m = the edge's position in its factor).
    edge_log_psi: Vec<f64>,
    /// Factor of each edge.
    edge_factor: Vec<u32>,
    /// Cell i's edges are `cell_edges[cell_start[i] .. cell_start[i + 1]]`.
    cell_start: Vec<u32>,
    cell_edges: Vec<u32>,
    /// Beam-end cells of the hits (deduplicated): the "heat map" of Dhiman §IV-A.
    heat: Vec<u32>,
    prior: Option<UnaryPrior>,
}

impl FactorGraph {
    /// A graph over `n_cells` cells from explicit factors; `heat` lists the heat-map cells.
    pub fn new(
        n_cells: usize,
        factors: &[FactorSpec],
        prior: Option<UnaryPrior>,
        heat: Vec<u32>,
    ) -> anyhow::Result<Self> {
        ensure!(n_cells < u32::MAX as usize, "too many cells");
        if let Some(p) = prior {
            ensure!(
                p.p_occupied > 0.0 && p.p_occupied < 1.0,
                "cell prior {} is not in (0, 1)",
                p.p_occupied
            );
        }
        let mut b = Builder::new(n_cells, prior);
        for f in factors {
            ensure!(
                f.cells.len() == f.log_psi.len(),
                "factor has {} cells but {} potentials",
                f.cells.len(),
                f.log_psi.len()
            );
            for (&c, &l) in f.cells.iter().zip(&f.log_psi) {
                ensure!((c as usize) < n_cells, "cell {c} out of range");
                b.edge(c, l);
            }
            b.close(f.log_psi_clear);
        }
        b.heat = heat;
        b.finish()
    }

    /// The graph of every ray in `store` (see the module documentation).
    pub fn from_store<S, R>(
        store: &RayStore<S, R>,
        model: ReferenceModel,
        prior: Option<UnaryPrior>,
    ) -> anyhow::Result<Self>
    where
        S: AsRef<[StoredScan]> + AsMut<[StoredScan]>,
        R: AsRef<[StoredRay]> + AsMut<[StoredRay]>,
    {
        let g = *store.geometry();
        let (w, h) = (g.width(), g.height());
        let mut b = Builder::new(g.len(), prior);
        for scan in store.scans() {
            let rays = store
                .rays()
                .get(scan.first as usize..(scan.first + scan.len) as usize)
                .unwrap_or(&[]);
            for r in rays {
                let geom = store.ray_geometry(&scan.pose, r.angle);
                let ray = geom.ray;
                let Some(steps) = ray.clip(w, h) else {
                    continue;
                };
                // The distances of ReferenceGibbs::log_likelihood: steps × step length (cells).
                let step = f64::from(geom.step_q12) / 4096.0;
                let n = ray.steps() as f64;
                let no_return = r.z_q4 == NONE;
                let z = f64::from(r.z_q4) / 16.0;
                ray.for_each_index(steps, w, |i, idx| {
                    let f = i as f64;
                    b.edge(
                        idx as u32,
                        model.log_lik(Some((z - f) * step), Some((n - f) * step), no_return),
                    );
                });
                b.close(model.log_lik(None, None, no_return));
                if !no_return {
                    // The cell at the measured range (rounded to a step).
                    let m = ((u64::from(r.z_q4) + 8) / 16).min(ray.steps());
                    if let Some(idx) = g.index(ray.cell_at(m)) {
                        b.heat.push(idx as u32);
                    }
                }
            }
        }
        b.finish()
    }

    /// The graph of a recorded dataset: its scans enter an `ogm_core` ray store (unbounded: every
    /// beam is kept) with the mapper's range limits, then [`FactorGraph::from_store`].
    pub fn from_scans(
        geometry: GridGeometry,
        mapper: &MapperConfig,
        scans: &[ScanRecord],
        model: ReferenceModel,
        prior: Option<UnaryPrior>,
    ) -> anyhow::Result<Self> {
        let total: usize = scans.iter().map(|s| s.beams.len()).sum();
        let mut store = RayStore::new(
            geometry,
            mapper.max_range_mm,
            mapper.min_range_mm,
            vec![StoredScan::default(); scans.len().max(1)],
            vec![StoredRay::default(); total.max(1)],
        )
        .map_err(|e| anyhow!("ray store: {e}"))?;
        for s in scans {
            store.add_scan(&s.pose, &s.beams);
        }
        ensure!(
            store.stats().thinnings == 0,
            "ray store thinned although sized for every beam"
        );
        Self::from_store(&store, model, prior)
    }

    /// Number of cells (variables).
    pub fn n_cells(&self) -> usize {
        self.n_cells
    }

    /// Number of factors (rays).
    pub fn n_factors(&self) -> usize {
        self.factor_clear.len()
    }

    /// Number of edges (cell, ray).
    pub fn n_edges(&self) -> usize {
        self.edge_cell.len()
    }

    /// The cell prior, if any.
    pub fn prior(&self) -> Option<UnaryPrior> {
        self.prior
    }

    /// Edge range of factor `f`.
    #[inline]
    pub fn factor_edges(&self, f: usize) -> std::ops::Range<usize> {
        self.factor_start[f] as usize..self.factor_start[f + 1] as usize
    }

    /// `ln ψ_clear` of factor `f`.
    #[inline]
    pub fn log_psi_clear(&self, f: usize) -> f64 {
        self.factor_clear[f]
    }

    /// Cell of edge `e`.
    #[inline]
    pub fn edge_cell(&self, e: usize) -> usize {
        self.edge_cell[e] as usize
    }

    /// `ln ψ_m` of edge `e`.
    #[inline]
    pub fn edge_log_psi(&self, e: usize) -> f64 {
        self.edge_log_psi[e]
    }

    /// Factor of edge `e`.
    #[inline]
    pub fn edge_factor(&self, e: usize) -> usize {
        self.edge_factor[e] as usize
    }

    /// Cells of all edges (edge order).
    pub fn edge_cells(&self) -> &[u32] {
        &self.edge_cell
    }

    /// `ln ψ_m` of all edges.
    pub fn edge_log_psis(&self) -> &[f64] {
        &self.edge_log_psi
    }

    /// The edges of cell `i`.
    #[inline]
    pub fn cell_edges(&self, i: usize) -> &[u32] {
        &self.cell_edges[self.cell_start[i] as usize..self.cell_start[i + 1] as usize]
    }

    /// Number of factors of cell `i`.
    #[inline]
    pub fn degree(&self, i: usize) -> usize {
        (self.cell_start[i + 1] - self.cell_start[i]) as usize
    }

    /// The heat-map cells (deduplicated beam-end cells of hits).
    pub fn heat(&self) -> &[u32] {
        &self.heat
    }

    /// Unary energy `−ln p(x_i)` (0 without a prior).
    #[inline]
    pub fn unary(&self, occupied: bool) -> f64 {
        self.prior.map_or(0.0, |p| p.energy(occupied))
    }

    /// Position (within factor `f`) of its first occupied cell under `labels`, or the factor's
    /// length if none is occupied.
    #[inline]
    pub fn first_occupied(&self, f: usize, labels: &[u8]) -> usize {
        let r = self.factor_edges(f);
        let len = r.len();
        self.edge_cell[r]
            .iter()
            .position(|&c| labels[c as usize] != 0)
            .unwrap_or(len)
    }

    /// `ln ψ_f` when the first occupied cell of factor `f` is at position `pos` (its length =
    /// none occupied).
    #[inline]
    pub fn log_psi_at(&self, f: usize, pos: usize) -> f64 {
        let r = self.factor_edges(f);
        if pos < r.len() {
            self.edge_log_psi[r.start + pos]
        } else {
            self.factor_clear[f]
        }
    }

    /// The energy of a labelling (`labels[i] != 0` = occupied).
    pub fn energy(&self, labels: &[u8]) -> Energy {
        assert_eq!(labels.len(), self.n_cells, "labels for every cell");
        let nll = -(0..self.n_factors())
            .map(|f| self.log_psi_at(f, self.first_occupied(f, labels)))
            .sum::<f64>();
        let prior = match self.prior {
            Some(p) => {
                let occ = labels.iter().filter(|&&l| l != 0).count() as f64;
                occ * p.energy(true) + (self.n_cells as f64 - occ) * p.energy(false)
            }
            None => 0.0,
        };
        Energy { nll, prior }
    }

    /// The energy of a probability map thresholded at 0.5: a cell is occupied iff `p > 0.5`
    /// (so never-observed cells at exactly 0.5 count as free; NaN counts as free).
    pub fn energy_of_probs(&self, probs: &[f64]) -> Energy {
        self.energy(&threshold_labels(probs))
    }
}

/// Labels of a probability map: occupied iff `p > 0.5`.
pub fn threshold_labels(probs: &[f64]) -> Vec<u8> {
    probs.iter().map(|&p| u8::from(p > 0.5)).collect()
}

/// Accumulates factors, then builds the cell → edge index.
struct Builder {
    n_cells: usize,
    factor_start: Vec<u32>,
    factor_clear: Vec<f64>,
    edge_cell: Vec<u32>,
    edge_log_psi: Vec<f64>,
    heat: Vec<u32>,
    prior: Option<UnaryPrior>,
}

impl Builder {
    fn new(n_cells: usize, prior: Option<UnaryPrior>) -> Self {
        Builder {
            n_cells,
            factor_start: vec![0],
            factor_clear: Vec::new(),
            edge_cell: Vec::new(),
            edge_log_psi: Vec::new(),
            heat: Vec::new(),
            prior,
        }
    }

    fn edge(&mut self, cell: u32, log_psi: f64) {
        self.edge_cell.push(cell);
        self.edge_log_psi.push(log_psi);
    }

    /// Ends the current factor (a factor with no in-map cell is dropped: it is a constant).
    fn close(&mut self, log_psi_clear: f64) {
        let start = *self.factor_start.last().unwrap_or(&0);
        if self.edge_cell.len() as u32 == start {
            return;
        }
        self.factor_start.push(self.edge_cell.len() as u32);
        self.factor_clear.push(log_psi_clear);
    }

    fn finish(mut self) -> anyhow::Result<FactorGraph> {
        ensure!(
            self.edge_cell.len() < u32::MAX as usize,
            "too many edges for u32 indices"
        );
        let n = self.n_cells;
        let mut edge_factor = vec![0u32; self.edge_cell.len()];
        for f in 0..self.factor_clear.len() {
            for e in self.factor_start[f]..self.factor_start[f + 1] {
                edge_factor[e as usize] = f as u32;
            }
        }
        let mut cell_start = vec![0u32; n + 1];
        for &c in &self.edge_cell {
            cell_start[c as usize + 1] += 1;
        }
        for i in 0..n {
            cell_start[i + 1] += cell_start[i];
        }
        let mut fill = cell_start.clone();
        let mut cell_edges = vec![0u32; self.edge_cell.len()];
        for (e, &c) in self.edge_cell.iter().enumerate() {
            cell_edges[fill[c as usize] as usize] = e as u32;
            fill[c as usize] += 1;
        }
        self.heat.sort_unstable();
        self.heat.dedup();
        Ok(FactorGraph {
            n_cells: n,
            factor_start: self.factor_start,
            factor_clear: self.factor_clear,
            edge_cell: self.edge_cell,
            edge_log_psi: self.edge_log_psi,
            edge_factor,
            cell_start,
            cell_edges,
            heat: self.heat,
            prior: self.prior,
        })
    }
}
