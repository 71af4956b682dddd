//! The `skyview` layout: a second texture bundle, of skybake's design, for renderers that want
//! the sky within the accuracy targets where Bruneton 2017's 4-D table (ν × μs × μ × r with
//! linear filtering) cannot reach them (docs/lut.md, "Accuracy and cost": its error is the
//! interpolation of that table, not its content).
//!
//! Where his layout's error comes from, and what this one does instead:
//!
//! - **ν (8 nodes, linear)**: here the angle between view and sun is replaced by the view's
//!   azimuth from the sun (0–180°, nodes dense near the sun), and both single-scattering parts
//!   are stored *without* their phase functions (Rayleigh single + multiple / Rayleigh phase,
//!   and single Mie without phase, per channel), so the client multiplies by the exact phase
//!   functions and the aureole is as sharp as the aerosol's phase function;
//! - **μs (13 nodes by day, linear)**: the sun's elevation above the observer's horizon has its
//!   own nodes ([`SUN_SEGMENTS`], 0.5° in twilight at the ground, warped towards sunset aloft,
//!   [`sun_warp`]), and on the limb rows the coordinate moves
//!   towards the sun's elevation above the horizon of the ray's tangent point ([`sun_shift`]),
//!   so the earth's shadow reaching a limb ray stays near one node;
//! - **r (32 nodes, linear in ρ)**: altitude nodes quadratic in the altitude (dense low);
//! - radiance that falls by orders of magnitude between nodes (aloft, twilight): every axis is
//!   interpolated in **ln L**, with the Lagrange polynomial through 4 nodes ([`Stencil`], exact
//!   for the exponential of a cubic, bounded by the nodes' range), done by the client from
//!   single texel fetches, as his shader interpolates ν by hand;
//! - the view zenith is relative to the horizon of the observer's altitude (Hillaire 2020,
//!   §5.3's sky-view parameterisation: nodes quadratic towards the horizon, from above and below),
//!   so the horizon stays on a node at every altitude; the limb rows (between the horizontal
//!   and the horizon) follow the square-root cusp of the limb just below the horizontal
//!   ([`limb_depth`]);
//! - half floats with a per-slice scale (a float table, one value per altitude, sun and
//!   channel), so twilight values keep half floats' full relative precision.
//!
//! The textures hold the sky seen from an observer inside the atmosphere (0 to the top), for
//! every view direction (above the horizon: to the top of the atmosphere; below: to the ground,
//! without the ground's reflection, which the client adds with the irradiance) and sun elevation
//! from [`SUN_MIN_DEG`] to 90°. Transmittance is Bruneton's texture as it is (its error is
//! 0.006 % by day); the sky's irradiance on a horizontal surface is a table on the same
//! altitude × sun nodes. Every texel is computed along its own ray with the `sky` product's
//! quadrature and sources ([`crate::build::FamilyScratch`]), so the bundle equals the products
//! at its nodes.

use rayon::prelude::*;
use serde_json::{json, Value};
use skybake_physics::atmosphere::geometry::horizon_mu;
use skybake_physics::atmosphere::shared::SharedTables;
use skybake_physics::phase::Phase;
use std::f64::consts::PI;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Mutex, OnceLock};
use std::time::Instant;

use crate::build::{self, channel_setup, Channels, FamilyScratch, Sample, Texture};
use crate::ms_rows;
use crate::param::{self, AtmosphereParameters};

/// The layout's name (`--layout`, the manifest's `format`).
pub const LAYOUT: &str = "skyview";
/// Layout version (bumped when a file or a field changes meaning).
/// 2: the limb rows' sun coordinate is the sun's elevation above the tangent point's horizon
/// ([`sun_shift`]), sun nodes from −23°, Lagrange interpolation over 4 nodes per axis.
/// 3: the limb rows at y = 2x² − x³ ([`limb_depth`]), the sun nodes warped towards s = 0
/// with the altitude ([`sun_warp`]).
/// 4: a slice's largest texel stored as [`SLICE_PEAK`] (2¹⁵) instead of 1, its scale divided
/// accordingly (the reader's and the shader's math unchanged).
/// The sky rows concentrate on the band above the earth's shadow at low altitude in twilight
/// ([`sky_row_focus`]); 81 sun nodes (0.25° apart from −1° to 2°).
/// 5: on the focused rows the azimuth columns are read each at its own elevation relative to the band
/// ([`band_relative_elevation`]), and the rows' focus is stronger ([`BAND_FOCUS`] 14); and
/// the azimuth columns depend on the altitude, denser around 90° from the sun aloft
/// ([`azimuth_coord`]); the altitude nodes denser near the top ([`altitude_coord`]).
/// 6: the sky rows' focus grows from 1 to 5 km ([`band_focus_strength`]), and each (altitude,
/// sun) slice is read at the query's elevation relative to the band moved to the slice's
/// ([`band_slice_elevation`]) on the slice's own rows, instead of at the query's row.
/// 7: the columns' map relative to the band acts from δ below the horizontal up, through the
/// horizontal (version 6: faded to the identity below 0.5°), a column moved across the
/// horizontal read on the other segment's rows ([`band_horizon_taper`], [`band_row`]).
/// 8: the texels' multiple scattering computed on every other azimuth column and interpolated
/// to the others in ln J where the computed columns show it smooth (`ms_columns`; texels
/// within 0.7 %, the layout unchanged).
/// 9: the sky rows' focus carried up to 20 km (fading out at 20–25 km, [`BAND_ALTITUDE_M`]) with
/// the band's elevation fitted from 10 to 20 km ([`BAND_CENTRE_ALOFT`]) and its depth held from
/// 5 km up ([`BAND_DEPTH_TOP_M`]); the multiple scattering on every other sun node as well.
/// The limb rows' sun coordinate moves towards the tangent point's over a depth of 50 km
/// instead of 20 km ([`LIMB_SHADOW_SCALE_M`]), and aloft the sky rows' towards the sun's
/// elevation where the ray leaves the atmosphere ([`SKY_EXIT_ALTITUDE_M`], [`sun_shift`]).
/// 10: the limb rows concentrate on the band below the horizontal seen from 6–25 km
/// ([`limb_row_focus`]), each slice read at the query's depth relative to it
/// ([`limb_slice_depth`]).
/// 11: the sky rows' focus grows again from 5 to 8 km ([`BAND_FOCUS_ALOFT`]); the limb slices'
/// depth map in two pieces, the horizon fixed ([`LIMB_BAND_MAX_FRACTION`]); aloft away from the
/// sun the deep limb rows' sun coordinate goes back to the observer's horizon ([`limb_near_end`]).
/// 12: the columns' map relative to the band with the band's depth measured aloft, 1.8° from
/// 12.5–17 km up ([`band_azimuth_depth_deg`]; the reader only); the irradiance texels' multiple
/// scattering on every other direction, interpolated where smooth (`ms_directions`; within
/// 4.1·10⁻⁴); the sky rows' band focus fades in from a sun at −5…−3° (was −7…−4°,
/// [`BAND_SUN_RANGE`]): the rows near the horizontal towards the sun in deep twilight.
/// 13: sun nodes every 0.125° from 0° to 0.5° (where the air around an observer 6–20 km up comes
/// into the sunlight) and every 0.5° from 1° to 2°, the same number ([`SUN_SEGMENTS`]);
/// each altitude node's columns read at the query's azimuth's coordinate in the node's own
/// map (version 12: every node at the query's altitude's coordinate), and the columns focused at
/// 110° from the sun from 20–30 km up ([`azimuth_focus`]); the manifest lists every node's
/// column azimuths (`azimuth_nodes_rad`);
/// the sky rows' band focus fades out as the band rises from 6° to 9°
/// ([`BAND_CENTRE_RANGE_DEG`]): the rows near the horizontal towards the sun at sunset.
/// 14: the columns' square-root weight 0.72 below 15 km ([`AZIMUTH_GROUND_WEIGHT`]) and a
/// quarter of the sky rows' band focus kept above the fade ([`BAND_CENTRE_FLOOR`]); four altitude
/// nodes inserted halfway (15.3, 18.5, 51.3, 57.9 km, [`ALTITUDE_INSERTED`]); the half texels
/// rounded to 8 mantissa bits ([`HALF_MANTISSA_BITS`]) and the ZIP blocks deflated at level 6.
/// 15: aloft in deep twilight the limb rows' near end fades in over 66–127° from the sun
/// ([`LIMB_NEAR_END_AZIMUTH`]), the columns' focus centred at 115°, and the sun warp centred on
/// the terminator's kink on the sky rows towards the sun from 40–60 km up ([`SUN_WARP_CENTRE`]);
/// from 6–12 km up the sky rows' focus under a low band at [`BAND_FOCUS_PLACE_ALOFT`] of the
/// antisolar band and stronger, and the band's sun term turned smoothly ([`BAND_SUN_SOFT_DEG`]).
/// 16: the same texels; the slices' map aloft grows the band curved (0.045 per km at 10 km to
/// 0.015 at 20 km) and acts through the horizontal from 5–8 km up ([`BAND_SLICE_THROUGH_M`]).
/// 17: the sky rows' focus moves and grows aloft from 4–10 km ([`BAND_FOCUS_PLACE_M`]; texels
/// change); on the limb rows the sun nodes whose slice would be read past its horizon are left
/// out of the sun stencil (`limb_sun_lowest`).
/// 18: from 6.5–8 km up to 11–12.5 km the sky rows' focus is wide, from the antisolar band down to
/// the band 140° from the sun, and 1.5 times as strong ([`sky_row_focus`]; texels change).
/// 19: the sky rows' focus and the band maps kept up to 35–40 km, the band rising aloft, the
/// slices' map faded in with the azimuth aloft (texels change); the columns continued by mirror
/// images past the sun and the antisolar point, and the limb slices' horizon held longer.
/// 20: the limb rows' focus kept up to 25–30 km; on the limb rows the interval's lower sun node
/// is left out where its slice would be read deeper than [`LIMB_BAND_DEEPEST`] of the way to its
/// horizon.
/// 21: the sky rows' exit shift faded out over 90–120° from the sun ([`sky_exit_azimuth`];
/// texels change); on the limb rows each altitude node is read at the query's sun coordinate
/// formed with that node's own tangent-point weight ([`limb_node_shift`]; reader and shader).
/// 22: on the limb rows each altitude node read with the query's exponential below 11–20 km and
/// with the query's weight ω above 25–29 km ([`limb_node_shift`]; reader and shader, texels as
/// version 21's).
/// 23: from 33–36 km up to 45–50 km, sun coordinate −0.75…1°, the limb rows focused on the
/// earth's shadow's edge 14 km + 6 km per degree below the observer ([`limb_edge_focus`]; texels,
/// reader, shader and manifest).
pub const SKYVIEW_VERSION: &str = "23";

/// Altitude nodes of the base map ([`altitude_abscissa`], about (top − bottom) · (x / 27)²,
/// denser near the top): its integers 0..=27.
pub const N_ALT_BASE: usize = 28;
/// Altitude nodes added halfway between base nodes, at these base abscissas: 10.5 and 11.5
/// (15.3 and 18.5 km, between the base nodes 13.9 / 16.9 / 20.2 km), where deep in twilight
/// the glow towards the sun needs them (15 km, sun −12°, 1° up 60° from the sun: the altitude
/// axis alone −13.4 %, +0.7 % with the nodes twice as dense), and 18.5 and 19.5 (51.3 and
/// 57.9 km; base 48.2 / 54.5 / 61.4 km), the sky deep in twilight at 55–60 km (56.8 km, 141°
/// from the sun: +7.0 %). The base nodes stay where they were; a query whose 4 altitude nodes
/// are all base nodes reads them with the same weights. (Also at 8.5 and 9.5, 9.8 and 12.5 km:
/// the earth's shadow seen from 9.5 / 12.5 km went 6.05 → 7.26 % and 2.42 → 3.42 %, docs/lut.md,
/// "Tried and not kept".)
pub const ALTITUDE_INSERTED: [f64; 4] = [10.5, 11.5, 18.5, 19.5];
/// Altitude nodes: the base nodes and the inserted ones, in increasing altitude.
pub const N_ALT: usize = N_ALT_BASE + ALTITUDE_INSERTED.len();
/// Sun nodes, uniform in the sun node coordinate t: the sun's elevation above the observer's
/// horizon (its elevation + the horizon's dip at the node's altitude, so sunset is on the same
/// node at every altitude), warped towards sunset aloft between −8° and 6° ([`sun_warp`]):
/// every 2° from [`SUN_MIN_DEG`] to −15°, every 1° to −8°, every 0.5° to 6° (twilight and
/// sunset; every 0.25° from −1° to 0°, where the sun sets at the observer, 0.125° to 0.5°, 0.25°
/// to 1°), every 1° to 20° (low sun), every 4° to 104° (the zenith seen from the top of a 100 km
/// atmosphere is 100.1° above its horizon). Why 0.125° from 0° to 0.5°: seen from 6–20 km in low
/// twilight opposite the sun, the sky near the horizontal brightens steeply once the sunlight
/// that reaches the air around the observer stops grazing the lowest few km (ln L at the band's
/// elevation rises 0.6 per unit of t below t ≈ 0.25 and 4 above t ≈ 0.45; `sky` product, 680 nm,
/// 8 / 12.5 / 20 km, 120–150° from the sun): with 0.25° the sun axis alone erred by +4.1 / +5.9
/// / +7.2 % there, with 0.125° by +0.3 % (12.5 km). The two nodes come from 1°–2° (0.5° apart),
/// so the node count and the texels stay, the build's rays +2 % (nodes moved from 20°–104° instead
/// made the texels 279 kB larger and the day sky at the ground near the horizon worse).
pub const SUN_MIN_DEG: f64 = -23.0;
pub const SUN_SEGMENTS: [(f64, f64, usize); 10] = [
    (-23.0, 2.0, 4),
    (-15.0, 1.0, 7),
    (-8.0, 0.5, 14),
    (-1.0, 0.25, 4),
    (0.0, 0.125, 4),
    (0.5, 0.25, 2),
    (1.0, 0.5, 2),
    (2.0, 0.5, 8),
    (6.0, 1.0, 14),
    (20.0, 4.0, 21),
];
pub const N_SUN: usize = 4 + 7 + 14 + 4 + 4 + 2 + 2 + 8 + 14 + 21 + 1;
/// View rows: from the zenith to the horizontal ([`N_VIEW_SKY`], θ = 90° (1 − (1 − x)²)),
/// from the horizontal to the horizon ([`N_VIEW_LIMB`], the ray's tangent altitude from the
/// observer's to 0 at the depths [`limb_depth`]) and from the horizon to the nadir
/// ([`N_VIEW_DOWN`], θ = θ_h + (π − θ_h) x²).
pub const N_VIEW_SKY: usize = 22;
pub const N_VIEW_LIMB: usize = 16;
pub const N_VIEW_UP: usize = N_VIEW_SKY + N_VIEW_LIMB;
pub const N_VIEW_DOWN: usize = 8;
pub const N_VIEW: usize = N_VIEW_UP + N_VIEW_DOWN;
/// The value a slice's largest texel is stored as (its scale = that texel's value / this):
/// 2¹⁵, so a slice spans half floats' whole normal range, 2¹⁵ down to 2⁻¹⁴ (a ratio of
/// 5·10⁸, every value with 11 significant bits). With the largest texel at 1 (version 3) the
/// normal range was 2¹⁴ = 1.6·10⁴: aloft in twilight (sun −12…−6°, 60–100 km) the sky away
/// from the lit limb is 10⁻⁶…10⁻⁸ of its slice's largest value and fell into the subnormals
/// (at the nodes of those slices the reader erred by up to 19.5 %, now 4.6·10⁻⁴;
/// tests/atmosphere/lut_skyview.rs, `skyview_dim_twilight_slices_keep_half_precision`).
pub const SLICE_PEAK: f64 = 32768.0;

/// Mantissa bits kept of the texels' half floats (of 10): rounded to nearest, at most
/// 2⁻⁹ = 0.2 % relative; the two lowest bits zero deflate to almost nothing (the two texture
/// files 9.52 → 7.7 MB at the same nodes), which pays for the altitude nodes
/// [`ALTITUDE_INSERTED`].
pub const HALF_MANTISSA_BITS: u32 = 8;

/// Azimuth-from-the-sun nodes, φ_a = π (a / (N − 1))².
pub const N_AZ: usize = 20;

/// File names.
pub const RAYLEIGH_FILE: &str = "skyview_rayleigh.exr";
pub const MIE_FILE: &str = "skyview_mie.exr";
pub const SCALE_FILE: &str = "skyview_scale.exr";
pub const IRRADIANCE_FILE: &str = "skyview_irradiance.exr";

/// Sun node `j`: the sun's elevation above the observer's horizon, degrees.
pub fn sun_node_deg(j: usize) -> f64 {
    let mut first = 0;
    for (start, step, n) in SUN_SEGMENTS {
        if j <= first + n {
            return start + (j - first) as f64 * step;
        }
        first += n;
    }
    let (start, step, n) = SUN_SEGMENTS[SUN_SEGMENTS.len() - 1];
    start + n as f64 * step
}

/// Continuous sun node coordinate of an elevation above the observer's horizon (degrees),
/// clamped to the nodes.
pub fn sun_coord(above_horizon_deg: f64) -> f64 {
    let mut first = 0.0;
    for (start, step, n) in SUN_SEGMENTS {
        let end = start + n as f64 * step;
        if above_horizon_deg <= end {
            return first + ((above_horizon_deg - start) / step).max(0.0);
        }
        first += n as f64;
    }
    (N_SUN - 1) as f64
}

/// The horizon's dip below the horizontal at radius `r`, rad.
pub fn dip(r: f64, bottom: f64) -> f64 {
    (bottom / r).min(1.0).acos()
}

/// The angle (rad) added to the sun's elevation to make the sun coordinate of a ray from radius
/// `r` with view zenith angle `theta` at azimuth `cos_phi` from the sun (cosine), `limb` when the
/// ray is in the limb rows' segment (between the horizontal and the horizon), `top` the top of
/// the atmosphere's radius. Rays below the horizon (and above the horizontal below
/// [`SKY_EXIT_ALTITUDE_M`] or away from the sun): the horizon's dip at the observer, so the
/// coordinate is the sun's elevation above the observer's horizon (sunset on one node at every
/// altitude).
/// Limb rays: towards the sun's elevation above the horizon of the ray's tangent point (its
/// lowest and densest point), γ cos φ + dip(r_t), with γ = θ − π/2 the angle between the
/// observer's and the tangent point's verticals and r_t = r cos γ (to first order in γ the
/// sun's elevation at the tangent point is its elevation at the observer + γ cos φ), weighted
/// by 1 − exp(−(r − r_t) / [`LIMB_SHADOW_SCALE_M`]) (aloft away from the sun times
/// 1 − [`limb_near_end`]): the earth's shadow reaches a deep limb
/// ray's tangent point at coordinate 0 at every altitude, row and azimuth, so the limb's fall
/// into the shadow stays near one sun node instead of moving across the nodes with the rows.
/// Sky rays (above the horizontal) aloft, looking towards the sun: the sun's elevation at the
/// ray's exit through the top, α max(cos φ, 0) higher (α the central angle from the observer to
/// the exit point, at distance x = the ray's length to the top `top`: α = atan2(x sin θ,
/// r + x cos θ)), weighted by a smoothstep over [`SKY_EXIT_ALTITUDE_M`] and by
/// [`sky_exit_azimuth`] (cos φ towards the sun, faded to 0 away from it). Seen from altitude in
/// deep twilight such a ray reaches the sunlit air only near its far end, so the sky brightens
/// (e.g. 88.5 km, 440 nm: 10-fold within a row) where the sun at the exit point clears the
/// earth's shadow: at a nearly constant coordinate on every row with the shift (within ±0.15° from
/// 0.5° to 16° of elevation), on a diagonal across the rows and sun nodes without it. Away from
/// the sun the ray's near end is the lit one, and the observer's horizon stays (the weight 0).
pub fn sun_shift(r: f64, theta: f64, cos_phi: f64, bottom: f64, top: f64, limb: bool) -> f64 {
    if limb {
        let r_t = r * (theta - 0.5 * PI).max(0.0).cos();
        limb_shift_with(
            r,
            theta,
            cos_phi,
            bottom,
            limb_tangent_weight(cos_phi, r - bottom, r - r_t),
        )
    } else if theta <= 0.5 * PI {
        let [h0, h1] = SKY_EXIT_ALTITUDE_M;
        let w = smoothstep(h0, h1, r - bottom) * sky_exit_azimuth(cos_phi);
        if w == 0.0 {
            return dip(r, bottom);
        }
        // The ray's exit through the top, x along it, and the central angle to it.
        let mu = theta.cos();
        let x = ray_length(r, mu, bottom, top, false);
        let alpha = (x * theta.sin()).atan2(r + x * mu);
        dip(r, bottom) + w * alpha
    } else {
        dip(r, bottom)
    }
}

/// [`sun_shift`] of a limb ray (from radius `r` at zenith `theta`, azimuth `cos_phi` from the
/// sun) with the tangent point's weight `w` given: dip + w (γ cos φ + dip(r_t) − dip)
/// ([`sun_shift`]: w = (1 − exp(−(r − r_t) / 50 km)) (1 − n), n = [`limb_near_end`]).
pub fn limb_shift_with(r: f64, theta: f64, cos_phi: f64, bottom: f64, w: f64) -> f64 {
    let gamma = (theta - 0.5 * PI).max(0.0);
    let r_t = r * gamma.cos();
    let tangent = gamma * cos_phi + dip(r_t, bottom);
    let observer = dip(r, bottom);
    observer + w * (tangent - observer)
}

/// The tangent point's weight w of a limb ray at altitude `h` (m) whose tangent point lies
/// `depth` (m) below it, azimuth `cos_phi` from the sun ([`sun_shift`]):
/// (1 − exp(−depth / [`LIMB_SHADOW_SCALE_M`])) (1 − [`limb_near_end`]).
pub fn limb_tangent_weight(cos_phi: f64, h: f64, depth: f64) -> f64 {
    (1.0 - (-depth / LIMB_SHADOW_SCALE_M).exp()) * (1.0 - limb_near_end(cos_phi, h, depth))
}

/// The sun coordinate's shift (rad) at which altitude node `h_n` (m) is read for a limb query
/// (from radius `r` at zenith `theta`, azimuth `cos_phi` from the sun). The node's texel at sun
/// node s_j holds its ray (the query's depth fraction y = (r − r_t) / (r − R) at the node,
/// depth y h_n) at the sun's elevation above the node's horizon s_j − w_n t_n, t = γ cos φ +
/// dip(r_t) − dip(r) (the tangent point's horizon relative to the observer's), w_n =
/// [`limb_tangent_weight`] at the node's altitude and depth. Read at w_n t_n + ω (t − t_n) above
/// the query's coordinate, it holds the query's ray with the sun ω (t − t_n) higher above the
/// observer's horizon and (1 − ω)(t_n − t) higher above the tangent point's: ω weighs the two
/// edges of the limb's radiance (where the sun clears the observer's own air, the near end, and
/// where it clears the tangent point). Three altitude ranges of the query, blended by
/// smoothsteps so nothing jumps:
/// - below [`LIMB_NODE_WEIGHT_ALTITUDE_M`] (11–20 km) the query's exponential
///   1 − exp(−(r − r_t) / [`LIMB_SHADOW_SCALE_M`]) times the node's 1 − n ([`limb_near_end`],
///   0 there) in place of w_n, ω = w_n: the coordinate the limb rows' focus was fitted in
///   ([`LIMB_BAND_DEPTH_M`]);
/// - above it ω = w_n, each node its own whole weight (seen from 35 km the nodes 27.9–42.4 km,
///   n from 0.02 to 1, held the query's limb ray at sun elevations 4–5° apart with the query's w
///   everywhere);
/// - above [`LIMB_NODE_QUERY_WEIGHT_M`] (25–29 km) ω moves to the query's own w, one
///   equivalence for every node a query reads: seen from 30 / 35 km, sun −4.75 / −5.25°, the
///   limb 0.3 / 0.25° above the horizon opposite the sun (680 nm), the altitude nodes alone over
///   exact slices erred by −16.7 / −26.5 % with ω = w_n (docs/lut.md).
pub fn limb_node_shift(r: f64, theta: f64, cos_phi: f64, bottom: f64, h_n: f64) -> f64 {
    let gamma = (theta - 0.5 * PI).max(0.0);
    let r_t = r * gamma.cos();
    let h = r - bottom;
    let y = if r > bottom {
        ((r - r_t) / h).clamp(0.0, 1.0)
    } else {
        0.0
    };
    // The node's weight: the query's exponential below LIMB_NODE_WEIGHT_ALTITUDE_M, the node's
    // own above (both times the node's 1 − n).
    let [b0, b1] = LIMB_NODE_WEIGHT_ALTITUDE_M;
    let b = smoothstep(b0, b1, h);
    let e_q = 1.0 - (-(r - r_t) / LIMB_SHADOW_SCALE_M).exp();
    let e_n = 1.0 - (-(y * h_n) / LIMB_SHADOW_SCALE_M).exp();
    let w_n = (e_q + b * (e_n - e_q)) * (1.0 - limb_near_end(cos_phi, h_n, y * h_n));
    let [h0, h1] = LIMB_NODE_QUERY_WEIGHT_M;
    let lambda = smoothstep(h0, h1, h);
    if lambda <= 0.0 {
        return limb_shift_with(r, theta, cos_phi, bottom, w_n);
    }
    let observer = dip(r, bottom);
    let t = gamma * cos_phi + dip(r_t, bottom) - observer;
    // The node's ray at the query's depth fraction (its γ from 1 − cos γ = y h_n / r_n).
    let r_n = bottom + h_n;
    let gamma_n = 2.0 * (0.5 * y * h_n / r_n).sqrt().min(1.0).asin();
    let t_n = gamma_n * cos_phi + dip(r_n - y * h_n, bottom) - dip(r_n, bottom);
    let w = limb_tangent_weight(cos_phi, h, r - r_t);
    let omega = w_n + lambda * (w - w_n);
    observer + w_n * t_n + omega * (t - t_n)
}

/// The query altitudes (m) between which [`limb_node_shift`]'s ω moves (smoothstep) from each
/// altitude node's own tangent-point weight to the query's.
pub const LIMB_NODE_QUERY_WEIGHT_M: [f64; 2] = [25_000.0, 29_000.0];

/// The query altitudes (m) over which [`limb_node_shift`] goes from the query's exponential
/// (below) to each node's whole tangent-point weight (above). Measured on the earth's shadow
/// seen aloft (grid / dense / between the dense check's samples, %; docs/lut.md): the node's
/// whole weight everywhere (version 21) 9.5 km 2.41 / 2.83 / 3.06, 12.5 km 2.89 / 2.89 / 2.29,
/// 17.5 km 4.94 / 6.67 / 2.62, off the asserted altitudes 16.25 km 4.17 / 4.17 / 3.37;
/// (11 km, 20 km): 2.41 / 2.42 / 3.06, **1.87 / 2.39 / 2.42**, **4.94 / 4.94** / 2.62, 16.25 km
/// 4.17 / 4.17 / 4.05; (12.5 km, 20 km) 12.5 km 2.11 / 2.39 / 2.66, 16.25 km between 3.89 %;
/// (15 km, 20 km) the same at 12.5 km, 16.25 km between 4.66 %; 20–40 km unchanged by each.
pub const LIMB_NODE_WEIGHT_ALTITUDE_M: [f64; 2] = [11_000.0, 20_000.0];

/// The share of a limb ray's weight towards the tangent point's sun coordinate ([`sun_shift`])
/// given back to the observer's horizon, at azimuth `cos_phi` (cosine) from the sun, altitude
/// `h` (m) and depth `depth` (m) of the ray's tangent point below the observer:
/// (1 − smoothstep(c₀, c₁, cos φ)) smoothstep(d₀, d₁, depth) smoothstep(h₀, h₁, h)
/// ([`LIMB_NEAR_END_AZIMUTH`], [`LIMB_NEAR_END_DEPTH_M`], [`LIMB_NEAR_END_ALTITUDE_M`]). Seen
/// from altitude away from the sun, every limb row brightens steepest with the sun's elevation
/// (ln L by 4–9 per degree; earth, 22–90 km, 100–180° from the sun) where the sun clears the
/// observer's own horizon, 0.4–0.9° above it on every row: a constant coordinate with the
/// observer's horizon, spread over 1–13° across the rows with the tangent point's weight
/// 1 − exp(−(r − r_t) / 50 km), which put that edge between sun nodes on a diagonal across
/// the rows and columns. Towards the sun the tangent point's weight stays.
pub fn limb_near_end(cos_phi: f64, h: f64, depth: f64) -> f64 {
    let [c0, c1] = LIMB_NEAR_END_AZIMUTH;
    let [d0, d1] = LIMB_NEAR_END_DEPTH_M;
    let [h0, h1] = LIMB_NEAR_END_ALTITUDE_M;
    (1.0 - smoothstep(c0, c1, cos_phi)) * smoothstep(d0, d1, depth) * smoothstep(h0, h1, h)
}

/// The azimuths (cosine from the sun) between which [`limb_near_end`] fades out (1 below the
/// first, 0 above the second). Measured (docs/lut.md; version 10: 3.45 / 14.5 %), the sky from
/// 20–100 km with the sun −6…5° / −12…−6°, on every limb row (no depth fade): (−0.5, 0.1)
/// 3.78 / 13.8 %, (−0.3, 0) 5.49 / 13.8 %, (−0.7, 0.2) 3.74 / 13.7 % (a shallow limb ray at
/// 43 km, the sun 6.4° above the observer's horizon, worse with the observer's horizon);
/// from 8–16 km of depth: 2.96 / 13.8 %. Version 15: (−0.5, 0.1) → (−0.6, 0.4), a wider fade
/// (66–127° from the sun): seen from 79.5 km, sun −8.75°, a limb ray 94° from the sun, 32 km deep,
/// is lit at its near end, and with (−0.5, 0.1) its coordinate moved by ~1.2° of sun within
/// 36° of azimuth (every axis erred by several %, the reader +12.42 %); (−0.6, 0.4): 9.67 %, the
/// sky from 20–100 km with the sun −6…5° 2.91 % either way.
pub const LIMB_NEAR_END_AZIMUTH: [f64; 2] = [-0.6, 0.4];
/// The tangent point's depths (m) below the observer between which [`limb_near_end`] fades in.
pub const LIMB_NEAR_END_DEPTH_M: [f64; 2] = [8_000.0, 16_000.0];
/// The altitudes (m) between which [`limb_near_end`] fades in (below, the limb rows' coordinate
/// of version 10, on which the limb rows' focus is fitted). A query reads the altitude nodes
/// around it at its own coordinate, so the fade starts above the nodes a 20 km query reads
/// (up to 26.9 km): faded in from 20 to 25 km, the earth's shadow seen from 20 km went 3.28 →
/// 7.05 % (`skyview_the_earth_shadow_seen_aloft`).
pub const LIMB_NEAR_END_ALTITUDE_M: [f64; 2] = [26_000.0, 40_000.0];

