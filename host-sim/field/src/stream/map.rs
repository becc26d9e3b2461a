//! The map a stream carries: [`StreamedMap`], every tile applied in order, and its cells as
//! probabilities ([`stream_probabilities`], what `listen` saves and `export --stream` writes).

use anyhow::anyhow;
use ogm_core::wire;

use super::{OwnedHello, OwnedTile};

/// The map as rebuilt from the stream's tiles.
#[derive(Clone, Debug, PartialEq)]
pub struct StreamedMap {
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Tile edge.
    pub edge: usize,
    /// Log-odds (raw `i16`), row-major.
    pub log_odds: Vec<i16>,
    /// Marginal counts.
    pub counts: Vec<u8>,
    /// Current sample.
    pub sample: Vec<bool>,
    /// Tiles applied.
    pub tiles: u64,
}

impl StreamedMap {
    /// An all-unknown map.
    pub fn new(width: usize, height: usize, edge: usize) -> Self {
        StreamedMap {
            width,
            height,
            edge: edge.max(1),
            log_odds: vec![0; width * height],
            counts: vec![0; width * height],
            sample: vec![false; width * height],
            tiles: 0,
        }
    }

    /// Applies a tile ([`wire::decode_tile`], the stream's one tile codec); returns the cells
    /// it covered. A tile outside the map or of the wrong size changes nothing.
    pub fn apply(&mut self, t: &OwnedTile) -> anyhow::Result<wire::TileRect> {
        let tile = wire::Tile {
            layer: t.layer,
            tx: t.tx,
            ty: t.ty,
            data: &t.data,
        };
        let rect = wire::decode_tile(&tile, self.width, self.height, self.edge, self)
            .map_err(|e| anyhow!("tile {:?} ({}, {}): {e}", t.layer, t.tx, t.ty))?;
        self.tiles += 1;
        Ok(rect)
    }
}

impl wire::TileSink for StreamedMap {
    fn set_log_odds(&mut self, index: usize, raw: i16) {
        if let Some(c) = self.log_odds.get_mut(index) {
            *c = raw;
        }
    }

    fn set_count(&mut self, index: usize, count: u8) {
        if let Some(c) = self.counts.get_mut(index) {
            *c = count;
        }
    }

    fn set_occupied(&mut self, index: usize, occupied: bool) {
        if let Some(c) = self.sample.get_mut(index) {
            *c = occupied;
        }
    }
}

/// Which map to render.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MapLayer {
    /// The sampler's marginals (cells whose marginal tile has not arrived take their log-odds
    /// probability).
    Marginals,
    /// The log-odds map.
    LogOdds,
    /// The sampler's estimates wherever their tile arrived, never-measured cells included (the
    /// prior's inference there: how `eval-log` scores its samplers); 0.5 where none arrived.
    Estimates,
}

/// Per-cell probabilities of a streamed map, as `host-sim export --stream` computes them:
/// log-odds 0 (never measured) is 0.5 (unknown) in the first two layers; with
/// [`MapLayer::Marginals`] a cell whose marginal tile arrived (`have_counts`) is `count /
/// counts_of_one` (capped at 1), any other its log-odds probability; [`MapLayer::Estimates`] is
/// that estimate in every cell whose tile arrived, measured or not, and 0.5 elsewhere.
pub fn stream_probabilities(
    map: &StreamedMap,
    have_counts: &[bool],
    counts_of_one: u32,
    layer: MapLayer,
) -> Vec<f64> {
    (0..map.width * map.height)
        .map(|i| {
            let estimate = || {
                let c = map.counts.get(i).copied().unwrap_or(0);
                (f64::from(c) / f64::from(counts_of_one.max(1))).min(1.0)
            };
            let have = have_counts.get(i) == Some(&true);
            let l = map.log_odds.get(i).copied().unwrap_or(0);
            match layer {
                MapLayer::Estimates if have => estimate(),
                MapLayer::Estimates => 0.5,
                _ if l == 0 => 0.5,
                MapLayer::Marginals if have => estimate(),
                _ => ogm_core::LogOdds(l).probability(),
            }
        })
        .collect()
}

/// The count that means p = 1: the last `Sampler` report's `samples` under the paper's
/// estimator (`Estimator::Counts`), else the robot's `count_max` (255 without a `Hello`).
pub fn counts_of_one(
    config: Option<&ogm_core::config::RunConfig>,
    hello: Option<&OwnedHello>,
    samples: u32,
) -> u32 {
    match config.map(|c| c.estimator) {
        Some(ogm_core::config::Estimator::Counts) => samples,
        _ => hello.map_or(255, |h| h.count_max),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Four cells: measured with an estimate, measured without, never measured with an
    /// estimate, never measured without.
    #[test]
    fn each_layer_reads_the_cells_it_says() {
        let mut m = StreamedMap::new(4, 1, 16);
        m.log_odds = vec![1024, -1024, 0, 0];
        m.counts = vec![255, 0, 51, 0];
        let have = [true, false, true, false];
        let p = |layer| stream_probabilities(&m, &have, 255, layer);
        let lo = |l: i16| ogm_core::LogOdds(l).probability();
        assert_eq!(p(MapLayer::LogOdds), vec![lo(1024), lo(-1024), 0.5, 0.5]);
        assert_eq!(p(MapLayer::Marginals), vec![1.0, lo(-1024), 0.5, 0.5]);
        assert_eq!(p(MapLayer::Estimates), vec![1.0, 0.5, 0.2, 0.5]);
    }
}
