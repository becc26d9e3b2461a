//! Where the listener's map goes: files (PNG + map_server PGM/YAML and `status.json`, through
//! the writer `host-sim export` uses), the MCAP recording and the live view.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use anyhow::Context;

use super::{Listener, LOG_ODDS_STEM, MAP_STEM, STATUS_FILE};
use crate::export::export_world;
use crate::stream::{counts_of_one, stream_probabilities, BuildingRender, MapLayer};
use crate::world::load::{DEFAULT_FREE_THRESH, DEFAULT_OCCUPIED_THRESH};
use crate::world::{probabilities_to_world, World};

/// One map layer, owned, for the recording and the live view ([`Listener::map_layers`]).
struct LayerCells {
    /// The sampler's marginals (else the log-odds).
    marginals: bool,
    /// p(occupied), or `None` where nothing was observed; row-major, row 0 at the bottom.
    cells: Vec<Option<f64>>,
    width: usize,
    height: usize,
    cell_m: f64,
    origin_m: (f64, f64),
}

impl LayerCells {
    fn frame(&self) -> crate::recording::GridFrame<'_> {
        crate::recording::GridFrame {
            width: self.width,
            height: self.height,
            cell_m: self.cell_m,
            origin_m: self.origin_m,
            cells: &self.cells,
        }
    }
}

/// How often the live view gets the maps while tiles arrive.
pub const LIVE_PERIOD: Duration = Duration::from_millis(500);

impl Listener {
    /// Serves the live view on `addr` from now on (`crate::live`); the address it listens on.
    pub fn serve_live(&mut self, addr: &str) -> anyhow::Result<std::net::SocketAddr> {
        let server = crate::live::LiveServer::start(addr)?;
        let a = server.local_addr();
        self.live = Some(server);
        self.live_dirty = true;
        Ok(a)
    }

    /// The live view's server, if any.
    pub fn live(&self) -> Option<&crate::live::LiveServer> {
        self.live.as_ref()
    }

    /// Sends both maps to the live view if tiles arrived since it last got them, at most every
    /// [`LIVE_PERIOD`] (a map is a few hundred KiB of JSON; the viewer needs no more).
    pub fn live_tick(&mut self) {
        if self.live.is_none()
            || !self.live_dirty
            || self.live_sent.is_some_and(|t| t.elapsed() < LIVE_PERIOD)
        {
            return;
        }
        self.live_dirty = false;
        self.live_sent = Some(Instant::now());
        let t = crate::recording::now_ns();
        for layer in self.map_layers() {
            let channel = if layer.marginals {
                crate::recording::Channel::Marginals
            } else {
                crate::recording::Channel::LogOdds
            };
            if let Some(live) = self.live.as_ref() {
                live.publish(
                    channel,
                    t,
                    &crate::recording::grid_message(&layer.frame(), t),
                );
            }
        }
    }

    /// Records from now on into the MCAP file `path` (replaced), starting with the map as it
    /// stands (a resumed capture's).
    pub fn record_to(&mut self, path: &Path) -> anyhow::Result<()> {
        self.recording = Some(crate::recording::Recording::create(path)?);
        self.record_maps();
        Ok(())
    }

    /// Closes the recording (summary and index written); its path, if there was one.
    pub fn finish_recording(&mut self) -> anyhow::Result<Option<PathBuf>> {
        self.recording.take().map(|r| r.finish()).transpose()
    }

    /// Both layers into the recording, if any. A write error ends the recording with a warning
    /// (the maps on disk are unaffected).
    fn record_maps(&mut self) {
        if self.recording.is_none() {
            return;
        }
        let t = crate::recording::now_ns();
        for layer in self.map_layers() {
            if let Some(r) = self.recording.as_mut() {
                if let Err(e) = r.grid(layer.marginals, &layer.frame(), t) {
                    eprintln!("warning: {e:#}; recording stopped");
                    self.recording = None;
                }
            }
        }
    }