/// The depth of a limb ray's tangent point below the observer (m) over which the limb rows' sun
/// coordinate moves from the observer's horizon to the tangent point's ([`sun_shift`]): weight
/// 1 − exp(−(r − r_t) / this). Near the horizontal the air at the observer's altitude lights the
/// ray as much as the tangent point's. Aloft in twilight the limb's radiance has two edges: where
/// the shadow leaves the tangent point (at a constant coordinate with w = 1) and where it leaves
/// the observer's own air, the ray's near end (at a constant coordinate with w = 0; a limb ray
/// seen from 23 km opposite the sun brightens 3–7 fold there, at the same elevation of the sun
/// on every row); the smaller w keeps the second from crossing the rows between sun nodes.
/// Measured (docs/lut.md): 20, 30, 40, 45, 50, 55 and 60 km, the sky from 20–100 km with the sun
/// −6…5° 6.98, 5.04, 4.48, 4.11, 3.45, 3.96, 5.84 %.
pub const LIMB_SHADOW_SCALE_M: f64 = 50_000.0;

/// The altitudes (m) between which the sky rows' sun coordinate moves (smoothstep) from the
/// observer's horizon to the exit point's ([`sun_shift`]); below the first, the observer's.
pub const SKY_EXIT_ALTITUDE_M: [f64; 2] = [20_000.0, 40_000.0];

/// The azimuth weight of the sky rows' exit shift ([`sun_shift`]) at `cos_phi` (cosine of the
/// view's azimuth from the sun): cos φ towards the sun, and away from it cos φ (1 + cos φ / f)²
/// down to cos φ = −f ([`SKY_EXIT_AZIMUTH_FADE`]), 0 beyond: continuous with its slope at 90°
/// from the sun and at −f. The exit point's sun elevation is α cos φ above the observer's to
/// first order on both sides of 90°; with max(cos φ, 0) (layout version ≤ 20) the coordinate had
/// a kink at 90°, where the sky near the horizontal aloft falls steeply with the azimuth, and the
/// columns' cubic across it read the sky 1° up 90° from the sun, sun −6°, 37 % too dark at 40 km.
pub fn sky_exit_azimuth(cos_phi: f64) -> f64 {
    let f = SKY_EXIT_AZIMUTH_FADE;
    if cos_phi >= 0.0 {
        cos_phi
    } else if cos_phi > -f {
        cos_phi * (1.0 + cos_phi / f).powi(2)
    } else {
        0.0
    }
}

/// The cosine of the azimuth from the sun (negated) over which [`sky_exit_azimuth`] fades out
/// away from the sun (0.5: 120° from the sun, where the band maps above the earth's shadow fade
/// in).
pub const SKY_EXIT_AZIMUTH_FADE: f64 = 0.5;

/// The altitude nodes' map aloft ([`altitude_coord`]): x = √η + c (η^p − η^q), η = h / thickness,
/// `[c, p, q]`.
pub const ALTITUDE_TOP: [f64; 3] = [0.12, 8.0, 2.0];

/// Base abscissa of altitude node `k` ([`altitude_abscissa`] at its altitude): the integers
/// 0..=27 merged with [`ALTITUDE_INSERTED`], in increasing order.
pub fn altitude_node_x(k: usize) -> f64 {
    let mut x = 0.0;
    let mut inserted = ALTITUDE_INSERTED.iter().peekable();
    let mut next_base = 1.0;
    for _ in 0..k.min(N_ALT - 1) {
        match inserted.peek() {
            Some(&&i) if i < next_base => {
                x = i;
                inserted.next();
            }
            _ => {
                x = next_base;
                next_base += 1.0;
            }
        }
    }
    x
}

/// Altitude of node `k`, m, for an atmosphere `thickness` m thick: the root of
/// [`altitude_abscissa`]`(h) =` [`altitude_node_x`]`(k)` (by bisection; the map's ends are the
/// atmosphere's).
pub fn altitude_node_m(k: usize, thickness: f64) -> f64 {
    if k == 0 {
        return 0.0;
    }
    if k >= N_ALT - 1 {
        return thickness;
    }
    root_of_increasing(
        |h| altitude_abscissa(h, thickness),
        altitude_node_x(k),
        0.0,
        thickness,
        80,
    )
}

