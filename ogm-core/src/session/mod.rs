//! One mapping engine: the online log-odds mapper, the ray store and the patch Gibbs sampler,
//! built together from one [`RunConfig`] over caller memory, driven by three calls.
//!
//! ```
//! # #[cfg(feature = "alloc")] {
//! use ogm_core::session::{Owned, Session, Sizes};
//! use ogm_core::config::{Budget, RunConfig};
//! use ogm_core::{Angle, Beam, Pose, Range};
//!
//! let config = RunConfig::ROBOT
//!     .with_origin_mm(-3200, -3200)
//!     .with_max_range_mm(6000)
//!     .with_budget(Budget::Fixed { updates: 500 });
//! let mut session = Session::new(config, Owned::<u8>::buffers(&Sizes::grid(128, 128))).unwrap();
//! // A robot at the origin in a round room of radius 2 m: 360 hits.
//! let beams: Vec<Beam> = (0..360)
//!     .map(|d| Beam { angle: Angle::from_centidegrees(100 * d), range: Range::Hit(2000) })
//!     .collect();
//! let inserted = session.insert(&Pose::default(), &beams).unwrap();
//! assert!(inserted.stats.cells_hit > 0);
//! let (lo, hi) = inserted.changed_box(); // the cells it may have changed
//! assert!(lo.x <= 64 && 64 <= hi.x);
//! session.step(500); // between scans: improve the map
//! assert!(session.marginal(64 * 128 + 64).is_some()); // the cell under the robot
//! # }
//! ```
//!
//! [`Session::insert`] updates the log-odds map, seeds newly observed cells in the sampler's
//! sample and stores the scan's rays when the data term reads rays, and says what it did
//! ([`Inserted`]: the mapper's statistics, the rays stored, the box of cells it changed);
//! [`Session::step`] runs a bounded number of patch updates; the maps are read per cell or as
//! wire tiles ([`crate::wire::TileSource`]). What the memory is — `&'static mut` arrays on the
//! firmware, `Vec`s on the host ([`Owned`], feature `alloc`) — is one [`Storage`] type.

mod insert;
mod restore;
mod settings;
mod track;
mod window;

pub use insert::Inserted;
pub use restore::{RestoreError, RestoreStep, TileRestore, MAX_RESTORE_CELLS};
#[cfg(feature = "alloc")]
pub use track::OwnedMarks;
pub use track::{correction_report, MarkWords, TRACK_POINTS};
pub use window::{LeavingTile, Shift};

use crate::config::RunConfig;
use crate::localize::{Correction, TrackState};
use crate::sampler::gibbs::{self, BorderPrior, Count, Gibbs, LocalRay};
use crate::sampler::ray_store::{RayStore, StoredRay, StoredScan};
use crate::wire::SamplerReport;
use crate::{Beam, GridGeometry, LogOdds, LogOddsGrid, Mapper, Pose};

/// The memory of a [`Session`]: one type naming every buffer's type (each a slice-like owner:
/// `&'static mut [T; N]`, `&mut [T]`, `Vec<T>`, ...).
pub trait Storage {
    /// The marginal counter (`u8` on the firmware).
    type Count: Count;
    /// Log-odds cells.
    type Grid: AsRef<[LogOdds]> + AsMut<[LogOdds]>;
    /// The mapper's per-scan marks ([`crate::map::mapper::marks_len`] words), which also lend
    /// the scan matcher its points ([`MarkWords`]).
    type Marks: MarkWords;
    /// The ray store's scans.
    type Scans: AsRef<[StoredScan]> + AsMut<[StoredScan]>;
    /// The ray store's rays.
    type Rays: AsRef<[StoredRay]> + AsMut<[StoredRay]>;
    /// The sampler's current sample, one bit per cell.
    type Sample: AsRef<[u32]> + AsMut<[u32]>;
    /// The sampler's marginal counts, one per cell.
    type Counts: AsRef<[Self::Count]> + AsMut<[Self::Count]>;
    /// The sampler's tile-visit ray list.
    type Local: AsRef<[LocalRay]> + AsMut<[LocalRay]>;
    /// The block bitsets over the local rays ([`gibbs::block_words`]).
    type Blocks: AsRef<[u32]> + AsMut<[u32]>;
}