    /// Both layers as the recording and the live view send them.
    fn map_layers(&self) -> Vec<LayerCells> {
        let Some(render) = self.render() else {
            return Vec::new();
        };
        let map = &render.map;
        let (width, height) = (map.width, map.height);
        let known: Vec<bool> = (0..width * height)
            .map(|i| map.log_odds.get(i).is_some_and(|&l| l != 0))
            .collect();
        let (cell_m, origin_m) = self.geometry(&render);
        let mut out = Vec::new();
        for (marginals, layer) in [(true, MapLayer::Marginals), (false, MapLayer::LogOdds)] {
            let probs = self.probabilities_of(&render, layer);
            let cells: Vec<Option<f64>> = probs
                .iter()
                .zip(&known)
                .map(|(&p, &k)| k.then_some(p))
                .collect();
            out.push(LayerCells {
                marginals,
                cells,
                width,
                height,
                cell_m,
                origin_m,
            });
        }
        out
    }

    /// Probabilities of `layer` over [`Listener::map`] (none before the first `Hello` or tile).
    pub fn probabilities(&self, layer: MapLayer) -> Option<Vec<f64>> {
        Some(self.probabilities_of(&self.render()?, layer))
    }

    fn probabilities_of(&self, render: &BuildingRender, layer: MapLayer) -> Vec<f64> {
        let one = counts_of_one(
            self.stats.config.as_ref(),
            self.stats.hello.as_ref(),
            self.samples,
        );
        stream_probabilities(&render.map, &render.have_counts, one, layer)
    }

    /// Cell size (m) and the world position of the rendered map's cell (0, 0) (m): building
    /// cell (0, 0) is at the robot's `Configured` origin (else 5 cm at (0, 0)), moved by the
    /// tiles that arrived left of or below the robot's grid.
    fn geometry(&self, render: &BuildingRender) -> (f64, (f64, f64)) {
        let (cell_m, origin_m) = match &self.stats.config {
            Some(c) if c.cell_mm > 0 => (
                f64::from(c.cell_mm) / 1000.0,
                (
                    f64::from(c.origin_x_mm) / 1000.0,
                    f64::from(c.origin_y_mm) / 1000.0,
                ),
            ),
            _ => (0.05, (0.0, 0.0)),
        };
        (cell_m, render.origin_m(cell_m, origin_m))
    }

    /// The map of `layer` as a trinary world (export's thresholds); the whole building for a
    /// rolling window's stream; cell size and origin from the robot's `Configured`, else 5 cm
    /// at (0, 0).
    pub fn world(&self, layer: MapLayer) -> Option<World> {
        let render = self.render()?;
        let probs = self.probabilities_of(&render, layer);
        let (res, origin) = self.geometry(&render);
        Some(probabilities_to_world(
            &probs,
            render.map.width,
            render.map.height,
            res,
            origin,
            DEFAULT_OCCUPIED_THRESH,
            DEFAULT_FREE_THRESH,
        ))
    }

    /// Writes `map.*`, `log_odds.*` (when there is a map) and `status.json` into `dir`, each
    /// file first into `dir/.saving/` and then renamed into place (images before their YAML).
    /// Returns the files written.
    pub fn save(&mut self, dir: &Path) -> anyhow::Result<Vec<PathBuf>> {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("{}: cannot create directory", dir.display()))?;
        let tmp = dir.join(".saving");
        std::fs::create_dir_all(&tmp)
            .with_context(|| format!("{}: cannot create directory", tmp.display()))?;
        self.stats.saves += 1;
        let mut written = Vec::new();
        let mut rename = |name: &str| -> anyhow::Result<()> {
            let to = dir.join(name);
            std::fs::rename(tmp.join(name), &to)
                .with_context(|| format!("{}: cannot write", to.display()))?;
            written.push(to);
            Ok(())
        };
        for (stem, layer) in [
            (MAP_STEM, MapLayer::Marginals),
            (LOG_ODDS_STEM, MapLayer::LogOdds),
        ] {
            let Some(world) = self.world(layer) else {
                continue;
            };
            export_world(&tmp.join(format!("{stem}.yaml")), &world)?;
            for ext in ["pgm", "png", "yaml"] {
                rename(&format!("{stem}.{ext}"))?;
            }
        }
        self.record_maps();
        let json = serde_json::to_string_pretty(&self.stats)?;
        std::fs::write(tmp.join(STATUS_FILE), json + "\n")
            .with_context(|| format!("{}: cannot write", tmp.display()))?;
        rename(STATUS_FILE)?;
        let _ = std::fs::remove_dir(&tmp);
        self.dirty = false;
        Ok(written)
    }
}