/// The root of `f(x) = target` for `f` increasing on `[lo, hi]`, by `iterations` bisections
/// (the inverses of the node maps).
fn root_of_increasing(
    f: impl Fn(f64) -> f64,
    target: f64,
    mut lo: f64,
    mut hi: f64,
    iterations: usize,
) -> f64 {
    for _ in 0..iterations {
        let mid = 0.5 * (lo + hi);
        if f(mid) < target {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    0.5 * (lo + hi)
}

/// Base altitude abscissa of altitude `h` (m): x (N_ALT_BASE − 1) with
/// x = √η + c (η^p − η^q), η = h / thickness, [c, p, q] = [`ALTITUDE_TOP`], the abscissa of the
/// altitude axis's Lagrange interpolation. The square root
/// alone (version 4) puts the nodes 7 km apart at the top; seen from there in deep twilight
/// the lit part of a ray lies just below the top of the atmosphere and appears and vanishes
/// between two nodes. The added term, 0 at both ends, moves nodes from the middle altitudes
/// (16 % sparser at 50 km) to the top (1 + 2c(p − q) = 2.4 times as dense at 100 km: the last
/// interval 3.3 km instead of 7.3 km), and moves the nodes below 10 km by less than 0.4 % of their coordinate (its
/// slope at the ground is 0).
pub fn altitude_abscissa(h: f64, thickness: f64) -> f64 {
    let e = (h / thickness).clamp(0.0, 1.0);
    let [c, p, q] = ALTITUDE_TOP;
    (e.sqrt() + c * (e.powf(p) - e.powf(q))) * (N_ALT_BASE - 1) as f64
}

/// Continuous altitude node coordinate of altitude `h` (m): the node k below it plus the
/// fraction of the way to node k + 1 in [`altitude_abscissa`].
pub fn altitude_coord(h: f64, thickness: f64) -> f64 {
    let x = altitude_abscissa(h, thickness);
    let mut k = 0;
    while k + 2 < N_ALT && altitude_node_x(k + 1) <= x {
        k += 1;
    }
    let (x0, x1) = (altitude_node_x(k), altitude_node_x(k + 1));
    k as f64 + ((x - x0) / (x1 - x0)).clamp(0.0, 1.0)
}

/// Zenith angle of the horizon seen from radius `r` (rad): π/2 + the horizon's dip.
pub fn horizon_zenith(r: f64, bottom: f64) -> f64 {
    PI - (bottom / r).min(1.0).asin()
}

/// View zenith angle (rad) of row `i` at radius `r` (see [`N_VIEW_SKY`]), and whether it looks
/// below the horizon; `sun_deg`: the sun's elevation above the observer's horizon (degrees),
/// on which the sky rows depend at low altitude in twilight ([`sky_row_focus`]).
pub fn view_node(i: usize, r: f64, bottom: f64, sun_deg: f64) -> (f64, bool) {
    view_theta(row_segment(i), i as f64, r, bottom, sun_deg)
}

/// The view segment of row `i`: 0 the sky rows, 1 the limb rows, 2 the rows below the horizon
/// (see [`N_VIEW_SKY`], [`N_VIEW_UP`]).
pub fn row_segment(i: usize) -> usize {
    if i < N_VIEW_SKY {
        0
    } else if i < N_VIEW_UP {
        1
    } else {
        2
    }
}

/// View zenith angle (rad) of the continuous row coordinate `row` of segment `seg` at radius
/// `r` and sun `sun_deg` above the observer's horizon (the inverse of [`view_coord`];
/// [`view_node`] at the rows).
pub fn view_theta(seg: usize, row: f64, r: f64, bottom: f64, sun_deg: f64) -> (f64, bool) {
    let th = horizon_zenith(r, bottom);
    if seg == 0 {
        let x = row / (N_VIEW_SKY - 1) as f64;
        let (c, k, w) = sky_row_focus(sun_deg, r - bottom);
        (0.5 * PI - sky_row_elevation(x, c, k, w).to_radians(), false)
    } else if seg == 1 {
        let x = (row - N_VIEW_SKY as f64) / (N_VIEW_LIMB - 1) as f64;
        let y = limb_depth_focused(x, sun_deg, r - bottom);
        // Tangent radius from r (horizontal) to the ground (the horizon).
        let r_t = r - (r - bottom) * y;
        (0.5 * PI + (r_t / r).min(1.0).acos(), false)
    } else {
        let x = (row - N_VIEW_UP as f64) / (N_VIEW_DOWN - 1) as f64;
        (th + (PI - th) * x * x, true)
    }
}

/// Row segment of view zenith `theta` at radius `r` (0 sky, 1 limb, 2 below the horizon) and
/// its continuous row coordinate (the inverse of [`view_node`]), the sun `sun_deg` above the
/// observer's horizon.
pub fn view_coord(theta: f64, r: f64, bottom: f64, sun_deg: f64) -> (usize, f64) {
    let th = horizon_zenith(r, bottom);
    if theta <= 0.5 * PI {
        let (c, k, w) = sky_row_focus(sun_deg, r - bottom);
        let x = sky_row((0.5 * PI - theta).to_degrees(), c, k, w);
        (0, x * (N_VIEW_SKY - 1) as f64)
    } else if theta < th {
        let y = limb_depth_of(theta, r, bottom);
        (
            1,
            N_VIEW_SKY as f64 + limb_row_focused(y, sun_deg, r - bottom) * (N_VIEW_LIMB - 1) as f64,
        )
    } else {
        let x = ((theta - th) / (PI - th)).clamp(0.0, 1.0).sqrt();
        (2, N_VIEW_UP as f64 + x * (N_VIEW_DOWN - 1) as f64)
    }
}

/// The sunlit band above the earth's shadow (the rise of the antisolar twilight sky from the
/// shadow's floor to the bright band above it, steepest in the red, where it is lit by sunlight
/// that grazed the ground): its elevation
/// (degrees, opposite the sun, where ln L rises fastest) with the sun `sun_deg` above the
/// observer's horizon at altitude `h` (m): u = [`BAND_SUN_DEG`] − s turned smoothly to 0
/// over [`BAND_SUN_SOFT_DEG`], c = ((a₀ + a₁ h) u +
/// (a₂ + a₃ h) u²)(1 + ρ (h − h₀)), h in km up to h₀ = 10 in the first factor
/// ([`BAND_CENTRE`]) and from h₀ to h₁ = 20 in the second (ρ = [`BAND_CENTRE_ALOFT`],
/// (h₀, h₁) = [`BAND_CENTRE_ALOFT_M`]). The coefficients are 0.85 times a fit to the `sky`
/// product opposite the sun (earth, 680 nm, 0–10 km, the sun's elevation −4.5…0°; within 0.3°
/// where the rise is steeper than a factor 1.6 per degree); ρ a fit of the same at 10–20 km
/// (the sun 2° below to 1.6° above the observer's horizon, within 0.45°; the fit at 10 km
/// extrapolated in h lies up to 2.3° too high at 10–20 km, held at 10 km up to 2.6° too low):
/// away from the antisolar azimuth the band lies lower (150° from the sun: about 0.7 of its
/// elevation at 180°), and the rows' focus sits between the two.
pub fn band_centre_deg(sun_deg: f64, h: f64) -> f64 {
    let w = BAND_SUN_SOFT_DEG;
    let x = (BAND_SUN_DEG - sun_deg) / w;
    // w ln(1 + eˣ), written to keep eˣ finite.
    let u = w * (x.max(0.0) + (-x.abs()).exp().ln_1p());
    let [h0, h1] = BAND_CENTRE_ALOFT_M;
    let km = (h / 1000.0).clamp(0.0, h0 / 1000.0);
    let aloft = 1.0
        + BAND_CENTRE_ALOFT * ((h - h0) / 1000.0).clamp(0.0, (h1 - h0) / 1000.0)
        + band_centre_top(h, BAND_CENTRE_TOP);
    let [a0, a1, a2, a3] = BAND_CENTRE;
    (((a0 + a1 * km) * u + (a2 + a3 * km) * u * u) * aloft).min(45.0)
}

/// The altitudes (m) between which [`band_centre_deg`] grows by [`BAND_CENTRE_ALOFT`] per km
/// (below the first the low fit's altitude dependence, above the second by [`BAND_CENTRE_TOP`]).
pub const BAND_CENTRE_ALOFT_M: [f64; 2] = [10_000.0, 20_000.0];
/// [`band_centre_deg`]'s growth per km between the altitudes of [`BAND_CENTRE_ALOFT_M`].
pub const BAND_CENTRE_ALOFT: f64 = 0.03;
/// The band's growth per km above the second altitude of [`BAND_CENTRE_ALOFT_M`] up to
/// [`BAND_CENTRE_TOP_M`] (held above), in [`band_centre_deg`] and [`band_slice_centre_deg`] alike
/// ([`band_centre_top`]). Measured on the `sky` product (680 nm, the elevation where ln L per
/// metre rises fastest 180° from the sun, the sun at the observer's horizon): 5.2 / 5.5 / 5.8 /
/// 6.3 / 6.7 / 7.2° seen from 20 / 22.5 / 25 / 30 / 35 / 40 km, about 0.025 per km of the fit's
/// 1.3 at 20 km (held at 20 km: 5.0°).
pub const BAND_CENTRE_TOP: f64 = 0.025;
/// The altitude (m) up to which the band grows by [`BAND_CENTRE_TOP`] per km.
pub const BAND_CENTRE_TOP_M: f64 = 40_000.0;

/// The band's growth above the second altitude of [`BAND_CENTRE_ALOFT_M`] at altitude `h` (m):
/// `rate` per km ([`BAND_CENTRE_TOP`] in [`band_centre_deg`], [`BAND_SLICE_TOP`] in
/// [`band_slice_centre_deg`]) up to [`BAND_CENTRE_TOP_M`], added to their factors (both 1.3 at
/// 20 km).
pub fn band_centre_top(h: f64, rate: f64) -> f64 {
    let h1 = BAND_CENTRE_ALOFT_M[1];
    rate * ((h - h1) / 1000.0).clamp(0.0, (BAND_CENTRE_TOP_M - h1).max(0.0) / 1000.0)
}

/// The sun coordinate (degrees above the observer's horizon) at which the band of
/// [`band_centre_deg`] reaches the horizontal.
pub const BAND_SUN_DEG: f64 = 2.0;
/// The width (degrees) over which [`band_centre_deg`]'s u = [`BAND_SUN_DEG`] − s turns to 0: u =
/// w ln(1 + exp((2° − s)/w)) (version 14: max(2° − s, 0), whose corner at s = 2° the slices' map
/// [`band_slice_elevation`] carried into the sun nodes: seen from 6.5–15 km with the sun 1.9°
/// above the observer's horizon, 2–2.5° up opposite the sun in the blue, where no sharp band
/// lies, the nodes at 1.5° and 2° were read 1.2° apart. The sun axis alone (the `sky` product at
/// the nodes at the mapped elevations, 440 nm) erred +2.6 / +2.0 / +3.2 / +4.3 % at 6.5 / 8 / 11 /
/// 15 km with the corner, 0.1 % with w = 0.5°, 0.2–0.4 % with 0.25°; the band's own cases at
/// s ≈ 0.1° unchanged).
pub const BAND_SUN_SOFT_DEG: f64 = 0.5;
/// [`band_centre_deg`]'s coefficients: a₀, a₁ (per km), a₂, a₃ (per km) (0.85 × the fit's
/// 0.49, 0.06, 0.185, 0.023).
pub const BAND_CENTRE: [f64; 4] = [0.4165, 0.051, 0.157_25, 0.019_55];
/// The sky rows' focus strength on the band ([`sky_row_focus`], [`sky_row_elevation`]).
pub const BAND_FOCUS: f64 = 14.0;
/// Sun coordinates (degrees) between which the focus fades in (the first two: 0 below the
/// first, full above the second) and out (the last two). The focus draws the rows towards the
/// band (12–45° high with the sun 4–8° below the observer's horizon) and away from the
/// horizontal, where towards the sun in deep twilight the glow brightens steeply: with the
/// fade-in from −7° to −4° (version 11) the rows alone erred by +17 % at 5 km (sun −7°, 0.25°
/// above the horizontal towards the sun, 440 nm; 0.7 % with rows twice as dense) and −11.5 %
/// at 20 km (sun −9°); from −5° to −3° the grid of that glow (0–20 km, sun −12…−6°) reads
/// 9.6 % at 5 km and 8.4 % at 20 km (−6°…−3.5°: 12.9 / 10.2 %), and the grids of the band
/// itself (the earth's shadow rising and seen aloft) are unchanged.
pub const BAND_SUN_RANGE: [f64; 4] = [-5.0, -3.0, 1.0, 5.0];
/// Altitudes (m) between which the focus and the maps relative to the band fade out (full below
/// the first, none above the second). Version 18: from 35–40 km (20–25 km before):
/// seen from 20–40 km the band is as sharp as from 20 km (ln L per metre rises by 2.5–2.8 per
/// degree of elevation 180° from the sun, the sun at the observer's horizon, 680 nm), and with
/// the fade at 20–25 km the reader erred by up to 46.5 / 69.6 / 118 % seen from 22.5 / 25 /
/// 30 km (the sky about 5–6° up 165–180° from the sun; at 22.5 km the rows +22 % alone, the
/// 23.8 km node's rows +50 %, the altitude axis +11 %; at 25 km the columns +61 % alone).
pub const BAND_ALTITUDE_M: [f64; 2] = [35_000.0, 40_000.0];
/// The band's elevations (degrees, [`band_centre_deg`]) between which the focus fades out
/// (full below the first, none above the second). The focus draws the rows towards the band
/// and away from the horizontal (the last sky row 0.5–1.2° up instead of 0.2° with the band
/// 9–12° high), where towards the sun the twilight glow brightens steeply: the rows alone erred
/// by +9.2 % at 5 km (sun −6°, 0.25° above the horizontal towards the sun, 440 nm; +0.7 % with
/// a quarter of the focus), +6.8 % at 10 km (sun −6°). With the band this high its rise lies
/// above the views near the horizon, and the rows without focus follow it (10 km, sun −6°,
/// 8° up opposite the sun: −0.7 %), but not a band 5.7° high at 20 km (+31 % without focus).
/// The maps relative to the band keep their weight ([`band_map_weight`]): with them faded too,
/// the band seen from 20 km (sun −6°, 150° from the sun, 8.5° up) read 7.1 % instead of 3.1 %.
pub const BAND_CENTRE_RANGE_DEG: [f64; 2] = [6.0, 9.0];
/// The share of the sky rows' focus kept above [`BAND_CENTRE_RANGE_DEG`] (version 13: 0). Seen
/// from 6.5–20 km with the sun 5–6° below the horizontal the band is 8.5–10° high, and the
/// unfocused rows (2–3° apart there) miss its rise: the rows alone (4-node Lagrange over the
/// rows, the `sky` product at the rows' elevations, 680 nm, 150–180° from the sun) erred by
/// 5.9 / 7.7 / 8.1 / 9.4 / 10.7 % at 6.5 / 9.5 / 12.5 / 15 / 20 km, with a quarter of the focus
/// 1.0 / 2.2 / 4.0 % at 6.5 / 9.5 / 12.5 km; the glow towards the sun near the horizontal (the
/// reason for the fade) 2.1 → 2.3 % at 0–15 km (0.15 / 0.4 of the focus: 3.1 / 1.6 % at 9.5 km,
/// 2.1 / 3.8 % on the glow).
pub const BAND_CENTRE_FLOOR: f64 = 0.25;

fn smoothstep(a: f64, b: f64, x: f64) -> f64 {
    let t = ((x - a) / (b - a)).clamp(0.0, 1.0);
    t * t * (3.0 - 2.0 * t)
}

/// The sky rows' focus at sun `sun_deg` above the observer's horizon and altitude `h` (m): the
/// focus's elevation c_f = c p, p = q + (P [`BAND_ANTISOLAR`] − q) v, q = 1 + (P
/// [`BAND_ANTISOLAR`] − 1) a (c the band's, [`band_centre_deg`], degrees; P =
/// [`BAND_FOCUS_PLACE_ALOFT`]), the focus strength k = W (l (1 + G a) + F (1 − l)) (1 + V v)
/// [`band_focus_strength`] and the focus's width w (in x₀, [`sky_row_elevation`]): W the fades
/// of [`BAND_SUN_RANGE`] and [`BAND_ALTITUDE_M`] ([`band_map_weight`]), l = 1 − smoothstep over
/// [`BAND_CENTRE_RANGE_DEG`] of c, F = [`BAND_CENTRE_FLOOR`], G = [`BAND_FOCUS_HIGH`], a = l
/// smoothstep over [`BAND_FOCUS_PLACE_M`] of h, V = [`BAND_FOCUS_WIDE`], v = l times the fades
/// of [`BAND_FOCUS_WIDTH_M`] (smoothsteps 3t² − 2t³), w = v max(x₀(e_w) − x₀(c_f), 0), e_w =
/// max((c [`BAND_ANTISOLAR`] + δ) R − δ, [`BAND_FOCUS_WIDTH_FLOOR_DEG`]) the band's elevation
/// at −cos φ = R = [`BAND_FOCUS_WIDTH_AZIMUTH`] ([`band_relative_elevation`], δ =
/// [`band_azimuth_depth_deg`]); k = 0 by day, deep in twilight and aloft: the rows of version 3.
pub fn sky_row_focus(sun_deg: f64, h: f64) -> (f64, f64, f64) {
    let [c0, c1] = BAND_CENTRE_RANGE_DEG;
    let [h0, h1] = BAND_FOCUS_PLACE_M;
    let [w0, w1, w2, w3] = BAND_FOCUS_WIDTH_M;
    let c = band_centre_deg(sun_deg, h);
    // The share of the focus under a low band (1 − high), where it moves and grows aloft.
    let low = 1.0 - smoothstep(c0, c1, c);
    let aloft = smoothstep(h0, h1, h) * low;
    let wide = smoothstep(w0, w1, h) * (1.0 - smoothstep(w2, w3, h)) * low;
    let f = band_map_weight(sun_deg, h)
        * (low * (1.0 + BAND_FOCUS_HIGH * aloft) + BAND_CENTRE_FLOOR * (1.0 - low));
    let place = 1.0 + (BAND_FOCUS_PLACE_ALOFT * BAND_ANTISOLAR - 1.0) * aloft;
    // Where the focus is wide its upper end sits at P of the antisolar band.
    let place = place + (BAND_FOCUS_PLACE_ALOFT * BAND_ANTISOLAR - place) * wide;
    let k = f * band_focus_strength(h) * (1.0 + BAND_FOCUS_WIDE * wide);
    if wide <= 0.0 {
        return (c * place, k, 0.0);
    }
    let delta = band_azimuth_depth_deg(h);
    let e_w = ((c * BAND_ANTISOLAR + delta) * BAND_FOCUS_WIDTH_AZIMUTH - delta)
        .max(BAND_FOCUS_WIDTH_FLOOR_DEG);
    let x0 = |e: f64| 1.0 - (e / 90.0).clamp(0.0, 1.0).sqrt();
    (c * place, k, (x0(e_w) - x0(c * place)).max(0.0) * wide)
}

/// The sky rows' focus's elevation aloft as a fraction of the band's elevation opposite the sun
/// ([`BAND_ANTISOLAR`] · [`band_centre_deg`]; below [`BAND_FOCUS_PLACE_M`] 1 / [`BAND_ANTISOLAR`]
/// = 0.85 of it, between its elevations 150° and 180° from the sun). Seen from 8–20 km the rows
/// alone (the `sky` product at the rows, Lagrange over their logarithms, 680 nm) erred by
/// +4.3 / +7.2 / +4.0 / −5.2 % at 8 / 11 / 12.5 / 20 km 3–5° up opposite the sun, at the band
/// there, above the focus at 0.85 of it; with 0.92 and [`BAND_FOCUS_HIGH`] from 6–12 km (and
/// [`BAND_SUN_SOFT_DEG`]) the earth's shadow seen aloft (the reader, sun every 0.25°, 120–180°
/// from the sun) 4.55 / 6.25 / 4.54 / 9.90 → 3.78 / 3.82 / 4.16 / 7.70 % there (docs/lut.md,
/// version 15's scan: 1 or 0.85 of it worse at 12.5 or 20 km).
pub const BAND_FOCUS_PLACE_ALOFT: f64 = 0.92;
/// The altitudes (m) between which the focus's place moves (smoothstep) to
/// [`BAND_FOCUS_PLACE_ALOFT`] of the antisolar band and its strength grows by
/// [`BAND_FOCUS_HIGH`] ([`sky_row_focus`]), both under a low band only (faded out with
/// [`BAND_CENTRE_RANGE_DEG`]: the share [`BAND_CENTRE_FLOOR`] kept under a high band is version
/// 14's, for the glow towards the sun near the horizontal, which with both there read 3.26 %
/// at 10 km, sun −6°, 0.25° up towards the sun, 440 nm, against 2.94 % at the ground).
/// Version 17: from 4–10 km (version 15: 6–12 km). Seen from 6.5 km (sun −2.25°, 2.25° up
/// opposite the sun, 680 nm) the query lies between the focus and the antisolar band, and the
/// rows alone (the `sky` product at each altitude node's rows, Lagrange over their logarithms,
/// then over the altitude nodes) erred by +3.50 %, +2.62 % from 4–10 km; on the reader's dense
/// check of the earth's shadow seen from 6.5 km 3.49 → 2.52 % (3–9 km: 2.51 %, 5–11 km: 3.12 %,
/// 4–12 km: 2.93 %; docs/lut.md).
pub const BAND_FOCUS_PLACE_M: [f64; 2] = [4_000.0, 10_000.0];
/// How much stronger the sky rows' focus is under a low band from [`BAND_FOCUS_PLACE_M`] up
/// ([`sky_row_focus`]).
pub const BAND_FOCUS_HIGH: f64 = 0.3;
/// The −cos φ (φ the azimuth from the sun; 140°) down to whose band elevation the sky rows'
/// focus is wide under a low band within [`BAND_FOCUS_WIDTH_M`] ([`sky_row_focus`]). The reader
/// reads each azimuth column at its own elevation relative to the band
/// ([`band_relative_elevation`]), lower than the antisolar band away from 180°, while a slice's
/// rows have one focus: seen from 8 and 11 km the rows within the columns 130–160° from the sun,
/// 0.8–2° below the focus, erred by +2.1 to +4.0 % (680 nm). Version 18.
pub const BAND_FOCUS_WIDTH_AZIMUTH: f64 = 0.766;
/// The lowest elevation (degrees) of the wide focus's lower end ([`BAND_FOCUS_WIDTH_AZIMUTH`]).
pub const BAND_FOCUS_WIDTH_FLOOR_DEG: f64 = 0.25;
/// The altitudes (m) between which the focus's width fades in (the first two, smoothstep) and
/// out (the last two).
pub const BAND_FOCUS_WIDTH_M: [f64; 4] = [6_500.0, 8_000.0, 11_000.0, 12_500.0];
/// How much stronger the sky rows' focus is where it is wide ([`sky_row_focus`]): the wide
/// focus alone (×1) spreads the rows over the width, 6.97 / 8.17 % seen from 11 / 12.5 km
/// without the fades in altitude, 2.79 / 3.46 % at 11 / 9.5 km with them; ×1.5 the earth's shadow
/// seen aloft within 3 % (docs/lut.md, version 18).
pub const BAND_FOCUS_WIDE: f64 = 0.5;

/// The weight (0…1) of the maps relative to the band ([`band_slice_elevation`],
/// [`band_relative_elevation`]) at sun `sun_deg` above the observer's horizon and altitude `h`
/// (m): the fades of [`BAND_SUN_RANGE`] and [`BAND_ALTITUDE_M`], the sky rows' focus without its
/// fade in the band's elevation ([`BAND_CENTRE_RANGE_DEG`]): a band too high for the rows'
/// focus is still read relative to its place across the sun, altitude and azimuth nodes.
pub fn band_map_weight(sun_deg: f64, h: f64) -> f64 {
    let [s0, s1, s2, s3] = BAND_SUN_RANGE;
    let [h0, h1] = BAND_ALTITUDE_M;
    smoothstep(s0, s1, sun_deg)
        * (1.0 - smoothstep(s2, s3, sun_deg))
        * (1.0 - smoothstep(h0, h1, h))
}

/// How much stronger the sky rows' focus is from [`BAND_FOCUS_GROWTH_M`] up
/// ([`band_focus_strength`]).
pub const BAND_FOCUS_GROWTH: f64 = 0.7;
/// The altitudes (m) between which the focus grows (smoothstep) by [`BAND_FOCUS_GROWTH`].
pub const BAND_FOCUS_GROWTH_M: [f64; 2] = [1_000.0, 5_000.0];

/// How much stronger again the sky rows' focus is from [`BAND_FOCUS_ALOFT_M`] up
/// ([`band_focus_strength`]).
pub const BAND_FOCUS_ALOFT: f64 = 0.6;
/// The altitudes (m) between which the focus grows (smoothstep) by [`BAND_FOCUS_ALOFT`].
pub const BAND_FOCUS_ALOFT_M: [f64; 2] = [5_000.0, 8_000.0];

/// The sky rows' full focus strength at altitude `h` (m): [`BAND_FOCUS`] (1 + g smoothstep(h₀,
/// h₁, h)) (1 + g' smoothstep(h₂, h₃, h)), g = [`BAND_FOCUS_GROWTH`], (h₀, h₁) =
/// [`BAND_FOCUS_GROWTH_M`], g' = [`BAND_FOCUS_ALOFT`], (h₂, h₃) = [`BAND_FOCUS_ALOFT_M`]. The
/// band above the earth's shadow sharpens with the observer's altitude (measured on the `sky`
/// product at 680 nm, sun 0.3–0.6° above the observer's horizon: ln L rises by 0.85 per degree
/// of elevation at 1 km, 1.8 at 2.5 km, 2.5 at 5 km), so the rows there are denser at the band;
/// from 8 km up the rows alone (4-node Lagrange over the focused rows, the `sky` product at the
/// rows' elevations) still erred by 9.8 % at 8 km and 16 % at 20 km opposite the sun, at the
/// band (0.3–1 % with rows twice as dense), 1.5 % with g' = 0.6.
pub fn band_focus_strength(h: f64) -> f64 {
    let [h0, h1] = BAND_FOCUS_GROWTH_M;
    let [h2, h3] = BAND_FOCUS_ALOFT_M;
    BAND_FOCUS
        * (1.0 + BAND_FOCUS_GROWTH * smoothstep(h0, h1, h))
        * (1.0 + BAND_FOCUS_ALOFT * smoothstep(h2, h3, h))
}

/// The band's growth per km aloft in the slices' map ([`band_slice_centre_deg`]) at the first
/// and the second altitude of [`BAND_CENTRE_ALOFT_M`] (linear between them, held above).
/// Measured on the `sky` product (680 nm, 180° from the sun, the sun 0.13° above the observer's
/// horizon, the elevation where ln L rises fastest, every 0.05°): the band at the altitude nodes
/// 8.8 / 11.2 / 13.9 / 15.3 / 16.9 / 18.5 / 20.2 km lies 3.35 / 3.70 / 4.05 / 4.25 / 4.40 / 4.60 /
/// 4.80° up; [`band_centre_deg`] (growth 0.03 per km) puts it at 3.29 / 3.65 / 3.93 / 4.09 /
/// 4.25 / 4.42 / 4.58°, this growth at 3.29 / 3.71 / 4.06 / 4.22 / 4.36 / 4.49 / 4.58°. On the
/// earth's shadow seen from 8 / 9.5 / 11 km (the grid, [`band_slice_elevation`] alone changed)
/// 1.92 / 4.82 / 2.33 % → 1.14 / 2.32 / 1.85 %; a growth of 0.045 throughout: 20 km 2.94 →
/// 3.99 %; 0.04 to 0.02: 9.5 km 3.18 %; 0.06 to 0: 9.5 km 2.61 % (docs/lut.md).
pub const BAND_SLICE_ALOFT: [f64; 2] = [0.045, 0.015];

/// The band's elevation (degrees) opposite the sun over [`BAND_ANTISOLAR`] in the slices' map
/// ([`band_slice_elevation`]) with the sun `sun_deg` above the observer's horizon at altitude
/// `h` (m): [`band_centre_deg`]'s low fit at min(h, h₀) times
/// g = 1 + a x + (b − a) x² / (2 L), x = h − h₀ in km up to L = h₁ − h₀
/// ((h₀, h₁) = [`BAND_CENTRE_ALOFT_M`], (a, b) = [`BAND_SLICE_ALOFT`]): the growth per km a at
/// h₀ falling linearly to b at h₁, where g = 1.3 as in [`band_centre_deg`], and above h₁
/// [`band_centre_top`] (as in [`band_centre_deg`]). From 10 to 15 km
/// the band seen opposite the sun rises faster with the observer's altitude than that fit's
/// growth of 0.03 per km (within 0.05° of this growth); from 17 km up it lies up to 0.2° above
/// both, but the altitude nodes read there with a faster growth err more at 20 km
/// ([`BAND_SLICE_ALOFT`]). The sky rows' focus and the columns' map keep [`band_centre_deg`]
/// (the texels do not depend on this map).
pub fn band_slice_centre_deg(sun_deg: f64, h: f64) -> f64 {
    let [h0, h1] = BAND_CENTRE_ALOFT_M;
    let [a, b] = BAND_SLICE_ALOFT;
    let l = ((h1 - h0) / 1000.0).max(1e-3);
    let x = ((h - h0) / 1000.0).clamp(0.0, l);
    let g = 1.0 + a * x + (b - a) * x * x / (2.0 * l) + band_centre_top(h, BAND_SLICE_TOP);
    (band_centre_deg(sun_deg, h.min(h0)) * g).min(45.0)
}

/// The query's altitudes (m) between which the slices' map ([`band_slice_elevation`]) comes to
/// act from −δ up through the horizontal instead of from the horizontal up (smoothstep; a slice
/// moved below the horizontal is read on the limb rows, as the columns' map reads a column,
/// [`band_row`]). Seen from 8–15 km, 120° from the sun, the band lies at the horizontal with the
/// sun 1.1–1.3° above the observer's horizon, between sun nodes 0.5° apart, where the map was
/// the identity (the sun nodes alone −2.7…−4.3 %).
pub const BAND_SLICE_THROUGH_M: [f64; 2] = [5_000.0, 8_000.0];

/// The band's growth per km in the slices' map ([`band_slice_centre_deg`]) above the second
/// altitude of [`BAND_CENTRE_ALOFT_M`] up to [`BAND_CENTRE_TOP_M`] (the sky rows' focus and the
/// columns' map: [`BAND_CENTRE_TOP`]).
pub const BAND_SLICE_TOP: f64 = 0.015;

/// The query's altitudes (m) between which the slices' map ([`band_slice_elevation`]) comes to
/// be faded in with the query's −cos φ over [`BAND_ANTISOLAR_RANGE`], as the columns' map
/// ([`band_relative_elevation`]; below them it acts at every azimuth).
pub const BAND_SLICE_AZIMUTH_M: [f64; 2] = [20_000.0, 25_000.0];

/// The elevation (degrees) at which a slice of sun node `sun_n` (its sun coordinate, degrees
/// above the observer's horizon) and altitude node `h_n` (m) is read for a query at elevation
/// `eps` (degrees) with the sun `sun_q` above the observer's horizon at altitude `h_q`: where
/// `eps` lies relative to the band above the earth's shadow at the query's sun and altitude,
/// moved to the same place relative to the band at the node's. The band's height above −δ
/// (δ = [`band_depth_deg`], [`band_relative_elevation`]) at any azimuth is
/// (C + δ)(−cos φ), C = [`BAND_ANTISOLAR`] · [`band_centre_deg`], so the map is affine about
/// −δ, e = (ε + δ_q)(C_n + δ_n)/(C_q + δ_q) − δ_n, whatever the azimuth: the shadow's floor
/// (anchored at the horizon) and the band's rise (which climbs about 2° per degree the sun
/// sinks) keep their places, so the interpolation over the sun and altitude nodes follows the
/// band instead of crossing it (Lagrange interpolation of a function along a moving feature:
/// the coordinate relative to the feature, as for the limb's sun coordinate, [`sun_shift`]).
/// Faded to the identity as [`band_relative_elevation`]: with the query's [`band_map_weight`], above 2–4
/// times the band's height and below [`BAND_HORIZON_DEG`] (the horizontal, where the sky rows
/// meet the limb rows), or aloft below −δ ([`BAND_SLICE_THROUGH_M`]).
pub fn band_slice_elevation(
    eps: f64,
    sun_q: f64,
    h_q: f64,
    sun_n: f64,
    h_n: f64,
    cos_phi: f64,
) -> f64 {
    let c_q = band_slice_centre_deg(sun_q, h_q);
    let w_q = band_map_weight(sun_q, h_q);
    if w_q < 1e-6 {
        return eps;
    }
    let (d_q, d_n) = (band_depth_deg(h_q), band_depth_deg(h_n));
    // The band's height above −δ opposite the sun (at least 0.1°: the ratio's floor).
    let height_q = (c_q * BAND_ANTISOLAR + d_q).max(0.1);
    let height_n = (band_slice_centre_deg(sun_n, h_n) * BAND_ANTISOLAR + d_n).max(0.1);
    let w = height_q.max(0.5);
    // Aloft from −δ up through the horizontal ([`BAND_SLICE_THROUGH_M`]).
    let [a0, a1] = BAND_SLICE_THROUGH_M;
    let through = smoothstep(a0, a1, h_q);
    let horizon = smoothstep(0.0, BAND_HORIZON_DEG, eps) * (1.0 - through)
        + band_horizon_taper(eps, d_q) * through;
    // Aloft faded in with the query's −cos φ, as the columns' map ([`BAND_SLICE_AZIMUTH_M`]).
    let (lo, hi) = BAND_ANTISOLAR_RANGE;
    let [z0, z1] = BAND_SLICE_AZIMUTH_M;
    let azimuth = 1.0 - smoothstep(z0, z1, h_q) * (1.0 - smoothstep(lo, hi, -cos_phi));
    let fade = w_q * (1.0 - smoothstep(2.0 * w, 4.0 * w, eps)) * horizon * azimuth;
    let mapped = (eps + d_q) * height_n / height_q - d_n;
    eps + fade * (mapped - eps)
}

/// The band's elevation (degrees) opposite the sun relative to [`band_centre_deg`] (the rows'
/// focus sits at 0.85 of it, between its elevations at 150° and 180° from the sun).
pub const BAND_ANTISOLAR: f64 = 1.0 / 0.85;
/// How deep below the horizontal (degrees per km of the observer's altitude, up to
/// [`BAND_DEPTH_TOP_M`]) the point lies from which the band's elevation scales with −cos φ
/// ([`band_relative_elevation`], [`band_depth_deg`]).
/// Measured on the `sky` product (680 nm, the elevation where ln L rises fastest at 150° and
/// 180° from the sun): 1.2–1.8° at 2.5 km and 1.5–3° at 5 km with the sun 0.5° below to 1.5°
/// above the observer's horizon (where the band is sharpest), ≈ 0.25–1° at 1 km (version 5:
/// 0.25 per km).
pub const BAND_DEPTH_PER_KM: f64 = 0.5;
/// The altitude (m) up to which the band's depth grows ([`band_depth_deg`]). Measured on the
/// `sky` product (680 nm, the band's elevation at 120–180° from the sun fitted as
/// (c₁₈₀ + δ)(−cos φ) − δ, the sun 2° below to 0.2° above the observer's horizon): δ ≈ 0.9–1.4°
/// at 6 km, 1.3–2.3° at 10–20 km, not the 5° of the depth grown to 10 km (with which the
/// columns' map moved the band below the horizontal 100–120° from the sun aloft: 9.1 % at
/// 14 km, 119° from the sun).
pub const BAND_DEPTH_TOP_M: f64 = 5_000.0;

/// The band's depth δ (degrees below the horizontal) at altitude `h` (m): [`BAND_DEPTH_PER_KM`]
/// times h in km up to [`BAND_DEPTH_TOP_M`].
pub fn band_depth_deg(h: f64) -> f64 {
    BAND_DEPTH_PER_KM * (h / 1000.0).clamp(0.0, BAND_DEPTH_TOP_M / 1000.0)
}
/// The band's depth (degrees) in the columns' map ([`band_relative_elevation`]) from
/// [`BAND_AZIMUTH_DEPTH_ALOFT_M`] up ([`band_azimuth_depth_deg`]). Measured on the `sky` product
/// (680 nm, the elevation where ln L rises fastest at 120–180° from the sun, fitted as
/// (c₁₈₀ + δ)(−cos φ) − δ, within 0.1°; the sun 0.75° below to 0.75° above the observer's
/// horizon): δ = 1.4–2.2° at 6.5–20 km (1.5–1.8° where the band is sharpest), not
/// [`band_depth_deg`]'s 2.5°. On the dense check of the band seen aloft (sun every 0.25°, 120–180°
/// every 15°; 6.5 / 8 / 9.5 / 11 / 12.5 / 15 / 20 km) 1.8° from 12.5–17 km took 5.72 / 7.28 /
/// 5.66 / 6.91 / 9.25 / 7.57 / 11.27 % to 5.72 / 7.28 / 5.69 / 6.95 / 8.63 / 5.97 / 10.37 %; from
/// 5–8 km (1.6° / 2°) it was worse at 11–12.5 km (8.40 / 11.50 %; 6.99 / 9.84 %): the slices'
/// map keeps δ = 2.5° (1.6° there: 8 km 7.28 → 8.35 %).
pub const BAND_AZIMUTH_DEPTH_ALOFT: f64 = 1.8;
/// The altitudes (m) between which the columns' map's depth moves (smoothstep) from
/// [`band_depth_deg`] to [`BAND_AZIMUTH_DEPTH_ALOFT`].
pub const BAND_AZIMUTH_DEPTH_ALOFT_M: [f64; 2] = [12_500.0, 17_000.0];

/// The band's depth δ (degrees) in the columns' map at altitude `h` (m): [`band_depth_deg`]
/// moved to [`BAND_AZIMUTH_DEPTH_ALOFT`] by smoothstep(h₀, h₁, h), (h₀, h₁) =
/// [`BAND_AZIMUTH_DEPTH_ALOFT_M`].
pub fn band_azimuth_depth_deg(h: f64) -> f64 {
    let [h0, h1] = BAND_AZIMUTH_DEPTH_ALOFT_M;
    let d = band_depth_deg(h);
    d + (BAND_AZIMUTH_DEPTH_ALOFT - d) * smoothstep(h0, h1, h)
}

/// The −cos φ (φ the azimuth from the sun) over which [`band_relative_elevation`] fades in
/// (smoothstep; 102° to 120°); below the first the columns' heights are held at it. Nearer 90°
/// the band lies at or below the horizon and its height above −δ vanishes: a ratio of such
/// heights would move an elevation of 5° at 95° from the sun to 23° at 112° (measured: 26 % at
/// the ground with the sun at −3.4°, 95° from the sun, in the blue, with the heights held at 0.05).
pub const BAND_ANTISOLAR_RANGE: (f64, f64) = (0.2, 0.5);
/// The elevation (degrees) below which [`band_relative_elevation`] returns to the identity at
/// the horizontal (smoothstep from 0), where the sky rows meet the limb rows, which have no
/// such map: the reader is continuous across the horizontal.
pub const BAND_HORIZON_DEG: f64 = 0.5;

/// The elevation (degrees) that lies, at azimuth `cos_phi_a` (cosine) from the sun, where the
/// elevation `eps` (degrees) lies at the query's azimuth `cos_phi_q` relative to the band above
/// the earth's shadow, with the sun `sun_deg` above the observer's horizon at altitude `h` (m).
/// Away from the antisolar point the band lies lower: from the earth's shadow's geometry (its
/// edge a great circle of the sky about the antisolar point in the sky of a distant observer,
/// whose elevation falls as −cos φ; measured on the `sky` product at 680 nm from 1–8 km, sun
/// −3…0.5° above the observer's horizon, within 0.2° from 112° to 180°), its elevation at
/// azimuth φ is c(φ) = (c₁₈₀ + δ)(−cos φ) − δ, δ = [`band_azimuth_depth_deg`], c₁₈₀ the band's
/// elevation opposite the sun ([`BAND_ANTISOLAR`] · [`band_centre_deg`]). The map is affine
/// about −δ, (ε + δ)·(c_a + δ)/(c_q + δ) − δ (the band onto the band), faded to the identity
/// above 2–4 times the band's height (at least 0.5°), at the horizontal ([`BAND_HORIZON_DEG`])
/// and with the maps' weight ([`band_map_weight`]), and faded in with the query's −cos φ
/// ([`BAND_ANTISOLAR_RANGE`]: the identity within 102° of the sun). The reader evaluates each azimuth column at this elevation, so
/// the interpolation over the columns follows the band.
pub fn band_relative_elevation(
    eps: f64,
    sun_deg: f64,
    h: f64,
    cos_phi_q: f64,
    cos_phi_a: f64,
) -> f64 {
    let c = band_centre_deg(sun_deg, h);
    let weight = band_map_weight(sun_deg, h);
    if weight < 1e-6 {
        return eps;
    }
    let delta = band_azimuth_depth_deg(h);
    let height = c * BAND_ANTISOLAR + delta;
    // (c_a + δ) / (c_q + δ): the band's height above −δ at the column over the query's.
    let (lo, hi) = BAND_ANTISOLAR_RANGE;
    let ratio = (-cos_phi_a).max(lo) / (-cos_phi_q).max(lo);
    let w = height.max(0.5);
    let fade = weight * (1.0 - smoothstep(2.0 * w, 4.0 * w, eps)) * smoothstep(lo, hi, -cos_phi_q);
    eps + band_horizon_taper(eps, delta) * fade * (eps + delta) * (ratio - 1.0)
}

/// Where the columns' map of [`band_relative_elevation`] acts near the horizontal: from −δ
/// (below the horizontal, where its displacement (ε + δ)(ratio − 1) vanishes, so the map is
/// continuous there) up, through the horizontal into the limb rows. Seen from a few km in
/// low twilight the band's edge crosses the horizontal at the azimuth where −cos φ =
/// δ/(c₁₈₀ + δ) (about 130° from the sun at 5 km with the sun 0.8° above the observer's
/// horizon), a corner of ln L in the azimuth that the columns (17° apart there) cannot follow
/// at one elevation; read relative to the band they do. Below −δ, the identity.
pub fn band_horizon_taper(eps: f64, delta: f64) -> f64 {
    if eps >= -delta {
        1.0
    } else {
        0.0
    }
}

/// The row segment (0 the sky rows, 1 the limb rows) and continuous row of elevation `e`
/// (degrees) for an observer at altitude `h` (m) on rows of focus (c, k) ([`sky_row_focus`]):
/// where the columns' map ([`band_relative_elevation`]) moves an elevation across the
/// horizontal, a column is read on the other segment's rows (the limb's at the query's
/// altitude, as the reader reads every altitude node's limb rows at the query's depth, on the
/// slice's limb rows, `limb` = [the query's sun coordinate, the slice's, the slice's altitude],
/// [`limb_slice_depth`], [`limb_row_focus`]).
pub fn band_row(
    e: f64,
    h: f64,
    bottom: f64,
    focus: (f64, f64, f64),
    limb: [f64; 3],
) -> (usize, f64) {
    if e >= 0.0 || h <= 0.0 {
        let (c, k, w) = focus;
        return (0, sky_row(e, c, k, w) * (N_VIEW_SKY - 1) as f64);
    }
    // The ray's tangent point's depth below the observer: r − r_t = 2 r sin²(e/2).
    let half = 0.5 * e.to_radians();
    let y = (2.0 * (bottom + h) * half.sin() * half.sin() / h).clamp(0.0, 1.0);
    (
        1,
        N_VIEW_SKY as f64
            + limb_row_focused(
                limb_slice_depth(y, limb[0], h, limb[1], limb[2]),
                limb[1],
                limb[2],
            ) * (N_VIEW_LIMB - 1) as f64,
    )
}

/// Elevation (degrees) of the sky rows' coordinate x ∈ [0, 1] (0 the zenith, 1 the horizontal)
/// with focus (c, k) ([`sky_row_focus`]). Without focus (k = 0) version 3's rows: elevation
/// 90° (1 − x₀)², x₀ = x. With it, x₀ (the unfocused coordinate) = x_c + sinh(A + x (B − A)) / k,
/// x_c = 1 − √(c / 90°) the band's, A = asinh(−k x_c), B = asinh(k (1 − x_c)): the rows are
/// k / (B − A) times as dense at the band as without the focus (and sparser far from it), the
/// focus moving with the band as the sun sets (the band's row coordinate −A / (B − A) still
/// moves, about as much as in version 3's rows: a row coordinate fixed on the band would need a
/// kink in the map or a focus solved by iteration). A focus of width w > 0 ([`sky_row_focus`]):
/// x₀ = G⁻¹(A + x (B − A)), G = [`focus_warp`] (as dense as at x_c over [x_c, x_c + w]); w = 0
/// the same.
pub fn sky_row_elevation(x: f64, c: f64, k: f64, w: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    let x0 = if k < 1e-6 {
        x
    } else {
        let xc = 1.0 - (c / 90.0).clamp(0.0, 1.0).sqrt();
        let (a, b) = focus_ends(xc, k, w);
        focus_unwarp(a + x * (b - a), xc, k, w).clamp(0.0, 1.0)
    };
    90.0 * (1.0 - x0) * (1.0 - x0)
}

/// The inverse of [`sky_row_elevation`]: x₀ = 1 − √(ε / 90°), x = (G(x₀) − A) / (B − A).
pub fn sky_row(elevation_deg: f64, c: f64, k: f64, w: f64) -> f64 {
    let x0 = 1.0 - (elevation_deg / 90.0).clamp(0.0, 1.0).sqrt();
    if k < 1e-6 {
        return x0;
    }
    let xc = 1.0 - (c / 90.0).clamp(0.0, 1.0).sqrt();
    let (a, b) = focus_ends(xc, k, w);
    ((focus_warp(x0, xc, k, w) - a) / (b - a)).clamp(0.0, 1.0)
}

/// The focused coordinate G(x₀) of a focus of strength `k` over [x_c, x_c + w]: asinh(k (x₀ −
/// x_c)) below x_c, k (x₀ − x_c) across the focus, k w + asinh(k (x₀ − x_c − w)) past it.
pub fn focus_warp(x0: f64, xc: f64, k: f64, w: f64) -> f64 {
    if x0 < xc {
        (k * (x0 - xc)).asinh()
    } else if x0 <= xc + w {
        k * (x0 - xc)
    } else {
        k * w + (k * (x0 - xc - w)).asinh()
    }
}

/// The inverse of [`focus_warp`].
pub fn focus_unwarp(g: f64, xc: f64, k: f64, w: f64) -> f64 {
    if g < 0.0 {
        xc + g.sinh() / k
    } else if g <= k * w {
        xc + g / k
    } else {
        xc + w + (g - k * w).sinh() / k
    }
}

/// A = G(0), B = G(1) of [`focus_warp`].
pub fn focus_ends(xc: f64, k: f64, w: f64) -> (f64, f64) {
    (focus_warp(0.0, xc, k, w), focus_warp(1.0, xc, k, w))
}

/// The limb rows' depth y = (r − r_t) / (r − bottom) of the ray's tangent point below the
/// observer, at the rows' uniform coordinate x ∈ [0, 1]: y = 2x² − x³. Just below the horizontal
/// the ray gains the air behind its tangent point over a length √(2 r (r − r_t)), so the limb's
/// radiance grows as √y there (a square-root cusp no polynomial in y follows); in x it is
/// smooth (y ≈ 2x²), and at the horizon the rows are as dense in y as uniform ones (dy/dx = 1).
pub fn limb_depth(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    x * x * (2.0 - x)
}

/// The inverse of [`limb_depth`]: the root in [0, 1] of x³ − 2x² + y = 0, in the trigonometric
/// form of the cubic's three real roots (x = 2/3 + (4/3) cos(acos(1 − 27y/16)/3 − 2π/3)).
pub fn limb_row(y: f64) -> f64 {
    let y = y.clamp(0.0, 1.0);
    let phi = (1.0 - 27.0 / 16.0 * y).clamp(-1.0, 1.0).acos();
    (2.0 / 3.0 + 4.0 / 3.0 * (phi / 3.0 - 2.0 * PI / 3.0).cos()).clamp(0.0, 1.0)
}

/// The depth y = (r − r_t) / (r − bottom) ∈ [0, 1] of the tangent point of a limb ray of zenith
/// angle `theta` seen from radius `r` (1 at or below the ground).
pub fn limb_depth_of(theta: f64, r: f64, bottom: f64) -> f64 {
    if r <= bottom {
        return 1.0;
    }
    let r_t = r * (theta - 0.5 * PI).cos();
    ((r - r_t) / (r - bottom)).clamp(0.0, 1.0)
}

/// The row coordinate (∈ [0, 1]) of the unfocused coordinate `x0` ∈ [0, 1] on rows focused
/// with strength `k` at `xc`: (asinh(k (x₀ − x_c)) − A) / (B − A), A = asinh(−k x_c),
/// B = asinh(k (1 − x_c)) (the sky rows' focus, [`sky_row_elevation`]; k / (B − A) times as
/// dense at x_c, sparser far from it; the identity for k = 0).
pub fn focus_coord(x0: f64, xc: f64, k: f64) -> f64 {
    if k < 1e-6 {
        return x0;
    }
    let a = (-k * xc).asinh();
    let b = (k * (1.0 - xc)).asinh();
    (((k * (x0 - xc)).asinh() - a) / (b - a)).clamp(0.0, 1.0)
}

/// The inverse of [`focus_coord`]: x₀ = x_c + sinh(A + x (B − A)) / k.
pub fn focus_inverse(x: f64, xc: f64, k: f64) -> f64 {
    if k < 1e-6 {
        return x;
    }
    let a = (-k * xc).asinh();
    let b = (k * (1.0 - xc)).asinh();
    (xc + (a + x.clamp(0.0, 1.0) * (b - a)).sinh() / k).clamp(0.0, 1.0)
}

/// The depth (m) below the observer of the tangent point of the limb rays where the band above
/// the earth's shadow lies seen from altitude, D = d₀ + d₁ s + d₂ s² (s the sun's elevation above
/// the observer's horizon in degrees, the limb rows' sun coordinate, [`sun_shift`]):
/// `[d₀, d₁, d₂]`. Fitted on the `sky` product (earth, 680 nm, the depth where ln L per metre
/// of ray rises fastest along the limb, 12.5–20 km, 150° and 180° from the sun, s −1.6…0.4°,
/// where the rise is steeper than 8 per unit of the rows' coordinate: within 0.43 km rms; the
/// depth hardly depends on the altitude (at s = 0: 8.4 km at 11–15 km, 7.3 km at 20 km), it
/// lies 3 km deeper 120° from the sun).
pub const LIMB_BAND_DEPTH_M: [f64; 3] = [8_200.0, -7_760.0, -900.0];
/// The limb rows' focus strength on that band ([`limb_row_focus`]).
pub const LIMB_BAND_FOCUS: f64 = 6.0;
/// The sun coordinates (degrees) between which the limb rows' focus fades in (the first two)
/// and out (the last two).
pub const LIMB_BAND_SUN_RANGE: [f64; 4] = [-3.0, -2.0, 0.0, 0.75];
/// The least band depth (m) in the ratio of [`limb_slice_depth`] (near the end of the focus's
/// sun range the fit falls to 0 where the band reaches the horizontal: with 1 km and the focus
/// fading out at s = 0.5…1.5° the ratio moved the limb 2° above the observer's horizon across
/// the horizon's blue glow, 49 % at 15 km and 65 % at 20 km, sun −2°).
pub const LIMB_BAND_DEPTH_FLOOR_M: f64 = 2_500.0;
/// The exponent a of the altitudes' ratio (h_q / h_n)^a in [`limb_slice_depth`]: 1 maps the
/// depth in metres (the band's depth hardly depends on the altitude), 0 the depth's fraction of
/// the altitude; with 1 an altitude node below the band's depth (at 12.5 km the 8.8 km node) is
/// read at its horizon. Measured on the grid of the earth's shadow seen aloft, 12.5 / 20 km:
/// a = 0: 5.37 / 9.09 %, 0.5: 2.72 / 3.28 %, 1: 12.1 / 3.28 %.
pub const LIMB_BAND_ALTITUDE_EXPONENT: f64 = 0.5;
/// The largest depth fraction of the band (D / h) in [`limb_slice_depth`]'s two-piece map (the
/// band's depth at or below the ground would make the map's second piece singular).
pub const LIMB_BAND_MAX_FRACTION: f64 = 0.95;
/// The band's depth fractions (D / h) between which [`limb_slice_depth`]'s second piece (the
/// horizon held) fades out (smoothstep) to version 10's map affine about the horizontal: where
/// the band nears the horizon the second piece is squeezed (measured at 20 km, sun −4°, 150°
/// from the sun, 0.3° above the horizon, D/h = 0.87: +4.1 % held, +2.7 % affine). Version 19:
/// (0.5, 0.8) → (0.65, 0.9); seen from 12.5 km, sun −2.625°, the limb 0.2° above the horizon
/// 157.5° from the sun (D/h = 0.73) the slices of the sun nodes below were read at depth
/// 0.97–0.99, on their sparse rows near the horizon (the reader +4.79 %, 3.42 % held longer; the
/// shadow seen from 15–20 km unchanged, 17.5 km 8.72 % either way).
pub const LIMB_BAND_HORIZON_HELD: [f64; 2] = [0.65, 0.9];
/// The altitudes (m) between which the limb rows' focus fades in (the first two) and out (the
/// last two). Version 20: out from 25–30 km (20–25 km before): the limb just above the horizon
/// 165–180° from the sun seen from 22.5 / 25 km on the dense check of the earth's shadow 26.9 /
/// 39.5 → 5.7 / 23.0 % (30 km 54.5 → 54.6 %; 22.5 km 6.8 % with [`LIMB_BAND_DEEPEST`]), the
/// random samples of the sun −6…5° from 20–100 km 2.89 % either way (version 18's 19.6 % with
/// it was the slices' band map, since faded in with the azimuth aloft). Out from 30–35 km: 5.1 /
/// 18.7 / **61.7** %; from 35–40 km: 5.1 / 18.7 / 61.7 %, 35 km 166 → 175 % (docs/lut.md, "Tried
/// and not kept").
pub const LIMB_BAND_ALTITUDE_M: [f64; 4] = [6_000.0, 9_000.0, 25_000.0, 30_000.0];

/// The limb rows' focus at sun coordinate `sun_deg` (degrees, [`sun_shift`]) and altitude `h`
/// (m): (x_c, k), x_c = [`limb_row`] of the band's depth D / h ([`LIMB_BAND_DEPTH_M`], clamped
/// to [0, 1]), k = [`LIMB_BAND_FOCUS`] times the smoothsteps of [`LIMB_BAND_SUN_RANGE`] and
/// [`LIMB_BAND_ALTITUDE_M`] (0 elsewhere: the limb rows of versions 2–9). Seen from 10–20 km
/// with the sun just above the observer's horizon, the sky opposite the sun rises from the
/// earth's shadow to the band above it below the horizontal, on the limb rows: ln L per metre
/// rises by up to 27 per unit of the rows' coordinate (1.8 per row at 20 km; 680 nm), at a
/// depth moving 7 km per degree of the sun, so the rows concentrate there as the sky rows do on
/// the band above the horizontal ([`sky_row_focus`]).
pub fn limb_row_focus(sun_deg: f64, h: f64) -> (f64, f64) {
    let f = limb_band_fade(sun_deg, h);
    if f <= 0.0 || h <= 0.0 {
        return limb_edge_focus(sun_deg, h);
    }
    let [d0, d1, d2] = LIMB_BAND_DEPTH_M;
    let depth = d0 + d1 * sun_deg + d2 * sun_deg * sun_deg;
    (limb_row((depth / h).clamp(0.0, 1.0)), f * LIMB_BAND_FOCUS)
}

/// The fade ∈ [0, 1] of the limb rows' focus on the band ([`limb_row_focus`] below 30 km): the
/// smoothsteps of [`LIMB_BAND_SUN_RANGE`] and [`LIMB_BAND_ALTITUDE_M`]; the slices' depth map
/// ([`limb_slice_depth`]) and the limb's sun stencil ([`limb_sun_stencil`]) act with it (not
/// with the focus on the shadow's edge aloft, [`limb_edge_focus`]).
pub fn limb_band_fade(sun_deg: f64, h: f64) -> f64 {
    let [s0, s1, s2, s3] = LIMB_BAND_SUN_RANGE;
    let [h0, h1, h2, h3] = LIMB_BAND_ALTITUDE_M;
    if h <= 0.0 {
        return 0.0;
    }
    smoothstep(s0, s1, sun_deg)
        * (1.0 - smoothstep(s2, s3, sun_deg))
        * smoothstep(h0, h1, h)
        * (1.0 - smoothstep(h2, h3, h))
}

/// The depth (m) below the observer of the earth's shadow's edge on the limb seen from 35–45 km,
/// D = d₀ + d₁ s (s the limb rows' sun coordinate, degrees): `[d₀, d₁]`. Measured on the `sky`
/// product (earth, 680 nm, the depth where ln L per metre of ray falls fastest along the limb,
/// 150° and 180° from the sun): 37.1 km 13.4 / 12.5 km at s = 0, 14.4 km at s = 0.30°; 42.4 km
/// 12.2 km at s = 0, 14.3 km at s = 0.28° (ln L falling by 36–53 per unit of depth fraction,
/// 2.5–4 per limb row without a focus); at s ≤ −0.6° no edge there (ln L within 4 per unit).
/// The focus 1.2 km below the fit (d₀ 12.8 → 14 km) took the earth's shadow seen from 35 / 40 km
/// (dense) from 25.2 / 21.1 to 24.0 / 16.2 % (docs/lut.md).
pub const LIMB_EDGE_DEPTH_M: [f64; 2] = [14_000.0, 6_000.0];
/// The limb rows' focus strength on that edge ([`limb_edge_focus`]). 10 instead of 6: 40 km
/// 10.4–11.4 % but the limb 0.25° above the horizon seen from 35 km 29–31 % (the rows near the
/// horizon sparser).
pub const LIMB_EDGE_FOCUS: f64 = 6.0;
/// The sun coordinates (degrees) between which the focus on the edge fades in (the first two)
/// and out (the last two).
pub const LIMB_EDGE_SUN_RANGE: [f64; 4] = [-0.75, -0.25, 0.5, 1.0];
/// The altitudes (m) between which the focus on the edge fades in (the first two) and out (the
/// last two): above the band's focus ([`LIMB_BAND_ALTITUDE_M`], out by 30 km).
pub const LIMB_EDGE_ALTITUDE_M: [f64; 4] = [33_000.0, 36_000.0, 45_000.0, 50_000.0];

/// The limb rows' focus on the earth's shadow's edge seen from 35–45 km at sun coordinate
/// `sun_deg` (degrees) and altitude `h` (m): (x_c, k), x_c = [`limb_row`] of
/// [`LIMB_EDGE_DEPTH_M`]'s depth / h, k = [`LIMB_EDGE_FOCUS`] times the smoothsteps of
/// [`LIMB_EDGE_SUN_RANGE`] and [`LIMB_EDGE_ALTITUDE_M`]. From 35 km up, with the sun just
/// above the observer's horizon, the edge crosses the limb 12–15 km below the observer, deeper
/// than the band's focus ([`LIMB_BAND_DEPTH_M`], 5.8 km at s = 0.3°), which is off there.
pub fn limb_edge_focus(sun_deg: f64, h: f64) -> (f64, f64) {
    let [s0, s1, s2, s3] = LIMB_EDGE_SUN_RANGE;
    let [h0, h1, h2, h3] = LIMB_EDGE_ALTITUDE_M;
    let f = smoothstep(s0, s1, sun_deg)
        * (1.0 - smoothstep(s2, s3, sun_deg))
        * smoothstep(h0, h1, h)
        * (1.0 - smoothstep(h2, h3, h));
    if f <= 0.0 || h <= 0.0 {
        return (0.0, 0.0);
    }
    let [d0, d1] = LIMB_EDGE_DEPTH_M;
    (
        limb_row(((d0 + d1 * sun_deg) / h).clamp(0.0, 1.0)),
        f * LIMB_EDGE_FOCUS,
    )
}

/// The depth (m) below the observer of the band above the earth's shadow seen on the limb at
/// sun coordinate `sun_deg` ([`LIMB_BAND_DEPTH_M`]), at least 1 km (where the ratio of two of
/// them is taken, [`limb_slice_depth`]).
pub fn limb_band_depth_m(sun_deg: f64) -> f64 {
    let [d0, d1, d2] = LIMB_BAND_DEPTH_M;
    let s = sun_deg.clamp(LIMB_BAND_SUN_RANGE[0] - 1.0, LIMB_BAND_SUN_RANGE[3]);
    (d0 + d1 * s + d2 * s * s).max(LIMB_BAND_DEPTH_FLOOR_M)
}

/// The depth y_n ∈ [0, 1] at which the limb rows of a slice of sun coordinate `sun_n` and
/// altitude `h_n` (m) are read for a query at depth `y` with sun coordinate `sun_q` at altitude
/// `h_q`: where the query lies relative to the band above the earth's shadow, moved to the same
/// place relative to the band at the slice's sun. The band lies at a depth D(s) in metres
/// ([`limb_band_depth_m`]) that hardly depends on the altitude: its depth fraction
/// y_b = D(s_q)/h_q at the query's is moved to y_b ρ, ρ = (h_q/h_n)^a D(s_n)/D(s_q)
/// (a = [`LIMB_BAND_ALTITUDE_EXPONENT`]; both fractions at most [`LIMB_BAND_MAX_FRACTION`]),
/// linearly from the horizontal (depth 0, where the limb meets the sky rows) to the band and
/// from the band to the horizon (depth 1), both ends fixed (the second piece faded to y ρ where
/// the band nears the horizon, [`LIMB_BAND_HORIZON_HELD`]); faded with the query's focus
/// ([`limb_row_focus`]'s fades). Without it the interpolation over the sun and altitude nodes at
/// one depth fraction crosses the band (it moves 7 km of depth per degree of the sun, and a
/// fraction of different altitudes is a different depth); with the map affine about the
/// horizontal alone (version 10) the slices of a query near the horizon were read up to a
/// quarter of the depth away, across the horizon's glow (the sun axis alone +8.5 % at 20 km,
/// 120° from the sun, 440 nm, 0.29° above the horizon).
pub fn limb_slice_depth(y: f64, sun_q: f64, h_q: f64, sun_n: f64, h_n: f64) -> f64 {
    let f = limb_band_fade(sun_q, h_q);
    if f <= 0.0 || h_n <= 0.0 {
        return y;
    }
    let d = limb_slice_map(y, sun_q, h_q, sun_n, h_n);
    y + f * (d.clamp(0.0, 1.0) - y)
}

/// [`limb_slice_depth`]'s map before its fade and clamp: the depth fraction in the slice of
/// sun coordinate `sun_n` and altitude `h_n` (m) of the depth `y` of a query with sun coordinate
/// `sun_q` at altitude `h_q` (m), above 1 where it lies past the slice's horizon.
pub fn limb_slice_map(y: f64, sun_q: f64, h_q: f64, sun_n: f64, h_n: f64) -> f64 {
    let dq = limb_band_depth_m(sun_q);
    let rho = (h_q / h_n).powf(LIMB_BAND_ALTITUDE_EXPONENT) * limb_band_depth_m(sun_n) / dq;
    let yb = (dq / h_q).min(LIMB_BAND_MAX_FRACTION);
    let ybn = (yb * rho).min(LIMB_BAND_MAX_FRACTION);
    if y <= yb {
        y * rho
    } else {
        // The horizon held where the band lies well above it (w = 1), not where it nears it.
        let [w0, w1] = LIMB_BAND_HORIZON_HELD;
        let w = 1.0 - smoothstep(w0, w1, yb);
        y * rho + w * (ybn + (y - yb) * (1.0 - ybn) / (1.0 - yb) - y * rho)
    }
}

/// [`limb_slice_depth`] before its clamp: y + f (m − y), m = [`limb_slice_map`], f the query's
/// focus fade (y where f = 0): the depth at which the slice of sun coordinate `sun_n` and
/// altitude `h_n` (m) is read for a query at depth `y` with sun coordinate `sun_q` at altitude
/// `h_q` (m), above 1 past the slice's horizon.
pub fn limb_slice_reach(y: f64, sun_q: f64, h_q: f64, sun_n: f64, h_n: f64) -> f64 {
    let f = limb_band_fade(sun_q, h_q);
    if f <= 0.0 || h_n <= 0.0 {
        return y;
    }
    y + f * (limb_slice_map(y, sun_q, h_q, sun_n, h_n) - y)
}

/// Whether [`limb_slice_depth`] reads the slice of sun coordinate `sun_n` and altitude `h_n`
/// (m) past its horizon for a query at depth `y` with sun coordinate `sun_q` at altitude `h_q`
/// (m): [`limb_slice_reach`] > 1 (the depth is then clamped towards the horizon). Where the
/// band lies near the horizon (20 km up, the sun 1–2° below the tangent point's horizon) the
/// band of the next lower sun node lies past it, and a query just past its own band would read
/// that slice at its horizon, across the band.
pub fn limb_slice_past_horizon(y: f64, sun_q: f64, h_q: f64, sun_n: f64, h_n: f64) -> bool {
    limb_slice_reach(y, sun_q, h_q, sun_n, h_n) > 1.0
}

/// The deepest depth (a fraction of the altitude) at which the limb rows read the slice of the
/// sun interval's lower node ([`limb_sun_stencil`]). Seen from 17.5 km, sun −3.75°, the limb
/// 0.5° above the horizon 165° from the sun (the band at D/h = 0.955, at the horizon), the
/// 16.88 km slice of the lower node read at 0.989 on its sparse rows near the horizon (rows
/// +11.8 %, the sun and altitude nodes over exact slices +6.27 %, 680 nm). Scan (the earth's
/// shadow seen from 12.5 / 17.5 km, between the dense check's samples / dense): 1 (none left
/// out) 3.42 / 8.72 %, 0.97 2.66 / 6.49 %.
pub const LIMB_BAND_DEEPEST: f64 = 0.97;

/// Altitude node `h_n`'s (m) sun stencil on the limb rows for a query at depth `y` with sun
/// coordinate `sun_q` at altitude `h_q` (m) whose sun stencil is `ss` (at node coordinate
/// `deg_q`, degrees; `nodes` as [`Stencil::with_nodes`]): where the interval's lower node's
/// slice would be read deeper than [`LIMB_BAND_DEEPEST`] ([`limb_slice_reach`]) the line
/// through the two nodes above it, extrapolated ([`Stencil::below`]); else without the lower
/// nodes read past the horizon ([`limb_sun_lowest`]). Two-node stencils as they are.
#[allow(clippy::too_many_arguments)]
pub fn limb_sun_stencil(
    ss: Stencil,
    y: f64,
    sun_q: f64,
    h_q: f64,
    h_n: f64,
    thickness: f64,
    deg_q: f64,
    nodes: usize,
) -> Stencil {
    if nodes <= 2 || ss.len <= 2 {
        return ss;
    }
    let b = warp_strength(h_n, thickness);
    let focused = limb_band_fade(sun_q, h_q) > 0.0 && h_n > 0.0;
    if focused && ss.t > 0.0 && ss.i0 + 2 < N_SUN {
        let s_i0 = sun_warp(sun_node_deg(ss.i0), b, 0.0);
        if limb_slice_reach(y, sun_q, h_q, s_i0, h_n) > LIMB_BAND_DEEPEST {
            return Stencil::below(ss.i0 + 1, sun_node_deg, deg_q);
        }
    }
    if ss.i0 == ss.first {
        return ss;
    }
    let lo = limb_sun_lowest(y, sun_q, h_q, h_n, thickness, ss.first, ss.i0);
    if lo == ss.first {
        return ss;
    }
    Stencil::with_nodes(
        ss.i0 as f64 + ss.t,
        lo,
        N_SUN - 1,
        sun_node_deg,
        deg_q,
        nodes,
    )
}

/// The lowest sun node the limb rows of altitude node `h_n` (m) read for a query at depth `y`
/// with sun coordinate `sun_q` at altitude `h_q` (m) whose sun stencil starts at node `first`
/// and whose interval starts at `i0`: the first node from `first` to `i0` whose slice
/// ([`sun_warp`] of its node at `h_n`) is not read past its horizon
/// ([`limb_slice_past_horizon`]), at most `i0` (the interval's nodes are kept). The sun
/// stencil of that altitude node starts there (quadratic through the interval and the node
/// above it instead of cubic through a node read at its horizon).
pub fn limb_sun_lowest(
    y: f64,
    sun_q: f64,
    h_q: f64,
    h_n: f64,
    thickness: f64,
    first: usize,
    i0: usize,
) -> usize {
    let b = warp_strength(h_n, thickness);
    let mut lo = first;
    for j in first..i0 {
        if limb_slice_past_horizon(y, sun_q, h_q, sun_warp(sun_node_deg(j), b, 0.0), h_n) {
            lo = j + 1;
        }
    }
    lo
}

/// The limb rows' coordinate (∈ [0, 1]) of depth `y` (see [`limb_depth`]) on the rows of sun
/// coordinate `sun_deg` and altitude `h` (m): [`focus_coord`] of [`limb_row`] with
/// [`limb_row_focus`].
pub fn limb_row_focused(y: f64, sun_deg: f64, h: f64) -> f64 {
    let (xc, k) = limb_row_focus(sun_deg, h);
    focus_coord(limb_row(y), xc, k)
}

/// The inverse of [`limb_row_focused`]: the depth of the limb rows' coordinate `x`.
pub fn limb_depth_focused(x: f64, sun_deg: f64, h: f64) -> f64 {
    let (xc, k) = limb_row_focus(sun_deg, h);
    limb_depth(focus_inverse(x, xc, k))
}

/// The twilight warp's strength at the top of the atmosphere ([`warp_strength`]).
pub const SUN_WARP: f64 = 3.0;

/// The twilight warp's strength b at altitude `h` of an atmosphere `thickness` thick:
/// [`SUN_WARP`] · √(h / thickness) (∝ the horizon's distance ρ ≈ √(2 R h); 0 at the ground).
pub fn warp_strength(h: f64, thickness: f64) -> f64 {
    SUN_WARP * (h / thickness).clamp(0.0, 1.0).sqrt()
}

/// The sun's elevation above the observer's horizon (deg) at sun coordinate `t` (deg; the sun
/// nodes are uniform in it), warp strength `b` ([`warp_strength`]) and centre `c` (deg,
/// [`sun_warp_centre`]; 0 but on the sky rows towards the sun aloft): inside [`SUN_WARP_RANGE`]
/// s = c + e sinh(b (t − c) / e) / sinh(b), e = c + 8° below c and 6° − c above (the range's
/// ends stay where they are), outside s = t. Why: from an observer at altitude h the sunlight
/// grazes the earth at the tangent altitude h_t ≈ ρ s − R s²/2 (ρ = √(r² − R²)), and the
/// earth's shadow above it rises by about ρ |s| for s < 0; the sky's logarithm varies on the
/// scale of the air's scale height in those altitudes, i.e. on ~0.5° of s at the ground but
/// ~0.05° at 100 km (ρ = 1100 km). The warp makes the nodes near s = c b / sinh(b) times
/// denser (0.30 at the top: 0.15°), coarser towards the range's ends where the sky aloft is
/// either fully lit or dark.
pub fn sun_warp(t: f64, b: f64, c: f64) -> f64 {
    let (lo, hi) = (SUN_WARP_RANGE.0, SUN_WARP_RANGE.1);
    if b < 1e-6 || t <= lo || t >= hi {
        return t;
    }
    let e = if t < c { c - lo } else { hi - c };
    c + e * (b * (t - c) / e).sinh() / b.sinh()
}

/// The inverse of [`sun_warp`].
pub fn sun_unwarp(s: f64, b: f64, c: f64) -> f64 {
    let (lo, hi) = (SUN_WARP_RANGE.0, SUN_WARP_RANGE.1);
    if b < 1e-6 || s <= lo || s >= hi {
        return s;
    }
    let e = if s < c { c - lo } else { hi - c };
    c + e * ((s - c) * b.sinh() / e).asinh() / b
}

/// The twilight warp's centre c (deg; [`sun_warp`]) at altitude `h` (m) on the view rows'
/// segment `seg` (0 sky, 1 limb, 2 below the horizon), `cos_phi` the azimuth's cosine from the
/// sun, in an atmosphere from `bottom` to `top` (radii, m): on the sky rows towards the sun
/// [`SUN_WARP_CENTRE`] max(cos φ, 0)² smoothstep([`SUN_WARP_CENTRE_ALTITUDE_M`], h)
/// (dip(r) − dip(top)), 0 elsewhere. Seen from 50–100 km in deep twilight a steep sky ray towards
/// the sun brightens sharply where sunlight grazing the ground starts to reach the top of the
/// atmosphere above the observer: the sun dip(top) below the observer's horizontal, i.e.
/// s = dip(r) − dip(top) (−2.3° at 59 km, where the warp centred at 0 had its nodes 0.35° apart;
/// 0.23° centred there). Away from the sun (the sky rows near the horizontal) and on the limb
/// rows the sky's steepest edge stays where the sun clears the observer's own horizon and the
/// tangent point's, at s ≈ 0, and the centre with it.
pub fn sun_warp_centre(h: f64, bottom: f64, top: f64, seg: usize, cos_phi: f64) -> f64 {
    let [h0, h1] = SUN_WARP_CENTRE_ALTITUDE_M;
    let w = smoothstep(h0, h1, h);
    if seg != 0 || cos_phi <= 0.0 || w <= 0.0 {
        return 0.0;
    }
    SUN_WARP_CENTRE
        * cos_phi
        * cos_phi
        * w
        * (dip(bottom + h, bottom) - dip(top, bottom)).to_degrees()
}

/// The weight of the twilight warp's centre on the sky rows towards the sun ([`sun_warp_centre`]).
pub const SUN_WARP_CENTRE: f64 = 1.0;

/// The altitudes (m) between which the twilight warp's centre fades in ([`sun_warp_centre`]):
/// above those where the sky rows' and the limb rows' band maps act (below 40 km, whose slices
/// then keep the warp centred at 0), and above the nodes a query at 30 km reads (from
/// 30–50 km the sky 30 km up 58° from the sun, sun −3.6°, went 2.91 → 2.93 %).
pub const SUN_WARP_CENTRE_ALTITUDE_M: [f64; 2] = [40_000.0, 60_000.0];

/// The sun coordinates the twilight warp acts between (deg).
pub const SUN_WARP_RANGE: (f64, f64) = (-8.0, 6.0);

/// First and last row of segment `seg`.
pub fn segment_rows(seg: usize) -> (usize, usize) {
    match seg {
        0 => (0, N_VIEW_SKY - 1),
        1 => (N_VIEW_SKY, N_VIEW_UP - 1),
        _ => (N_VIEW_UP, N_VIEW - 1),
    }
}

/// The weight of the columns' square-root map aloft ([`azimuth_weight`]): the rest goes to
/// sin²(φ/2) = (1 − cos φ)/2, dense around 90° from the sun.
pub const AZIMUTH_ALOFT_WEIGHT: f64 = 0.5;

/// The weight of the columns' square-root map below [`AZIMUTH_ALOFT_M`] ([`azimuth_weight`];
/// version 13: 1, the square root alone). In low twilight the glow 90° from the sun and the band
/// above the earth's shadow 120–135° from the sun vary fastest with the azimuth, where the square
/// root's columns are 13–16° apart (9–11° with 0.65). The columns' axis alone (Lagrange over the
/// `sky` product at the columns, 680 nm, sun −6…5°, 5–15 km): 90° from the sun 2.6 / 3.9 / 5.1 %
/// at 5 / 10 / 15 km with 1, 1.1 / 0.8 / 0.7 % with 0.65; 120–180° at 0–15 km up to 6.3 % with 1,
/// 2.2 % with 0.65; by day (sun 5–50°, 0–12 km) 0.67 → 0.54 %. With the altitude nodes
/// inserted at 15.3 and 18.5 km, 0.72 reads the deep-twilight glow at 5 km within 10 % (0.65:
/// 10.16 %), the sunset glow within 3 % either way.
pub const AZIMUTH_GROUND_WEIGHT: f64 = 0.72;

/// The altitudes (m) between which the columns' map moves from the square root (below) to its
/// blend with (1 − cos φ)/2 (above), [`azimuth_weight`].
pub const AZIMUTH_ALOFT_M: [f64; 2] = [15_000.0, 25_000.0];

/// The weight α of the columns' square-root map at altitude `h` (m): [`AZIMUTH_GROUND_WEIGHT`]
/// below [`AZIMUTH_ALOFT_M`], [`AZIMUTH_ALOFT_WEIGHT`] above, a smoothstep between. Seen from
/// altitude in twilight, a ray near the horizontal crosses the earth's shadow where the sun's
/// elevation along it, which changes by (x/R) cos φ over a distance x, meets the shadow: the
/// edge moves fastest with the azimuth φ around 90° from the sun, where the square root's
/// columns are 9–10° apart; near the ground the low sky's band above the shadow wants the
/// antisolar columns dense, which the square root's share keeps there.
pub fn azimuth_weight(h: f64) -> f64 {
    let [h0, h1] = AZIMUTH_ALOFT_M;
    AZIMUTH_GROUND_WEIGHT - (AZIMUTH_GROUND_WEIGHT - AZIMUTH_ALOFT_WEIGHT) * smoothstep(h0, h1, h)
}

/// Azimuth from the sun of column `a` at altitude `h` (m), rad: the root of
/// [`azimuth_coord`]`(φ, h) = a` (by bisection; π (a / (N_AZ − 1))² where the map is the
/// square root alone).
pub fn azimuth_node(a: usize, h: f64) -> f64 {
    let x = a as f64 / (N_AZ - 1) as f64;
    if azimuth_weight(h) == 1.0 || a == 0 || a >= N_AZ - 1 {
        return PI * x * x;
    }
    root_of_increasing(|phi| azimuth_coord(phi, h), a as f64, 0.0, PI, 64)
}

/// The columns' focus aloft ([`azimuth_focus`]): its weight β at the top of
/// [`AZIMUTH_FOCUS_ALTITUDE_M`], its centre φ_c and width w (degrees).
pub const AZIMUTH_FOCUS: [f64; 3] = [0.25, 115.0, 20.0];

/// The altitudes (m) between which the columns' focus ([`azimuth_focus`]) fades in (smoothstep).
pub const AZIMUTH_FOCUS_ALTITUDE_M: [f64; 2] = [20_000.0, 30_000.0];

/// The columns' focus aloft at azimuth `phi` (rad) and altitude `h` (m): (β, G(φ)), β =
/// [`AZIMUTH_FOCUS`]`[0]` smoothstep([`AZIMUTH_FOCUS_ALTITUDE_M`], h), G(φ) = (tanh((φ − φ_c)/w)
/// − tanh(−φ_c/w)) / (tanh((π − φ_c)/w) − tanh(−φ_c/w)) (0 at the sun, 1 opposite it, steepest
/// at φ_c). [`azimuth_coord`] gives β of the column coordinate to G. Seen from 30–100 km in
/// deep twilight a ray near the horizontal climbs into sunlight towards its far end up to
/// cos φ = −sin ε / sin d (ε its elevation, d the central angle to its exit; along the ray the
/// sun's elevation above the local horizon changes by cos φ + sin ε / sin d per radian of
/// central angle): the lit far end is cut off between 90° and 130° from the sun, where ln L
/// falls by 3.3 within 30° (1.4 per column without the focus, 79.5 km, 440 nm). Centred at 115°
/// since version 15 (with 110° the 79.5 km sky 109° from the sun, sun −8.75°, erred by 9.8 %,
/// 7.2 % with 115°; 105°: the limb 94° from the sun 13.6 %).
pub fn azimuth_focus(phi: f64, h: f64) -> (f64, f64) {
    let [b, c, w] = AZIMUTH_FOCUS;
    let [h0, h1] = AZIMUTH_FOCUS_ALTITUDE_M;
    let beta = b * smoothstep(h0, h1, h);
    if beta <= 0.0 {
        return (0.0, 0.0);
    }
    let (c, w) = (c.to_radians(), w.to_radians());
    let g = |p: f64| ((p - c) / w).tanh();
    (beta, (g(phi) - g(0.0)) / (g(PI) - g(0.0)))
}

/// Continuous column coordinate of azimuth `phi` ∈ [0, π] at altitude `h` (m):
/// (α √(φ/π) + (1 − α − β) sin²(φ/2) + β G(φ))(N_AZ − 1), α = [`azimuth_weight`]`(h)` (the
/// square root dense near the sun, sin²(φ/2) around 90° from it), (β, G) = [`azimuth_focus`]
/// (0 below 20 km).
pub fn azimuth_coord(phi: f64, h: f64) -> f64 {
    let phi = phi.clamp(0.0, PI);
    let alpha = azimuth_weight(h);
    let (beta, g) = azimuth_focus(phi, h);
    let u = alpha * (phi / PI).sqrt() + (1.0 - alpha - beta) * (0.5 * phi).sin().powi(2) + beta * g;
    u * (N_AZ - 1) as f64
}

/// The query altitudes (m) between which each altitude node's columns move from the query's
/// column coordinate to the node's own ([`node_column`]).
pub const AZIMUTH_NODE_READ_M: [f64; 2] = [15_000.0, 20_000.0];

/// The column coordinate at which a query at azimuth `phi` (rad) and altitude `h` (m), column
/// coordinate `col_q` = [`azimuth_coord`]`(phi, h)`, reads altitude node `k` of an atmosphere
/// `thickness` thick: col_q + λ ([`azimuth_coord`]`(phi, h_k)` − col_q), λ = smoothstep over
/// [`AZIMUTH_NODE_READ_M`] of h. The columns' map varies with the altitude from 15 km up
/// ([`azimuth_weight`], [`azimuth_focus`]), so a texel of node k lies at the azimuth of its
/// column in the node's own map: read at the query's coordinate, a node of another altitude is
/// read up to ~0.4 of a column away (30 km, 58° from the sun, with the focus), read at its own
/// (λ = 1) it is read at the query's azimuth. Below 15 km (λ = 0) every node is read at the
/// query's coordinate as in version 12, whose band maps were fitted with that reading (the
/// earth's shadow seen from 15 km, the dense check, 5.97 → 6.83 % with λ = 1 there).
pub fn node_column(phi: f64, col_q: f64, h: f64, k: usize, thickness: f64) -> f64 {
    let [h0, h1] = AZIMUTH_NODE_READ_M;
    let lambda = smoothstep(h0, h1, h);
    if lambda <= 0.0 {
        return col_q;
    }
    col_q + lambda * (azimuth_coord(phi, altitude_node_m(k, thickness)) - col_q)
}

/// The columns' stencil at column coordinate `col` with at most `nodes` nodes ([`Stencil`]), over
/// the columns continued by mirror images past the sun (φ = 0) and the antisolar point (φ = π):
/// its node v is column v − 1 ([`column_texel`]; the nodes −1 and N_AZ are columns 1 and
/// N_AZ − 2). The sky is symmetric about the sun's vertical plane, so the mirror images are the
/// sky at −φ and 2π − φ, and a query in the first or last column interval gets a cubic centred
/// on its interval instead of the quadratic over the three nodes on one side. The columns near
/// 180° are 15–24° apart (the last interval 158–180° at 20 km): the limb seen from 20 km 165°
/// from the sun, sun −4°, 0.54° above the horizon, the columns' axis alone −5.09 % → −0.79 %
/// (680 nm, the `sky` product at the columns).
pub fn column_stencil(col: f64, nodes: usize) -> Stencil {
    let v = col + 1.0;
    Stencil::with_nodes(v, 0, N_AZ + 1, |a| a as f64, v, nodes)
}

/// The texel column of node `v` of [`column_stencil`]: v − 1 reflected into 0..N_AZ − 1.
pub fn column_texel(v: usize) -> usize {
    let last = N_AZ - 1;
    match v {
        0 => 1,
        v if v - 1 > last => (2 * last).saturating_sub(v - 1),
        v => v - 1,
    }
}

/// Where a node's length is zero — rays up from the top node, rays down from the ground node —
/// the node is evaluated this far inside the atmosphere (m): its stored value is the limit of
/// radiance / length there.
pub const EVAL_OFFSET_M: f64 = 10.0;

/// The radius at which texel rows of altitude node `k` and view row `i` are evaluated: the
/// node's, or [`EVAL_OFFSET_M`] inside where the node's ray has no length.
pub fn eval_radius(k: usize, i: usize, bottom: f64, thickness: f64) -> f64 {
    let r = bottom + altitude_node_m(k, thickness);
    if k == N_ALT - 1 && i < N_VIEW_UP {
        r - EVAL_OFFSET_M
    } else if k == 0 && i >= N_VIEW_UP {
        r + EVAL_OFFSET_M
    } else {
        r
    }
}

/// Length of the ray from radius `r` with zenith cosine `mu` to the top of the atmosphere, or
/// to the ground when `ground` (the divisor of the stored scattering: the texels hold
/// radiance per metre of ray, which varies little with altitude and view where the radiance
/// itself goes to zero with the ray's length).
pub fn ray_length(r: f64, mu: f64, bottom: f64, top: f64, ground: bool) -> f64 {
    if ground {
        let disc = r * r * (mu * mu - 1.0) + bottom * bottom;
        (-r * mu - disc.max(0.0).sqrt()).max(0.0)
    } else {
        let disc = r * r * (mu * mu - 1.0) + top * top;
        (-r * mu + disc.max(0.0).sqrt()).max(0.0)
    }
}

/// The computed `skyview` bundle.
#[derive(Debug, Clone)]
pub struct SkyViewBundle {
    pub channels: Channels,
    pub wavelengths_nm: Vec<f64>,
    /// Radii, solar irradiance, coefficients (as Bruneton's; `mie_phase_function_g` is the
    /// aerosol phase function's asymmetry parameter).
    pub params: AtmosphereParameters,
    /// The aerosol's phase function, applied by the client to the single Mie table.
    pub aerosol_phase: Phase,
    /// Bruneton's transmittance texture (his parameterisation).
    pub transmittance: Texture,
    /// Single Rayleigh scattering without its phase function + multiple scattering divided by
    /// the Rayleigh phase function, per metre of the ray ([`ray_length`]), divided by the
    /// slice's scale: width N_AZ, height N_VIEW,
    /// depth N_ALT · N_SUN (slice = altitude · N_SUN + sun), half floats.
    pub rayleigh: Texture,
    /// Single Mie scattering without its phase function, per metre of ray, divided by the
    /// slice's scale; as above.
    pub mie: Texture,
    /// Per-slice scales: width N_SUN, height N_ALT, 2 × channels (Rayleigh-like then Mie), floats.
    pub scale: Texture,
    /// Sky irradiance on a horizontal surface divided by the depth of the atmosphere above the
    /// node (top − r; the top node evaluated [`EVAL_OFFSET_M`] below the top): width N_SUN,
    /// height N_ALT, floats.
    pub irradiance: Texture,
    /// Wall-clock ms: precise table, transmittance, sky view, irradiance.
    pub timing_ms: [f64; 4],
}

/// An altitude node's part of the sky view's textures, once final: N_SUN slices of
/// [`SkyViewBundle::rayleigh`] and of [`SkyViewBundle::mie`], and their scales
/// (`[sun][Rayleigh-like | Mie][channel]`, [`SkyViewBundle::scale`]'s row).
struct AltitudeSlices {
    rayleigh: Vec<f32>,
    mie: Vec<f32>,
    scales: Vec<f32>,
}

/// Computes the `skyview` bundle on `shared` (its precise table built or built here), `steps`
/// samples per ray segment (the products' `Quality::steps`).
pub fn build_skyview(
    shared: &SharedTables,
    channels: Channels,
    steps: usize,
    cancelled: &(dyn Fn() -> bool + Sync),
) -> crate::Result<SkyViewBundle> {
    build_skyview_into(shared, channels, steps, cancelled, &|_, _, _| {})
}

/// An altitude node's final slices: (node k, its Rayleigh-like and its Mie values, N_SUN
/// slices as in [`SkyViewBundle::rayleigh`] and [`SkyViewBundle::mie`]: scaled, rounded,
/// `[sun][view][azimuth][channel]`).
pub type AltitudeSink<'a> = dyn Fn(usize, &[f32], &[f32]) + Sync + 'a;

/// [`build_skyview`], handing each altitude node's slices to `finished` as soon as they are
/// final, while the other nodes' rows are still computed (on the thread that completed the
/// node: a caller can encode them there, on a core the build's last rows leave idle).
pub fn build_skyview_into(
    shared: &SharedTables,
    channels: Channels,
    steps: usize,
    cancelled: &(dyn Fn() -> bool + Sync),
    finished: &AltitudeSink<'_>,
) -> crate::Result<SkyViewBundle> {
    let m = &shared.medium;
    let (idx, params) = channel_setup(m, &channels)?;
    let n_c = idx.len();
    let e0 = params.solar_irradiance.clone();
    let tp = Instant::now();
    shared
        .precise_unless(cancelled)
        .ok_or(crate::Error::Cancelled)?;
    let t_precise = tp.elapsed().as_secs_f64() * 1e3;

    let t0 = Instant::now();
    let transmittance = build::transmittance_texture(m, &params, &idx, cancelled);
    if cancelled() {
        return Err(crate::Error::Cancelled);
    }
    let t_transmittance = t0.elapsed().as_secs_f64() * 1e3;

    // The sky view and the irradiance side by side (both read the table, built above on this
    // thread: a rayon task must not wait on the table's `OnceLock` while its own thread may be
    // the one building it): the cores stay busy across each stage's last tasks and the sky
    // view's serial assembly.
    let bottom = params.bottom_radius;
    let thickness = params.top_radius - bottom;
    // μs of sun node j at altitude node k.
    // The nodes' altitudes and the columns' azimuths at each (roots of their coordinates).
    let heights: Vec<f64> = (0..N_ALT).map(|k| altitude_node_m(k, thickness)).collect();
    let columns: Vec<[f64; N_AZ]> = heights
        .iter()
        .map(|&h| std::array::from_fn(|a| azimuth_node(a, h)))
        .collect();
    let sun_mu = |k: usize, j: usize| {
        let h = heights[k];
        let s = sun_warp(sun_node_deg(j), warp_strength(h, thickness), 0.0);
        (s.to_radians() - dip(bottom + h, bottom)).sin()
    };
    // Sky view: one task per (altitude, view) ray, all its (sun, azimuth) texels.
    let sky_view = || -> crate::Result<(Texture, Texture, Texture, f64)> {
        let t1 = Instant::now();
        let per_family = N_SUN * N_AZ * n_c;
        let n_l = m.len();
        // The multiple scattering of every other view row first, then the rows between from them
        // where smooth ([`ms_rows`]): `known` holds the first pass's per metre, by task.
        let segment = |i: usize| segment_rows(row_segment(i));
        let row_computed = |i: usize| {
            let (first, last) = segment(i);
            ms_rows::computed(i, first, last)
        };
        let ray_task =
            |scratch: &mut FamilyScratch<'_>, task: usize, known: &[Option<Vec<f64>>]| {
                let (k, i) = (task / N_VIEW, task % N_VIEW);
                let mut s_out = vec![0.0; per_family];
                let mut m_out = vec![0.0; per_family];
                let mut record = None;
                if cancelled() {
                    return ((s_out, m_out), record);
                }
                let r = eval_radius(k, i, bottom, thickness);
                let b = warp_strength(heights[k], thickness);
                let seg = row_segment(i);
                let centre = |cos_phi: f64| {
                    sun_warp_centre(heights[k], bottom, bottom + thickness, seg, cos_phi)
                };
                let c = centre(1.0);
                let s_j: Vec<f64> = (0..N_SUN)
                    .map(|j| sun_warp(sun_node_deg(j), b, c))
                    .collect();
                let c_a: [f64; N_AZ] = std::array::from_fn(|a| centre(columns[k][a].cos()));
                // The rays of this row: one for the suns whose row does not move (every sun
                // but on the sky rows in low twilight, [`sky_row_focus`]), one per other sun.
                let focused = |j: usize| {
                    if i < N_VIEW_SKY {
                        sky_row_focus(s_j[j], r - bottom).1 > 0.0
                    } else {
                        i < N_VIEW_UP && limb_row_focus(s_j[j], r - bottom).1 > 0.0
                    }
                };
                let mut rays: Vec<Vec<usize>> = vec![(0..N_SUN).filter(|&j| !focused(j)).collect()];
                rays.extend((0..N_SUN).filter(|&j| focused(j)).map(|j| vec![j]));
                for (g, suns) in rays.iter().enumerate().filter(|(_, v)| !v.is_empty()) {
                    let (theta, ground) = view_node(i, r, bottom, s_j[suns[0]]);
                    let mu_h = horizon_mu(r, bottom);
                    let mu = if ground {
                        (theta.cos().min(mu_h) - 1e-9).max(-1.0)
                    } else {
                        theta.cos().max(mu_h + 1e-9).min(1.0)
                    };
                    let sin_t = (1.0 - mu * mu).max(0.0).sqrt();
                    let d = ray_length(r, mu, bottom, bottom + thickness, ground);
                    scratch.prepare(r, mu, steps);
                    let mut nus = Vec::with_capacity(suns.len() * N_AZ);
                    for &j in suns {
                        for a in 0..N_AZ {
                            let phi = columns[k][a];
                            let limb = (N_VIEW_SKY..N_VIEW_UP).contains(&i);
                            let shift =
                                sun_shift(r, theta, phi.cos(), bottom, bottom + thickness, limb);
                            let s_ja = sun_warp(sun_node_deg(j), b, c_a[a]);
                            let mu_s = (s_ja.to_radians() - shift).sin();
                            let sin_s = (1.0 - mu_s * mu_s).max(0.0).sqrt();
                            let nu = (mu * mu_s + sin_t * sin_s * phi.cos()).clamp(-1.0, 1.0);
                            scratch.push_sun(mu_s, nu);
                            nus.push(nu);
                        }
                    }
                    let sun_at: Vec<f64> = suns.iter().map(|&j| s_j[j]).collect();
                    let (first, last) = segment(i);
                    let stencil = ms_rows::stencils(first, last)[i - first];
                    match stencil {
                        Some(st) if g == 0 && !known.is_empty() => {
                            let entry =
                                |t: usize, l: usize| (suns[t / N_AZ] * N_AZ + t % N_AZ) * n_l + l;
                            let row = |c: usize| known[k * N_VIEW + first + c].as_deref();
                            scratch.integrate_grid_guessed(
                                &columns[k],
                                &sun_at,
                                ms_rows::TOLERANCE,
                                |t, l| {
                                    let e = entry(t, l);
                                    let (y, rough) =
                                        ms_rows::guess(&st, |c| row(c).map_or(f64::NAN, |r| r[e]))?;
                                    Some((y * d, rough))
                                },
                            );
                        }
                        _ => scratch.integrate_grid(&columns[k], &sun_at),
                    }
                    if g == 0 && stencil.is_none() {
                        let mut per_m = vec![f64::NAN; N_SUN * N_AZ * n_l];
                        for (n, &j) in suns.iter().enumerate() {
                            for a in 0..N_AZ {
                                let ms = scratch.texel(n * N_AZ + a).multiple;
                                for l in 0..n_l {
                                    per_m[(j * N_AZ + a) * n_l + l] = ms[l] / d;
                                }
                            }
                        }
                        record = Some(per_m);
                    }
                    for (n, &j) in suns.iter().enumerate() {
                        for a in 0..N_AZ {
                            let nu = nus[n * N_AZ + a];
                            let p_r = param::rayleigh_phase(nu);
                            let s = scratch.texel(n * N_AZ + a);
                            let o = (j * N_AZ + a) * n_c;
                            for (c, &l) in idx.iter().enumerate() {
                                s_out[o + c] = (s.rayleigh[l] + s.multiple[l] / p_r) * e0[c] / d;
                                m_out[o + c] = s.mie[l] * e0[c] / d;
                            }
                        }
                    }
                }
                ((s_out, m_out), record)
            };
        // Every task its own rayon job (`with_max_len(1)`): rayon's adaptive split otherwise
        // leaves runs of tens of tasks that a thread works through alone, and a pass could end
        // on one of them with the other core idle. The tasks' scratch buffers are kept in a
        // pool between them (a job's own would be allocated again for every task).
        let pool: Mutex<Vec<FamilyScratch<'_>>> = Mutex::new(Vec::new());
        let with_scratch = |task: usize, known: &[Option<Vec<f64>>]| {
            let mut scratch = pool
                .lock()
                .ok()
                .and_then(|mut p| p.pop())
                .unwrap_or_else(|| FamilyScratch::new(shared, m.len()));
            let out = ray_task(&mut scratch, task, known);
            if let Ok(mut p) = pool.lock() {
                p.push(scratch);
            }
            out
        };
        let pass = |tasks: Vec<usize>, known: &[Option<Vec<f64>>]| -> Vec<_> {
            tasks
                .into_par_iter()
                .with_max_len(1)
                .map(|task| {
                    let t = Instant::now();
                    let out = with_scratch(task, known);
                    (task, out, t.elapsed())
                })
                .collect()
        };
        let (first_tasks, mut other_tasks): (Vec<usize>, Vec<usize>) =
            (0..N_ALT * N_VIEW).partition(|&task| row_computed(task % N_VIEW));
        let mut families = vec![(Vec::new(), Vec::new()); N_ALT * N_VIEW];
        let mut known: Vec<Option<Vec<f64>>> = vec![None; N_ALT * N_VIEW];
        let mut took = vec![std::time::Duration::ZERO; N_ALT * N_VIEW];
        for (task, (family, record), dt) in pass(first_tasks, &[]) {
            families[task] = family;
            known[task] = record;
            took[task] = dt;
        }
        // The rows between in the order of the longest of their two neighbours' times in the
        // first pass (a row costs about what the rows around it cost: its suns' refinements), so
        // that the pass does not end on one long task with the other core idle; the tasks'
        // results are placed by their index, whatever the order.
        let around = |task: usize| {
            let i = task % N_VIEW;
            let before = if i > 0 { took[task - 1] } else { took[task] };
            let after = if i + 1 < N_VIEW {
                took[task + 1]
            } else {
                took[task]
            };
            before.max(after)
        };
        other_tasks.sort_by_key(|&task| std::cmp::Reverse(around(task)));
        // The rows between land in `later`; the task that completes an altitude node's rows
        // assembles its slices there and then (each (altitude, sun) slice scaled to its peak
        // and rounded, the slices on the cores) and hands them to `finished`, so that the
        // node's encoding overlaps the pass's last tasks.
        let later: Vec<OnceLock<(Vec<f64>, Vec<f64>)>> =
            (0..N_ALT * N_VIEW).map(|_| OnceLock::new()).collect();
        let pending: Vec<AtomicUsize> = (0..N_ALT)
            .map(|k| AtomicUsize::new(other_tasks.iter().filter(|&&t| t / N_VIEW == k).count()))
            .collect();
        let nodes: Vec<OnceLock<AltitudeSlices>> = (0..N_ALT).map(|_| OnceLock::new()).collect();
        let slab = N_VIEW * N_AZ * n_c;
        let finish = |k: usize| {
            let family = |task: usize| later[task].get().unwrap_or(&families[task]);
            let mut parts = [vec![0.0f32; N_SUN * slab], vec![0.0f32; N_SUN * slab]];
            let mut scales = vec![0.0f32; N_SUN * 2 * n_c];
            for (part, data) in parts.iter_mut().enumerate() {
                let per_slice: Vec<Vec<f32>> = data
                    .par_chunks_mut(slab)
                    .enumerate()
                    .map(|(j, out)| {
                        let mut scales = vec![0.0f32; n_c];
                        for c in 0..n_c {
                            let value = |i: usize, a: usize| {
                                let (s, mm) = family(k * N_VIEW + i);
                                let v = if part == 0 { s } else { mm };
                                v[(j * N_AZ + a) * n_c + c]
                            };
                            let mut max = 0.0f64;
                            for i in 0..N_VIEW {
                                for a in 0..N_AZ {
                                    max = max.max(value(i, a));
                                }
                            }
                            let sc = if max > 0.0 { max / SLICE_PEAK } else { 1.0 };
                            scales[c] = sc as f32;
                            for i in 0..N_VIEW {
                                for a in 0..N_AZ {
                                    out[(i * N_AZ + a) * n_c + c] = (value(i, a) / sc) as f32;
                                }
                            }
                        }
                        build::round_to_half_bits(out, HALF_MANTISSA_BITS);
                        scales
                    })
                    .collect();
                for (j, sc) in per_slice.iter().enumerate() {
                    let o = j * 2 * n_c + part * n_c;
                    scales[o..o + n_c].copy_from_slice(sc);
                }
            }
            let [rayleigh, mie] = parts;
            finished(k, &rayleigh, &mie);
            let _ = nodes[k].set(AltitudeSlices {
                rayleigh,
                mie,
                scales,
            });
        };
        // (Every node has rows between; one without would be final now.)
        (0..N_ALT)
            .into_par_iter()
            .filter(|&k| pending[k].load(Ordering::Acquire) == 0)
            .for_each(finish);
        other_tasks
            .into_par_iter()
            .with_max_len(1)
            .for_each(|task| {
                let (family, _) = with_scratch(task, &known);
                let _ = later[task].set(family);
                let k = task / N_VIEW;
                if pending[k].fetch_sub(1, Ordering::AcqRel) == 1 && !cancelled() {
                    finish(k);
                }
            });
        drop(known);
        if cancelled() {
            return Err(crate::Error::Cancelled);
        }
        let mut rayleigh = Texture::new(N_AZ, N_VIEW, N_ALT * N_SUN, n_c, Sample::Half);
        let mut mie = Texture::new(N_AZ, N_VIEW, N_ALT * N_SUN, n_c, Sample::Half);
        let mut scale = Texture::new(N_SUN, N_ALT, 1, 2 * n_c, Sample::Float);
        let per_node = N_SUN * slab;
        for (k, node) in nodes.into_iter().enumerate() {
            let node = node.into_inner().ok_or(crate::Error::Cancelled)?;
            rayleigh.data[k * per_node..][..per_node].copy_from_slice(&node.rayleigh);
            mie.data[k * per_node..][..per_node].copy_from_slice(&node.mie);
            let n = N_SUN * 2 * n_c;
            scale.data[k * n..][..n].copy_from_slice(&node.scales);
        }
        Ok((rayleigh, mie, scale, t1.elapsed().as_secs_f64() * 1e3))
    };

    // Irradiance on the altitude × sun nodes.
    let irradiance = || -> crate::Result<(Texture, f64)> {
        let t2 = Instant::now();
        let radii: Vec<f64> = (0..N_ALT)
            .map(|k| (bottom + heights[k]).min(bottom + thickness - EVAL_OFFSET_M))
            .collect();
        let sums = build::irradiance_grid(
            shared,
            build::IrradianceGrid {
                radii: &radii,
                width: N_SUN,
                mu_s: &sun_mu,
                ms_columns: true,
            },
            &idx,
            &e0,
            steps,
            cancelled,
        );
        if cancelled() {
            return Err(crate::Error::Cancelled);
        }
        let mut irradiance = Texture::new(N_SUN, N_ALT, 1, n_c, Sample::Float);
        for (n, (o, s)) in irradiance.data.iter_mut().zip(sums).enumerate() {
            let depth = bottom + thickness - radii[n / (N_SUN * n_c)];
            *o = (s / depth) as f32;
        }
        Ok((irradiance, t2.elapsed().as_secs_f64() * 1e3))
    };
    let (view, irradiance) = rayon::join(sky_view, irradiance);
    let (rayleigh, mie, scale, t_view) = view?;
    let (irradiance, t_irradiance) = irradiance?;

    Ok(SkyViewBundle {
        wavelengths_nm: idx.iter().map(|&i| m.wavelengths_nm[i]).collect(),
        channels,
        params,
        aerosol_phase: m.mie_phase,
        transmittance,
        rayleigh,
        mie,
        scale,
        irradiance,
        timing_ms: [t_precise, t_transmittance, t_view, t_irradiance],
    })
}

type Vec3 = [f64; 3];

fn dot(a: Vec3, b: Vec3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Node index and fraction of a continuous coordinate over `n` nodes.
fn split(x: f64, n: usize) -> (usize, f64) {
    let x = x.clamp(0.0, (n - 1) as f64);
    let i = (x.floor() as usize).min(n - 2);
    (i, x - i as f64)
}

/// Geometric interpolation (linear in ln) between two values, linear where one is not positive.
fn geo_mix(a: f64, b: f64, t: f64) -> f64 {
    if t == 0.0 {
        a
    } else if t == 1.0 {
        b
    } else if a > 0.0 && b > 0.0 {
        a * (b / a).powf(t)
    } else {
        a + (b - a) * t
    }
}

/// Interpolation weights along one node axis: the (up to) four nodes around a query, within
/// one segment of the axis, and their Lagrange weights at the query's abscissa (cubic inside
/// the segment, quadratic in its first and last interval, linear in a segment of two nodes).
#[derive(Debug, Clone, Copy)]
pub struct Stencil {
    /// First node of the stencil.
    pub first: usize,
    /// Number of nodes (2 to 4).
    pub len: usize,
    /// Lagrange weights of the nodes first..first + len (they sum to 1).
    pub w: [f64; 4],
    /// The interval's lower node (first + 0 or 1) and the fraction within it (the geometric
    /// interpolation's, where a value is not positive).
    pub i0: usize,
    pub t: f64,
}

impl Stencil {
    /// The stencil of continuous node coordinate `y` in the segment of nodes `lo..=hi`, the
    /// nodes' abscissas `x(i)` and the query's `xq` (the abscissa in which the interpolation is
    /// polynomial; the node coordinate itself where the nodes are uniform in it).
    pub fn new(y: f64, lo: usize, hi: usize, x: impl Fn(usize) -> f64, xq: f64) -> Self {
        Self::with_nodes(y, lo, hi, x, xq, 4)
    }

    /// As [`Self::new`] with at most `nodes` nodes (4: cubic; 2: the interval's two nodes,
    /// geometric interpolation).
    pub fn with_nodes(
        y: f64,
        lo: usize,
        hi: usize,
        x: impl Fn(usize) -> f64,
        xq: f64,
        nodes: usize,
    ) -> Self {
        let y = y.clamp(lo as f64, hi as f64);
        let i0 = (y.floor() as usize).clamp(lo, hi - 1);
        let t = y - i0 as f64;
        let (first, last) = if nodes <= 2 {
            (i0, i0 + 1)
        } else {
            (i0.saturating_sub(1).max(lo), (i0 + 2).min(hi))
        };
        let len = last - first + 1;
        let mut w = [0.0; 4];
        if t == 0.0 {
            w[i0 - first] = 1.0;
        } else {
            for (m, wm) in w.iter_mut().enumerate().take(len) {
                let xm = x(first + m);
                *wm = (0..len)
                    .filter(|&n| n != m)
                    .map(|n| {
                        let xn = x(first + n);
                        (xq - xn) / (xm - xn)
                    })
                    .product();
            }
        }
        Self {
            first,
            len,
            w,
            i0,
            t,
        }
    }

    /// The stencil of `xq` below node `first`'s abscissa (`x` as in [`Self::new`]): the line
    /// through nodes `first` and `first + 1`, extrapolated (t = (xq − x₀)/(x₁ − x₀) < 0; not
    /// bounded by the values' range, [`Self::mix`]).
    pub fn below(first: usize, x: impl Fn(usize) -> f64, xq: f64) -> Self {
        let (x0, x1) = (x(first), x(first + 1));
        let t = ((xq - x0) / (x1 - x0)).min(0.0);
        Self {
            first,
            len: 2,
            w: [1.0 - t, t, 0.0, 0.0],
            i0: first,
            t,
        }
    }

    /// Interpolates `v` (the stencil's node values): the Lagrange polynomial of their
    /// logarithms (exact for exponentials of a cubic), bounded by the values' range (not where
    /// extrapolating, t < 0: [`Self::below`]); where a value is not positive, geometric between
    /// the interval's two nodes ([`geo_mix`]).
    pub fn mix(&self, v: &[f64]) -> f64 {
        let v = &v[..self.len];
        let (a, b) = (v[self.i0 - self.first], v[self.i0 + 1 - self.first]);
        if self.t == 0.0 {
            return a;
        }
        if v.iter().any(|&x| x <= 0.0 || !x.is_finite()) {
            // Extrapolating (t < 0): the first node's value.
            return if self.t < 0.0 {
                a
            } else {
                geo_mix(a, b, self.t)
            };
        }
        let ln: f64 = v.iter().zip(&self.w).map(|(x, w)| w * x.ln()).sum();
        if self.t < 0.0 {
            return ln.exp();
        }
        let (lo, hi) = v
            .iter()
            .fold((f64::MAX, 0.0f64), |(l, h), &x| (l.min(x), h.max(x)));
        ln.exp().clamp(lo, hi)
    }
}

/// Reads a `skyview` bundle the way its client (a shader) does: Lagrange interpolation of the
/// logarithms ([`Stencil`]) over the azimuth columns, the view rows (times the slice's scale),
/// the sun's and the altitude's nodes, four nodes per axis.
pub struct SkyViewReader<'a> {
    pub bundle: &'a SkyViewBundle,
    /// Nodes per axis (altitude, sun, view rows, azimuth columns): 4 (the layout's reading);
    /// 2 (geometric between the interval's nodes) to measure what the cubic gains.
    pub nodes: [usize; 4],
}

impl<'a> SkyViewReader<'a> {
    pub fn new(bundle: &'a SkyViewBundle) -> Self {
        Self {
            bundle,
            nodes: [4; 4],
        }
    }

    /// Row `y` of slice `z` at the columns' stencil `sc` (the azimuth's: Lagrange interpolation
    /// of the logarithms over 4 columns, as the other axes), without the slice's scale (part 0
    /// = Rayleigh-like, 1 = Mie).
    fn fetch(&self, part: usize, z: usize, sc: &Stencil, y: usize, out: &mut [f64]) {
        let b = self.bundle;
        let t = if part == 0 { &b.rayleigh } else { &b.mie };
        for (c, o) in out.iter_mut().enumerate() {
            let mut v = [0.0; 4];
            for (m, vm) in v.iter_mut().enumerate().take(sc.len) {
                *vm = t.texel(column_texel(sc.first + m), y, z)[c] as f64;
            }
            *o = sc.mix(&v);
        }
    }

    /// The value of slice `z` at the columns' stencil `sc` where each column `m` has its own
    /// row stencil `rows[m]` (the sky rows in low twilight, [`band_relative_elevation`]): over
    /// the rows within each column, then over the columns, without the slice's scale.
    fn fetch_band(
        &self,
        part: usize,
        z: usize,
        sc: &Stencil,
        rows: &[Stencil; 4],
        out: &mut [f64],
    ) {
        let b = self.bundle;
        let t = if part == 0 { &b.rayleigh } else { &b.mie };
        for (c, o) in out.iter_mut().enumerate() {
            let mut v = [0.0; 4];
            for (m, vm) in v.iter_mut().enumerate().take(sc.len) {
                let sv = &rows[m];
                let mut w = [0.0; 4];
                for (n, wn) in w.iter_mut().enumerate().take(sv.len) {
                    *wn = t.texel(column_texel(sc.first + m), sv.first + n, z)[c] as f64;
                }
                *vm = sv.mix(&w);
            }
            *o = sc.mix(&v);
        }
    }

    /// On the sky rows, the rows' stencil of each of the 4 columns of `sc` in slice (altitude
    /// node `k`, sun node `j`) for a query at elevation `eps` (degrees), the sun `s_deg` above
    /// the observer's horizon at altitude `h` (m), azimuth `cos_phi` (cosine) from the sun: the
    /// query's place relative to the band above the earth's shadow moved to the slice's
    /// ([`band_slice_elevation`]) and to the column's azimuth in the slice
    /// ([`band_relative_elevation`]; the column's azimuth at `h` blended to the node's altitude's
    /// as [`node_column`] blends the coordinates), on
    /// the slice's own rows ([`sky_row_focus`] at the node's sun and altitude). `None` where
    /// neither the query nor the slice has a focus (the slice is read at the query's row).
    #[allow(clippy::too_many_arguments)]
    fn band_rows(
        &self,
        eps: f64,
        s_deg: f64,
        h: f64,
        cos_phi: f64,
        sc: &Stencil,
        k: usize,
        j: usize,
    ) -> Option<[Stencil; 4]> {
        let p = &self.bundle.params;
        let thickness = p.top_radius - p.bottom_radius;
        let h_n = altitude_node_m(k, thickness);
        // (The band maps act below 40 km, where the warp's centre is 0.)
        let s_n = sun_warp(sun_node_deg(j), warp_strength(h_n, thickness), 0.0);
        let focus_n = sky_row_focus(s_n, h_n);
        if band_map_weight(s_deg, h) < 1e-6 && band_map_weight(s_n, h_n) < 1e-6 {
            return None;
        }
        let e_n = band_slice_elevation(eps, s_deg, h, s_n, h_n, cos_phi);
        Some(std::array::from_fn(|m| {
            let a = column_texel(sc.first + m);
            // The column's azimuth: the query's altitude's where the node is read at the
            // query's column coordinate (version 12), the node's where at its own.
            let lambda = smoothstep(AZIMUTH_NODE_READ_M[0], AZIMUTH_NODE_READ_M[1], h);
            let cos_a = if lambda > 0.0 {
                (1.0 - lambda) * azimuth_node(a, h).cos() + lambda * azimuth_node(a, h_n).cos()
            } else {
                azimuth_node(a, h).cos()
            };
            let e = band_relative_elevation(e_n, s_n, h_n, cos_phi, cos_a);
            let (seg, y) = band_row(e, h, p.bottom_radius, focus_n, [s_deg, s_n, h_n]);
            let (lo, hi) = segment_rows(seg);
            Stencil::with_nodes(y, lo, hi, |i| i as f64, y, self.nodes[2])
        }))
    }

    /// The altitude and sun stencils at radius `r` (clamped to the atmosphere) and sun zenith
    /// cosine `mu_s`; `shift`: [`sun_shift`] of the query's ray.
    fn altitude_sun_stencils(
        &self,
        r: f64,
        mu_s: f64,
        shift: f64,
        seg: usize,
        cos_phi: f64,
    ) -> (Stencil, Stencil, f64) {
        let p = &self.bundle.params;
        let thickness = p.top_radius - p.bottom_radius;
        let ya = altitude_coord(r - p.bottom_radius, thickness);
        let sa = Stencil::with_nodes(
            ya,
            0,
            N_ALT - 1,
            altitude_node_x,
            altitude_abscissa(r - p.bottom_radius, thickness),
            self.nodes[0],
        );
        let (ss, deg) = self.sun_stencil_at(r, mu_s, shift, seg, cos_phi);
        (sa, ss, deg)
    }

    /// The sun stencil at radius `r` (clamped to the atmosphere) and sun zenith cosine `mu_s`
    /// for the sun coordinate's shift `shift` ([`sun_shift`], or [`limb_node_shift`] for one
    /// altitude node), and the query's node coordinate (degrees).
    fn sun_stencil_at(
        &self,
        r: f64,
        mu_s: f64,
        shift: f64,
        seg: usize,
        cos_phi: f64,
    ) -> (Stencil, f64) {
        let p = &self.bundle.params;
        let thickness = p.top_radius - p.bottom_radius;
        let above = mu_s.clamp(-1.0, 1.0).asin() + shift;
        let deg = sun_unwarp(
            above.to_degrees(),
            warp_strength(r - p.bottom_radius, thickness),
            sun_warp_centre(
                r - p.bottom_radius,
                p.bottom_radius,
                p.top_radius,
                seg,
                cos_phi,
            ),
        )
        .clamp(SUN_MIN_DEG, sun_node_deg(N_SUN - 1));
        let ss = Stencil::with_nodes(
            sun_coord(deg),
            0,
            N_SUN - 1,
            sun_node_deg,
            deg,
            self.nodes[1],
        );
        (ss, deg)
    }

    /// The stored sky at radius `r` (inside the atmosphere) for view zenith cosine `mu`, sun
    /// zenith cosine `mu_s` and view–sun cosine `nu`: (Rayleigh-like, single Mie), both without
    /// phase functions.
    pub fn scattering(&self, r: f64, mu: f64, mu_s: f64, nu: f64) -> (Vec<f64>, Vec<f64>) {
        let p = &self.bundle.params;
        let n_c = self.bundle.wavelengths_nm.len();
        let r = r.clamp(p.bottom_radius, p.top_radius);
        let theta = mu.clamp(-1.0, 1.0).acos();
        let den = ((1.0 - mu * mu) * (1.0 - mu_s * mu_s)).max(0.0).sqrt();
        let cos_phi = if den > 1e-12 {
            ((nu - mu * mu_s) / den).clamp(-1.0, 1.0)
        } else {
            1.0
        };
        let phi = cos_phi.acos();
        let thickness = p.top_radius - p.bottom_radius;
        // Each altitude node's columns ([`node_column`]).
        let col_q = azimuth_coord(phi, r - p.bottom_radius);
        let columns = |k: usize| {
            column_stencil(
                node_column(phi, col_q, r - p.bottom_radius, k, thickness),
                self.nodes[3],
            )
        };
        let (seg, _) = view_coord(theta, r, p.bottom_radius, 0.0);
        let shift = sun_shift(r, theta, cos_phi, p.bottom_radius, p.top_radius, seg == 1);
        // The sky rows depend on the ray's sun coordinate (the sun's elevation + shift).
        let s_deg = (mu_s.clamp(-1.0, 1.0).asin() + shift).to_degrees();
        let (seg, row) = view_coord(theta, r, p.bottom_radius, s_deg);
        let (lo, hi) = segment_rows(seg);
        let sv = Stencil::with_nodes(row, lo, hi, |i| i as f64, row, self.nodes[2]);
        let h = r - p.bottom_radius;
        // On the limb rows each slice's own rows at the query's depth ([`limb_row_focus`] at
        // the slice's sun and altitude).
        let limb_y = limb_depth_of(theta, r, p.bottom_radius);
        let slice_rows = |k: usize, j: usize, s_k: f64| {
            if seg != 1 {
                return sv;
            }
            let h_n = altitude_node_m(k, thickness);
            // (The limb rows' warp is centred at 0.)
            let s_n = sun_warp(sun_node_deg(j), warp_strength(h_n, thickness), 0.0);
            let y_n = limb_slice_depth(limb_y, s_k, h, s_n, h_n);
            let y = N_VIEW_SKY as f64 + limb_row_focused(y_n, s_n, h_n) * (N_VIEW_LIMB - 1) as f64;
            Stencil::with_nodes(y, lo, hi, |i| i as f64, y, self.nodes[2])
        };
        let (sa, ss, _) = self.altitude_sun_stencils(r, mu_s, shift, seg, cos_phi);
        // On the limb rows, each altitude node read at the query's sun coordinate formed with
        // the node's own tangent-point weight aloft, the query's exponential below 11–20 km
        // ([`limb_node_shift`]), its sun stencil without the nodes read too deep
        // ([`limb_sun_stencil`]); with that coordinate (degrees).
        let sun_stencil = |k: usize| -> (Stencil, f64) {
            if seg != 1 {
                return (ss, s_deg);
            }
            let h_n = altitude_node_m(k, thickness);
            let shift_k = limb_node_shift(r, theta, cos_phi, p.bottom_radius, h_n);
            let s_k = (mu_s.clamp(-1.0, 1.0).asin() + shift_k).to_degrees();
            let (ss_k, deg_k) = self.sun_stencil_at(r, mu_s, shift_k, seg, cos_phi);
            let ss_k = limb_sun_stencil(ss_k, limb_y, s_k, h, h_n, thickness, deg_k, self.nodes[1]);
            (ss_k, s_k)
        };
        let band_rows = |k: usize, j: usize, sc: &Stencil| {
            (seg < 2)
                .then(|| self.band_rows(90.0 - theta.to_degrees(), s_deg, h, cos_phi, sc, k, j))
                .flatten()
        };
        let d = ray_length(r, mu, p.bottom_radius, p.top_radius, seg == 2);
        let mut out = [vec![0.0; n_c], vec![0.0; n_c]];
        let mut f = vec![0.0; n_c];
        // Node values per channel: [row][channel], then [sun][channel], then [altitude][channel].
        let mut by_row = vec![[0.0f64; 4]; n_c];
        let mut by_sun = vec![[0.0f64; 4]; n_c];
        let mut by_alt = vec![[0.0f64; 4]; n_c];
        for (part, out) in out.iter_mut().enumerate() {
            for ka in 0..sa.len {
                let k = sa.first + ka;
                let sc = columns(k);
                let (ss, s_k) = sun_stencil(k);
                for js in 0..ss.len {
                    let j = ss.first + js;
                    let z = k * N_SUN + j;
                    // The slice's scale (the interpolation commutes with a common factor).
                    let scale = self.bundle.scale.texel(j, k, 0);
                    if let Some(rows) = &band_rows(k, j, &sc) {
                        self.fetch_band(part, z, &sc, rows, &mut f);
                        for c in 0..n_c {
                            by_sun[c][js] = f[c] * scale[part * n_c + c] as f64;
                        }
                        continue;
                    }
                    let sv = slice_rows(k, j, s_k);
                    for iv in 0..sv.len {
                        self.fetch(part, z, &sc, sv.first + iv, &mut f);
                        for c in 0..n_c {
                            by_row[c][iv] = f[c];
                        }
                    }
                    for c in 0..n_c {
                        by_sun[c][js] = sv.mix(&by_row[c]) * scale[part * n_c + c] as f64;
                    }
                }
                for c in 0..n_c {
                    by_alt[c][ka] = ss.mix(&by_sun[c]);
                }
            }
            for c in 0..n_c {
                out[c] = sa.mix(&by_alt[c]) * d;
            }
        }
        let [s, mm] = out;
        (s, mm)
    }

    /// The sky's radiance seen from `camera` (m from the planet's centre; above the top it is
    /// moved along the view to the top) in direction `view` with the sun towards `sun`, and the
    /// transmittance of the view ray to the top (0 when it meets the ground), per channel, in
    /// the bundle's unit.
    pub fn sky_radiance(&self, camera: Vec3, view: Vec3, sun: Vec3) -> (Vec<f64>, Vec<f64>) {
        let b = self.bundle;
        let p = &b.params;
        let n_c = b.wavelengths_nm.len();
        let mut camera = camera;
        let mut r = dot(camera, camera).sqrt();
        let mut rmu = dot(camera, view);
        if r > p.top_radius {
            let disc = rmu * rmu - r * r + p.top_radius * p.top_radius;
            let to_top = -rmu - disc.max(0.0).sqrt();
            if disc < 0.0 || to_top < 0.0 {
                return (vec![0.0; n_c], vec![1.0; n_c]);
            }
            camera = [
                camera[0] + view[0] * to_top,
                camera[1] + view[1] * to_top,
                camera[2] + view[2] * to_top,
            ];
            r = p.top_radius;
            rmu += to_top;
        }
        let mu = rmu / r;
        let mu_s = dot(camera, sun) / r;
        let nu = dot(view, sun);
        let (s, mm) = self.scattering(r, mu, mu_s, nu);
        let p_r = param::rayleigh_phase(nu);
        let p_m = b.aerosol_phase.eval(nu);
        let ground = p.ray_intersects_ground(r, mu);
        let transmittance = if ground {
            vec![0.0; n_c]
        } else {
            crate::reader::transmittance_to_top(&b.transmittance, p, r, mu)
        };
        (
            s.iter().zip(&mm).map(|(s, m)| s * p_r + m * p_m).collect(),
            transmittance,
        )
    }

    /// The radiance scattered towards `camera` between it and `point` (the aerial perspective)
    /// and the transmittance between them, per channel: Bruneton & Neyret's construction (2008,
    /// §4, the in-scattering of a segment as the difference of two rays' scattering; Bruneton
    /// 2017's `GetSkyRadianceToPoint`), L(camera, v) − T(camera → point) · L(point, v) with
    /// v the direction from the camera to the point, both L from this layout ([`Self::sky_radiance`],
    /// phase functions applied) and T from Bruneton's transmittance texture (his
    /// `GetTransmittance`). For a point on the ground the second ray has no length: the result
    /// is the first ray's in-scattering to the ground.
    pub fn sky_radiance_to_point(
        &self,
        camera: Vec3,
        point: Vec3,
        sun: Vec3,
    ) -> (Vec<f64>, Vec<f64>) {
        let p = &self.bundle.params;
        let (camera, view, r, rmu, d) =
            crate::reader::segment_in_atmosphere(camera, point, p.top_radius);
        let mu = rmu / r;
        let ground = p.ray_intersects_ground(r, mu);
        let t = crate::reader::transmittance(&self.bundle.transmittance, p, r, mu, d, ground);
        let (l, _) = self.sky_radiance(camera, view, sun);
        let far = [
            camera[0] + view[0] * d,
            camera[1] + view[1] * d,
            camera[2] + view[2] * d,
        ];
        let (l_far, _) = self.sky_radiance(far, view, sun);
        (
            l.iter()
                .zip(&l_far)
                .zip(&t)
                .map(|((l, lf), t)| l - t * lf)
                .collect(),
            t,
        )
    }

    /// The sun's direct irradiance on a surface with `normal` at `point` and the sky's on a
    /// horizontal surface times Bruneton's tilt factor (1 + n·up)/2, as his
    /// `GetSunAndSkyIrradiance`.
    pub fn sun_and_sky_irradiance(
        &self,
        point: Vec3,
        normal: Vec3,
        sun: Vec3,
    ) -> (Vec<f64>, Vec<f64>) {
        let b = self.bundle;
        let p = &b.params;
        let n_c = b.wavelengths_nm.len();
        let r = dot(point, point).sqrt();
        let mu_s = dot(point, sun) / r;
        let rc = r.clamp(p.bottom_radius, p.top_radius);
        let (k0, tk) = split(
            altitude_coord(rc - p.bottom_radius, p.top_radius - p.bottom_radius),
            N_ALT,
        );
        let above_horizon = mu_s.clamp(-1.0, 1.0).asin() + dip(rc, p.bottom_radius);
        let t = sun_unwarp(
            above_horizon.to_degrees(),
            warp_strength(rc - p.bottom_radius, p.top_radius - p.bottom_radius),
            0.0,
        );
        let (j0, tj) = split(sun_coord(t), N_SUN);
        let e = |k: usize, j: usize, c: usize| b.irradiance.texel(j, k, 0)[c] as f64;
        let tilt = (1.0 + dot(normal, point) / r) * 0.5;
        let sky: Vec<f64> = (0..n_c)
            .map(|c| {
                let lo = geo_mix(e(k0, j0, c), e(k0, j0 + 1, c), tj);
                let hi = geo_mix(e(k0 + 1, j0, c), e(k0 + 1, j0 + 1, c), tj);
                geo_mix(lo, hi, tk) * tilt * (p.top_radius - rc)
            })
            .collect();
        let cos = dot(normal, sun).max(0.0);
        let t = crate::reader::transmittance_to_sun(&b.transmittance, p, r, mu_s);
        let direct = t
            .iter()
            .zip(&p.solar_irradiance)
            .map(|(t, e)| e * t * cos)
            .collect();
        (direct, sky)
    }
}

/// The aerosol phase function as the manifest describes it (what the client evaluates).
pub fn phase_json(phase: &Phase) -> Value {
    match *phase {
        Phase::CornetteShanks { g } => json!({"kind": "cornette_shanks", "g": g,
            "formula": "3/(8 pi) (1 - g^2)/(2 + g^2) (1 + nu^2) / (1 + g^2 - 2 g nu)^1.5"}),
        Phase::HenyeyGreenstein { g } => json!({"kind": "henyey_greenstein", "g": g,
            "formula": "(1 - g^2) / (4 pi (1 + g^2 - 2 g nu)^1.5)"}),
        Phase::Mixture {
            g,
            rayleigh_fraction,
        } => json!({"kind": "mixture", "g": g, "rayleigh_fraction": rayleigh_fraction,
            "formula": "(1 - f) cornette_shanks(g, nu) + f 3/(16 pi) (1 + nu^2)"}),
        Phase::Isotropic => json!({"kind": "isotropic", "formula": "1/(4 pi)"}),
        Phase::Rayleigh => json!({"kind": "rayleigh", "formula": "3/(16 pi) (1 + nu^2)"}),
    }
}

/// The phase function a manifest's `aerosol_phase_function` describes.
pub fn phase_from_json(v: &Value) -> crate::Result<Phase> {
    let bad = || {
        crate::Error::invalid(
            "manifest",
            "`aerosol_phase_function` is not a known phase function",
        )
    };
    let g = || {
        v.get("g")
            .and_then(Value::as_f64)
            .filter(|g| g.is_finite())
            .ok_or_else(bad)
    };
    Ok(match v.get("kind").and_then(Value::as_str) {
        Some("cornette_shanks") => Phase::CornetteShanks { g: g()? },
        Some("henyey_greenstein") => Phase::HenyeyGreenstein { g: g()? },
        Some("mixture") => Phase::Mixture {
            g: g()?,
            rayleigh_fraction: v
                .get("rayleigh_fraction")
                .and_then(Value::as_f64)
                .filter(|f| f.is_finite())
                .ok_or_else(bad)?,
        },
        Some("isotropic") => Phase::Isotropic,
        Some("rayleigh") => Phase::Rayleigh,
        _ => return Err(bad()),
    })
}

/// Stated error of each table: the largest relative error of what [`SkyViewReader`] computes
/// from it against skybake's own product, per band of the accuracy targets, measured by
/// tests/atmosphere/lut_skyview.rs (`earth`, quality `standard`, RGB form; docs/lut.md).
pub const STATED_ERRORS: &[(&str, &str, f64)] = &[
    ("transmittance", "direct normal irradiance (sun product), sun >= 5 deg, 0-100 km", 0.0003),
    ("transmittance", "direct normal irradiance (sun product), sun -6..5 deg", 0.004),
    ("rayleigh+mie", "sky radiance (sky product), sun >= 5 deg, view > 10 deg above the horizon, ground", 0.0027),
    ("rayleigh+mie", "sky radiance (sky product), sun >= 5 deg, view > 10 deg above the horizon, 0-20 km", 0.0017),
    ("rayleigh+mie", "sky radiance (sky product), sun >= 5 deg, view > 10 deg above the horizon, 20-100 km", 0.0026),
    ("rayleigh+mie", "sky radiance (sky product), sun >= 5 deg, view < 10 deg above the horizon, ground", 0.0045),
    ("rayleigh+mie", "sky radiance (sky product), sun >= 5 deg, view < 10 deg above the horizon, 0-20 km", 0.0048),
    ("rayleigh+mie", "sky radiance (sky product), sun >= 5 deg, view < 10 deg above the horizon, 20-100 km", 0.021),
    ("rayleigh+mie", "sky radiance (sky product), sun -6..5 deg, ground", 0.012),
    ("rayleigh+mie", "sky radiance (sky product), sun -6..5 deg, 0-5 km (the band above the earth's shadow 120 deg from the sun, 680 nm at 5 km, 0.5 deg above the horizontal; the twilight glow towards the sun at most 3 %)", 0.046),
    ("rayleigh+mie", "sky radiance (sky product), sun -6..5 deg, 5-8 km (the band above the earth's shadow, 680 nm at 8 km, 1.75 deg above the horizontal 150 deg from the sun, sun -2.5 deg, the dense check; between its samples 2.5 %)", 0.027),
    ("rayleigh+mie", "sky radiance (sky product), sun -6..5 deg, 8-12.5 km (the sky 2.1 deg up 172.5 deg from the sun, 680 nm at 9.5 km, sun -2.625 deg, between the dense check's samples; on them 2.4 % at 9.5 km, the sky 3.5 deg up 180 deg from the sun, 440 nm, and at 12.5 km, the limb 2 deg below the horizontal 135 deg from the sun; at 12.5 km 2.4 % between them; the twilight glow towards the sun at most 3 %)", 0.031),
    ("rayleigh+mie", "sky radiance (sky product), sun -6..5 deg, 12.5-20 km (the limb 0.9 deg above the horizon 172.5 deg from the sun, 680 nm at 20 km, sun -4.125 deg, between the dense check's samples; on them 4.6 % at 20 km, the sky 2.25 deg up 135 deg from the sun, and 4.9 % at 17.5 km, the sky 3 deg up 150 deg from the sun, sun -4 deg; the twilight glow towards the sun at most 3 %)", 0.052),
    ("rayleigh+mie", "sky radiance (sky product), sun -6..0 deg, 0-5 km, views within 10 deg of the horizon 150-180 deg from the sun (the earth's shadow rising; 680 nm at 2.5 km)", 0.022),
    ("rayleigh+mie", "sky radiance (sky product), sun -6..5 deg, 20-100 km (random samples: 2.9 %; but the limb just above the horizon 150-180 deg from the sun seen from 22.5-40 km, up to 32 %: 30 km, sun -4.75 deg, 5.25 deg below the horizontal opposite the sun, 680 nm; 24 % at 35 km, 18 % at 25 km, 16 % at 40 km, 5.4 % at 22.5 km; the sky just above the horizontal 30-120 deg from the sun with the sun at -6..-3 deg up to 23 % at 40 km, 19 % at 35 km, 9.9 % at 30 km, 5.5 % at 25 km, 4.9 % at 22.5 km, 5.8 % at 20 km; the band above the earth's shadow above the horizontal at most 9.1 %: 40 km, 6.5 % at 30 km, 4.9 % at 25 km, 4.0 % at 22.5 km)", 0.32),
    ("rayleigh+mie", "sky radiance (sky product), sun -12..-6 deg, ground", 0.033),
    ("rayleigh+mie", "sky radiance (sky product), sun -12..-6 deg, 0-20 km (the twilight glow towards the sun near the horizontal: 9.2 % at 5 km, sun -12 deg, 0.25 deg above the horizontal 30 deg from the sun, 680 nm)", 0.092),
    ("rayleigh+mie", "sky radiance (sky product), sun -12..-6 deg, 20-100 km (the sky towards the sun 10 deg above the horizontal, 440 nm at 45 km, sun -11 deg, on the dense check of 45-55 km 0-30 deg from the sun; random samples 8.1 %: the sky 2.8 deg above the horizontal 109 deg from the sun, 440 nm at 79.5 km, sun -8.75 deg)", 0.104),
    ("irradiance", "diffuse horizontal irradiance (sun product), sun >= 5 deg, 0-100 km", 0.015),
    ("irradiance", "diffuse horizontal irradiance (sun product), sun -12..5 deg, 0-100 km", 0.016),
];

fn sample_name(s: Sample) -> &'static str {
    match s {
        Sample::Half => "half",
        Sample::Float => "float",
    }
}

