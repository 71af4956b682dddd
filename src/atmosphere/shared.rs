//! Precomputed tables shared by every product of one (atmosphere, wavelengths, ground albedo):
//! the density-integral table and, built on first use, the fast and precise multiple-scattering
//! tables. Building them is the cold cost; every later sky/sun/ground/aerial request reuses them.

use super::medium::Medium;
use super::multiple_fast::{FastMultipleScattering, FastSettings};
use super::multiple_precise::{PreciseMultipleScattering, PreciseSettings};
use super::transmittance::DensityIntegralTable;
use std::sync::OnceLock;

/// Resolution of the shared density-integral table.
pub const TRANSMITTANCE_N_R: usize = 64;
/// Resolution of the shared density-integral table.
pub const TRANSMITTANCE_N_MU: usize = 256;
/// Quadrature intervals per ray of the density-integral table.
pub const TRANSMITTANCE_STEPS: usize = 500;

/// Shared tables for one medium.
pub struct SharedTables {
    pub medium: Medium,
    pub density: DensityIntegralTable,
    fast: OnceLock<FastMultipleScattering>,
    precise: OnceLock<PreciseMultipleScattering>,
    pub fast_settings: FastSettings,
    pub precise_settings: PreciseSettings,
}

impl SharedTables {
    /// Builds the density-integral table now; multiple-scattering tables are built on first use.
    pub fn new(
        medium: Medium,
        fast_settings: FastSettings,
        precise_settings: PreciseSettings,
    ) -> Self {
        let density = DensityIntegralTable::new(
            &medium,
            TRANSMITTANCE_N_R,
            TRANSMITTANCE_N_MU,
            TRANSMITTANCE_STEPS,
        );
        Self {
            medium,
            density,
            fast: OnceLock::new(),
            precise: OnceLock::new(),
            fast_settings,
            precise_settings,
        }
    }

    /// The fast (Hillaire 2020) multiple-scattering table, built on first use.
    pub fn fast(&self) -> &FastMultipleScattering {
        self.fast.get_or_init(|| {
            FastMultipleScattering::new(&self.medium, &self.density, self.fast_settings)
        })
    }

    /// The precise (orders of scattering) multiple-scattering table, built on first use.
    pub fn precise(&self) -> &PreciseMultipleScattering {
        self.precise.get_or_init(|| {
            PreciseMultipleScattering::new(&self.medium, &self.density, self.precise_settings)
        })
    }

    /// The precise table, built on first use unless `cancelled` returns true between two orders
    /// of scattering (issue 18); `None` then, and the table stays unbuilt: a later request builds
    /// it whole, and one waiting for this build builds it itself.
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
                let s = self.precise_settings;
                PreciseMultipleScattering::build(&self.medium, &self.density, s, cancelled)
                    .unwrap_or_else(|| std::panic::resume_unwind(Box::new(Stopped)))
            })
        }));
        match built {
            Ok(t) => Some(t),
            Err(payload) if payload.is::<Stopped>() => None,
            Err(payload) => std::panic::resume_unwind(payload),
        }
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
