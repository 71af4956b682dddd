//! Precomputed tables shared by every product of one (atmosphere, wavelengths, ground albedo):
//! the density-integral table and, built on first use, the fast and precise multiple-scattering
//! tables. Building them is the cold cost; every later sky/sun/ground/aerial request reuses them.
//!
//! Given a [`TableStore`] (the engine's hook to `store::tables`, which keeps them in the cache
//! directory), the precise table is loaded instead of built when a verified copy exists under the
//! medium's key, and saved after a build, so other processes (CLI calls, restarted servers, bake
//! jobs) skip the build. A stored table that fails verification or does not match the medium and
//! settings is rebuilt, never used.

use super::medium::Medium;
use super::multiple_fast::{FastMultipleScattering, FastSettings};
use super::multiple_precise::{PreciseMultipleScattering, PreciseSettings};
use super::transmittance::DensityIntegralTable;
use crate::image::SpectralImage;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, OnceLock};

/// Resolution of the shared density-integral table.
pub const TRANSMITTANCE_N_R: usize = 64;
/// Resolution of the shared density-integral table.
pub const TRANSMITTANCE_N_MU: usize = 256;
/// Quadrature intervals per ray of the density-integral table.
pub const TRANSMITTANCE_STEPS: usize = 500;

/// Where shared tables are kept between processes. `load` returns only verified tables (a corrupt
/// file is [`TableLoad::Rejected`]); `save` is best effort (a failure only costs a rebuild next
/// time).
pub trait TableStore: Send + Sync {
    /// The table stored under `key` (64 hex digits).
    fn load(&self, key: &str) -> TableLoad;
    /// Stores `table` under `key`.
    fn save(&self, key: &str, table: &SpectralImage);
}

/// What a [`TableStore`] found under a key.
pub enum TableLoad {
    /// A verified table.
    Found(SpectralImage),
    /// Nothing stored.
    Absent,
    /// A stored table that failed verification (checksum, key, decoding): removed, and counted
    /// with the tables refused ([`TableEvents`]).
    Rejected,
}

/// Counts of shared-table builds and loads (for metrics and tests).
#[derive(Debug, Default)]
pub struct TableEvents {
    /// Precise tables built.
    pub precise_built: AtomicU64,
    /// Precise tables loaded from the store.
    pub precise_loaded: AtomicU64,
    /// Stored precise tables refused (undecodable, or not matching the medium and settings).
    pub precise_rejected: AtomicU64,
    /// Density-integral tables built (builds started, cancelled ones included).
    pub density_built: AtomicU64,
    /// Density-integral tables loaded from the store.
    pub density_loaded: AtomicU64,
    /// Stored density-integral tables refused (not matching the medium or the resolution).
    pub density_rejected: AtomicU64,
}

impl TableEvents {
    fn bump(counter: &AtomicU64) {
        counter.fetch_add(1, Ordering::Relaxed);
    }
    /// Current value of a counter.
    pub fn get(counter: &AtomicU64) -> u64 {
        counter.load(Ordering::Relaxed)
    }
}

/// Persistence of one medium's tables: the store (none: build every time), the medium's key and
/// where to count builds and loads.
#[derive(Clone)]
pub struct Persistence {
    pub store: Option<Arc<dyn TableStore>>,
    /// Canonical description of the medium and quality (the engine's shared-table key).
    pub medium_key: String,
    /// Canonical description of what the density-integral table depends on (the radii and the
    /// density profiles; not the coefficients, wavelengths, albedo or quality), so every
    /// wavelength set and quality of one atmosphere, and atmospheres that differ only in their
    /// coefficients, share one stored density table.
    pub density_key: String,
    /// Engine version: part of the stored key, so a new engine never reads an old table.
    pub engine_version: &'static str,
    pub events: Arc<TableEvents>,
}

impl Persistence {
    /// The store key of table `kind` for this medium (blake3 over kind, medium key, versions).
    pub fn key(&self, kind: &str) -> String {
        let canonical = serde_json::json!({"shared_table": kind, "medium": self.medium_key});
        crate::key::cache_key(
            &canonical.to_string(),
            &format!(
                "{}+{}",
                self.engine_version,
                super::multiple_precise::TABLE_FORMAT
            ),
        )
    }

    /// The store key of the density-integral table (blake3 over the radii and profiles, the table's
    /// resolution, the engine version and the table format).
    pub fn density_table_key(&self) -> String {
        let canonical = serde_json::json!({
            "shared_table": "density",
            "profiles": self.density_key,
            "n_r": TRANSMITTANCE_N_R,
            "n_mu": TRANSMITTANCE_N_MU,
            "steps": TRANSMITTANCE_STEPS,
        });
        crate::key::cache_key(
            &canonical.to_string(),
            &format!(
                "{}+{}",
                self.engine_version,
                super::transmittance::DENSITY_TABLE_FORMAT
            ),
        )
    }
}