/// Every buffer of a [`Session`]. The grid's size is `width × height` of [`Buffers::width`] /
/// [`Buffers::height`]; the other lengths must fit it (checked by [`Session::new`]).
pub struct Buffers<S: Storage> {
    /// Grid columns.
    pub width: u16,
    /// Grid rows.
    pub height: u16,
    /// Log-odds cells, `width · height`.
    pub grid: S::Grid,
    /// Mapper marks.
    pub marks: S::Marks,
    /// Ray store scans (length = capacity; ≥ 1).
    pub scans: S::Scans,
    /// Ray store rays (length = capacity; ≥ 1).
    pub rays: S::Rays,
    /// Sample bits, ⌈cells / 32⌉ words.
    pub sample: S::Sample,
    /// Marginal counts, one per cell.
    pub counts: S::Counts,
    /// Tile-visit rays (length = capacity; ≥ 1).
    pub local: S::Local,
    /// Block bitsets for `local`.
    pub blocks: S::Blocks,
}

impl<S: Storage> Buffers<S> {
    /// The capacities these buffers give (what a firmware's `Hello` reports).
    pub fn sizes(&self) -> Sizes {
        Sizes {
            width: self.width,
            height: self.height,
            rays: self.rays.as_ref().len(),
            scans: self.scans.as_ref().len(),
            local: self.local.as_ref().len(),
        }
    }
}

/// A session's dimensions: the grid and the ray capacities.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Sizes {
    /// Grid columns.
    pub width: u16,
    /// Grid rows.
    pub height: u16,
    /// Ray store capacity, rays.
    pub rays: usize,
    /// Ray store capacity, scans.
    pub scans: usize,
    /// Tile-visit ray list capacity.
    pub local: usize,
}

impl Sizes {
    /// A `width × height` grid with the reference firmware's ray capacities.
    pub fn grid(width: u16, height: u16) -> Self {
        Sizes {
            width,
            height,
            ..Sizes::default()
        }
    }
}

impl Default for Sizes {
    /// A 256 × 256 grid (12.8 m at 5 cm) and ray capacities that hold a short run's rays
    /// (3 072 rays of 128 scans, 128 per tile visit): what a host session gets unless it
    /// says otherwise. A robot's own sizes are its board's, reported in its `Hello`.
    fn default() -> Self {
        Sizes {
            width: 256,
            height: 256,
            rays: 3072,
            scans: 128,
            local: 128,
        }
    }
}

/// Why [`Session::new`] failed: which part rejected the settings or its memory.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum SessionError {
    /// The grid placement (cell size, size).
    Geometry(crate::Error),
    /// The mapper (its buffers or sensor model).
    Mapper(crate::Error),
    /// The forward model (σ, outliers, range).
    ForwardModel(crate::Error),
    /// The ray store (ranges, buffers).
    Store(crate::Error),
    /// The sampler (settings, buffers).
    Sampler(crate::Error),
    /// The rolling window (a margin that leaves no band inside the grid, a shift that is not
    /// this window's or cannot be made).
    Window(crate::Error),
}

impl SessionError {
    /// The part's number on the wire ([`crate::wire::ConfigFault`]).
    pub fn fault(&self) -> crate::wire::ConfigFault {
        use crate::wire::ConfigFault as F;
        match self {
            SessionError::Geometry(_) => F::Geometry,
            SessionError::Mapper(_) => F::Mapper,
            SessionError::ForwardModel(_) => F::ForwardModel,
            SessionError::Store(_) => F::Store,
            SessionError::Sampler(_) => F::Sampler,
            SessionError::Window(_) => F::Window,
        }
    }
}

impl core::fmt::Display for SessionError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        let (what, e) = match self {
            SessionError::Geometry(e) => ("grid geometry", e),
            SessionError::Mapper(e) => ("mapper", e),
            SessionError::ForwardModel(e) => ("forward model", e),
            SessionError::Store(e) => ("ray store", e),
            SessionError::Sampler(e) => ("sampler", e),
            SessionError::Window(e) => ("rolling window", e),
        };
        write!(f, "{what}: {e}")
    }
}

impl core::error::Error for SessionError {}

/// The sampler of a session over storage `S`.
pub type SessionGibbs<S> = Gibbs<
    BorderPrior,
    <S as Storage>::Sample,
    <S as Storage>::Counts,
    <S as Storage>::Local,
    <S as Storage>::Blocks,
    <S as Storage>::Count,
>;

/// The mapping engine: mapper + ray store + border-conditioned patch sampler over storage `S`.
pub struct Session<S: Storage> {
    config: RunConfig,
    mapper: Mapper<S::Grid, S::Marks>,
    store: RayStore<S::Scans, S::Rays>,
    gibbs: SessionGibbs<S>,
    window: window::WindowState,
    /// The correction map ← odometry.
    track: TrackState,
    /// The last [`Session::correct`], for the insert of the same scan.
    pending: Option<Correction>,
}

