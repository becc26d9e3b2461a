//! The session's statistics as the wire reports them ([`ScanReport`], [`StoreReport`],
//! [`SamplerReport`]).

use crate::map::mapper::ScanStats;
use crate::sampler::gibbs::SamplerStats;
use crate::sampler::ray_store::StoreStats;
use crate::wire::{SamplerReport, ScanReport, StoreReport};

impl ScanReport {
    /// Copies the mapper's statistics in.
    pub fn set_scan_stats(&mut self, s: &ScanStats) {
        self.beams_used = s.beams_used;
        self.beams_dropped = s.beams_dropped;
        self.cells_hit = s.cells_hit;
        self.cells_freed = s.cells_freed;
    }
}

impl StoreReport {
    /// From the store's counters and fill.
    pub fn new(s: &StoreStats, decimation: u32, scans: usize, rays: usize) -> Self {
        StoreReport {
            scans_added: s.scans_added,
            rays_added: s.rays_added,
            rays_decimated: s.rays_decimated,
            rays_thinned: s.rays_thinned,
            rays_invalid: s.rays_invalid,
            thinnings: s.thinnings,
            decimation,
            scans: scans as u32,
            rays: rays as u32,
        }
    }
}

impl SamplerReport {
    /// From the sampler's counters.
    pub fn new(s: &SamplerStats, samples: u32, store: StoreReport) -> Self {
        SamplerReport {
            updates: s.updates,
            random_patches: s.random_patches,
            single_candidate: s.single_candidate,
            changed: s.changed,
            rays_evaluated: s.rays_evaluated,
            tile_visits: s.tile_visits,
            local_overflow: s.local_overflow,
            sweeps: s.sweeps,
            samples,
            store,
        }
    }
}
