//! The mapper's statistics as the wire reports them ([`ScanReport`]). The sampler's and the ray
//! store's counters are the wire's types already ([`crate::wire::SamplerReport`],
//! [`crate::wire::StoreReport`]).

use crate::map::mapper::ScanStats;
use crate::wire::ScanReport;

impl ScanReport {
    /// Copies the mapper's statistics in.
    pub fn set_scan_stats(&mut self, s: &ScanStats) {
        self.beams_used = s.beams_used;
        self.beams_dropped = s.beams_dropped;
        self.cells_hit = s.cells_hit;
        self.cells_freed = s.cells_freed;
    }
}
