//! The `skyview` texture bundle (skybake's second layout, docs/lut.md) read with its reader
//! (`skybake_lut::SkyViewReader`) against skybake's own `sky` and `sun` products at random
//! observers (0–100 km), view directions above the horizon and sun elevations (−12°…90°), on
//! `earth` at quality `standard`, RGB form: the largest relative error per band of the issue's
//! targets (≤ 1 % sky above the horizon with the sun ≥ 5°, ≤ 3 % within 10° of the horizon and
//! down to −6°, ≤ 10 % to −12°), printed and asserted (measured bound + a small margin).
//! The bundle's build (about 10 s of CPU) is shared by the tests; they are `#[ignore]`d in the
//! README's test command like the Bruneton bundle's and run with
//! `cargo test --release --test atmosphere -- --ignored lut_skyview::`.

use rand::{Rng, SeedableRng};
use rand_pcg::Pcg64;
use skybake_engine::engine::Engine;
use skybake_engine::spec::{CommonSpec, DomeShape};
use skybake_lut::skyview::{self, SkyViewBundle, SkyViewReader};
use skybake_lut::UNIT_SCALE;
use skybake_product::lut::{Layout, LutRequest};
use skybake_product::params::RequestParams;
use std::sync::OnceLock;

use crate::lut::{
    aerial_errors, altitude_band, describe, random_observer, rel, sky_samples, sun_dir, view_dir,
    Bands, SkySample,
};

struct Fixture {
    engine: Engine,
    request: LutRequest,
    bundle: SkyViewBundle,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let engine = Engine::new();
        let params = RequestParams {
            quality: std::env::var("SKYVIEW_QUALITY").ok(),
            ..Default::default()
        };
        let request = LutRequest::from_params(&params)
            .unwrap()
            .with_layout(Layout::SkyView);
        let t = std::time::Instant::now();
        let bundle = request.compute_skyview(&engine).unwrap();
        eprintln!(
            "skyview build: {:.0} ms wall; stages (precise table, transmittance, sky view, irradiance) ms {:?}",
            t.elapsed().as_secs_f64() * 1e3,
            bundle.timing_ms
        );
        Fixture {
            engine,
            request,
            bundle,
        }
    })
}

fn spec_at(f: &Fixture, altitude_m: f64, sun_deg: f64) -> CommonSpec {
    let mut s = f.request.spec.clone();
    s.observer_altitude_m = altitude_m;
    s.sun.sun_elevation_deg = sun_deg;
    s
}

/// The `sky` product's radiance in the `probes` directions (view zenith, azimuth from the sun,
/// degrees) for an observer at `altitude_m` and the sun at `sun_deg`, through the engine as a
/// request runs (the dome itself kept minimal).
fn sky_probes(
    f: &Fixture,
    altitude_m: f64,
    sun_deg: f64,
    probes: &[(f64, f64)],
) -> skybake_engine::engine::DomeProduct {
    f.engine
        .sky(
            &spec_at(f, altitude_m, sun_deg),
            DomeShape {
                elevation_count: 2,
                azimuth_count: 1,
            },
            probes,
        )
        .unwrap()
}

fn channel_index(f: &Fixture, product_nm: &[f64]) -> Vec<usize> {
    f.bundle
        .wavelengths_nm
        .iter()
        .map(|w| product_nm.iter().position(|x| x == w).unwrap())
        .collect()
}

/// One probe's (view zenith, azimuth from the sun) and its (reader, `sky` product) radiance per
/// bundle channel.
type ProbeResult = ((f64, f64), Vec<(f64, f64)>);

/// Folds one observer's and sun's [`reader_against_product`] results into `worst` (the largest
/// relative deviation of the reader from the `sky` product and its case); with `verbose`, every
/// deviation over 3 % printed, tagged `tag`.
fn fold_worst(
    f: &Fixture,
    tag: &str,
    altitude_m: f64,
    sun_deg: f64,
    results: &[ProbeResult],
    verbose: bool,
    worst: &mut (f64, String),
) {
    for &((view_zenith_deg, view_azimuth_deg), ref channels) in results {
        for (c, &(got, want)) in channels.iter().enumerate() {
            let e = rel(got, want);
            let nm = f.bundle.wavelengths_nm[c];
            if verbose && e > 0.03 {
                eprintln!(
                    "{tag} alt {altitude_m:.0} sun {sun_deg:.2} zen {view_zenith_deg:.2} az {view_azimuth_deg:.1} {nm} nm {:+.2}%",
                    100.0 * (got - want) / want
                );
            }
            if e > worst.0 {
                *worst = (
                    e,
                    format!(
                        "(alt {altitude_m:.0} m, sun {sun_deg:.2}, view zenith {view_zenith_deg:.2} azimuth {view_azimuth_deg:.1}, {nm} nm: {got:.4e} vs {want:.4e})"
                    ),
                );
            }
        }
    }
}

/// The reader's sky radiance against the `sky` product's ([`sky_probes`]) for an observer at
/// `altitude_m` and the sun at `sun_deg`: per probe direction (view zenith, azimuth from the sun,
/// degrees), the (reader, product) radiance of each of the bundle's channels, W m⁻² sr⁻¹ nm⁻¹.
#[allow(clippy::type_complexity)]
fn reader_against_product(
    f: &Fixture,
    reader: &SkyViewReader,
    altitude_m: f64,
    sun_deg: f64,
    probes: &[(f64, f64)],
) -> Vec<ProbeResult> {
    let bottom = f.bundle.params.bottom_radius;
    let product = sky_probes(f, altitude_m, sun_deg, probes);
    let idx = channel_index(f, &product.table.wavelengths_nm);
    product
        .probes
        .iter()
        .map(|p| {
            let (radiance, _) = reader.sky_radiance(
                [0.0, 0.0, bottom + altitude_m],
                view_dir(p.view_zenith_deg, p.view_azimuth_deg),
                sun_dir(sun_deg),
            );
            let channels = idx
                .iter()
                .enumerate()
                .map(|(c, &i)| (radiance[c] / UNIT_SCALE, p.radiance_w_m2_sr_nm[i]))
                .collect();
            ((p.view_zenith_deg, p.view_azimuth_deg), channels)
        })
        .collect()
}

/// The band of the targets a sky sample falls in.
fn target_band(sun_deg: f64, near_horizon: bool) -> &'static str {
    if sun_deg >= 5.0 {
        if near_horizon {
            "sun >= 5, view < 10 deg above horizon (target 3 %)"
        } else {
            "sun >= 5, view > 10 deg above horizon (target 1 %)"
        }
    } else if sun_deg >= -6.0 {
        "sun -6..5 (target 3 %)"
    } else {
        "sun -12..-6 (target 10 %)"
    }
}

/// The `sky` product's samples of the skyview tests (`sky_samples`: 96 random observers,
/// 12 views each), computed once.
fn samples(f: &Fixture) -> &'static [SkySample] {
    static S: OnceLock<Vec<SkySample>> = OnceLock::new();
    S.get_or_init(|| {
        sky_samples(
            &f.engine,
            f.bundle.params.bottom_radius,
            2027,
            96,
            |altitude, sun| spec_at(f, altitude, sun),
            |nm| channel_index(f, nm),
        )
    })
}

/// Largest error per band of `reader` over `samples`: by target band, and by target band and
/// altitude (ground, 0–20 km, 20–100 km).
fn sky_errors(f: &Fixture, reader: &SkyViewReader, samples: &[SkySample]) -> (Bands, Bands) {
    let mut bands = Bands::default();
    let mut by_altitude = Bands::default();
    let bottom = f.bundle.params.bottom_radius;
    for s in samples {
        let (radiance, _) = reader.sky_radiance(
            [0.0, 0.0, bottom + s.altitude_m],
            view_dir(s.view_zenith_deg, s.view_azimuth_deg),
            sun_dir(s.sun_deg),
        );
        let band = target_band(s.sun_deg, s.near_horizon);
        let alt_band = format!("{}, {}", band, altitude_band(s.altitude_m));
        for (c, &want) in s.radiance.iter().enumerate() {
            let got = radiance[c] / UNIT_SCALE;
            let e = rel(got, want);
            let what = describe(s, f.bundle.wavelengths_nm[c], got, want);
            bands.add_case(band, e, what.clone());
            by_altitude.add_case(&alt_band, e, what);
        }
    }
    (bands, by_altitude)
}