/// The `skyview` bundle's manifest, for the canonical request `request`; `names` are the
/// channels of every texture but the scale's (`scale_names`).
pub fn manifest(
    b: &SkyViewBundle,
    names: &[String],
    scale_names: &[String],
    request: Value,
    engine_version: &str,
) -> Value {
    let entry = |t: &Texture, file: &str, channels: &[String], what: &str| {
        json!({"file": file, "width": t.width, "height": t.height, "depth": t.depth,
            "sample": sample_name(t.sample), "channels": channels, "content": what})
    };
    let channels: Vec<Value> = names
        .iter()
        .zip(&b.wavelengths_nm)
        .map(|(n, w)| json!({"name": n, "wavelength_nm": w}))
        .collect();
    let sun_nodes: Vec<f64> = (0..N_SUN).map(sun_node_deg).collect();
    let thickness = b.params.top_radius - b.params.bottom_radius;
    let altitude_nodes: Vec<f64> = (0..N_ALT).map(|k| altitude_node_m(k, thickness)).collect();
    let azimuth_nodes: Vec<Vec<f64>> = altitude_nodes
        .iter()
        .map(|&h| (0..N_AZ).map(|a| azimuth_node(a, h)).collect())
        .collect();
    // Its own value: the whole manifest in one `json!` exceeds the macro's recursion limit.
    let limb_near_end = json!({
        "azimuth_cos": LIMB_NEAR_END_AZIMUTH,
        "depth_m": LIMB_NEAR_END_DEPTH_M,
        "altitude_range_m": LIMB_NEAR_END_ALTITUDE_M,
        "node_weight_altitude_m": LIMB_NODE_WEIGHT_ALTITUDE_M,
        "node_query_weight_altitude_m": LIMB_NODE_QUERY_WEIGHT_M,
    });
    let sky_row_band = json!({
        "sun_deg": BAND_SUN_DEG,
        "centre": BAND_CENTRE,
        "focus": BAND_FOCUS,
        "sun_range_deg": BAND_SUN_RANGE,
        "centre_range_deg": BAND_CENTRE_RANGE_DEG,
        "centre_floor": BAND_CENTRE_FLOOR,
        "altitude_range_m": BAND_ALTITUDE_M,
        "antisolar": BAND_ANTISOLAR,
        "depth_deg_per_km": BAND_DEPTH_PER_KM,
        "depth_top_m": BAND_DEPTH_TOP_M,
        "centre_aloft_per_km": BAND_CENTRE_ALOFT,
        "centre_aloft_altitude_m": BAND_CENTRE_ALOFT_M,
        "centre_top_per_km": BAND_CENTRE_TOP,
        "centre_top_altitude_m": BAND_CENTRE_TOP_M,
        "slices_aloft_per_km": BAND_SLICE_ALOFT,
        "slices_through_altitude_m": BAND_SLICE_THROUGH_M,
        "slices_top_per_km": BAND_SLICE_TOP,
        "slices_azimuth_altitude_m": BAND_SLICE_AZIMUTH_M,
        "horizon_deg": BAND_HORIZON_DEG,
        "antisolar_range": [BAND_ANTISOLAR_RANGE.0, BAND_ANTISOLAR_RANGE.1],
        "focus_growth": BAND_FOCUS_GROWTH,
        "focus_growth_altitude_m": BAND_FOCUS_GROWTH_M,
        "focus_aloft": BAND_FOCUS_ALOFT,
        "focus_aloft_altitude_m": BAND_FOCUS_ALOFT_M,
        "focus_place_aloft": BAND_FOCUS_PLACE_ALOFT,
        "focus_place_altitude_m": BAND_FOCUS_PLACE_M,
        "focus_high": BAND_FOCUS_HIGH,
        "focus_width_azimuth_cos": BAND_FOCUS_WIDTH_AZIMUTH,
        "focus_width_floor_deg": BAND_FOCUS_WIDTH_FLOOR_DEG,
        "focus_width_altitude_m": BAND_FOCUS_WIDTH_M,
        "focus_wide": BAND_FOCUS_WIDE,
        "sun_soft_deg": BAND_SUN_SOFT_DEG,
        "azimuth_depth_aloft_deg": BAND_AZIMUTH_DEPTH_ALOFT,
        "azimuth_depth_aloft_altitude_m": BAND_AZIMUTH_DEPTH_ALOFT_M,
        "slices": "on the sky rows, each (altitude node k, sun node j) slice of the interpolation is read on its own rows (the focus (c_n, k_n) at the node's sun coordinate s_n = the warped s_j at h_k and its altitude h_n = altitude_nodes_m[k]) where the query's or the slice's k > 0: at e_n = e + f (1 - smoothstep(2 w, 4 w, e)) (smoothstep(0, horizon_deg, e) (1 - t) + step(-delta_q, e) t) ((e + delta_q) H_n / H_q - delta_n - e) (1 - smoothstep(slices_azimuth_altitude_m[0], slices_azimuth_altitude_m[1], h) (1 - smoothstep(antisolar_range[0], antisolar_range[1], -cos phi))) (version 19: faded in with -cos phi aloft), t = smoothstep(slices_through_altitude_m[0], slices_through_altitude_m[1], h) (version 16; an e_n below 0 read on the limb rows as the azimuth formula's e_a), H = max(c_s antisolar + delta, 0.1) at the query's (s, h) and the node's (s_n, h_n), c_s the formula's c with its factor aloft replaced by 1 + a x + (b - a) x^2 / (2 L) + slices_top_per_km T (T as in the formula; version 19), x = clamp(h - centre_aloft_altitude_m[0], 0, L) / 1000, L = max((centre_aloft_altitude_m[1] - centre_aloft_altitude_m[0]) / 1000, 1e-3), [a, b] = slices_aloft_per_km (version 16), delta = depth_deg_per_km clamp(h, 0, depth_top_m) / 1000, w = max(H_q, 0.5), f = k / (focus (1 + focus_growth smoothstep(focus_growth_altitude_m[0], focus_growth_altitude_m[1], h)) (1 + focus_aloft smoothstep(focus_aloft_altitude_m[0], focus_aloft_altitude_m[1], h))) the query's fade (0 where k = 0), then each column at the azimuth formula's e_a with (c_n, k_n, h_n) in place of the query's",
        "azimuth": "on the sky rows and the limb rows where k > 0 each azimuth column a of the interpolation is read at its own elevation e_a (its own rows' stencil): d = depth_deg_per_km clamp(h, 0, depth_top_m) / 1000, delta = d + (azimuth_depth_aloft_deg - d) smoothstep(azimuth_depth_aloft_altitude_m[0], azimuth_depth_aloft_altitude_m[1], h) (version 12), w = max(c antisolar + delta, 0.5), ratio = max(-cos phi_a, antisolar_range[0]) / max(-cos phi, antisolar_range[0]), e_a = e + (k / (focus (1 + focus_growth smoothstep(focus_growth_altitude_m[0], focus_growth_altitude_m[1], h)) (1 + focus_aloft smoothstep(focus_aloft_altitude_m[0], focus_aloft_altitude_m[1], h)))) (1 - smoothstep(2 w, 4 w, e)) step(-delta, e) smoothstep(antisolar_range[0], antisolar_range[1], -cos phi) (e + delta) (ratio - 1) (version 7: from -delta up through the horizontal, where version 6 had smoothstep(0, horizon_deg, e)), e the query's elevation (deg), phi its azimuth from the sun, phi_a the column's in the slice (azimuth_nodes_rad[k][a], the slice's altitude node k; version 12: at the query's altitude h); where e_a >= 0 the column is read on the sky rows, below on the limb rows at the query's altitude h (depth y = 2 r sin^2(e_a / 2) / h); the band above the earth's shadow lies at (c antisolar + delta)(-cos phi) - delta",
        "formula": "the sky rows' focus at the sun's elevation s above the observer's horizon (deg) and altitude h (m): u = sun_soft_deg ln(1 + exp((sun_deg - s) / sun_soft_deg)) (version 14: max(sun_deg - s, 0)), km = clamp(h, 0, centre_aloft_altitude_m[0]) / 1000, c = min(((centre[0] + centre[1] km) u + (centre[2] + centre[3] km) u^2) (1 + centre_aloft_per_km clamp(h - centre_aloft_altitude_m[0], 0, centre_aloft_altitude_m[1] - centre_aloft_altitude_m[0]) / 1000 + centre_top_per_km T), 45), T = clamp(h - centre_aloft_altitude_m[1], 0, max(centre_top_altitude_m - centre_aloft_altitude_m[1], 0)) / 1000 (version 19) (deg, the band's elevation: the maps' c), the rows' focus at c_f = c (q + (focus_place_aloft antisolar - q) v), q = 1 + (focus_place_aloft antisolar - 1) a (x_c = 1 - sqrt(c_f / 90); version 15), l = 1 - smoothstep(centre_range_deg[0], centre_range_deg[1], c), a = l smoothstep(focus_place_altitude_m[0], focus_place_altitude_m[1], h), v = l smoothstep(focus_width_altitude_m[0], focus_width_altitude_m[1], h) (1 - smoothstep(focus_width_altitude_m[2], focus_width_altitude_m[3], h)) (version 18), k = smoothstep(sun_range_deg[0], sun_range_deg[1], s) (1 - smoothstep(sun_range_deg[2], sun_range_deg[3], s)) (1 - smoothstep(altitude_range_m[0], altitude_range_m[1], h)) (l (1 + focus_high a) + centre_floor (1 - l)) focus (1 + focus_growth smoothstep(focus_growth_altitude_m[0], focus_growth_altitude_m[1], h)) (1 + focus_aloft smoothstep(focus_aloft_altitude_m[0], focus_aloft_altitude_m[1], h)) (1 + focus_wide v), the focus's width w = v max(x0(e_w) - x_c, 0) (x0(e) = 1 - sqrt(e / 90), e_w = max((c antisolar + delta) focus_width_azimuth_cos - delta, focus_width_floor_deg), delta the azimuth formula's; version 18), smoothstep(a, b, x) = t^2 (3 - 2 t), t = clamp((x - a) / (b - a), 0, 1)",
    });
    let limb_row_band = json!({
        "depth_m": LIMB_BAND_DEPTH_M,
        "focus": LIMB_BAND_FOCUS,
        "sun_range_deg": LIMB_BAND_SUN_RANGE,
        "altitude_range_m": LIMB_BAND_ALTITUDE_M,
        "depth_floor_m": LIMB_BAND_DEPTH_FLOOR_M,
        "altitude_exponent": LIMB_BAND_ALTITUDE_EXPONENT,
        "max_fraction": LIMB_BAND_MAX_FRACTION,
        "horizon_held": LIMB_BAND_HORIZON_HELD,
        "deepest": LIMB_BAND_DEEPEST,
        "edge_depth_m": LIMB_EDGE_DEPTH_M,
        "edge_focus": LIMB_EDGE_FOCUS,
        "edge_sun_range_deg": LIMB_EDGE_SUN_RANGE,
        "edge_altitude_range_m": LIMB_EDGE_ALTITUDE_M,
        "slices": "on the limb rows each (altitude node k, sun node j) slice is read at the depth y_n = y + f (clamp(m, 0, 1) - y) on its own rows, m = y rho where y <= yb, else y rho + w (ybn + (y - yb) (1 - ybn) / (1 - yb) - y rho), w = 1 - smoothstep(horizon_held[0], horizon_held[1], yb), rho = (h / h_n)^altitude_exponent D(s_n) / D(s), yb = min(D(s) / h, max_fraction), ybn = min(yb rho, max_fraction) (formula at s_n, h_n), y the query's depth, s its sun coordinate, h its altitude, s_n and h_n the slice's (s_n = the warped s_j at h_n = altitude_nodes_m[k]), D(s) = max(depth_m[0] + depth_m[1] s' + depth_m[2] s'^2, depth_floor_m), s' = clamp(s, sun_range_deg[0] - 1, sun_range_deg[3]), f = k / focus at the query's (s, h) (y_n = y where f = 0); on the limb rows the sun stencil of altitude node k starts at the first node from the stencil's first up to its interval's lower node whose slice is not read past its horizon, y + f (m - y) <= 1, m = the map before its clamp (the stencil's polynomial through the remaining nodes); but where the focus acts (k > 0 at the query's s, h) and the interval's lower node i0's slice would be read deeper than deepest, y + f (m - y) > deepest (version 20), the stencil is the line in the logarithms through nodes i0 + 1 and i0 + 2, extrapolated to the query's node coordinate (weights 1 - t, t, t = (x - x_{i0+1}) / (x_{i0+2} - x_{i0+1}) < 0 in the sun node coordinates t_j, not bounded by the two values)",
        "formula": "the limb rows' focus (version 10) at sun coordinate s (deg; a texel's node s_j, for a query each slice's own s_n at its altitude h_n) and altitude h (m): depth D = depth_m[0] + depth_m[1] s + depth_m[2] s^2 (m), x_c = the limb coordinate of y_c = clamp(D / h, 0, 1) (x_c = 2/3 + (4/3) cos(acos(1 - 27 y_c / 16) / 3 - 2 pi / 3)), k = focus smoothstep(sun_range_deg[0], sun_range_deg[1], s) (1 - smoothstep(sun_range_deg[2], sun_range_deg[3], s)) smoothstep(altitude_range_m[0], altitude_range_m[1], h) (1 - smoothstep(altitude_range_m[2], altitude_range_m[3], h)) (0 where h <= 0); the limb row coordinate of depth y is x = (asinh(k (x0 - x_c)) - A) / (B - A), x0 = 2/3 + (4/3) cos(acos(1 - 27 y / 16) / 3 - 2 pi / 3), A = asinh(-k x_c), B = asinh(k (1 - x_c)) (x = x0 where k < 1e-6); inverse x0 = x_c + sinh(A + x (B - A)) / k, y = 2 x0^2 - x0^3. Where that k is 0 (the band's focus off, from 30 km up), the focus on the earth's shadow's edge aloft instead: D = edge_depth_m[0] + edge_depth_m[1] s, k = edge_focus smoothstep(edge_sun_range_deg[0], edge_sun_range_deg[1], s) (1 - smoothstep(edge_sun_range_deg[2], edge_sun_range_deg[3], s)) smoothstep(edge_altitude_range_m[0], edge_altitude_range_m[1], h) (1 - smoothstep(edge_altitude_range_m[2], edge_altitude_range_m[3], h)), the same x_c and rows; the slices' map's f and the sun stencil take the band's k alone. On the limb rows every (altitude node k, sun node j) slice is read on its own rows at the depth of `slices` (and a column moved below the horizontal by sky_row_band.azimuth likewise, at its depth 2 r sin^2(e_a / 2) / h)",
    });
    json!({
        "format": LAYOUT,
        "bundle_version": SKYVIEW_VERSION,
        "software": concat!("skybake ", env!("CARGO_PKG_VERSION")),
        "engine_version": engine_version,
        "request": request,
        "mode": "radiance",
        "channels": channels,
        "channel_formation": "each channel is the spectral quantity at its wavelength, not a band average or a colour-space conversion",
        "units": {
            "length": "m",
            "angle": "rad unless the name says deg",
            "radiance": "mW m^-2 sr^-1 nm^-1",
            "irradiance": "mW m^-2 nm^-1",
            "texture_value_per_watt": UNIT_SCALE_REF,
        },
        "parameterisation": {
            "reference": "skybake docs/lut.md, section `The skyview layout`",
            "altitude_nodes_m": altitude_nodes,
            "altitude_node": format!("the altitude abscissa of altitude h: x = (sqrt(e) + c (e^p - e^q)) {}, e = h / (top_radius - bottom_radius), [c, p, q] = altitude_map; node k (0..N_ALT-1, altitude_nodes_m) is the altitude whose abscissa is altitude_node_abscissas[k] (the integers 0..{} and the halves between some of them, increasing); a query's node interval is the k with altitude_node_abscissas[k] <= x < altitude_node_abscissas[k + 1]", N_ALT_BASE - 1, N_ALT_BASE - 1),
            "altitude_map": ALTITUDE_TOP,
            "altitude_node_abscissas": (0..N_ALT).map(altitude_node_x).collect::<Vec<_>>(),
            "texel_mantissa_bits": HALF_MANTISSA_BITS,
            "sun_elevation_nodes_deg": sun_nodes,
            "sun_node": "the sun node coordinate t_j (deg): every 2 deg from -23 to -15, every 1 deg to -8, every 0.5 deg to -1, every 0.25 deg to 0, every 0.125 deg to 0.5, every 0.25 deg to 1, every 0.5 deg to 6, every 1 deg to 20, every 4 deg to 104 (segments [start, step, intervals] in sun_segments). At altitude h the node's sun coordinate s_j = warp(t_j, b, c), b = sun_warp_strength * sqrt(h / (top_radius - bottom_radius)), warp(t, b, c) = c + e sinh(b (t - c) / e) / sinh(b) for sun_warp_range[0] < t < sun_warp_range[1] (e = c - sun_warp_range[0] for t < c, sun_warp_range[1] - c for t >= c), t elsewhere (and where b < 1e-6); its inverse t = c + e asinh((s - c) sinh(b) / e) / b gives a query's node coordinate, the interpolation's abscissa. The centre c (deg) = 0 but on the sky rows towards the sun (version 15): c = sun_warp_centre.weight max(cos(phi), 0)^2 smoothstep(sun_warp_centre.altitude_range_m[0], sun_warp_centre.altitude_range_m[1], h) (acos(bottom_radius / r) - acos(bottom_radius / top_radius)) in degrees, phi the view's (for a texel its column's) azimuth from the sun, h and r the query's (the node's) altitude and radius. s = the sun's elevation + shift: for view rows below the horizon (and the irradiance, and the sky rows below sky_exit_altitude_m[0] or more than acos(-sky_exit_azimuth_fade) from the sun) shift = the horizon's dip acos(bottom_radius / r), the sun's elevation above the observer's horizon; for the limb rows (between the horizontal and the horizon) shift = dip + w (gamma cos(phi) + acos(bottom_radius / r_t) - dip), w = (1 - exp(-(r - r_t) / limb_shadow_scale_m)) (1 - n), n = (1 - smoothstep(limb_near_end.azimuth_cos[0], limb_near_end.azimuth_cos[1], cos(phi))) smoothstep(limb_near_end.depth_m[0], limb_near_end.depth_m[1], r - r_t) smoothstep(limb_near_end.altitude_range_m[0], limb_near_end.altitude_range_m[1], h) (version 11: aloft away from the sun back towards the observer's horizon): towards the sun's elevation above the horizon of the ray's tangent point, with dip = acos(bottom_radius / r), gamma = theta - pi/2, r_t = r cos(gamma), phi the view's azimuth from the sun; for the sky rows (above the horizontal) shift = dip + smoothstep(sky_exit_altitude_m[0], sky_exit_altitude_m[1], h) g(cos(phi)) alpha, g(c) = c for c >= 0, c (1 + c / f)^2 for -f < c < 0, 0 below (f = sky_exit_azimuth_fade), alpha = atan2(x sin(theta), r + x cos(theta)), x the ray's length to the top (the central angle to where the ray leaves the atmosphere; smoothstep as in sky_row_band); the texels of a limb or sky row are at the sun elevations s_j - shift of their column's azimuth",
            "sun_warp_strength": SUN_WARP,
            "sun_warp_range": [SUN_WARP_RANGE.0, SUN_WARP_RANGE.1],
            "sun_warp_centre": {
                "weight": SUN_WARP_CENTRE,
                "altitude_range_m": SUN_WARP_CENTRE_ALTITUDE_M,
            },
            "limb_shadow_scale_m": LIMB_SHADOW_SCALE_M,
            "sky_exit_altitude_m": SKY_EXIT_ALTITUDE_M,
            "sky_exit_azimuth_fade": SKY_EXIT_AZIMUTH_FADE,
            "limb_near_end": limb_near_end,
            "sun_segments": SUN_SEGMENTS.iter().map(|(a, b, n)| json!([a, b, n])).collect::<Vec<_>>(),
            "sky_row_band": sky_row_band,
            "limb_row_band": limb_row_band,
            "view_rows": format!("rows 0..{} from the zenith to the horizontal: elevation = 90 (1 - x0)^2 (deg), x0 = G^-1(A + x (B - A)), x = row / {}, x_c = 1 - sqrt(c_f / 90), G(x0) = asinh(k (x0 - x_c)) for x0 < x_c, k (x0 - x_c) for x_c <= x0 <= x_c + w, k w + asinh(k (x0 - x_c - w)) above (version 18; w = 0 before), A = G(0), B = G(1), (c_f, k, w) the sky rows' focus (sky_row_band) at the sun's elevation above the observer's horizon (its node's s_j for a texel, the query's own for a query) and the observer's altitude; where k < 1e-6, x0 = x; inverse: x0 = 1 - sqrt(elevation / 90), x = (G(x0) - A) / (B - A) (or x0); rows {}..{} from the horizontal to the horizon: the ray's tangent radius r_t = r - (r - bottom_radius) y, y = 2 x0^2 - x0^3, x0 = the unfocused coordinate of x = (row - {}) / {} with the limb rows' focus (limb_row_band; x0 = x where k = 0; inverse: x0 = 2/3 + (4/3) cos(acos(1 - 27 y / 16) / 3 - 2 pi / 3)), theta = pi/2 + acos(r_t / r); rows {}..{} from the horizon to the nadir: theta = theta_h + (pi - theta_h) x^2, x = (row - {}) / {}, theta_h = pi - asin(bottom_radius / r); r the observer's radius. Interpolation over the rows around the view stays within its segment (see interpolation)", N_VIEW_SKY - 1, N_VIEW_SKY - 1, N_VIEW_SKY, N_VIEW_UP - 1, N_VIEW_SKY, N_VIEW_LIMB - 1, N_VIEW_UP, N_VIEW - 1, N_VIEW_UP, N_VIEW_DOWN - 1),
            "azimuth_columns": format!("the column coordinate of the view's azimuth phi from the sun's (0..pi) at altitude h (m): column = (alpha sqrt(phi / pi) + (1 - alpha - beta) sin(phi / 2)^2 + beta G(phi)) {}, alpha = azimuth_aloft.ground_weight - (azimuth_aloft.ground_weight - azimuth_aloft.weight) smoothstep(azimuth_aloft.altitude_range_m[0], azimuth_aloft.altitude_range_m[1], h) (version 14; version 13: ground_weight 1), beta = azimuth_focus.weight smoothstep(azimuth_focus.altitude_range_m[0], azimuth_focus.altitude_range_m[1], h), G(phi) = (tanh((phi - c) / w) - tanh(-c / w)) / (tanh((pi - c) / w) - tanh(-c / w)), c = azimuth_focus.centre_deg, w = azimuth_focus.width_deg (in rad; smoothstep as in sky_row_band); a texel of altitude node k lies at the phi whose coordinate at h_k is its column (azimuth_nodes_rad[k][column]); a query at altitude h reads altitude node k at column coordinate c_q + lambda (c_k - c_q), c_q its azimuth's coordinate at h, c_k at h_k (the node's own map), lambda = smoothstep(azimuth_focus.node_read_altitude_m[0], azimuth_focus.node_read_altitude_m[1], h) (version 13; version 12: c_q), and azimuth_nodes_rad[k] are the columns' azimuths in sky_row_band.azimuth", N_AZ - 1),
            "azimuth_aloft": {
                "weight": AZIMUTH_ALOFT_WEIGHT,
                "ground_weight": AZIMUTH_GROUND_WEIGHT,
                "altitude_range_m": AZIMUTH_ALOFT_M,
            },
            "azimuth_focus": {
                "weight": AZIMUTH_FOCUS[0],
                "centre_deg": AZIMUTH_FOCUS[1],
                "width_deg": AZIMUTH_FOCUS[2],
                "altitude_range_m": AZIMUTH_FOCUS_ALTITUDE_M,
                "node_read_altitude_m": AZIMUTH_NODE_READ_M,
            },
            "azimuth_nodes_rad": azimuth_nodes,
            "slices": "slice = altitude_index * N_SUN + sun_index; file row = slice * N_VIEW + view_row; texture coordinates at texel centres: u = (column + 0.5) / N_AZ, v = (view_row + 0.5) / N_VIEW",
            "sizes": {"N_ALT": N_ALT, "N_SUN": N_SUN, "N_VIEW_SKY": N_VIEW_SKY, "N_VIEW_LIMB": N_VIEW_LIMB, "N_VIEW_DOWN": N_VIEW_DOWN, "N_AZ": N_AZ},
            "interpolation": "per (altitude, sun, view row) node triple around the query: over the 4 azimuth columns around the query, then over the rows (times the slice's scale) (on the sky rows where the query's or the slice's focus k > 0: over each column's own rows in the slice, sky_row_band.slices and sky_row_band.azimuth, then over the columns), the sun nodes and then the altitude nodes, each axis with up to 4 nodes around the query within its segment (the row segments: sky, limb, below the horizon; 3 nodes in a segment's first and last interval; the columns continued by their mirror images, column -1 = column 1 and column N_AZ = column N_AZ - 2 (the sky at -phi and 2 pi - phi; version 19), so 4 columns in the first and last interval too): the Lagrange polynomial through the nodes' logarithms at the query, exp'd and bounded by the nodes' range; abscissas: for the altitude the nodes' altitude_node_abscissas and the query's x (altitude_node), else the node index (rows: as view_rows; columns: as azimuth_columns), for the sun the node's s_j in degrees; where a node value is not positive, geometric between the interval's two nodes, a^(1-t) b^t, linear where a value is not positive",
            "radiance": "L = rayleigh * RayleighPhase(nu) + mie * aerosol_phase_function(nu), nu = cos of the angle between view and sun; RayleighPhase = 3/(16 pi) (1 + nu^2)",
            "observer": "inside the atmosphere; above its top, move the observer along the view to the top first (a view missing the atmosphere sees nothing); views below the horizon: the in-scattered light along the ray to the ground, without the ground's reflection",
            "transmittance_texture": [crate::param::TRANSMITTANCE_WIDTH, crate::param::TRANSMITTANCE_HEIGHT],
            "transmittance": "Bruneton 2017's transmittance texture and GetTransmittanceTextureUvFromRMu, as in the bruneton2017 layout",
        },
        "atmosphere_parameters": b.params,
        "aerosol_phase_function": phase_json(&b.aerosol_phase),
        "sun": {
            "angular_radius_rad": b.params.sun_angular_radius,
            "radiance": "solar_irradiance / (pi * sun_angular_radius^2) per channel, times the transmittance to the sun, inside the disk",
        },
        "textures": {
            "transmittance": entry(&b.transmittance, crate::manifest::TRANSMITTANCE_FILE, names, "transmittance to the top of the atmosphere, (u, v) = GetTransmittanceTextureUvFromRMu(r, mu) (Bruneton 2017)"),
            "rayleigh": entry(&b.rayleigh, RAYLEIGH_FILE, names, "single Rayleigh scattering without its phase function + multiple scattering divided by RayleighPhase(nu), divided by the slice's rayleigh scale"),
            "mie": entry(&b.mie, MIE_FILE, names, "single Mie (aerosol) scattering without its phase function, divided by the slice's mie scale"),
            "scale": entry(&b.scale, SCALE_FILE, scale_names, "per slice (column = sun index, row = altitude index) and channel: the factor the rayleigh (rayleigh.*) and mie (mie.*) texels of that slice are multiplied by"),
            "irradiance": entry(&b.irradiance, IRRADIANCE_FILE, names, "the sky's (indirect) irradiance on a horizontal surface at the node altitudes (rows) and sun elevations (columns), interpolated geometrically like the sky; the sun's direct irradiance is computed from the transmittance texture"),
        },
        "stated_error": STATED_ERRORS.iter().map(|(t, what, e)| json!({"table": t, "measure": what, "max_relative_error": e})).collect::<Vec<_>>(),
    })
}

