//! An RGB-only request (a PNG) run at fewer wavelengths: the subset whose proxies' predicted change
//! of the RGB image fits the budget.

use super::*;

/// Factor on the proxies' predicted change of an RGB-only request run at fewer wavelengths
/// ([`RgbFacts`]): the proxies are the scene's light spectra, the pixels and directions mix them
/// (light scattered once and many times, along paths of every length), so the rule counts twice
/// the worst proxy's change. Measured (largest per-pixel or per-direction change of the RGB
/// relative to its mean channel, against the prediction): the fast sky at sun 30° 1.7 % of
/// 4.2 %, at sun 5° 4.8 % of 6.1 %, the ground 1.5 % of 4.2 %, the example cumulus frame under
/// the earth's atmosphere 0.5 % of 1.3 % (`tests/products/plan_rgb_only.rs`, `report/planner.md`); with
/// the proxies of the sunlit air alone, without the long view paths, the sky's largest change
/// exceeded the doubled prediction (5.1 % of 4.2 %).
pub const RGB_PROXY_SAFETY: f64 = 2.0;

pub use skybake_physics::spectrum::subsets::MIN_RGB_WAVELENGTHS;

/// A subset of the requested wavelengths and the change of the RGB image its proxies predict.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WavelengthCandidate {
    /// The wavelengths kept, nm, ascending (the first and last requested ones among them).
    pub internal_nm: Vec<f64>,
    /// The largest change of the proxies' linear sRGB, relative to their mean channel, when
    /// their spectra are known at `internal_nm` only (linear between them, as the frame's RGB
    /// planes are made) instead of at every requested wavelength.
    pub proxy_error: f64,
}

/// What the planner needs to know of an RGB-only frame request (one whose only output is the
/// RGB image, e.g. a PNG): its wavelengths and the subsets it could run at, fewest first.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RgbFacts {
    pub requested_nm: Vec<f64>,
    /// Subsets by backward elimination (each drops the interior wavelength whose loss changes
    /// the proxies least), fewest wavelengths first.
    pub candidates: Vec<WavelengthCandidate>,
}

/// An RGB-only request (a frame or a sky or ground PNG) run at fewer wavelengths than requested.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct WavelengthSubset {
    pub rule: &'static str,
    pub requested_nm: Vec<f64>,
    /// The wavelengths the frame runs at (its spectral planes; the RGB planes interpolate
    /// linearly between them).
    pub internal_nm: Vec<f64>,
    pub left_out_nm: Vec<f64>,
    /// [`RGB_PROXY_SAFETY`] × the candidate's proxy error, spent from the budget.
    pub predicted_error: f64,
    /// The budget's allowance when the rule ran.
    pub allowance: f64,
}

impl WavelengthSubset {
    /// One line for people.
    pub fn detail(&self) -> String {
        format!(
            "RGB-only output: runs at {} of the {} requested wavelengths ({} nm); the RGB image is predicted to change by {:.2} % of its mean channel, within the budget's {:.2} %",
            self.internal_nm.len(),
            self.requested_nm.len(),
            self.internal_nm
                .iter()
                .map(|w| format!("{w}"))
                .collect::<Vec<_>>()
                .join(", "),
            self.predicted_error * 100.0,
            self.allowance * 100.0
        )
    }
}

/// Cost rule on an RGB-only frame: it runs at the fewest of the requested wavelengths whose
/// predicted RGB change ([`RGB_PROXY_SAFETY`] × the proxies') fits in what is left of the
/// budget. Spends from `budget`; runs first ([`plan_frame`] and the renderer decide the same).
pub fn rgb_wavelengths_rule(f: &RgbFacts, budget: &mut Budget) -> Option<WavelengthSubset> {
    let c = f
        .candidates
        .iter()
        .filter(|c| {
            c.internal_nm.len() >= MIN_RGB_WAVELENGTHS && c.internal_nm.len() < f.requested_nm.len()
        })
        .find(|c| budget.try_spend(RGB_PROXY_SAFETY * c.proxy_error))?;
    Some(WavelengthSubset {
        rule: "rgb_only",
        requested_nm: f.requested_nm.clone(),
        internal_nm: c.internal_nm.clone(),
        left_out_nm: f
            .requested_nm
            .iter()
            .copied()
            .filter(|w| !c.internal_nm.contains(w))
            .collect(),
        predicted_error: RGB_PROXY_SAFETY * c.proxy_error,
        allowance: budget.allowance,
    })
}