#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_sky_radiance_matches_the_sky_product() {
    let f = fixture();
    let (bands, by_altitude) = sky_errors(f, &SkyViewReader::new(&f.bundle), samples(f));
    bands.print("skyview sky");
    by_altitude.print("skyview sky by altitude");
    let bands = by_altitude;
    // Measured on 2026-12-06 (earth, standard, RGB; layout version 6: the limb rows at
    // y = 2x² − x³, the sun nodes warped towards sunset aloft, 22 sky rows following the band
    // above the earth's shadow at low altitude, 81 sun nodes, the slices' largest texel stored
    // as 2¹⁵, the columns denser around 90° from the sun aloft, the altitude nodes denser near
    // the top, each slice read relative to the band and the focus growing to 5 km; version 9:
    // the limb's sun coordinate towards the tangent point's over 50 km, the sky rows' aloft
    // towards the exit point's; version 11: aloft away from the sun the deep limb rows' back
    // towards the observer's horizon; version 13: the columns focused at 110° from 20–30 km up,
    // each altitude node read at its own column coordinate from 15–20 km up; version 14: the
    // columns' square-root weight 0.72 below 15 km, a quarter of the sky rows' focus kept under
    // a high band; version 15: aloft the limb's near-end fade over 66–127° from the sun, the
    // columns' focus at 115°, the sun warp centred on the sky rows towards the sun). Where the
    // issue's target is met it is asserted, and the measured bound + ~12 % (the tighter): in every
    // band since version 15 (−12…−6° from 20–100 km: 12.42 → 8.79 %). After version 20 (the sky
    // rows' exit shift without its kink at 90° from the sun, `skyview::sky_exit_azimuth`):
    // 20–100 km, −12…−6° 8.79 → 8.05 %, −6…5° 2.94 → 2.89 %, sun ≥ 5° above 10° 0.253 → 0.250 %.
    for (band, measured, target) in [
        (
            "sun >= 5, view > 10 deg above horizon (target 1 %), ground",
            0.00269,
            Some(0.01),
        ),
        (
            "sun >= 5, view > 10 deg above horizon (target 1 %), 0-20 km",
            0.00168,
            Some(0.01),
        ),
        (
            "sun >= 5, view > 10 deg above horizon (target 1 %), 20-100 km",
            0.00250,
            Some(0.01),
        ),
        (
            "sun >= 5, view < 10 deg above horizon (target 3 %), ground",
            0.00449,
            Some(0.03),
        ),
        (
            "sun >= 5, view < 10 deg above horizon (target 3 %), 0-20 km",
            0.00484,
            Some(0.03),
        ),
        (
            "sun >= 5, view < 10 deg above horizon (target 3 %), 20-100 km",
            0.02022,
            Some(0.03),
        ),
        ("sun -6..5 (target 3 %), ground", 0.01194, Some(0.03)),
        ("sun -6..5 (target 3 %), 0-20 km", 0.01440, Some(0.03)),
        ("sun -6..5 (target 3 %), 20-100 km", 0.02889, Some(0.03)),
        ("sun -12..-6 (target 10 %), ground", 0.03319, Some(0.10)),
        ("sun -12..-6 (target 10 %), 0-20 km", 0.04724, Some(0.10)),
        ("sun -12..-6 (target 10 %), 20-100 km", 0.08053, Some(0.10)),
    ] {
        let bound = target.map_or(measured * 1.12, |t: f64| t.min(measured * 1.12));
        assert!(bands.get(band) > 0.0, "no sample in {band}");
        assert!(bands.get(band) < bound, "{band}: {bands:?}");
    }
}

/// Every axis needs its 4 nodes (the shader's 512 texel fetches per pixel): read with 2 nodes
/// (geometric between the interval's two) on one axis, some band of the targets gets
/// markedly worse. Measured (2026-12-05, standard, layout version 5): altitude — sun ≥ 5°,
/// view > 10°, 0–20 km 0.083 → 0.85 %; sun — −6…5°, 0–20 km 1.39 → 2.48 %; view rows — −12…−6°
/// at the ground 3.4 → 5.9 %; azimuth — −6…5° at the ground 1.49 → 3.01 % (over the 3 % target).
/// (Version 4: 0.18 → 0.86, 1.36 → 2.48, 3.4 → 5.9, 1.49 → 3.01 %; version 3: 0.18 → 0.86, 2.6 → 6.0, 3.4 → 5.9, 1.3 → 3.8 %.) Version 5 (the columns read
/// relative to the band): the same but the azimuth, −6…5° at the ground 1.47 → 2.14 %; asserted
/// on the grid of the earth's shadow rising instead ([`shadow_rise_errors`]: 5.32 → 8.32 %).
/// Version 6 (2026-12-06, each slice read relative to the band): the same but −6…5° at the
/// ground 1.27 → 2.14 % with 2 columns, and the grid 3.13 → 6.92 %. Version 9 (the focus up
/// to 20 km): the sun axis asserted on the grid seen aloft at 8–11 km instead (5.23 → 10.0 %).
/// Version 14 (the columns' square-root weight 0.72 below 15 km, denser 90–135° from the sun):
/// the azimuth asserted on −6…5° at the ground again (1.19 → 1.93 %; the earth's shadow rising
/// 2.16 → 3.08 %, the twilight glow at sunset 2.99 → 3.58 %).
#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_four_nodes_per_axis_are_needed() {
    let f = fixture();
    let (_, four) = sky_errors(f, &SkyViewReader::new(&f.bundle), samples(f));
    for (axis, band) in [
        (
            0,
            "sun >= 5, view > 10 deg above horizon (target 1 %), 0-20 km",
        ),
        // The sun: with the sun nodes 0.125° apart from 0° to 0.5° (layout version 13) the
        // random samples' worst on the band aloft needs the 4 sun nodes (5.19 % with 2, 1.59 %
        // with 4; version 12's grid of the earth's shadow seen aloft at 8–11 km: 10.0 / 5.23 %,
        // now 7.55 / 6.05 %, its worst the altitude axis).
        (1, "sun -6..5 (target 3 %), 0-20 km"),
        (2, "sun -12..-6 (target 10 %), ground"),
        (3, "sun -6..5 (target 3 %), ground"),
    ] {
        let mut reader = SkyViewReader::new(&f.bundle);
        reader.nodes[axis] = 2;
        let (_, two) = sky_errors(f, &reader, samples(f));
        eprintln!(
            "skyview axis {axis} with 2 nodes: {band}: {:.3} % (4 nodes: {:.3} %)",
            two.get(band) * 100.0,
            four.get(band) * 100.0
        );
        assert!(two.get(band) > 1.5 * four.get(band), "axis {axis}: {band}");
    }
}

