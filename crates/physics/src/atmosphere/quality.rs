//! Table resolutions of the quality presets (`draft`, `standard`, `high`, `reference`): one table
//! that the engine, the planner and the cost estimate read.

use crate::atmosphere::multiple_fast::FastSettings;
use crate::atmosphere::multiple_precise::PreciseSettings;
use serde::{Deserialize, Serialize};

use crate::{Error, Result};

/// Table resolutions for a quality preset.
pub fn settings_for(q: Quality) -> (FastSettings, PreciseSettings) {
    let fast = FastSettings::default();
    let precise = PreciseSettings::default();
    match q {
        Quality::Draft => (
            FastSettings {
                n_r: 16,
                n_mu_s: 32,
                steps: 12,
                ..fast
            },
            PreciseSettings {
                n_r: 12,
                n_mu_s: 20,
                n_mu: 24,
                n_phi: 8,
                steps: 12,
                tolerance: 1e-2,
                ..precise
            },
        ),
        Quality::Standard => (fast, precise),
        Quality::High => (
            FastSettings {
                directions_mu: 16,
                steps: 24,
                ..fast
            },
            // Orders to 10⁻⁴ (as `reference`): the geometric tail that ends the series takes the
            // angular shape of the last computed order, still peaked towards the sun after the
            // 5 orders 10⁻³ stops at in hazy air, while the orders it stands for are more
            // diffuse; it left the low sky opposite a low sun 0.4 points dark against DISORT
            // (Cornette-Shanks g 0.7, optical depth 0.4: −1.21 % at 10⁻³, −0.88 % at 10⁻⁴, 7
            // orders; −0.83 % without the tail, 14 orders). The planner's orders-under-budget rule
            // may still loosen it in a measured aerosol band (skybake_engine::plan::budget).
            PreciseSettings {
                n_r: 28,
                n_mu_s: 36,
                n_mu: 40,
                n_phi: 16,
                steps: 28,
                tolerance: 1e-4,
                ..precise
            },
        ),
        Quality::Reference => (
            FastSettings {
                n_r: 64,
                n_mu_s: 96,
                directions_mu: 16,
                directions_phi: 16,
                steps: 32,
            },
            PreciseSettings {
                n_r: 36,
                n_mu_s: 48,
                n_mu: 48,
                n_phi: 20,
                steps: 40,
                tolerance: 1e-4,
                ..precise
            },
        ),
    }
}

/// Quality presets: ray-marching steps and table resolutions.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Quality {
    Draft,
    Standard,
    High,
    Reference,
}

impl Quality {
    pub fn parse(s: &str) -> Result<Self> {
        match s {
            "draft" => Ok(Self::Draft),
            "standard" => Ok(Self::Standard),
            "high" => Ok(Self::High),
            "reference" => Ok(Self::Reference),
            _ => Err(Error::invalid(
                "quality",
                format!("'{s}' is not one of draft, standard, high, reference"),
            )),
        }
    }

    /// Samples per ray segment for product rays.
    pub fn steps(self) -> usize {
        match self {
            Self::Draft => 16,
            Self::Standard => 32,
            Self::High => 64,
            Self::Reference => 160,
        }
    }
}