impl<S: Storage> Session<S> {
    /// Builds the engine over `buffers` with the host's settings, and resets the sampler on the
    /// empty map. The grid is `buffers.width × buffers.height` cells placed by `config`.
    pub fn new(config: RunConfig, buffers: Buffers<S>) -> Result<Self, SessionError> {
        let mut s = Session::parts(config, buffers)?;
        s.reset()?;
        Ok(s)
    }

    /// [`Session::new`] into `slot` (a board's `static`): the same engine, built where it
    /// stays. The sampler is reset there, not in a local copy, so the engine (~5 KiB on the
    /// firmware) is not on the stack once more while it is built.
    pub fn new_in(
        slot: &mut Option<Self>,
        config: RunConfig,
        buffers: Buffers<S>,
    ) -> Result<&mut Self, SessionError> {
        let s = slot.insert(Session::parts(config, buffers)?);
        s.reset()?;
        Ok(s)
    }

    /// The engine before the sampler's reset.
    fn parts(config: RunConfig, buffers: Buffers<S>) -> Result<Self, SessionError> {
        let geometry = config
            .geometry(buffers.width, buffers.height)
            .map_err(SessionError::Geometry)?;
        let margin = u32::from(config.window_margin_cells);
        if 2 * margin >= u32::from(buffers.width.min(buffers.height)) {
            return Err(SessionError::Window(crate::Error::InvalidGeometry));
        }
        let grid = LogOddsGrid::new(geometry, buffers.grid).map_err(SessionError::Geometry)?;
        let mapper_config = config.mapper_config().map_err(SessionError::Mapper)?;
        let mapper =
            Mapper::new(grid, buffers.marks, mapper_config).map_err(SessionError::Mapper)?;
        // The evidence term reads no rays: no forward-model tables to build.
        let forward = if config.data.uses_rays() {
            config.forward_model().map_err(SessionError::ForwardModel)?
        } else {
            crate::sampler::forward_model::ForwardModel::pcsm()
        };
        let store = RayStore::new(
            geometry,
            config.max_range_mm,
            config.min_range_mm,
            buffers.scans,
            buffers.rays,
        )
        .map_err(SessionError::Store)?;
        let gibbs = Gibbs::new(
            geometry,
            BorderPrior::default(),
            forward,
            config.sampler_config(),
            gibbs::Buffers {
                sample: buffers.sample,
                counts: buffers.counts,
                local: buffers.local,
                blocks: buffers.blocks,
            },
        )
        .map_err(SessionError::Sampler)?;
        Ok(Session {
            config,
            mapper,
            store,
            gibbs,
            window: window::WindowState::default(),
            track: TrackState::new(),
            pending: None,
        })
    }

    /// Restarts the sampler on the current map (estimates cleared, sample from the log-odds).
    pub fn reset(&mut self) -> Result<(), SessionError> {
        self.gibbs
            .reset(self.mapper.grid().cells(), &mut self.store)
            .map_err(SessionError::Sampler)
    }