/// At its nodes the bundle is the `sky` product: random texels (altitude, sun, view above the
/// horizon, azimuth node) read back through the reader at exactly their direction equal the
/// product there to the half floats' rounding.
#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_nodes_equal_the_sky_product() {
    let f = fixture();
    let reader = SkyViewReader::new(&f.bundle);
    let mut rng = Pcg64::seed_from_u64(7);
    let bottom = f.bundle.params.bottom_radius;
    let thickness = f.bundle.params.top_radius - bottom;
    let mut worst = 0.0f64;
    for _ in 0..24 {
        // Not the top node (evaluated 10 m below the top) nor the horizon row (nudged).
        let k = rng.random_range(0..skyview::N_ALT - 1);
        let altitude = skyview::altitude_node_m(k, thickness);
        let r = bottom + altitude;
        // At the ground the limb rows are the horizontal (nudged).
        let rows = if k == 0 {
            skyview::N_VIEW_SKY - 1
        } else {
            skyview::N_VIEW_UP - 1
        };
        // A row and a column; the sun on a node of the ray's sun coordinate (the sun's
        // elevation + `sun_shift`), between -12° and 90°. Above the horizontal the shift is
        // the horizon's dip at every azimuth below 20 km and away from the sun: 2 views there
        // share the sun (and its rows).
        let i = rng.random_range(0..rows);
        let a = rng.random_range(0..skyview::N_AZ);
        // A query at the zenith has no azimuth and reads column 0 (whose sun nodes towards the
        // sun aloft are not the other columns', `skyview::sun_warp_centre`).
        let a = if i == 0 { 0 } else { a };
        let phi = skyview::azimuth_node(a, altitude);
        let limb = i >= skyview::N_VIEW_SKY;
        // The sky rows' elevation depends on the sun node (in low twilight,
        // `skyview::sky_row_focus`), the limb rows' sun coordinate on the row.
        let b = skyview::warp_strength(altitude, thickness);
        let c = skyview::sun_warp_centre(
            altitude,
            bottom,
            bottom + thickness,
            usize::from(limb),
            phi.cos(),
        );
        let (theta, sun_deg, s_j, j) = loop {
            let j = rng.random_range(0..skyview::N_SUN);
            let s_j = skyview::sun_warp(skyview::sun_node_deg(j), b, c);
            let (theta, _) = skyview::view_node(i, r, bottom, s_j);
            let shift = skyview::sun_shift(r, theta, phi.cos(), bottom, bottom + thickness, limb)
                .to_degrees();
            let e = s_j - shift;
            if (-12.0..=90.0).contains(&e) {
                break (theta, e, s_j, j);
            }
        };
        let mut probes = vec![(theta.to_degrees(), phi.to_degrees())];
        if !limb {
            let i = rng.random_range(0..skyview::N_VIEW_SKY);
            let a = rng.random_range(0..skyview::N_AZ);
            let a = if i == 0 { 0 } else { a };
            let (theta, _) = skyview::view_node(i, r, bottom, s_j);
            let phi = skyview::azimuth_node(a, altitude);
            // Aloft towards the sun the sky rows' shift and the warp's centre depend on the
            // view: a second view shares the sun (is a node) only where its sun coordinate less
            // its shift is the first's.
            let shift = skyview::sun_shift(r, theta, phi.cos(), bottom, bottom + thickness, false);
            let c = skyview::sun_warp_centre(altitude, bottom, bottom + thickness, 0, phi.cos());
            let s_a = skyview::sun_warp(skyview::sun_node_deg(j), b, c);
            if (s_a - shift.to_degrees() - sun_deg).abs() < 1e-9 {
                probes.push((theta.to_degrees(), phi.to_degrees()));
            }
        }
        let product = sky_probes(f, altitude, sun_deg, &probes);
        let idx = channel_index(f, &product.table.wavelengths_nm);
        // Half floats hold a slice's values to 2^-11 relative down to 2^-29 of its largest
        // value (`skyview::SLICE_PEAK`): deviations are relative to the radiance itself.
        for p in &product.probes {
            let (radiance, _) = reader.sky_radiance(
                [0.0, 0.0, bottom + altitude],
                view_dir(p.view_zenith_deg, p.view_azimuth_deg),
                sun_dir(sun_deg),
            );
            for (c, &i) in idx.iter().enumerate() {
                let want = p.radiance_w_m2_sr_nm[i];
                if want > 0.0 {
                    let e = rel(radiance[c] / UNIT_SCALE, want);
                    worst = worst.max(e);
                }
            }
        }
    }
    eprintln!("skyview nodes: largest relative deviation from the sky product {worst:.2e}");
    // The texels' rounding to 8 mantissa bits (≤ 2⁻⁹ = 1.95·10⁻³, [`skyview::HALF_MANTISSA_BITS`])
    // and the multiple scattering the build interpolates between sun nodes where smooth
    // (docs/lut.md, "Cost"): 4.48·10⁻³ (layout version 14; 2.50·10⁻³ with 32 altitude nodes and the columns of version 13, 2026-12-06; with 10 bits and 28
    // nodes 3.24·10⁻³ at 549 m, sun −7.74°, zenith 8.4°, 112° from the sun, that slice sharing
    // its row's ray with the unfocused suns). Bound: measured + ~12 %.
    assert!(worst < 5.0e-3, "{worst}");
}

/// The dim slices keep half floats' relative precision: aloft in deep twilight (sun −12…−6°,
/// 55–86 km) the sky away from the lit limb is 10⁻⁶…10⁻⁸ of its slice's largest value. At
/// nodes of those slices (every other sky row but the zenith, 5 azimuths), the reader equals the
/// `sky` product to 3.3·10⁻³ relative to the radiance itself (no floor): the texels' rounding to
/// 8 mantissa bits, ≤ 2⁻⁹ = 1.95·10⁻³ ([`skyview::HALF_MANTISSA_BITS`]; measured 1.89·10⁻³,
/// 2026-12-06, 68.6 km, sun −11.96°, zenith 44°, antisolar; with 10 bits 7.8·10⁻⁴, bound
/// 2·10⁻³), and since layout version 15 2.92·10⁻³ (68.6 km, sun −12.37°, zenith 44°, 40° from the
/// sun, 550 nm: a column towards the sun whose sun nodes move with the warp's centre,
/// `skyview::sun_warp_centre`; not decomposed: probably the build's interpolation of the
/// multiple scattering between columns where smooth, docs/lut.md "Cost", its columns now at
/// other sun elevations than their neighbours').
/// Measured (2026-12-05, standard, 10 bits):
/// 4.6·10⁻⁴ (version 9, each node at its own sun elevation towards the sun: 5.7·10⁻⁴) with
/// the slices' largest texel stored as 2¹⁵ ([`skyview::SLICE_PEAK`]); with it
/// stored as 1 (version 3: the values below 2⁻¹⁴ of the largest are subnormal), 19.5 %
/// (85.7 km, sun −11.6°, zenith 65°, antisolar: 6.8·10⁻¹¹ W m⁻² sr⁻¹ nm⁻¹).
#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_dim_twilight_slices_keep_half_precision() {
    let f = fixture();
    let reader = SkyViewReader::new(&f.bundle);
    let bottom = f.bundle.params.bottom_radius;
    let thickness = f.bundle.params.top_radius - bottom;
    let mut worst = (0.0f64, String::new());
    for k in [20, 23, 25] {
        let altitude = skyview::altitude_node_m(k, thickness);
        let r = bottom + altitude;
        let shift = skyview::dip(r, bottom).to_degrees();
        let b = skyview::warp_strength(altitude, thickness);
        // Two sun nodes with the sun's elevation in −12…−6° away from the sun (above the
        // horizontal the sun coordinate is there the elevation + the horizon's dip, and the
        // twilight warp centred at 0).
        let suns: Vec<usize> = (0..skyview::N_SUN)
            .filter(|&j| {
                let e = skyview::sun_warp(skyview::sun_node_deg(j), b, 0.0) - shift;
                (-12.0..=-6.0).contains(&e)
            })
            .collect();
        assert!(suns.len() >= 2, "altitude node {k}: {suns:?}");
        for j in [suns[0], suns[suns.len() - 1]] {
            // Not the zenith row: a query at the zenith has no azimuth and reads column 0, whose
            // sun nodes towards the sun aloft are not the other columns'
            // (`skyview::sun_warp_centre`).
            for i in (2..skyview::N_VIEW_SKY - 1).step_by(2) {
                for a in [0, 5, 10, 15, skyview::N_AZ - 1] {
                    let phi = skyview::azimuth_node(a, altitude);
                    // Towards the sun the warp's centre moves with the azimuth
                    // (`skyview::sun_warp_centre`): the node's sun coordinate is its column's.
                    let c = skyview::sun_warp_centre(
                        altitude,
                        bottom,
                        bottom + thickness,
                        0,
                        phi.cos(),
                    );
                    let s_j = skyview::sun_warp(skyview::sun_node_deg(j), b, c);
                    let theta = skyview::view_node(i, r, bottom, s_j).0;
                    // Aloft towards the sun the sky rows' sun coordinate moves towards the
                    // sun's elevation where the ray leaves the atmosphere (`sun_shift`): the
                    // node's sun elevation is the coordinate less the texel's own shift.
                    let sun_deg = s_j
                        - skyview::sun_shift(
                            r,
                            theta,
                            phi.cos(),
                            bottom,
                            bottom + thickness,
                            false,
                        )
                        .to_degrees();
                    let product = sky_probes(
                        f,
                        altitude,
                        sun_deg,
                        &[(theta.to_degrees(), phi.to_degrees())],
                    );
                    let idx = channel_index(f, &product.table.wavelengths_nm);
                    let p = &product.probes[0];
                    let (radiance, _) = reader.sky_radiance(
                        [0.0, 0.0, r],
                        view_dir(p.view_zenith_deg, p.view_azimuth_deg),
                        sun_dir(sun_deg),
                    );
                    for (c, &i) in idx.iter().enumerate() {
                        let want = p.radiance_w_m2_sr_nm[i];
                        assert!(want > 0.0, "no light at {altitude} m, sun {sun_deg}");
                        let e = rel(radiance[c] / UNIT_SCALE, want);
                        if e > worst.0 {
                            worst = (
                                e,
                                format!(
                                    "alt {altitude:.0} m, sun {sun_deg:.2}, view {:.2}/{:.2}, channel {c}: {:.4e} vs {want:.4e}",
                                    p.view_zenith_deg,
                                    p.view_azimuth_deg,
                                    radiance[c] / UNIT_SCALE
                                ),
                            );
                        }
                    }
                }
            }
        }
    }
    eprintln!(
        "skyview dim twilight nodes: largest relative deviation {:.2e} ({})",
        worst.0, worst.1
    );
    assert!(worst.0 < 3.3e-3, "{}", worst.1);
}