#[cfg(test)]
mod tests {
    use super::super::stats::{Gap, Notice};
    use super::super::test_stream::{config, frame, hello, stream};
    use super::super::CAPTURE_FILE;
    use super::*;
    use ogm_core::wire::DeviceMsg;

    /// What `host-sim export --stream CAPTURE --out OUT` writes, with the command's defaults
    /// (the marginals layer, map_server's thresholds; the capture carries its `Configured`, so
    /// the fallback geometry is not used).
    fn export_stream(capture: &Path, out: &Path) {
        let world = crate::export::world_from_stream(
            capture,
            "marginals",
            DEFAULT_OCCUPIED_THRESH,
            DEFAULT_FREE_THRESH,
            || Ok((0.05, (0.0, 0.0))),
        )
        .unwrap();
        export_world(out, &world).unwrap();
    }

    #[test]
    fn saved_files_equal_export_of_the_capture_and_a_restart_resumes() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("listen");
        std::fs::create_dir_all(&out).unwrap();
        let capture = out.join(CAPTURE_FILE);
        let s = stream(&[0, 1, 2, 3, 4, 5]);
        // First listener: scans 0..=2 and 5 bytes of scan 3's report, then it is killed (no
        // save).
        let first = stream(&[0, 1, 2]);
        let k = first.len() + 5;
        {
            let mut a = Listener::with_capture(&capture, false).unwrap();
            for c in s[..k].chunks(64) {
                a.push(c);
            }
            assert_eq!(a.stats().scans_seen, 3);
        }
        // Scans 3 and 4 happen while nobody listens; the second listener gets scan 5 on.
        let hello_len = hello().len() + frame(&DeviceMsg::Configured(config())).len();
        let only5 = stream(&[5]);
        let mut b = Listener::with_capture(&capture, false).unwrap();
        assert_eq!(b.stats().restarts, 1);
        assert_eq!(b.stats().scans_seen, 3);
        let n = b.push(&only5[hello_len..]);
        assert!(n.contains(&Notice::Gap(Gap { first: 3, last: 4 })), "{n:?}");
        assert!(n.iter().any(|x| matches!(x, Notice::Resynced(_))), "{n:?}");
        assert_eq!(b.stats().scans_missed, 2);
        assert_eq!(b.stats().bad_frames, 1); // scan 3's cut report
        let files = b.save(&out).unwrap();
        assert_eq!(files.len(), 7, "{files:?}");
        assert!(!out.join(".saving").exists());
        // The same files as `host-sim export --stream` on the capture.
        let exp = dir.path().join("export");
        export_stream(&capture, &exp.join("map.yaml"));
        for f in ["map.pgm", "map.yaml", "map.png"] {
            assert_eq!(
                std::fs::read(out.join(f)).unwrap(),
                std::fs::read(exp.join(f)).unwrap(),
                "{f}"
            );
        }
        let yaml = std::fs::read_to_string(out.join("map.yaml")).unwrap();
        assert!(yaml.contains("image: map.pgm") && yaml.contains("origin: [-1.0, 0.5, 0.0]"));
        // status.json carries the counters; a third start counts restart 2.
        let st: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(out.join(STATUS_FILE)).unwrap()).unwrap();
        assert_eq!(st["scans_missed"], 2);
        assert_eq!(st["gaps"][0]["first"], 3);
        let c = Listener::with_capture(&capture, false).unwrap();
        assert_eq!(c.stats().restarts, 2);
        assert_eq!(c.map(), b.map());
        // --fresh starts over.
        let d = Listener::with_capture(&capture, true).unwrap();
        assert!(d.map().is_none());
        assert_eq!(std::fs::metadata(&capture).unwrap().len(), 0);
    }
}