/// Shared tables for one medium.
pub struct SharedTables {
    pub medium: Medium,
    density: OnceLock<DensityIntegralTable>,
    fast: OnceLock<FastMultipleScattering>,
    precise: OnceLock<PreciseMultipleScattering>,
    pub fast_settings: FastSettings,
    pub precise_settings: PreciseSettings,
    persistence: Option<Persistence>,
    /// Set once the precise table is wanted: the density-integral table goes through the store
    /// only with it, so requests that need no precise table (the fast method) neither open the
    /// store nor add files to it.
    precise_wanted: AtomicBool,
}

impl SharedTables {
    /// Builds the density-integral table now; multiple-scattering tables are built on first use.
    pub fn new(
        medium: Medium,
        fast_settings: FastSettings,
        precise_settings: PreciseSettings,
    ) -> Self {
        Self::new_unless(medium, fast_settings, precise_settings, &|| false)
            .unwrap_or_else(|| unreachable!("never cancelled"))
    }

    /// [`Self::new`], stopped (`None`) when `cancelled` returns true between two rows of the
    /// density-integral table (every waiting client has gone).
    pub fn new_unless(
        medium: Medium,
        fast_settings: FastSettings,
        precise_settings: PreciseSettings,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Option<Self> {
        let density = DensityIntegralTable::new_unless(
            &medium,
            TRANSMITTANCE_N_R,
            TRANSMITTANCE_N_MU,
            TRANSMITTANCE_STEPS,
            cancelled,
        )?;
        Some(Self {
            medium,
            density: OnceLock::from(density),
            fast: OnceLock::new(),
            precise: OnceLock::new(),
            fast_settings,
            precise_settings,
            persistence: None,
            precise_wanted: AtomicBool::new(false),
        })
    }

    /// Loads and saves the precise table through `persistence` from now on.
    pub fn with_persistence(mut self, persistence: Persistence) -> Self {
        self.persistence = Some(persistence);
        self
    }

    /// Shared tables kept through `persistence`, all made on first use: the precise table is
    /// loaded from the table store when a verified copy made for this medium exists, else built
    /// and stored; the density-integral table likewise, under its own key (one per set of
    /// density profiles), when the precise table is wanted (before that it is built in-process).
    pub fn persistent(
        medium: Medium,
        fast_settings: FastSettings,
        precise_settings: PreciseSettings,
        persistence: Persistence,
    ) -> Self {
        Self {
            medium,
            density: OnceLock::new(),
            fast: OnceLock::new(),
            precise: OnceLock::new(),
            fast_settings,
            precise_settings,
            persistence: Some(persistence),
            precise_wanted: AtomicBool::new(false),
        }
    }

    /// The density-integral table D_k(r, μ), made on first use (see [`Self::persistent`]).
    pub fn density(&self) -> &DensityIntegralTable {
        self.density_unless(&|| false)
            .unwrap_or_else(|| unreachable!("never cancelled"))
    }

    /// The density-integral table, made on first use unless `cancelled` returns true between two
    /// rows of its build (every waiting client has gone); `None` then, and the table stays unbuilt.
    pub fn density_unless(
        &self,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Option<&DensityIntegralTable> {
        init_unless(&self.density, || self.load_or_build_density(cancelled))
    }

    fn load_or_build_density(
        &self,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Option<DensityIntegralTable> {
        let medium = &self.medium;
        let build = || {
            DensityIntegralTable::new_unless(
                medium,
                TRANSMITTANCE_N_R,
                TRANSMITTANCE_N_MU,
                TRANSMITTANCE_STEPS,
                cancelled,
            )
        };
        let Some(p) = &self.persistence else {
            return build();
        };
        let Some(store) = p
            .store
            .as_ref()
            .filter(|_| self.precise_wanted.load(Ordering::Relaxed))
        else {
            // Counted when started, like every table build (a cancelled one too).
            TableEvents::bump(&p.events.density_built);
            return build();
        };
        let key = p.density_table_key();
        let loaded = store.load(&key);
        if let TableLoad::Rejected = loaded {
            tracing::warn!(key, "stored density table failed verification; rebuilding");
            TableEvents::bump(&p.events.density_rejected);
        }
        if let TableLoad::Found(image) = loaded {
            match DensityIntegralTable::from_image(
                &image,
                medium,
                TRANSMITTANCE_N_R,
                TRANSMITTANCE_N_MU,
                TRANSMITTANCE_STEPS,
            ) {
                Some(table) => {
                    tracing::debug!(key, "density table loaded from the table store");
                    TableEvents::bump(&p.events.density_loaded);
                    return Some(table);
                }
                None => {
                    tracing::warn!(key, "stored density table does not match; rebuilding");
                    TableEvents::bump(&p.events.density_rejected);
                }
            }
        }
        TableEvents::bump(&p.events.density_built);
        let table = build()?;
        match table.to_image(medium) {
            Ok(image) => store.save(&key, &image),
            Err(e) => tracing::warn!(key, error = %e, "density table not stored"),
        }
        Some(table)
    }

    /// The fast (Hillaire 2020) multiple-scattering table, built on first use.
    pub fn fast(&self) -> &FastMultipleScattering {
        self.fast.get_or_init(|| {
            FastMultipleScattering::new(&self.medium, self.density(), self.fast_settings)
        })
    }

    /// The fast table, built on first use unless `cancelled` returns true between two rows of its
    /// passes (every waiting client has gone); `None` then, and the table stays unbuilt.
    pub fn fast_unless(
        &self,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Option<&FastMultipleScattering> {
        init_unless(&self.fast, || {
            FastMultipleScattering::new_unless(
                &self.medium,
                self.density_unless(cancelled)?,
                self.fast_settings,
                cancelled,
            )
        })
    }

    /// The precise (orders of scattering) multiple-scattering table: loaded from the table store
    /// when a verified, matching copy exists, otherwise built (and then stored).
    pub fn precise(&self) -> &PreciseMultipleScattering {
        self.precise.get_or_init(|| {
            self.load_or_build_precise(&|| false)
                .unwrap_or_else(|| unreachable!("never cancelled"))
        })
    }

    /// The precise table, loaded or built on first use unless `cancelled` returns true between two
    /// orders of scattering (every waiting client has gone); `None` then, and the table stays unbuilt: a later request
    /// builds it whole, and one waiting for this build builds it itself.
    pub fn precise_unless(
        &self,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Option<&PreciseMultipleScattering> {
        /// The unwind payload that leaves `OnceLock::get_or_init` without initialising it.
        struct Stopped;
        if let Some(t) = self.precise.get() {
            return Some(t);
        }
        let built = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            self.precise.get_or_init(|| {
                self.load_or_build_precise(cancelled)
                    .unwrap_or_else(|| std::panic::resume_unwind(Box::new(Stopped)))
            })
        }));
        match built {
            Ok(t) => Some(t),
            Err(payload) if payload.is::<Stopped>() => None,
            Err(payload) => std::panic::resume_unwind(payload),
        }
    }

    /// Loads the precise table from the table store, or builds it (`None` when cancelled) and
    /// stores it.
    fn load_or_build_precise(
        &self,
        cancelled: &(dyn Fn() -> bool + Sync),
    ) -> Option<PreciseMultipleScattering> {
        self.precise_wanted.store(true, Ordering::Relaxed);
        let build = || {
            PreciseMultipleScattering::build(
                &self.medium,
                self.density_unless(cancelled)?,
                self.precise_settings,
                cancelled,
            )
        };
        let Some(p) = &self.persistence else {
            return build();
        };
        let key = p.key("precise");
        let Some(store) = &p.store else {
            let table = build()?;
            TableEvents::bump(&p.events.precise_built);
            return Some(table);
        };
        let loaded = store.load(&key);
        if let TableLoad::Rejected = loaded {
            tracing::warn!(key, "stored precise table failed verification; rebuilding");
            TableEvents::bump(&p.events.precise_rejected);
        }
        if let TableLoad::Found(image) = loaded {
            match PreciseMultipleScattering::from_image(&image, &self.medium, self.precise_settings)
            {
                Some(table) => {
                    tracing::info!(key, "precise table loaded from the table store");
                    TableEvents::bump(&p.events.precise_loaded);
                    return Some(table);
                }
                None => {
                    tracing::warn!(key, "stored precise table does not match; rebuilding");
                    TableEvents::bump(&p.events.precise_rejected);
                }
            }
        }
        let table = build()?;
        TableEvents::bump(&p.events.precise_built);
        tracing::info!(key, "precise table built");
        match table.to_image(&self.medium) {
            Ok(image) => store.save(&key, &image),
            Err(e) => tracing::warn!(key, error = %e, "precise table not stored"),
        }
        Some(table)
    }

    /// Whether the precise table exists already.
    pub fn has_precise(&self) -> bool {
        self.precise.get().is_some()
    }

    /// Whether the fast table exists already.
    pub fn has_fast(&self) -> bool {
        self.fast.get().is_some()
    }
}

/// `cell`'s value, initialised by `build` unless `build` gives `None` (a cancelled build): then
/// `None`, and the cell stays empty, so a later caller builds it whole (and a caller waiting on
/// this build builds it itself). `OnceLock` has no stable fallible initialiser; leaving
/// `get_or_init` by an unwind with a private payload leaves the cell uninitialised.
pub fn init_unless<T>(cell: &OnceLock<T>, build: impl FnOnce() -> Option<T>) -> Option<&T> {
    /// The unwind payload of a cancelled build.
    struct Stopped;
    if let Some(t) = cell.get() {
        return Some(t);
    }
    let built = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        cell.get_or_init(|| build().unwrap_or_else(|| std::panic::resume_unwind(Box::new(Stopped))))
    }));
    match built {
        Ok(t) => Some(t),
        Err(payload) if payload.is::<Stopped>() => None,
        Err(payload) => std::panic::resume_unwind(payload),
    }
}