/// The twilight glow above the sun's azimuth in deep twilight (sun −12…−6°) from the ground to
/// 20 km: a dense grid the random samples miss (they read 3.8 % at most in this band).
/// Observers at 0, 2.5, 5, 10, 15 and 20 km; the sun at −12…−6° in 1° steps; views from 60° to
/// 0.25° above the horizon in 1° steps (0.25° steps in the lowest 5°) at 0°, 30°, 60° and 90°
/// from the sun's azimuth. Returns the largest relative error over the grid and its case.
fn twilight_glow_errors(f: &Fixture, reader: &SkyViewReader, suns: &[f64]) -> (f64, String) {
    let verbose = std::env::var("SKYVIEW_GLOW_VERBOSE").is_ok();
    let mut worst = (0.0f64, String::new());
    let mut zeniths = Vec::new();
    let mut z = 30.0;
    while z <= 85.0 {
        zeniths.push(z);
        z += 1.0;
    }
    let mut z = 85.25;
    while z <= 89.75 {
        zeniths.push(z);
        z += 0.25;
    }
    let probes: Vec<(f64, f64)> = [0.0, 30.0, 60.0, 90.0]
        .iter()
        .flat_map(|&az| zeniths.iter().map(move |&z| (z, az)))
        .collect();
    for altitude in [0.0, 2500.0, 5000.0, 10000.0, 15000.0, 20000.0] {
        for &sun in suns {
            let results = reader_against_product(f, reader, altitude, sun, &probes);
            fold_worst(f, "glow", altitude, sun, &results, verbose, &mut worst);
        }
    }
    worst
}

/// The twilight glow in deep twilight, 0–20 km (see [`twilight_glow_errors`]); the issue's
/// target is 10 % (sun down to −12°), met since layout version 14: measured on 2026-12-06 (earth,
/// standard, RGB) 9.21 % at 5 km, sun −12°, 0.25° above the horizontal 30° from the sun, 680 nm
/// (the altitude nodes inserted at 15.3 and 18.5 km alone: 9.00 % at 15 km; the columns'
/// square-root weight at 0.65 instead of 0.72: 10.16 % at 5 km, 60° from the sun). Version 13:
/// 14.4 % at 15 km, sun −12°, 1° above the horizontal 60° from the sun, 680 nm, too dark: the
/// altitude nodes; per altitude 6.8 / 7.5 / 8.7 / 6.4 / 14.4 / 7.4 % at
/// 0 / 2.5 / 5 / 10 / 15 / 20 km; version 12: 6.8 / 7.5 / 9.6 / 7.8 / 14.4 / 8.4 %). (Version 11: 17.8 % at 5 km, sun −7°, 0.25° above the
/// horizontal towards the sun, 440 nm, too bright: the sky rows, drawn towards the band above
/// the earth's shadow opposite the sun; the focus now fades in from −5° to −3° of the sun's
/// elevation above the observer's horizon.) The target is asserted, and the measured + ~12 %.
#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_the_twilight_glow_in_deep_twilight() {
    let f = fixture();
    let suns = [-12.0, -11.0, -10.0, -9.0, -8.0, -7.0, -6.0];
    let (worst, case) = twilight_glow_errors(f, &SkyViewReader::new(&f.bundle), &suns);
    eprintln!(
        "skyview twilight glow, 0-20 km, sun -12..-6 (target 10 %): {:.3} % {case}",
        100.0 * worst
    );
    let measured = 0.0921;
    assert!(worst > 0.0, "no sample");
    assert!(worst < (measured * 1.12f64).min(0.10), "{worst} {case}");
}

/// The same grid as [`twilight_glow_errors`] with the sun at −6…5° in 1° steps (the issue's
/// target 3 %; the random samples read 1.36 % at 0–20 km), met: measured on 2026-12-06 (earth,
/// standard, RGB, layout version 14) 2.99 % at 15 km, sun −6°, 1° above the horizontal 30°
/// from the sun, 440 nm (version 13: 9.54 % at 15 km, sun −6°, 0.75° above the horizontal 90°
/// from the sun, 680 nm, too dark: the azimuth columns −5.1 %, the altitude nodes −4.3 %; 10 km
/// 4.50 %, 90° from the sun; the columns' square-root weight 0.65 below 15 km took the grid to
/// 2.94 %). The target is asserted, and the measured + ~12 % (the tighter).
/// (Version 12: 9.65 % at 5 km, sun −6°, 0.25° above the horizontal towards the sun, 440 nm, too
/// bright: the sky rows, drawn towards the band above the earth's shadow, 9–12° high; their
/// focus now fades out to a quarter as the band rises from 6° to 9°.)
#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_the_twilight_glow_at_sunset() {
    let f = fixture();
    let suns: Vec<f64> = (-6..=5).map(f64::from).collect();
    let (worst, case) = twilight_glow_errors(f, &SkyViewReader::new(&f.bundle), &suns);
    eprintln!(
        "skyview twilight glow, 0-20 km, sun -6..5 (target 3 %): {:.3} % {case}",
        100.0 * worst
    );
    let measured = 0.0294;
    assert!(worst > 0.0, "no sample");
    assert!(worst < (measured * 1.12f64).min(0.03), "{worst} {case}");
}