const UNIT_SCALE_REF: f64 = crate::build::UNIT_SCALE;

#[cfg(test)]
mod tests {
    use super::*;

    const R: f64 = 6_360_000.0;
    const H: f64 = 100_000.0;

    /// The columns' stencil continued by mirror images: hand values. Its nodes past the ends
    /// are columns 1 and N_AZ − 2, a query in the last interval gets the centred cubic's weights
    /// (−1, 9, 9, −1)/16 at its middle, which are exact for a parabola even about φ = π.
    #[test]
    fn the_columns_are_mirrored_past_the_sun_and_the_antisolar_point() {
        assert_eq!(column_texel(0), 1);
        assert_eq!(column_texel(1), 0);
        assert_eq!(column_texel(N_AZ), N_AZ - 1);
        assert_eq!(column_texel(N_AZ + 1), N_AZ - 2);
        let last = (N_AZ - 1) as f64;
        let st = column_stencil(last - 0.5, 4);
        assert_eq!((st.first, st.len), (N_AZ - 2, 4));
        let cols: Vec<usize> = (0..4).map(|m| column_texel(st.first + m)).collect();
        assert_eq!(cols, vec![N_AZ - 3, N_AZ - 2, N_AZ - 1, N_AZ - 2]);
        for (w, want) in st.w.iter().zip([-1.0, 9.0, 9.0, -1.0]) {
            assert!((w - want / 16.0).abs() < 1e-12, "{:?}", st.w);
        }
        // f = (column − last)²: 4, 1, 0, 1 at the nodes, 0.25 at the query.
        let f: f64 = cols
            .iter()
            .zip(&st.w)
            .map(|(&a, w)| w * (a as f64 - last).powi(2))
            .sum();
        assert!((f - 0.25).abs() < 1e-12, "{f}");
        // Near the sun: the first interval reads column 1 on both sides of column 0.
        let st = column_stencil(0.5, 4);
        assert_eq!((st.first, st.len), (0, 4));
        let cols: Vec<usize> = (0..4).map(|m| column_texel(st.first + m)).collect();
        assert_eq!(cols, vec![1, 0, 1, 2]);
        // Inside, the same nodes as the unmirrored stencil.
        let st = column_stencil(7.25, 4);
        assert_eq!((column_texel(st.first), st.len), (6, 4));
        // Two nodes: the interval's.
        let st = column_stencil(last - 0.5, 2);
        assert_eq!((column_texel(st.first), st.len), (N_AZ - 2, 2));
    }