    /// Integrates a scan taken at `odometry`: corrects the pose by matching the scan against
    /// the map ([`Session::correct`], with [`crate::config::PoseCorrection::Match`]; else the
    /// pose as it came), then, at the corrected pose: log-odds update, seeding of the cells it
    /// observes for the first time in the sampler's sample, its rays into the store when the
    /// data term reads rays. [`Inserted::correction`] says which pose was used and why.
    ///
    /// With a rolling window, call [`Session::correct`] first, then [`Session::shift_for`] with
    /// the corrected pose (and stream and apply its shift): this insert then uses that
    /// correction (the last `correct` of the same `odometry` pose). Beams whose rays leave the
    /// window are clipped and counted ([`Inserted::beams_clipped`]). Fails only if the mapper
    /// rejects the scan, which a session's mapper (its marks checked when built, a ray model:
    /// the settings cannot name the cone model) never does.
    // Out of line: inlined into the firmware's scan step, the sweep's register allocation
    // followed whatever code surrounds the call (+0.8 % of its instructions on the M4 from a
    // change there that the sweep never runs); on its own it is the same code for every caller,
    // and 0.3 % over the inlined original in the self-test.
    #[inline(never)]
    pub fn insert<'b>(
        &mut self,
        odometry: &Pose,
        beams: &'b [Beam],
    ) -> crate::Result<Inserted<'b>> {
        let correction = match self.pending.take() {
            Some(c) if c.odometry == *odometry => c,
            _ => {
                let c = self.correct(odometry, beams);
                self.pending = None;
                c
            }
        };
        let pose = &correction.pose;
        let clipped = if self.config.window_margin_cells > 0 {
            self.count_clipped(pose, beams)
        } else {
            0
        };
        let done = insert::insert_and_seed(
            &mut self.mapper,
            &mut self.store,
            &mut self.gibbs,
            pose,
            beams,
        )?;
        let mut inserted = insert::inserted(&self.mapper, pose, beams, done);
        inserted.beams_clipped = clipped;
        inserted.correction = correction;
        Ok(inserted)
    }

    /// Runs `updates` patch updates of the sampler (bounded work: a few hundred to a few
    /// thousand instructions each on a Cortex-M4); returns how many ran.
    // Inlined into the caller's time-budget loop, as a direct `Gibbs::step` call was: out of
    // line it cost 29 more instructions per patch on the M4 (seed 3, 16-update chunks).
    #[inline(always)]
    pub fn step(&mut self, updates: u32) -> u32 {
        self.gibbs
            .step(&mut self.store, self.mapper.grid().cells(), updates)
    }

    /// The settings.
    pub fn config(&self) -> &RunConfig {
        &self.config
    }

    /// Where the grid lies.
    pub fn geometry(&self) -> GridGeometry {
        *self.mapper.grid().geometry()
    }

    /// The online log-odds map, row-major.
    pub fn log_odds(&self) -> &[LogOdds] {
        self.mapper.grid().cells()
    }

    /// The sampler's estimate of p(occupied) of cell `index` (`None` before its first sample or
    /// outside the grid).
    pub fn marginal(&self, index: usize) -> Option<f32> {
        self.gibbs.marginal(index)
    }

    /// The mapper.
    pub fn mapper(&self) -> &Mapper<S::Grid, S::Marks> {
        &self.mapper
    }

    /// The ray store.
    pub fn store(&self) -> &RayStore<S::Scans, S::Rays> {
        &self.store
    }

    /// The sampler.
    pub fn gibbs(&self) -> &SessionGibbs<S> {
        &self.gibbs
    }

    /// The sampler and store statistics as the wire reports them.
    pub fn sampler_report(&self) -> SamplerReport {
        SamplerReport {
            samples: self.gibbs.samples(),
            store: self.store.stats(),
            ..self.gibbs.stats()
        }
    }
}

impl<S: Storage> crate::wire::TileSource for Session<S> {
    fn log_odds(&self, index: usize) -> i16 {
        self.mapper.grid().cells().get(index).map_or(0, |c| c.raw())
    }

    fn count(&self, index: usize) -> u8 {
        self.gibbs.count(index).min(255) as u8
    }

    fn occupied(&self, index: usize) -> bool {
        self.gibbs.occupied(index)
    }
}

/// Heap storage for host tools (feature `alloc`): `Vec`s, counters of type `N`.
#[cfg(feature = "alloc")]
pub struct Owned<N>(core::marker::PhantomData<N>);

#[cfg(feature = "alloc")]
impl<N: Count> Storage for Owned<N> {
    type Count = N;
    type Grid = alloc::vec::Vec<LogOdds>;
    type Marks = OwnedMarks;
    type Scans = alloc::vec::Vec<StoredScan>;
    type Rays = alloc::vec::Vec<StoredRay>;
    type Sample = alloc::vec::Vec<u32>;
    type Counts = alloc::vec::Vec<N>;
    type Local = alloc::vec::Vec<LocalRay>;
    type Blocks = alloc::vec::Vec<u32>;
}

#[cfg(feature = "alloc")]
impl<N: Count> Owned<N> {
    /// Zeroed buffers of `sizes` (capacities of 0 count as 1).
    pub fn buffers(sizes: &Sizes) -> Buffers<Self> {
        use alloc::vec;
        let cells = usize::from(sizes.width) * usize::from(sizes.height);
        let local = sizes.local.max(1);
        Buffers {
            width: sizes.width,
            height: sizes.height,
            grid: vec![LogOdds::ZERO; cells],
            marks: OwnedMarks::new(crate::map::mapper::marks_len(cells)),
            scans: vec![StoredScan::default(); sizes.scans.max(1)],
            rays: vec![StoredRay::default(); sizes.rays.max(1)],
            sample: vec![0; cells.div_ceil(32)],
            counts: vec![N::default(); cells],
            local: vec![LocalRay::default(); local],
            blocks: vec![0; gibbs::block_words(local, gibbs::DEFAULT_BLOCK_GRID)],
        }
    }
}