#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_sun_and_sky_irradiance_match_the_sun_product() {
    let f = fixture();
    let reader = SkyViewReader::new(&f.bundle);
    let mut rng = Pcg64::seed_from_u64(2027);
    let mut direct = Bands::default();
    let mut sky = Bands::default();
    let bottom = f.bundle.params.bottom_radius;
    for case in 0..32 {
        let (altitude, sun_deg) = random_observer(&mut rng, case);
        let product = f.engine.sun(&spec_at(f, altitude, sun_deg)).unwrap();
        let idx = channel_index(f, &product.wavelengths_nm);
        let point = [0.0, 0.0, bottom + altitude];
        let sun = sun_dir(sun_deg);
        let (dni, _) = reader.sun_and_sky_irradiance(point, sun, sun);
        let (_, dhi) = reader.sun_and_sky_irradiance(point, [0.0, 0.0, 1.0], sun);
        let band = format!(
            "{}, {}",
            if sun_deg >= 5.0 {
                "sun >= 5"
            } else if sun_deg >= -6.0 {
                "sun -6..5"
            } else {
                "sun -12..-6"
            },
            if altitude == 0.0 { "ground" } else { "aloft" }
        );
        for (c, &i) in idx.iter().enumerate() {
            let want = product.direct_normal_irradiance_w_m2_nm[i];
            if want > 1e-3 * product.solar_irradiance_w_m2_nm[i] {
                direct.add(&band, rel(dni[c] / UNIT_SCALE, want));
            }
            let want = product.diffuse_horizontal_irradiance_w_m2_nm[i];
            let got = dhi[c] / UNIT_SCALE;
            sky.add_case(
                &band,
                rel(got, want),
                format!("(alt {altitude:.0} m, sun {sun_deg:.2}: {got:.4e} vs {want:.4e})"),
            );
        }
    }
    direct.print("skyview sun direct normal");
    sky.print("skyview sky diffuse horizontal");
    // Measured 0.006 %, 0.023 %, 0.041 %, 0.38 % (Bruneton's transmittance texture) and for
    // the sky's irradiance 0.24 % (ground, sun >= 5), 1.45 % (aloft, sun >= 5; layout version
    // 4: 1.27 %, version 5's altitude nodes 16 % sparser at 50 km), 0.34 %, 1.06 % (sun -6..5;
    // version 4: 0.66 %), 0.03 %, 1.50 % (sun -12..-6: 2e-8 W m-2 nm-1 at 63 km, on the sun
    // nodes that the twilight warp spreads away from sunset; layout version 2: 0.73 %).
    for (band, measured) in [
        ("sun >= 5, ground", 6e-5),
        ("sun >= 5, aloft", 2.3e-4),
        ("sun -6..5, ground", 4.1e-4),
        ("sun -6..5, aloft", 0.0038),
    ] {
        assert!(
            direct.get(band) < measured * 1.12 + 1e-5,
            "{band}: {direct:?}"
        );
    }
    for (band, measured) in [
        ("sun >= 5, ground", 0.0024),
        ("sun >= 5, aloft", 0.0145),
        ("sun -6..5, ground", 0.0034),
        ("sun -6..5, aloft", 0.0106),
        ("sun -12..-6, ground", 0.0004),
        ("sun -12..-6, aloft", 0.0150),
    ] {
        assert!(sky.get(band) > 0.0, "no sample in {band}");
        assert!(sky.get(band) < measured * 1.12, "{band}: {sky:?}");
    }
}

/// The aerial perspective (`SkyViewReader::sky_radiance_to_point`: L(camera, v) − T · L(point,
/// v), Bruneton & Neyret 2008 §4) against the `aerial` product at random observers and suns, the
/// same cases and measures as Bruneton's layout's test (tests/atmosphere/lut.rs): in-scatter
/// relative to the whole 50 km path's, transmittance absolute.
#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_aerial_perspective_matches_the_aerial_product() {
    let f = fixture();
    let reader = SkyViewReader::new(&f.bundle);
    let (inscatter, transmittance) = aerial_errors(
        &f.engine,
        f.bundle.params.bottom_radius,
        |altitude, sun_deg| spec_at(f, altitude, sun_deg),
        |nm| channel_index(f, nm),
        |camera, point, sun| reader.sky_radiance_to_point(camera, point, sun),
    );
    inscatter.print("skyview aerial in-scattered radiance");
    transmittance.print("skyview aerial transmittance (absolute)");
    // Measured (2026-12-05, standard, layout version 2): in-scatter by day 0-20 km 3.37 %
    // (Bruneton's layout: 7.7 %); transmittance aloft 0.11 % (the same texture). Aloft and in twilight the difference
    // of two lookups is meaningless for short or downward paths, as in his layout: printed only.
    assert!(inscatter.get("sun >= 5, 0-20 km") < 0.040, "{inscatter:?}");
    assert!(
        transmittance.get("sun >= 5, 20-100 km") < 0.0013,
        "{transmittance:?}"
    );
}

/// The files: sizes (the budget: ≤ 10 MB for the RGB bundle) and a manifest that
/// names the layout and every texture.
#[test]
#[ignore = "builds a bundle twice (about 20 s of CPU): run with --ignored lut_skyview::"]
fn skyview_files_and_manifest() {
    let f = fixture();
    let files = f.request.skyview_files(&f.bundle).unwrap();
    let total: usize = files.iter().map(|(_, b)| b.len()).sum();
    for (name, bytes) in &files {
        eprintln!("skyview file {name}: {} bytes", bytes.len());
    }
    eprintln!("skyview bundle: {total} bytes");
    assert!(total < 10_000_000, "{total} bytes");
    // The files as the CLI, the service and bakes make them (the Rayleigh-like and Mie files
    // compressed altitude node by node during the build) are those of the finished bundle.
    let (streamed, _) = f
        .request
        .compute_files_unless(&f.engine, &|| false)
        .unwrap();
    assert_eq!(streamed.len(), files.len());
    for ((name, bytes), (streamed_name, streamed_bytes)) in files.iter().zip(&streamed) {
        assert_eq!(name, streamed_name);
        assert!(bytes == streamed_bytes, "{name} differs when streamed");
    }
    let (_, manifest) = files.last().unwrap();
    let m: serde_json::Value = serde_json::from_slice(manifest).unwrap();
    assert_eq!(m["format"], "skyview");
    for t in ["transmittance", "rayleigh", "mie", "scale", "irradiance"] {
        let file = m["textures"][t]["file"].as_str().unwrap();
        assert!(files.iter().any(|(n, _)| *n == file), "{t}: {file}");
    }
}

/// The layouts by name: an unknown one is refused naming `layout`; the `skyview` request has its
/// own cache key (Bruneton's is unchanged).
#[test]
fn layouts_are_named_and_keyed_apart() {
    assert_eq!(Layout::parse("skyview").unwrap(), Layout::SkyView);
    assert_eq!(Layout::parse("bruneton2017").unwrap(), Layout::Bruneton2017);
    let err = Layout::parse("Skyview").unwrap_err();
    assert!(
        matches!(&err, skybake_physics::Error::OutOfRange { field, .. } if field == "layout"),
        "{err}"
    );
    let bruneton = LutRequest::from_params(&RequestParams::default()).unwrap();
    let sky = bruneton.clone().with_layout(Layout::SkyView);
    assert_ne!(bruneton.cache_key(), sky.cache_key());
    assert!(bruneton.canonical().get("layout").is_none());
    assert_eq!(sky.canonical()["layout"], "skyview");
}

/// The twilight sky just above the horizon opposite the sun at low altitude (the earth's shadow
/// rising opposite the setting sun): a dense grid the random samples miss.
/// Observers at `altitudes_m`, sun −6…0° in 1° steps, view zeniths from 80° down to 0.2°
/// above the horizon in 0.25° steps, azimuths 150° and 180° from the sun. Returns, per
/// altitude, the largest relative error over the grid and its case.
fn shadow_grid_errors(
    f: &Fixture,
    reader: &SkyViewReader,
    altitudes_m: &[f64],
) -> Vec<(f64, String)> {
    let bottom = f.bundle.params.bottom_radius;
    let verbose = std::env::var("SKYVIEW_SHADOW_VERBOSE").is_ok();
    let mut per_altitude = Vec::new();
    for &altitude in altitudes_m {
        let mut worst = (0.0f64, String::new());
        let dip = (bottom / (bottom + altitude)).acos().to_degrees();
        let mut probes = Vec::new();
        for az in [150.0, 180.0] {
            let mut z = 80.0;
            while z < 90.0 + dip - 0.2 {
                probes.push((z, az));
                z += 0.25;
            }
        }
        for sun in [-6.0, -5.0, -4.0, -3.0, -2.0, -1.0, 0.0] {
            for ((view_zenith_deg, view_azimuth_deg), channels) in
                reader_against_product(f, reader, altitude, sun, &probes)
            {
                let mut line = String::new();
                for (c, &(got, want)) in channels.iter().enumerate() {
                    let e = rel(got, want);
                    line += &format!(" {:+.2}%", 100.0 * (got - want) / want);
                    if e > worst.0 {
                        worst = (
                            e,
                            format!(
                                "(alt {altitude:.0} m, sun {sun:.0}, view zenith {:.2} azimuth {:.0}, {} nm: {got:.4e} vs {want:.4e})",
                                view_zenith_deg, view_azimuth_deg, f.bundle.wavelengths_nm[c]
                            ),
                        );
                    }
                }
                if verbose {
                    eprintln!(
                        "shadow alt {altitude:.0} sun {sun:.0} zen {:.2} az {:.0}:{line}",
                        view_zenith_deg, view_azimuth_deg
                    );
                }
            }
        }
        per_altitude.push(worst);
    }
    per_altitude
}