    #[test]
    fn node_coordinates_invert_the_nodes() {
        for j in 0..N_SUN {
            assert!(
                (sun_coord(sun_node_deg(j)) - j as f64).abs() < 1e-9,
                "sun node {j}"
            );
        }
        // Increasing, from −15° to 104°.
        assert_eq!(sun_node_deg(0), SUN_MIN_DEG);
        assert!((sun_node_deg(N_SUN - 1) - 104.0).abs() < 1e-12);
        assert!((1..N_SUN).all(|j| sun_node_deg(j) > sun_node_deg(j - 1)));
        for k in 0..N_ALT {
            let h = altitude_node_m(k, H);
            assert!(
                (altitude_coord(h, H) - k as f64).abs() < 1e-9,
                "altitude node {k}"
            );
        }
        for h in [0.0, 15_000.0, 20_000.0, 50_000.0, H] {
            for a in 0..N_AZ {
                assert!((azimuth_coord(azimuth_node(a, h), h) - a as f64).abs() < 1e-9);
            }
        }
        // The square root alone would put column 7 at π (7/19)²; with sin²(φ/2)'s share the
        // columns near the ground are sparser near the sun, denser around 90° from it.
        assert!(azimuth_node(7, 15_000.0) > PI * (7.0f64 / 19.0).powi(2));
        // The altitude nodes: near the square root's below 10 km; the last interval 3.3 km (7.3 km).
        for k in 1..8 {
            let sqrt_map = H * (k as f64 / (N_ALT_BASE - 1) as f64).powi(2);
            assert!(
                (altitude_node_m(k, H) / sqrt_map - 1.0).abs() < 0.01,
                "node {k}"
            );
        }
        // The base nodes and the inserted halves, increasing; the halves halfway between.
        assert_eq!(altitude_node_x(N_ALT - 1), (N_ALT_BASE - 1) as f64);
        assert!((1..N_ALT).all(|k| altitude_node_x(k) > altitude_node_x(k - 1)));
        let halves: Vec<f64> = (0..N_ALT)
            .map(altitude_node_x)
            .filter(|x| x.fract() != 0.0)
            .collect();
        assert_eq!(halves, ALTITUDE_INSERTED);
        let top_gap = H - altitude_node_m(N_ALT - 2, H);
        assert!((3_200.0..3_400.0).contains(&top_gap), "{top_gap}");
        let gap = |a: usize, h: f64| azimuth_node(a + 1, h) - azimuth_node(a, h);
        assert!((1..N_AZ).all(|a| azimuth_node(a, H) > azimuth_node(a - 1, H)));
        let near_90 = (
            azimuth_coord(0.5 * PI, H) as usize,
            azimuth_coord(0.5 * PI, 0.0) as usize,
        );
        assert!(gap(near_90.0, H) < 0.9 * gap(near_90.1, 0.0));
        let sqrt_gap =
            PI * ((near_90.1 + 1) as f64 / 19.0).powi(2) - PI * (near_90.1 as f64 / 19.0).powi(2);
        assert!(
            gap(near_90.1, 0.0) < 0.85 * sqrt_gap,
            "{} {sqrt_gap}",
            gap(near_90.1, 0.0)
        );
        for r in [R + 50.0, R + 3000.0, R + 12_000.0, R + 60_000.0, R + H] {
            for sun in [-8.0, -5.0, -2.0, 0.0, 2.5, 10.0] {
                for i in 0..N_VIEW {
                    let (theta, below) = view_node(i, r, R, sun);
                    assert_eq!(below, i >= N_VIEW_UP);
                    let (seg, row) = view_coord(theta, r, R, sun);
                    // The segments' shared edges (horizontal, horizon) belong to either side.
                    let ok = (row - i as f64).abs() < 1e-6
                        || (i == N_VIEW_SKY
                            && seg == 0
                            && (row - (N_VIEW_SKY - 1) as f64).abs() < 1e-6)
                        || (i == N_VIEW_UP - 1
                            && seg == 2
                            && (row - N_VIEW_UP as f64).abs() < 1e-6);
                    assert!(
                        ok,
                        "r {r}, sun {sun}, row {i}: theta {theta} -> ({seg}, {row})"
                    );
                }
                // Zenith, horizontal and horizon where the geometry puts them.
                assert!(view_node(0, r, R, sun).0.abs() < 1e-12);
                assert!((view_node(N_VIEW_SKY - 1, r, R, sun).0 - 0.5 * PI).abs() < 1e-12);
                assert!(
                    (view_node(N_VIEW_UP - 1, r, R, sun).0 - horizon_zenith(r, R)).abs() < 1e-9
                );
                assert!((view_node(N_VIEW - 1, r, R, sun).0 - PI).abs() < 1e-12);
            }
        }
    }

    #[test]
    fn the_columns_focus_near_115_degrees_aloft() {
        // No focus below 20 km; from 30 km up the columns 1.7 times as dense at 115° as
        // without it (the square root and sin²(φ/2) blend alone), and still increasing.
        for phi in [0.3, 1.5, 1.92, 3.0] {
            assert_eq!(azimuth_focus(phi, 19_999.0), (0.0, 0.0));
        }
        let (beta, g) = azimuth_focus(PI, 50_000.0);
        assert_eq!(beta, AZIMUTH_FOCUS[0]);
        assert!((g - 1.0).abs() < 1e-12 && azimuth_focus(0.0, 50_000.0).1.abs() < 1e-12);
        let dphi = 1e-6;
        let slope = |phi: f64, h: f64| {
            (azimuth_coord(phi + dphi, h) - azimuth_coord(phi - dphi, h)) / (2.0 * dphi)
        };
        let alpha = azimuth_weight(50_000.0);
        let plain = |phi: f64| {
            (alpha * 0.5 / (phi * PI).sqrt() + (1.0 - alpha) * 0.5 * phi.sin()) * (N_AZ - 1) as f64
        };
        let at = AZIMUTH_FOCUS[1].to_radians();
        let gain = slope(at, 50_000.0) / plain(at);
        assert!((1.6..1.8).contains(&gain), "{gain}");
        for h in [25_000.0, 30_000.0, H] {
            assert!((1..N_AZ).all(|a| azimuth_node(a, h) > azimuth_node(a - 1, h)));
        }
    }

    #[test]
    fn the_wide_focus_spans_the_band_from_140_to_180_degrees() {
        // Outside the width's altitudes (and under a high band) no width: the focus of version 17.
        for (sun, h) in [
            (0.5, 6000.0),
            (0.5, 13_000.0),
            (-3.0, 9500.0),
            (0.5, 30_000.0),
        ] {
            assert_eq!(sky_row_focus(sun, h).2, 0.0, "sun {sun}, h {h}");
        }
        // At 10 km with the sun 0.5° above the observer's horizon: full width, from the focus
        // at 0.92 of the antisolar band down to the band 140° from the sun, 1.5 times as strong.
        let (h, sun) = (10_000.0, 0.5);
        let (c, k, w) = sky_row_focus(sun, h);
        let band = band_centre_deg(sun, h);
        assert!(band < 6.0);
        assert!((c - 0.92 * BAND_ANTISOLAR * band).abs() < 1e-9);
        let k_full = band_focus_strength(h) * (1.0 + BAND_FOCUS_HIGH);
        assert!((k - 1.5 * k_full).abs() < 1e-9, "{k} vs {k_full}");
        let delta = band_azimuth_depth_deg(h);
        let e_w = (BAND_ANTISOLAR * band + delta) * (140.0f64).to_radians().cos().abs() - delta;
        assert!(e_w > 0.25 && e_w < c, "{e_w} {c}");
        let x0 = |e: f64| 1.0 - (e / 90.0f64).sqrt();
        assert!((w - (x0(e_w) - x0(c))).abs() < 1e-3, "{w}");
        // The rows invert, and are as dense across the width as at its upper end (in x0),
        // denser than outside it.
        for n in 0..=200 {
            let x = n as f64 / 200.0;
            assert!((sky_row(sky_row_elevation(x, c, k, w), c, k, w) - x).abs() < 1e-9);
        }
        let dx0 = |e: f64| {
            let d = 1e-5;
            let x = |e: f64| sky_row(e, c, k, w);
            // x0 per unit of x at elevation e.
            (x0(e - d) - x0(e + d)) / (x(e - d) - x(e + d))
        };
        let (top, bottom) = (dx0(c - 1e-3), dx0(e_w + 1e-3));
        assert!((top / bottom - 1.0).abs() < 1e-3, "{top} {bottom}");
        assert!(dx0(0.5 * (c + e_w)) < 1.001 * top);
        assert!(dx0(2.0 * c) > 2.0 * top && dx0(0.1) > 1.2 * top);
    }

    #[test]
    fn the_sky_rows_follow_the_band() {
        // By day, deep in twilight and aloft: version 3's rows, θ = 90° (1 − (1 − x)²).
        // (Deep in twilight, −5°, the band 15–20° high: the horizontal kept dense for the glow
        // towards the sun, version 12.)
        for (sun, h) in [(5.0, 0.0), (-8.0, 0.0), (-5.0, 5000.0), (-2.0, 45_000.0)] {
            let (c, k, w) = sky_row_focus(sun, h);
            assert_eq!(k, 0.0, "sun {sun}, h {h}");
            for n in 0..=10 {
                let x = n as f64 / 10.0;
                let want = 90.0 * (1.0 - x) * (1.0 - x);
                assert!((sky_row_elevation(x, c, k, w) - want).abs() < 1e-12);
            }
        }
        // At 10 km with the sun −3° above the observer's horizon the band is 13° high, past the
        // fade in its elevation: a quarter of the focus is kept (version 13: none).
        let (_, k, _) = sky_row_focus(-3.0, 10_000.0);
        assert!((k - BAND_CENTRE_FLOOR * band_focus_strength(10_000.0)).abs() < 1e-9);
        // In low twilight the rows are more than twice as dense as version 3's at the band's
        // elevation (which moves with the sun), sparser at the zenith; sky_row inverts
        // sky_row_elevation.
        let h = 5000.0;
        for sun in [-1.0, -0.5, 0.0, 0.5] {
            let (c, k, w) = sky_row_focus(sun, h);
            assert!(k > 0.0);
            assert!((sky_row_elevation(0.0, c, k, w) - 90.0).abs() < 1e-9);
            assert!(sky_row_elevation(1.0, c, k, w).abs() < 1e-9);
            for n in 0..=100 {
                let x = n as f64 / 100.0;
                assert!((sky_row(sky_row_elevation(x, c, k, w), c, k, w) - x).abs() < 1e-9);
            }
            // Degrees of elevation per unit of x at x (central difference).
            let spacing = |x: f64| {
                let dx = 1e-4;
                (sky_row_elevation(x - dx, c, k, w) - sky_row_elevation(x + dx, c, k, w))
                    / (2.0 * dx)
            };
            let x_band = sky_row(c, c, k, w);
            let x0 = 1.0 - (c / 90.0).sqrt();
            let base = 180.0 * (1.0 - x0);
            assert!(
                spacing(x_band) < 0.5 * base,
                "sun {sun}: {} vs {base}",
                spacing(x_band)
            );
            // Sparser than version 3's far from the band (the zenith).
            assert!(
                spacing(0.01) > 1.5 * 180.0 * 0.99,
                "sun {sun}: {}",
                spacing(0.01)
            );
        }
    }

    #[test]
    fn the_columns_follow_the_band_with_the_azimuth() {
        let cos = |deg: f64| deg.to_radians().cos();
        // By day and aloft, at the query's own azimuth and on the sun's side: the identity.
        assert_eq!(
            band_relative_elevation(3.0, 8.0, 0.0, cos(150.0), cos(180.0)),
            3.0
        );
        assert_eq!(
            band_relative_elevation(3.0, -1.0, 45_000.0, cos(150.0), cos(180.0)),
            3.0
        );
        assert_eq!(
            band_relative_elevation(3.0, -1.0, 5000.0, cos(150.0), cos(150.0)),
            3.0
        );
        assert_eq!(
            band_relative_elevation(3.0, -1.0, 5000.0, cos(40.0), cos(70.0)),
            3.0
        );
        // Low twilight at 5 km: the band's elevation at 150° from the sun onto its elevation
        // at 180° and 128° (c(φ) = (c₁₈₀ + δ)(−cos φ) − δ), the horizontal onto itself, the
        // zenith's region unchanged.
        let (h, sun) = (5000.0, -1.0);
        let delta = BAND_DEPTH_PER_KM * 5.0;
        let c180 = band_centre_deg(sun, h) * BAND_ANTISOLAR;
        let band = |phi: f64| (c180 + delta) * (-cos(phi)) - delta;
        for phi_a in [128.0, 144.0, 161.0, 180.0] {
            let got = band_relative_elevation(band(150.0), sun, h, cos(150.0), cos(phi_a));
            assert!(
                (got - band(phi_a)).abs() < 1e-9,
                "{phi_a}: {got} vs {}",
                band(phi_a)
            );
        }
        // Through the horizontal down to −δ (where the band's edge crosses the horizontal);
        // −δ onto itself, the identity below it.
        for phi_a in [128.0, 180.0] {
            let got = band_relative_elevation(0.0, sun, h, cos(150.0), cos(phi_a));
            let want = delta * (-cos(phi_a) / -cos(150.0) - 1.0);
            assert!((got - want).abs() < 1e-9, "{phi_a}: {got} vs {want}");
        }
        let floor = band_relative_elevation(-delta, sun, h, cos(150.0), cos(128.0));
        assert!((floor + delta).abs() < 1e-12, "{floor}");
        assert_eq!(
            band_relative_elevation(-delta - 0.1, sun, h, cos(150.0), cos(128.0)),
            -delta - 0.1
        );
        // A column moved below the horizontal is read on the limb rows at the query's
        // altitude, continuously with the sky rows at the horizontal.
        let (seg, row) = band_row(-0.5, h, R, (0.0, 0.0, 0.0), [0.0, 0.0, h]);
        assert_eq!(seg, 1);
        let (_, lr) = view_coord(0.5 * PI + 0.5f64.to_radians(), R + h, R, sun);
        assert!((row - lr).abs() < 1e-9, "{row} vs {lr}");
        assert_eq!(
            band_row(0.0, h, R, (0.0, 0.0, 0.0), [0.0, 0.0, h]),
            (0, (N_VIEW_SKY - 1) as f64)
        );
        assert!(
            (band_row(-1e-9, h, R, (0.0, 0.0, 0.0), [0.0, 0.0, h]).1 - N_VIEW_SKY as f64).abs()
                < 1e-6
        );
        assert_eq!(
            band_relative_elevation(60.0, sun, h, cos(150.0), cos(180.0)),
            60.0
        );
        // At the ground after sunset (no band height): finite.
        assert!(band_relative_elevation(1.0, 3.0, 0.0, cos(150.0), cos(180.0)).is_finite());
        // Aloft the columns' depth moves to the measured one (the slices' stays): the band at
        // 20 km with δ = BAND_AZIMUTH_DEPTH_ALOFT onto itself at every column.
        assert_eq!(band_azimuth_depth_deg(5000.0), band_depth_deg(5000.0));
        assert_eq!(band_azimuth_depth_deg(12_500.0), band_depth_deg(12_500.0));
        assert_eq!(band_azimuth_depth_deg(17_000.0), BAND_AZIMUTH_DEPTH_ALOFT);
        let mid = band_azimuth_depth_deg(14_750.0);
        assert!((mid - 0.5 * (band_depth_deg(14_750.0) + BAND_AZIMUTH_DEPTH_ALOFT)).abs() < 1e-12);
        let (h, sun) = (20_000.0, -1.0);
        let delta = BAND_AZIMUTH_DEPTH_ALOFT;
        let c180 = band_centre_deg(sun, h) * BAND_ANTISOLAR;
        let band = |phi: f64| (c180 + delta) * (-cos(phi)) - delta;
        for phi_a in [128.0, 144.0, 161.0, 180.0] {
            let got = band_relative_elevation(band(135.0), sun, h, cos(135.0), cos(phi_a));
            assert!(
                (got - band(phi_a)).abs() < 1e-9,
                "{phi_a}: {got} vs {}",
                band(phi_a)
            );
        }
    }