/// [`shadow_grid_errors`] at 0, 1, 2.5 and 5 km: the largest relative error over the grid and
/// its case.
fn shadow_rise_errors(f: &Fixture, reader: &SkyViewReader) -> (f64, String) {
    shadow_grid_errors(f, reader, &[0.0, 1000.0, 2500.0, 5000.0])
        .into_iter()
        .fold(
            (0.0f64, String::new()),
            |a, b| if b.0 > a.0 { b } else { a },
        )
}

/// The earth's shadow rising (see [`shadow_rise_errors`]). The target is 3 % (views
/// within 10° of the horizon, sun down to −6°), met on the grid: measured on 2026-12-06 (earth,
/// standard, RGB, layout version 14) 2.16 % at 2.5 km, sun 0°, view zenith 86.75°, azimuth
/// 150°, 680 nm (version 7: 2.37 % at 2.5 km, sun −1°, zenith 89.5°, 150°; version 6: 3.13 % at 5 km, sun −1°, the horizontal 150° from the sun, where
/// the columns' map relative to the band was the identity; version 5: 5.32 % at 5 km, version
/// 4: 16.4 %, version 3: 48 %), so the bound is the measured + ~12 %. The sunlit band above the antisolar horizon (lit by sunlight that
/// grazed the ground) rises ≈ 2° per degree the sun sinks and is sharpest (a factor of 10 per
/// degree at 5 km) just after sunset at the observer; the sky rows are denser around its
/// elevation opposite the sun, the sun nodes 0.25° apart around sunset, and the azimuth
/// columns are read each at its own elevation relative to the band, which lies lower away from
/// the antisolar point (docs/lut.md, the skyview layout's sky rows).
#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_the_earth_shadow_rising_at_low_altitude() {
    let f = fixture();
    let (worst, case) = shadow_rise_errors(f, &SkyViewReader::new(&f.bundle));
    eprintln!(
        "skyview earth's shadow rising, 0-5 km, sun -6..0 (target 3 %): {:.3} % {case}",
        100.0 * worst
    );
    let measured = 0.0218;
    assert!(worst > 0.0, "no sample");
    assert!(worst < measured * 1.12, "{worst} {case}");
}