    #[test]
    fn the_slices_are_read_relative_to_the_band() {
        // The band's fit aloft: continuous at 10 km, 1.3 times the 10 km fit's at 20 km, growing
        // by 0.025 of it per km to 40 km, held above; its depth held from 5 km up.
        let at = |h: f64| band_centre_deg(-1.0, h);
        assert!((at(10_000.0) - at(9_999.999)).abs() < 1e-5);
        assert!((at(20_000.0) / at(10_000.0) - 1.3).abs() < 1e-12);
        assert!((at(30_000.0) / at(10_000.0) - 1.55).abs() < 1e-12);
        assert_eq!(at(50_000.0), at(40_000.0));
        // The slices' map's band: the same up to 10 km, growing by 0.045 per km at 10 km and
        // 0.015 at 20 km (1.1875 times the 10 km fit's at 15 km, 1.3 at 20 km), by 0.015 to
        // 40 km, held above.
        let slice = |h: f64| band_slice_centre_deg(-1.0, h);
        assert_eq!(slice(8000.0), at(8000.0));
        assert_eq!(slice(10_000.0), at(10_000.0));
        assert!((slice(15_000.0) / slice(10_000.0) - 1.1875).abs() < 1e-12);
        assert!((slice(20_000.0) / slice(10_000.0) - 1.3).abs() < 1e-12);
        assert!((slice(30_000.0) / slice(10_000.0) - 1.45).abs() < 1e-12);
        assert_eq!(slice(50_000.0), slice(40_000.0));
        assert_eq!(band_depth_deg(5000.0), 2.5);
        assert_eq!(band_depth_deg(15_000.0), 2.5);
        // The focus grows from 1 to 5 km, again from 5 to 8 km, and no further.
        assert_eq!(band_focus_strength(0.0), BAND_FOCUS);
        assert_eq!(band_focus_strength(1000.0), BAND_FOCUS);
        let low = BAND_FOCUS * (1.0 + BAND_FOCUS_GROWTH);
        assert!((band_focus_strength(5000.0) - low).abs() < 1e-12);
        let full = low * (1.0 + BAND_FOCUS_ALOFT);
        assert!((band_focus_strength(8000.0) - full).abs() < 1e-12);
        assert!((band_focus_strength(15_000.0) - full).abs() < 1e-12);
        // Under a low band the focus sits at 0.85 of the antisolar band below 4 km, at 0.92 of
        // it and 1.3 times as strong from 10 km up, and 1.5 times that again where it is wide
        // (full up to 11 km, 7/27 at 12 km, none from 12.5 km); under a high band (c > 9°) as
        // below 4 km.
        let (c, k, _) = sky_row_focus(0.0, 4000.0);
        assert_eq!(c, band_centre_deg(0.0, 4000.0));
        assert!((k - band_focus_strength(4000.0)).abs() < 1e-9);
        for (h, wide) in [(10_000.0, 1.0), (12_000.0, 7.0 / 27.0), (15_000.0, 0.0)] {
            let (c, k, _) = sky_row_focus(0.0, h);
            let antisolar = BAND_ANTISOLAR * band_centre_deg(0.0, h);
            assert!(antisolar < 6.0);
            assert!(
                (c - 0.92 * antisolar).abs() < 1e-9,
                "{h}: {c} vs {antisolar}"
            );
            assert!(
                (k - 1.3 * full * (1.0 + 0.5 * wide)).abs() < 1e-9,
                "{h}: {k}"
            );
            let (c, k, _) = sky_row_focus(-3.0, h);
            assert!(band_centre_deg(-3.0, h) > 9.0);
            assert_eq!(c, band_centre_deg(-3.0, h));
            assert!((k - BAND_CENTRE_FLOOR * full).abs() < 1e-9, "{h}: {k}");
        }
        // By day and aloft (no focus at the query): the identity.
        assert_eq!(band_slice_elevation(3.0, 8.0, 0.0, 7.5, 0.0, -1.0), 3.0);
        assert_eq!(
            band_slice_elevation(3.0, -1.0, 45_000.0, -1.2, 42_000.0, -1.0),
            3.0
        );
        // Low twilight at 5 km: the band opposite the sun at the query's sun and altitude
        // lands on the band at the node's (and so at any azimuth: the map does not depend on
        // it), the horizontal on itself, the zenith's region unchanged.
        let (h, sun) = (5000.0, 0.0);
        let band = |s: f64, h: f64| band_centre_deg(s, h) * BAND_ANTISOLAR;
        for (s_n, h_n) in [
            (-0.25, 5000.0),
            (0.25, 5000.0),
            (0.0, 3435.0),
            (0.2, 6750.0),
        ] {
            let got = band_slice_elevation(band(sun, h), sun, h, s_n, h_n, -1.0);
            assert!(
                (got - band(s_n, h_n)).abs() < 1e-9,
                "{s_n} {h_n}: {got} vs {}",
                band(s_n, h_n)
            );
        }
        // Aloft the slices' band ([`band_slice_centre_deg`]) lands on the node's.
        let band_s = |s: f64, h: f64| band_slice_centre_deg(s, h) * BAND_ANTISOLAR;
        let got = band_slice_elevation(band_s(0.1, 12_000.0), 0.1, 12_000.0, 0.1, 15_340.0, -1.0);
        assert!((got - band_s(0.1, 15_340.0)).abs() < 1e-9, "{got}");
        assert!((band_s(0.1, 15_340.0) - band(0.1, 15_340.0)).abs() > 0.1);
        assert_eq!(band_slice_elevation(0.0, sun, h, -1.25, 5000.0, -1.0), 0.0);
        // From 8 km up the map acts from −δ (2.5°) up through the horizontal.
        assert!(band_slice_elevation(0.0, 0.5, 15_000.0, 0.75, 15_000.0, -1.0).abs() > 0.1);
        assert!(
            (band_slice_elevation(-2.5, 0.5, 15_000.0, 0.75, 15_000.0, -1.0) + 2.5).abs() < 1e-12
        );
        assert_eq!(
            band_slice_elevation(-2.6, 0.5, 15_000.0, 0.75, 15_000.0, -1.0),
            -2.6
        );
        assert_eq!(
            band_slice_elevation(60.0, sun, h, -1.25, 5000.0, -1.0),
            60.0
        );
        // At the ground after sunset (no band height): finite.
        assert!(band_slice_elevation(1.0, 3.0, 0.0, 2.5, 0.0, -1.0).is_finite());
        // From 20–25 km up faded in with −cos φ as the columns' map: towards the sun the
        // identity, opposite it and below 20 km at every azimuth not.
        let map = |h: f64, h_n: f64, cos_phi: f64| {
            band_slice_elevation(3.0, 0.2, h, 0.4, h_n, cos_phi) - 3.0
        };
        assert_eq!(map(25_000.0, 23_840.0, 0.9), 0.0);
        assert!(map(25_000.0, 23_840.0, -1.0).abs() > 0.01);
        assert!(map(15_000.0, 15_340.0, 0.9).abs() > 0.01);
    }

    #[test]
    fn the_limb_rows_follow_the_band_aloft() {
        // The focus and its inverse invert; the identity where the focus is off.
        for &(xc, k) in &[(0.3, 6.0), (0.9, 6.0), (0.0, 0.0)] {
            for n in 0..=20 {
                let x = n as f64 / 20.0;
                assert!((focus_coord(focus_inverse(x, xc, k), xc, k) - x).abs() < 1e-9);
            }
        }
        // Off by day, at the ground and at 30 km; on at 15 km with the sun at sunset.
        assert_eq!(limb_row_focus(10.0, 15_000.0).1, 0.0);
        assert_eq!(limb_row_focus(0.0, 3_000.0).1, 0.0);
        assert_eq!(limb_row_focus(0.0, 30_000.0).1, 0.0);
        // From 35 km up on the shadow's edge (12–15 km deep), off by day and from 50 km up; the
        // slices' depth map stays off there.
        let (xc, k) = limb_row_focus(0.0, 40_000.0);
        assert_eq!(k, LIMB_EDGE_FOCUS);
        assert!((limb_depth(xc) * 40_000.0 - LIMB_EDGE_DEPTH_M[0]).abs() < 1.0);
        assert_eq!(limb_row_focus(5.0, 40_000.0).1, 0.0);
        assert_eq!(limb_row_focus(0.0, 55_000.0).1, 0.0);
        assert_eq!(limb_slice_depth(0.3, 0.0, 40_000.0, 0.25, 42_000.0), 0.3);
        // Still on at 25 km (version 20): the limb seen from 22.5–25 km reads it.
        assert_eq!(limb_row_focus(-1.0, 25_000.0).1, LIMB_BAND_FOCUS);
        let (xc, k) = limb_row_focus(0.0, 15_000.0);
        assert!(k > 1.0);
        // The focus sits at the band's depth, and the rows are denser there than without it.
        let y_c = limb_depth(xc);
        assert!((y_c * 15_000.0 - LIMB_BAND_DEPTH_M[0]).abs() < 1.0);
        let dx = 1e-4;
        let dense =
            limb_row_focused(y_c + dx, 0.0, 15_000.0) - limb_row_focused(y_c, 0.0, 15_000.0);
        let plain = limb_row(y_c + dx) - limb_row(y_c);
        assert!(dense > 1.5 * plain, "{dense} {plain}");
        // A slice's depth: the query's where the focus is off, and the band onto the band.
        assert_eq!(limb_slice_depth(0.4, 10.0, 15_000.0, 9.0, 12_000.0), 0.4);
        let y_q = limb_band_depth_m(-0.5) / 15_000.0;
        let y_n = limb_slice_depth(y_q, -0.5, 15_000.0, -0.25, 15_000.0);
        assert!((y_n * 15_000.0 - limb_band_depth_m(-0.25)).abs() < 1.0);
        assert_eq!(limb_slice_depth(0.0, -0.5, 15_000.0, -0.25, 12_000.0), 0.0);
        // Where the band lies well above the horizon (20 km, s = 0: D/h = 0.41) the horizon
        // stays where it is, and the map is continuous at the band.
        assert!((limb_slice_depth(1.0, 0.0, 20_000.0, 0.25, 17_000.0) - 1.0).abs() < 1e-12);
        let yb = limb_band_depth_m(0.0) / 20_000.0;
        let below = limb_slice_depth(yb - 1e-9, 0.0, 20_000.0, 0.25, 17_000.0);
        let above = limb_slice_depth(yb + 1e-9, 0.0, 20_000.0, 0.25, 17_000.0);
        assert!((below - above).abs() < 1e-6, "{below} {above}");
        // Near the horizon (D/h ≥ 0.9) version 10's map, affine about the horizontal.
        let y_q = 0.9;
        let deep = limb_slice_depth(y_q, -0.5, 12_000.0, -0.25, 12_000.0);
        let affine = y_q * limb_band_depth_m(-0.25) / limb_band_depth_m(-0.5);
        assert!((deep - affine).abs() < 1e-12, "{deep} {affine}");
        // Seen from 20 km, 0.3° above the horizon (y = 0.877) at s = −1.223°: the band at
        // D(−1.223°) = 8.2 + 7.76 · 1.223 − 0.9 · 1.223² = 16.34 km (y_b = 0.817); the slice at
        // s = −1.938° has its band at 19.86 km, so y ρ = 0.877 · 19.86 / 16.34 = 1.066, the
        // horizon held 0.95 + 0.060 · 0.05 / 0.183 = 0.966 with the weight
        // 1 − smoothstep(0.65, 0.9, 0.817) = 0.256: 1.066 − 0.256 · 0.099 = 1.040, past its
        // horizon, and its sun node is left out of the stencil; the slice at −1.534° (17.99 km,
        // y ρ = 0.965, held 0.932: 0.957) is kept.
        let m = limb_slice_map(0.877, -1.223, 20_000.0, -1.938, 20_000.0);
        assert!((m - 1.040).abs() < 2e-3, "{m}");
        let m = limb_slice_map(0.877, -1.223, 20_000.0, -1.534, 20_000.0);
        assert!((m - 0.957).abs() < 2e-3, "{m}");
        assert!(limb_slice_past_horizon(
            0.877, -1.223, 20_000.0, -1.938, 20_000.0
        ));
        assert!(!limb_slice_past_horizon(
            0.877, -1.223, 20_000.0, -1.534, 20_000.0
        ));
        let thickness = 100_000.0;
        let b = warp_strength(20_000.0, thickness);
        let y = sun_coord(sun_unwarp(-1.223, b, 0.0));
        let i0 = y.floor() as usize;
        assert!((sun_warp(sun_node_deg(i0 - 1), b, 0.0) + 1.938).abs() < 0.01);
        let lowest = limb_sun_lowest(0.877, -1.223, 20_000.0, 20_000.0, thickness, i0 - 1, i0);
        assert_eq!(lowest, i0);
        // Where the band lies well above the horizon every node is kept.
        assert_eq!(
            limb_sun_lowest(0.5, -1.223, 20_000.0, 20_000.0, thickness, i0 - 1, i0),
            i0 - 1
        );
        // The interval's lower node (−1.534°) at y = 0.877 is read at 0.957, kept: the stencil
        // starts there. At y = 0.9 it would be read at y ρ = 0.990 held to 0.945: 0.990 − 0.256 ·
        // 0.046 = 0.979, deeper than 0.97: the line through the two nodes above, extrapolated.
        let deg = sun_unwarp(-1.223, b, 0.0);
        let ss = Stencil::new(y, 0, N_SUN - 1, sun_node_deg, deg);
        assert_eq!((ss.first, ss.i0), (i0 - 1, i0));
        let kept = limb_sun_stencil(ss, 0.877, -1.223, 20_000.0, 20_000.0, thickness, deg, 4);
        assert_eq!((kept.first, kept.len), (i0, 3));
        let m = limb_slice_reach(0.9, -1.223, 20_000.0, -1.534, 20_000.0);
        assert!((m - 0.979).abs() < 2e-3, "{m}");
        let deep = limb_sun_stencil(ss, 0.9, -1.223, 20_000.0, 20_000.0, thickness, deg, 4);
        assert_eq!((deep.first, deep.len, deep.i0), (i0 + 1, 2, i0 + 1));
        let t = (deg - sun_node_deg(i0 + 1)) / (sun_node_deg(i0 + 2) - sun_node_deg(i0 + 1));
        assert!(t < 0.0 && t > -2.0 && (deep.t - t).abs() < 1e-12, "{t}");
        assert_eq!(deep.w, [1.0 - t, t, 0.0, 0.0]);
        // Two-node stencils (the sun axis's two-node check) as they are.
        let two = Stencil::with_nodes(y, 0, N_SUN - 1, sun_node_deg, deg, 2);
        let same = limb_sun_stencil(two, 0.9, -1.223, 20_000.0, 20_000.0, thickness, deg, 2);
        assert_eq!((same.first, same.len), (two.first, two.len));
    }

    #[test]
    fn the_stencil_below_its_first_node_extrapolates_unbounded() {
        // Nodes at x = 5, 6 holding e¹, e²; at x = 4.5 the line in the logarithms gives e^0.5,
        // below both values (a bounded stencil would return e¹).
        let st = Stencil::below(5, |i| i as f64, 4.5);
        assert_eq!((st.first, st.len, st.i0), (5, 2, 5));
        assert_eq!(st.t, -0.5);
        let e = std::f64::consts::E;
        assert!((st.mix(&[e, e * e]) - 0.5f64.exp()).abs() < 1e-12);
        // A value not positive: the first node's value (the shader's GeoMix at t ≤ 0).
        assert_eq!(st.mix(&[e, 0.0]), e);
        assert_eq!(st.mix(&[0.0, e]), 0.0);
    }

    #[test]
    fn the_limb_rows_and_the_sun_warp_invert() {
        // The cubic's root is the row: y(x) at known points, and back.
        assert_eq!(limb_depth(0.0), 0.0);
        assert_eq!(limb_depth(1.0), 1.0);
        assert!((limb_depth(0.5) - 0.375).abs() < 1e-15);
        for n in 0..=100 {
            let x = n as f64 / 100.0;
            assert!((limb_row(limb_depth(x)) - x).abs() < 1e-9, "x {x}");
        }
        // The warp: identity at the ground and outside its range, continuous at the range's
        // ends, b / sinh(b) times denser at 0, inverted by sun_unwarp.
        assert_eq!(sun_warp(-3.0, 0.0, 0.0), -3.0);
        assert_eq!(sun_warp(12.0, 3.0, 0.0), 12.0);
        let b = warp_strength(H, H);
        assert_eq!(b, SUN_WARP);
        assert!((sun_warp(SUN_WARP_RANGE.0 + 1e-9, b, 0.0) - SUN_WARP_RANGE.0).abs() < 1e-6);
        assert!((sun_warp(SUN_WARP_RANGE.1 - 1e-9, b, 0.0) - SUN_WARP_RANGE.1).abs() < 1e-6);
        let slope = sun_warp(1e-6, b, 0.0) / 1e-6;
        assert!((slope - b / b.sinh()).abs() < 1e-6, "{slope}");
        for n in 0..=140 {
            let t = -8.0 + n as f64 * 0.1;
            for b in [0.0, 0.5, b] {
                assert!(
                    (sun_unwarp(sun_warp(t, b, 0.0), b, 0.0) - t).abs() < 1e-9,
                    "t {t}, b {b}"
                );
            }
        }
        // Centred at c: the ends still fixed, b / sinh(b) times denser at c (on both sides),
        // inverted by sun_unwarp.
        for c in [-2.3, -1.0, 0.5] {
            assert!((sun_warp(SUN_WARP_RANGE.0 + 1e-9, b, c) - SUN_WARP_RANGE.0).abs() < 1e-6);
            assert!((sun_warp(SUN_WARP_RANGE.1 - 1e-9, b, c) - SUN_WARP_RANGE.1).abs() < 1e-6);
            assert!((sun_warp(c, b, c) - c).abs() < 1e-12);
            for dt in [-1e-6, 1e-6] {
                let slope = (sun_warp(c + dt, b, c) - c) / dt;
                assert!((slope - b / b.sinh()).abs() < 1e-6, "c {c}: {slope}");
            }
            for n in 0..=140 {
                let t = -8.0 + n as f64 * 0.1;
                let s = sun_warp(t, b, c);
                assert!((sun_unwarp(s, b, c) - t).abs() < 1e-9, "t {t}, c {c}");
            }
        }
    }

    #[test]
    fn the_sun_warp_centres_on_the_sky_rows_towards_the_sun_aloft() {
        // The sky rows towards the sun from 60 km up: dip(r) − dip(top) (≈ −2.2° at 60 km, where
        // sunlight grazing the ground starts to reach the top above the observer), weighted by
        // cos² φ; 0 away from the sun, below 40 km, on the limb and ground rows.
        let (bottom, top) = (R, R + H);
        let dip_deg = |h: f64| ((R / (R + h)).acos()).to_degrees();
        let c = sun_warp_centre(60_000.0, bottom, top, 0, 1.0);
        assert!((c - (dip_deg(60_000.0) - dip_deg(H))).abs() < 1e-9, "{c}");
        assert!((-2.4..-2.1).contains(&c), "{c}");
        let half = sun_warp_centre(60_000.0, bottom, top, 0, 0.5_f64.sqrt());
        assert!((half - 0.5 * c).abs() < 1e-9);
        assert_eq!(sun_warp_centre(59_000.0, bottom, top, 0, -0.2), 0.0);
        assert_eq!(sun_warp_centre(39_000.0, bottom, top, 0, 1.0), 0.0);
        assert_eq!(sun_warp_centre(59_000.0, bottom, top, 1, 1.0), 0.0);
        assert_eq!(sun_warp_centre(59_000.0, bottom, top, 2, 1.0), 0.0);
        assert_eq!(sun_warp_centre(H, bottom, top, 0, 1.0), 0.0);
    }

    #[test]
    fn ray_lengths_are_the_geometric_ones() {
        // Straight up from the ground: the atmosphere's thickness; down to the ground from h:
        // h; a horizontal ray from the ground: sqrt(top² − R²).
        assert!((ray_length(R, 1.0, R, R + H, false) - H).abs() < 1e-6);
        assert!((ray_length(R + 5000.0, -1.0, R, R + H, true) - 5000.0).abs() < 1e-6);
        let horizontal = ((R + H).powi(2) - R * R).sqrt();
        assert!((ray_length(R, 0.0, R, R + H, false) - horizontal).abs() < 1e-6);
    }

    #[test]
    fn geometric_interpolation_is_exact_for_an_exponential() {
        let (a, b) = (3.0f64, 3.0 * (-2.0f64).exp());
        assert!((geo_mix(a, b, 0.25) - 3.0 * (-0.5f64).exp()).abs() < 1e-12);
        // A zero end falls back to linear.
        assert_eq!(geo_mix(0.0, 2.0, 0.5), 1.0);
    }

    #[test]
    fn the_stencil_is_exact_for_the_exponential_of_a_cubic_and_bounded() {
        // ln f = a cubic in the abscissa: 4 non-uniform nodes reproduce it inside the segment.
        let x = |i: usize| [0.0, 0.5, 1.5, 2.0, 3.0, 5.0][i];
        let ln_f = |x: f64| 0.3 - 1.2 * x + 0.4 * x * x - 0.05 * x * x * x;
        for (y, xq) in [(1.25, 0.75), (2.5, 1.75), (3.5, 4.0)] {
            let st = Stencil::new(y, 0, 5, x, xq);
            assert_eq!(st.len, 4);
            assert!((st.w.iter().sum::<f64>() - 1.0).abs() < 1e-12);
            let v: Vec<f64> = (st.first..st.first + 4).map(|i| ln_f(x(i)).exp()).collect();
            let got = st.mix(&v);
            assert!((got / ln_f(xq).exp() - 1.0).abs() < 1e-12, "y {y}: {got}");
        }
        // In a segment's first and last interval: 3 nodes (a quadratic); in a 2-node segment: 2.
        assert_eq!(Stencil::new(0.5, 0, 5, x, 0.25).len, 3);
        assert_eq!(Stencil::new(4.5, 0, 5, x, 4.0).len, 3);
        assert_eq!(Stencil::new(0.5, 0, 1, |i| i as f64, 0.5).len, 2);
        // A node returns its value; a step (the earth's shadow) does not overshoot.
        let st = Stencil::new(2.0, 0, 5, |i| i as f64, 2.0);
        assert_eq!(st.mix(&[1.0, 2.0, 3.0, 4.0]), 2.0);
        let st = Stencil::new(2.5, 0, 5, |i| i as f64, 2.5);
        let v = [1e-6, 1e-6, 1.0, 1.0];
        let got = st.mix(&v);
        assert!((1e-6..=1.0).contains(&got), "{got}");
        // A value that is not positive: geometric between the interval's two nodes.
        assert_eq!(st.mix(&[0.0, 2.0, 8.0, 1.0]), 4.0);
    }

    #[test]
    fn the_limb_sun_shift_follows_the_tangent_point() {
        let r = R + 60_000.0;
        let dip_r = dip(r, R);
        // Above the horizontal away from the sun, below the horizon, and on the limb at the
        // horizontal: the observer's horizon's dip.
        assert_eq!(
            sun_shift(r, 1.0, -SKY_EXIT_AZIMUTH_FADE, R, R + 100_000.0, false),
            dip_r
        );
        // The azimuth weight: continuous with its slope at 90° from the sun and at the fade's end.
        let g = sky_exit_azimuth;
        let f = SKY_EXIT_AZIMUTH_FADE;
        assert_eq!(g(0.3), 0.3);
        assert!(g(-1e-9).abs() < 2e-9 && ((g(1e-6) - g(-1e-6)) / 2e-6 - 1.0).abs() < 1e-5);
        assert!(g(-0.5 * f) < 0.0 && g(-f + 1e-6).abs() < 1e-11);
        assert_eq!(sun_shift(r, 2.0, 0.3, R, R + 100_000.0, false), dip_r);
        assert_eq!(
            sun_shift(R + 15_000.0, 1.0, 0.3, R, R + 100_000.0, false),
            dip(R + 15_000.0, R)
        );
        // Above the horizontal towards the sun from 40 km up: + max(cos φ, 0) times the central
        // angle to where the ray leaves the atmosphere (sin α = x sin θ / top, x the chord).
        let top = R + 100_000.0;
        for theta in [0.2f64, 1.0, 1.5, 0.5 * PI] {
            let x = -r * theta.cos() + (top * top - r * r * theta.sin().powi(2)).sqrt();
            let alpha = (x * theta.sin() / top).asin();
            let got = sun_shift(r, theta, 0.6, R, top, false);
            assert!(
                (got - dip_r - 0.6 * alpha).abs() < 1e-9,
                "theta {theta}: {got}"
            );
        }
        assert!((sun_shift(r, 0.5 * PI, -1.0, R, R + 100_000.0, true) - dip_r).abs() < 1e-12);
        // A deep limb ray (tangent point 40 km below the observer): the sun's elevation above
        // the tangent point's horizon, from spherical geometry (sin e_t = sin e cos γ + cos e
        // sin γ cos φ), agrees with the shift to first order in γ (γ = 6.4°: within 0.1°),
        // weighted by 1 - exp(-40/20).
        let r_t = R + 20_000.0;
        let gamma = (r_t / r).acos();
        let theta = 0.5 * PI + gamma;
        for cos_phi in [-1.0, -0.3, 0.0, 0.6, 1.0] {
            let e = (-8.0f64).to_radians();
            let e_t = (e.sin() * gamma.cos() + e.cos() * gamma.sin() * cos_phi).asin();
            let tangent = e_t + dip(r_t, R) - e;
            let w = (1.0 - (-40_000.0 / LIMB_SHADOW_SCALE_M).exp())
                * (1.0 - limb_near_end(cos_phi, 60_000.0, 40_000.0));
            let want = dip_r + w * (tangent - dip_r);
            let got = sun_shift(r, theta, cos_phi, R, R + 100_000.0, true);
            assert!(
                (got - want).abs() < 0.1f64.to_radians(),
                "cos phi {cos_phi}: {} vs {} deg",
                got.to_degrees(),
                want.to_degrees()
            );
        }
        // Aloft away from the sun a deep limb ray keeps the observer's horizon, towards the sun
        // the tangent point's weight (limb_near_end).
        assert_eq!(limb_near_end(-1.0, 60_000.0, 40_000.0), 1.0);
        assert_eq!(limb_near_end(0.5, 60_000.0, 40_000.0), 0.0);
        assert_eq!(limb_near_end(-1.0, 15_000.0, 40_000.0), 0.0);
        assert_eq!(limb_near_end(-1.0, 60_000.0, 2_000.0), 0.0);
        assert!((sun_shift(r, theta, -1.0, R, R + 100_000.0, true) - dip_r).abs() < 1e-12);
        // The shift never leaves the sun nodes' reach: elevation -12° at any limb ray from
        // 100 km is above the first node.
        let r = R + H;
        let th = horizon_zenith(r, R);
        for k in 0..=20 {
            let theta = 0.5 * PI + (th - 0.5 * PI) * k as f64 / 20.0;
            let s = -12.0 + sun_shift(r, theta, -1.0, R, R + 100_000.0, true).to_degrees();
            assert!(s >= SUN_MIN_DEG, "theta {theta}: {s}");
        }
    }

    #[test]
    fn each_altitude_node_reads_the_limb_at_its_tangent_point_weight() {
        // A limb ray seen from 35 km opposite the sun, 0.25° above the horizon (deep: r − r_t
        // near the observer's altitude).
        let r = R + 35_000.0;
        let theta = horizon_zenith(r, R) - 0.25f64.to_radians();
        let top = R + 100_000.0;
        // At the query's own altitude, the query's coordinate (sun_shift).
        assert!(
            (limb_node_shift(r, theta, -1.0, R, 35_000.0)
                - sun_shift(r, theta, -1.0, R, top, true))
            .abs()
                < 1e-12
        );
        // Above LIMB_NODE_QUERY_WEIGHT_M the query's weight w for every node: node n (its ray at
        // the query's depth fraction y) read w_n t_n + w (t − t_n) above the observer's horizon,
        // t = γ cos φ + dip(r_t) − dip(r); at 45 km w_n = 0 (n = 1).
        let gamma = theta - 0.5 * PI;
        let r_t = r * gamma.cos();
        let y = (r - r_t) / 35_000.0;
        let w = limb_tangent_weight(-1.0, 35_000.0, r - r_t);
        let t = -gamma + dip(r_t, R) - dip(r, R);
        let r_n = R + 45_000.0;
        let r_tn = r_n - y * 45_000.0;
        let t_n = -(r_tn / r_n).acos() + dip(r_tn, R) - dip(r_n, R);
        assert_eq!(limb_tangent_weight(-1.0, 45_000.0, y * 45_000.0), 0.0);
        let got = limb_node_shift(r, theta, -1.0, R, 45_000.0);
        assert!((got - (dip(r, R) + w * (t - t_n))).abs() < 1e-9, "{got}");
        // Below it (a query at 20 km), each node its own weight at its depth (version 21).
        let r = R + 20_000.0;
        let theta = horizon_zenith(r, R) - 0.25f64.to_radians();
        let y = (r - r * (theta - 0.5 * PI).cos()) / 20_000.0;
        for h_n in [16_880.0, 23_800.0] {
            let w_n = limb_tangent_weight(-1.0, h_n, y * h_n);
            assert!(
                (limb_node_shift(r, theta, -1.0, R, h_n) - limb_shift_with(r, theta, -1.0, R, w_n))
                    .abs()
                    < 1e-12
            );
        }
        // Below LIMB_NODE_WEIGHT_ALTITUDE_M every node a query reads (n = 0) at the query's own
        // coordinate: seen from 10 km, nodes at 7.5 and 12.5 km.
        let r_low = R + 10_000.0;
        let theta_low = horizon_zenith(r_low, R) - 0.25f64.to_radians();
        let own = sun_shift(r_low, theta_low, -1.0, R, top, true);
        for h_n in [7_500.0, 12_500.0] {
            assert!((limb_node_shift(r_low, theta_low, -1.0, R, h_n) - own).abs() < 1e-12);
        }
    }

    #[test]
    fn phase_functions_round_trip_through_the_manifest() {
        for p in [
            Phase::CornetteShanks { g: 0.8 },
            Phase::HenyeyGreenstein { g: 0.7 },
            Phase::Mixture {
                g: 0.85,
                rayleigh_fraction: 0.05,
            },
            Phase::Isotropic,
            Phase::Rayleigh,
        ] {
            assert_eq!(phase_from_json(&phase_json(&p)).unwrap(), p);
        }
        let e = phase_from_json(&json!({"kind": "cornette_shanks"})).unwrap_err();
        assert_eq!(e.field(), "manifest");
    }
}