/// The band above the earth's shadow seen from 6.5–40 km: the same grid as
/// [`shadow_grid_errors`] for observers above the low-altitude grid, the dense check around it
/// ([`shadow_aloft_errors`]: the sun every 0.25°, 120–180° from the sun every 15°), and from 6.5 to
/// 20 km the points halfway between the dense check's samples ([`shadow_between_errors`]). The
/// band sharpens with altitude and rises from 20 to 40 km; the sky rows' focus, the slices' and the
/// columns' band maps follow it (docs/lut.md, "The earth's shadow seen aloft").
///
/// Each bound is the measured worst + ~12 % (earth, standard, RGB, layout version 21 read with
/// each altitude node at its own tangent-point weight on the limb from 11–20 km up,
/// `skyview::limb_node_shift`, measured on 2026-12-07; 680 nm unless noted). The 3 % target (views within 10° of the
/// horizon, sun down to −6°) holds on the grid from 6.5 to 15 km and at 20–22.5 km and on the
/// dense check from 6.5 to 15 km; not at:
/// - 17.5 km: grid and dense 4.94 % (the sky 3° up 150° from the sun, sun −4°; the limb 4.26 %,
///   94° zenith 150° from the sun, sun −3.75°: 6.67 % with every node at its whole weight at
///   17.5 km, 6.49 % before `limb_node_shift`);
/// - 20 km dense 4.56 % (the sky 2.25° up 135° from the sun, sun −4.25°), between the samples
///   5.20 % (the limb 0.7° above the horizon 172.5° from the sun, sun −4.125°); 9.5 km between
///   the samples 3.06 % (the sky 2.1° up 172.5° from the sun);
/// - 25 / 30 / 35 / 40 km: grid 5.67 / 22.58 / 17.98 / 28.93 %, dense 18.15 / 34.97 / 27.57 /
///   28.93 %, 22.5 km dense 5.41 % (grid 2.23 %), all on the limb just above the horizon
///   150–180° from the sun (the limb rows' focus kept up to 25–30 km; the limb's near end fading
///   in over 26–40 km); above the horizontal alone (the band itself) 3.51 / 4.66 / 6.27 / 6.04 /
///   9.11 % at 22.5 / 25 / 30 / 35 / 40 km (120–180° from the sun; with the exit shift's azimuth
///   weight faded out over 90–120° from the sun, [`skyview::sky_exit_azimuth`], 22.5 km reads
///   4.03 %, the sky 0.5° up 120° from the sun, sun −4.25°: worse, its bound loosened to it).
///
/// From 25–29 km up every altitude node is read with the query's own tangent-point weight
/// (`skyview::LIMB_NODE_QUERY_WEIGHT_M`, after version 21): 30 / 35 / 40 km grid 22.58 / 17.98 /
/// 28.93 → 22.64 / 7.77 / 29.55 %, dense 34.97 / 27.57 / 28.93 → 31.86 / 25.07 / 29.55 % (40 km
/// worse, the limb 2.4° above the horizon opposite the sun, sun −6°: the rows alone +27.9 %; its
/// bound set at the new figure, loosened), 6.5–25 km unchanged.
///
/// Before `limb_node_shift` (every altitude node read at the query's own coordinate): 22.5 / 25 /
/// 30 / 35 / 40 km grid 2.90 / 8.76 / 37.69 / 129.7 / 147.6 %, dense 6.82 / 23.01 / 54.58 / 166.4
/// / 147.6 % (35 / 40 km not asserted then). With every node at its whole weight also below
/// 15–20 km (version 21) 9.5 / 12.5 km dense 2.83 / 2.89 %, 12.5 km grid 2.89 %, between the
/// samples 2.29 %; with the query's exponential there (`skyview::LIMB_NODE_WEIGHT_ALTITUDE_M`,
/// blended over 11–20 km) 2.42 / 2.39 %, 1.87 % and 2.42 % (that bound loosened to it, 2.29 →
/// 2.42 %), 8 km between the samples 2.34 → 2.53 % (version 20's; its bound loosened to it).
/// Version 19: 22.5 / 25 km dense 26.9 / 39.5 %. Version 18 (before the band's maps were kept
/// aloft and the columns mirrored): 20 km dense 4.53 %, between the samples 6.80 % (12.5 km
/// 4.79 %); 22.5 / 25 km dense 46.5 / 69.6 %.
/// The limb rows' focus on the shadow's edge aloft (`skyview::limb_edge_focus`): 40 km 29.55 →
/// 16.24 %, 35 km dense 25.07 → 24.05 %, 30 km grid 22.64 → 22.59 %; loosened to the measured:
/// 30 km dense 31.86 → 31.88 %, 35 km above the horizontal 6.04 → 6.11 %.
#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_the_earth_shadow_seen_aloft() {
    let f = fixture();
    let altitudes = [
        6500.0, 8000.0, 9500.0, 11000.0, 12500.0, 15000.0, 17500.0, 20000.0, 22500.0, 25000.0,
        30000.0, 35000.0, 40000.0,
    ];
    // Measured worst per altitude (the order of `altitudes`): the grid, the dense check, and the
    // dense check above the horizontal alone (the band itself; below it the limb).
    let measured = [
        0.0153, 0.0156, 0.0241, 0.0242, 0.0187, 0.0219, 0.0494, 0.0197, 0.0223, 0.0567, 0.2259,
        0.0777, 0.1624,
    ];
    let measured_dense = [
        0.0247, 0.0261, 0.0242, 0.0252, 0.0239, 0.0296, 0.0494, 0.0456, 0.0541, 0.1815, 0.3188,
        0.2405, 0.1624,
    ];
    let measured_sky = [
        0.0247, 0.0261, 0.0242, 0.0252, 0.0221, 0.0296, 0.0494, 0.0456, 0.0403, 0.0487, 0.0645,
        0.0611, 0.0905,
    ];
    // Between the dense check's samples, 6.5–20 km (the order of `altitudes`).
    let measured_between = [
        0.0165, 0.0253, 0.0306, 0.0263, 0.0242, 0.0293, 0.0262, 0.0520,
    ];
    let t = std::time::Instant::now();
    let reader = SkyViewReader::new(&f.bundle);
    let results = shadow_aloft_errors(f, &reader, &altitudes);
    let between = shadow_between_errors(f, &reader, &altitudes[..measured_between.len()]);
    eprintln!(
        "skyview earth's shadow seen aloft: grid and dense check in {:.1} s wall",
        t.elapsed().as_secs_f64()
    );
    let mut failures = Vec::new();
    for ((((alt, (grid, dense, sky)), m), md), ms) in altitudes
        .iter()
        .zip(&results)
        .zip(measured)
        .zip(measured_dense)
        .zip(measured_sky)
    {
        eprintln!(
            "skyview earth's shadow seen aloft, {:.1} km, sun -6..0 (target 3 %): grid {:.3} % {}; dense {:.3} % {}; above the horizontal {:.3} % {}",
            alt / 1e3,
            100.0 * grid.0,
            grid.1,
            100.0 * dense.0,
            dense.1,
            100.0 * sky.0,
            sky.1
        );
        assert!(
            grid.0 > 0.0 && dense.0 > 0.0 && sky.0 > 0.0,
            "no sample at {alt} m"
        );
        if sky.0 >= ms * 1.12 {
            failures.push(format!("above the horizontal {alt} m: {} {}", sky.0, sky.1));
        }
        if grid.0 >= m * 1.12 {
            failures.push(format!("grid {alt} m: {} {}", grid.0, grid.1));
        }
        if dense.0 >= md * 1.12 {
            failures.push(format!("dense {alt} m: {} {}", dense.0, dense.1));
        }
    }
    for ((alt, (e, case)), m) in altitudes.iter().zip(&between).zip(measured_between) {
        eprintln!(
            "skyview earth's shadow seen aloft, {:.1} km, between the dense check's samples (target 3 %): {:.3} % {case}",
            alt / 1e3,
            100.0 * e
        );
        assert!(*e > 0.0, "no sample at {alt} m");
        if *e >= m * 1.12 {
            failures.push(format!("between {alt} m: {e} {case}"));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

/// The earth's shadow seen aloft between the dense check's samples of [`shadow_aloft_errors`]:
/// the sun, the view zenith and the azimuth halfway between them (sun −5.875…−0.125° every
/// 0.25°, zeniths from 80.125° every 0.25° down to 0.2° above the horizon, 127.5–172.5° from
/// the sun every 15°): per altitude the largest relative error and its case.
fn shadow_between_errors(
    f: &Fixture,
    reader: &SkyViewReader,
    altitudes_m: &[f64],
) -> Vec<(f64, String)> {
    let bottom = f.bundle.params.bottom_radius;
    let mut per_altitude = Vec::new();
    for &altitude in altitudes_m {
        let mut worst = (0.0f64, String::new());
        let dip = (bottom / (bottom + altitude)).acos().to_degrees();
        let mut probes = Vec::new();
        for az in [127.5, 142.5, 157.5, 172.5] {
            let mut z = 80.125;
            while z < 90.0 + dip - 0.2 {
                probes.push((z, az));
                z += 0.25;
            }
        }
        for i in 0..24 {
            let sun = -5.875 + 0.25 * i as f64;
            for ((view_zenith_deg, view_azimuth_deg), channels) in
                reader_against_product(f, reader, altitude, sun, &probes)
            {
                for (c, &(got, want)) in channels.iter().enumerate() {
                    let e = rel(got, want);
                    if e > worst.0 {
                        worst = (
                            e,
                            format!(
                                "(alt {altitude:.0} m, sun {sun:.3}, view zenith {:.3} azimuth {:.1}, {} nm: {got:.4e} vs {want:.4e})",
                                view_zenith_deg, view_azimuth_deg, f.bundle.wavelengths_nm[c]
                            ),
                        );
                    }
                }
            }
        }
        per_altitude.push(worst);
    }
    per_altitude
}

/// The earth's shadow seen aloft on [`shadow_grid_errors`]'s grid (sun −6…0° every 1°, 150° and
/// 180° from the sun) and on the dense check around it (sun every 0.25°, 120–180° from the sun
/// every 15°; the grid is a subset, so one `sky` product per altitude and sun serves both):
/// per altitude the largest relative error and its case on each, and on the dense check above
/// the horizontal.
#[allow(clippy::type_complexity)]
fn shadow_aloft_errors(
    f: &Fixture,
    reader: &SkyViewReader,
    altitudes_m: &[f64],
) -> Vec<((f64, String), (f64, String), (f64, String))> {
    let bottom = f.bundle.params.bottom_radius;
    let mut per_altitude = Vec::new();
    for &altitude in altitudes_m {
        let (mut grid, mut dense) = ((0.0f64, String::new()), (0.0f64, String::new()));
        let mut sky = (0.0f64, String::new());
        let dip = (bottom / (bottom + altitude)).acos().to_degrees();
        let mut probes = Vec::new();
        for az in [120.0, 135.0, 150.0, 165.0, 180.0] {
            let mut z = 80.0;
            while z < 90.0 + dip - 0.2 {
                probes.push((z, az));
                z += 0.25;
            }
        }
        for i in 0..=24 {
            let sun = -6.0 + 0.25 * i as f64;
            let on_grid = i % 4 == 0;
            for ((view_zenith_deg, view_azimuth_deg), channels) in
                reader_against_product(f, reader, altitude, sun, &probes)
            {
                let grid_az = view_azimuth_deg == 150.0 || view_azimuth_deg == 180.0;
                for (c, &(got, want)) in channels.iter().enumerate() {
                    let e = rel(got, want);
                    let case = || {
                        format!(
                            "(alt {altitude:.0} m, sun {sun:.2}, view zenith {:.2} azimuth {:.0}, {} nm: {got:.4e} vs {want:.4e})",
                            view_zenith_deg, view_azimuth_deg, f.bundle.wavelengths_nm[c]
                        )
                    };
                    if e > dense.0 {
                        dense = (e, case());
                    }
                    if view_zenith_deg <= 90.0 && e > sky.0 {
                        sky = (e, case());
                    }
                    if on_grid && grid_az && e > grid.0 {
                        grid = (e, case());
                    }
                }
            }
        }
        per_altitude.push((grid, dense, sky));
    }
    per_altitude
}

/// The sky beside the sun's azimuth seen from 20–40 km in twilight: observers at `altitudes_m`,
/// the sun −6…−3° every 0.25°, view zeniths 84–89.75° every 0.25° and the limb just below the
/// horizontal (90.25°, 90.5°, 91°), 30–120° from the sun every 7.5° (where the browser test's
/// bands aloft found their worst; the grids of [`shadow_aloft_errors`] look 120–180° from the
/// sun). Per altitude the largest relative error and its case; with `SKYVIEW_GLOW_VERBOSE` every
/// case over 3 %.
fn side_aloft_errors(
    f: &Fixture,
    reader: &SkyViewReader,
    altitudes_m: &[f64],
) -> Vec<(f64, String)> {
    let verbose = std::env::var("SKYVIEW_GLOW_VERBOSE").is_ok();
    let mut zeniths: Vec<f64> = (0..24).map(|i| 84.0 + 0.25 * f64::from(i)).collect();
    zeniths.extend([90.25, 90.5, 91.0]);
    let probes: Vec<(f64, f64)> = (0..13)
        .map(|i| 30.0 + 7.5 * f64::from(i))
        .flat_map(|az| zeniths.iter().map(move |&z| (z, az)))
        .collect();
    let mut per_altitude = Vec::new();
    for &altitude in altitudes_m {
        let mut worst = (0.0f64, String::new());
        for i in 0..=12 {
            let sun = -6.0 + 0.25 * f64::from(i);
            let results = reader_against_product(f, reader, altitude, sun, &probes);
            fold_worst(f, "side", altitude, sun, &results, verbose, &mut worst);
        }
        per_altitude.push(worst);
    }
    per_altitude
}

/// The sky beside the sun's azimuth seen from 20–40 km, sun −6…−3° (see [`side_aloft_errors`]).
/// Each bound is the measured worst + ~12 % (earth, standard, RGB, layout version 20, measured on
/// 2026-12-07): 20 km 5.76 % (the limb at zenith 90.25° 105° from the sun, sun −4°, 680 nm),
/// 22.5 km 4.94 % (the same, sun −6°), 25 km 5.26 % (the sky 0.75° up 90° from the sun, sun
/// −5°), 30 / 35 / 40 km 22.4 / 34.1 / 37.9 % (the sky 0.25° up exactly 90° from the sun, sun
/// −5.5 / −6 / −6°, too dark; 82.5° and 97.5° from the sun read within 10 %): the 3 %
/// target not met. The sky rows' exit shift without its kink at 90° from the sun
/// ([`skyview::sky_exit_azimuth`], after version 20): 5.78 / 4.85 / 5.46 / 9.88 / 18.68 / 22.95 %
/// (25 km the sky 0.25° up 112.5° from the sun, sun −4.5°; 30 km 37.5° from the sun, sun −5°;
/// 35 / 40 km still 0.25° up 90° from the sun, sun −5.5 / −6°, 680 nm: the exit shift itself,
/// the columns alone −18.5 %, docs/lut.md), asserted; the target not met from 20 km up.
#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_the_sky_beside_the_sun_aloft() {
    let f = fixture();
    let altitudes = [20000.0, 22500.0, 25000.0, 30000.0, 35000.0, 40000.0];
    let measured = [0.0578, 0.0485, 0.0546, 0.0988, 0.1874, 0.2296];
    let t = std::time::Instant::now();
    let results = side_aloft_errors(f, &SkyViewReader::new(&f.bundle), &altitudes);
    eprintln!(
        "skyview sky beside the sun aloft: {:.1} s wall",
        t.elapsed().as_secs_f64()
    );
    let mut failures = Vec::new();
    for ((alt, (e, case)), m) in altitudes.iter().zip(&results).zip(measured) {
        eprintln!(
            "skyview sky beside the sun aloft, {:.1} km, sun -6..-3, 30-120 deg from the sun (target 3 %): {:.3} % {case}",
            alt / 1e3,
            100.0 * e
        );
        assert!(*e > 0.0, "no sample at {alt} m");
        if *e >= m * 1.12 {
            failures.push(format!("{alt} m: {e} {case}"));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}

/// The sky seen from 45–55 km towards the sun in deep twilight (sun −11…−8°): the reader against
/// the `sky` product, the largest relative error over the bundle's channels (with
/// `SKYVIEW_GLOW_VERBOSE` every case over 3 %). Two sets: the browser test's band
/// (tools/browser/lut_test.mjs, "45-55 km, sun -11..-8 deg, towards the sun": 45 and 55 km, sun
/// −8 and −11°, view zenith 20, 60, 85°, azimuth 0 and 45° from the sun, views within 8° of the
/// sun left out) and a denser set near the horizontal within 30° of the sun's azimuth (45, 47.5,
/// 50, 52.5, 55 km, sun −11, −10, −9, −8°, zenith 80–89.75°, azimuth 0, 10, 20, 30°).
fn toward_sun_deep_errors(f: &Fixture, reader: &SkyViewReader, dense: bool) -> (f64, String) {
    let verbose = std::env::var("SKYVIEW_GLOW_VERBOSE").is_ok();
    let (altitudes, suns, zeniths, azimuths): (&[f64], &[f64], &[f64], &[f64]) = if dense {
        (
            &[45000.0, 47500.0, 50000.0, 52500.0, 55000.0],
            &[-11.0, -10.0, -9.0, -8.0],
            &[
                80.0, 82.0, 84.0, 85.0, 86.0, 87.0, 88.0, 88.5, 89.0, 89.5, 89.75,
            ],
            &[0.0, 10.0, 20.0, 30.0],
        )
    } else {
        (
            &[45000.0, 55000.0],
            &[-8.0, -11.0],
            &[20.0, 60.0, 85.0],
            &[0.0, 45.0],
        )
    };
    let mut worst = (0.0f64, String::new());
    for &altitude in altitudes {
        for &sun in suns {
            // Away from the sun's disk and aureole, as the browser test's `cross`.
            let s = sun_dir(sun);
            let probes: Vec<(f64, f64)> = zeniths
                .iter()
                .flat_map(|&z| azimuths.iter().map(move |&a| (z, a)))
                .filter(|&(z, a)| {
                    let v = view_dir(z, a);
                    v[0] * s[0] + v[1] * s[1] + v[2] * s[2] <= 8f64.to_radians().cos()
                })
                .collect();
            let results = reader_against_product(f, reader, altitude, sun, &probes);
            fold_worst(f, "toward", altitude, sun, &results, verbose, &mut worst);
        }
    }
    worst
}

/// The sky seen from 45–55 km towards the sun, sun −11…−8° (see [`toward_sun_deep_errors`]):
/// the browser test's band, which no Rust check covered (the i27-exit23 change took it 3.85 →
/// 19.5 % in the browser, 45 km, sun −8°, zenith 85°, 680 nm), and the denser set near the
/// horizontal. Each bound is the measured worst + ~12 % (earth, standard, RGB, layout version 22,
/// measured on 2026-12-08): the browser band's samples 3.85 % (45 km, sun −11°, zenith 85°, 45°
/// from the sun, 680 nm; the browser's own figure 3.85 %), the dense set 10.30 % (45 km, sun
/// −11°, zenith 80° towards the sun, 440 nm, too dark): the 10 % target met on the
/// browser's samples, not quite on the dense set.
#[test]
#[ignore = "builds a bundle (about 10 s of CPU): run with --ignored lut_skyview::"]
fn skyview_the_sky_towards_the_sun_in_deep_twilight_aloft() {
    let f = fixture();
    let reader = SkyViewReader::new(&f.bundle);
    // [browser band's samples, dense set]
    let measured = [0.0385, 0.1030];
    let mut failures = Vec::new();
    for (dense, m) in [false, true].into_iter().zip(measured) {
        let (e, case) = toward_sun_deep_errors(f, &reader, dense);
        eprintln!(
            "skyview sky towards the sun in deep twilight, 45-55 km, sun -11..-8, {} (target 10 %): {:.3} % {case}",
            if dense {
                "zenith 80-89.75 deg, 0-30 deg from the sun"
            } else {
                "the browser band's samples"
            },
            100.0 * e
        );
        assert!(e > 0.0, "no sample");
        if e >= m * 1.12 {
            failures.push(format!("dense {dense}: {e} {case}"));
        }
    }
    assert!(failures.is_empty(), "{failures:?}");
}
