//! The `skyview` reader's intermediate quantities for one sky query, printed one per line
//! (`name value`), in the order tools/browser/skyview_trace.mjs reads the same quantities from
//! the shader (web/lut/skyview.glsl, its debug fragment shader tools/browser/skyview_trace.glsl):
//! the first line where the two differ locates a deviation of the shader from the reader. The
//! trace follows `SkyViewReader::scattering` step by step with the crate's public functions and
//! checks at the end that its radiance is the reader's.
//!
//! Usage: cargo run --release -p skybake-harness --features probes --example skyview_trace --
//!        BUNDLE_DIR ALTITUDE_M SUN_DEG VIEW_ZENITH_DEG AZIMUTH_DEG

// The trace indexes per-channel node arrays by the node, as the reader does.
#![allow(clippy::needless_range_loop)]

use std::path::Path;

use serde_json::Value;
use skybake_lut::load::{skyview_from_files, DecodedFile};
use skybake_lut::manifest::MANIFEST_FILE;
use skybake_lut::skyview::{
    altitude_abscissa, altitude_coord, altitude_node_m, altitude_node_x, azimuth_coord,
    band_centre_deg, band_map_weight, band_relative_elevation, band_row, band_slice_elevation,
    limb_depth_of, limb_node_shift, limb_row_focused, limb_slice_depth, limb_sun_stencil,
    ray_length, segment_rows, sky_row_focus, sun_coord, sun_node_deg, sun_shift, sun_unwarp,
    sun_warp, sun_warp_centre, view_coord, warp_strength, Stencil, N_ALT, N_SUN, N_VIEW_LIMB,
    N_VIEW_SKY, SUN_MIN_DEG,
};
use skybake_lut::{SkyViewBundle, SkyViewReader};

fn print(name: &str, v: &[f64]) {
    let s: Vec<String> = v.iter().map(|x| format!("{x:.9e}")).collect();
    println!("{name} {}", s.join(" "));
}

fn stencil(name: &str, s: &Stencil) {
    print(
        name,
        &[s.first as f64, s.len as f64, s.w[0], s.w[1], s.w[2], s.w[3]],
    );
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    if args.len() != 6 {
        eprintln!("usage: skyview_trace BUNDLE_DIR ALTITUDE_M SUN_DEG VIEW_ZENITH_DEG AZIMUTH_DEG");
        std::process::exit(2);
    }
    let dir = Path::new(&args[1]);
    let num = |i: usize| -> f64 {
        args[i].parse().unwrap_or_else(|_| {
            eprintln!("argument {i} is not a number: {}", args[i]);
            std::process::exit(2)
        })
    };
    let (alt, sun_el, zen, az) = (num(2), num(3), num(4), num(5));
    let manifest: Value = match std::fs::read_to_string(dir.join(MANIFEST_FILE))
        .map_err(|e| e.to_string())
        .and_then(|s| serde_json::from_str(&s).map_err(|e| e.to_string()))
    {
        Ok(m) => m,
        Err(e) => {
            eprintln!("{}: {e}", dir.join(MANIFEST_FILE).display());
            std::process::exit(1)
        }
    };
    let mut read = |file: &str| -> skybake_lut::Result<DecodedFile> {
        let bytes = std::fs::read(dir.join(file))
            .map_err(|e| skybake_lut::Error::invalid("bundle", format!("{file}: {e}")))?;
        skybake_store::texture::decode_texture_exr(&bytes)
            .map_err(|e| skybake_lut::Error::invalid("bundle", format!("{file}: {e}")))
    };
    let bundle: SkyViewBundle = match skyview_from_files(&manifest, &mut read) {
        Ok(b) => b,
        Err(e) => {
            eprintln!("{e}");
            std::process::exit(1)
        }
    };
    let p = &bundle.params;
    let (bottom, top) = (p.bottom_radius, p.top_radius);
    let thickness = top - bottom;
    // The query as tools/browser/lut_test.mjs forms it.
    let (z, a, e) = (zen.to_radians(), az.to_radians(), sun_el.to_radians());
    let camera = [0.0, 0.0, bottom + alt];
    let view = [z.sin() * a.cos(), z.sin() * a.sin(), z.cos()];
    let sun = [e.cos(), 0.0, e.sin()];

    // SkyViewReader::sky_radiance → scattering, step by step.
    let r = camera[2];
    let mu = view[2];
    let mu_s = sun[2];
    let nu = view[0] * sun[0] + view[1] * sun[1] + view[2] * sun[2];
    let h = r - bottom;
    print("h_mu_mus_nu", &[h, mu, mu_s, nu]);
    let theta = mu.clamp(-1.0, 1.0).acos();
    let den = ((1.0 - mu * mu) * (1.0 - mu_s * mu_s)).max(0.0).sqrt();
    let cos_phi = if den > 1e-12 {
        ((nu - mu * mu_s) / den).clamp(-1.0, 1.0)
    } else {
        1.0
    };
    // (The column at the query's altitude; each altitude node's own below.)
    let phi = cos_phi.acos();
    let col = azimuth_coord(phi, h);
    print("phi_column", &[phi, col]);
    let (seg, _) = view_coord(theta, r, bottom, 0.0);
    let shift = sun_shift(r, theta, cos_phi, bottom, top, seg == 1);
    let s_deg = (mu_s.clamp(-1.0, 1.0).asin() + shift).to_degrees();
    let limb_y = limb_depth_of(theta, r, bottom);
    // (The shader forms the limb depth on the limb rows only.)
    let limb_y_traced = if seg == 1 { limb_y } else { 0.0 };
    print(
        "segment_limby_shift_sq",
        &[seg as f64, limb_y_traced, shift, s_deg],
    );
    // The band's elevation (the shader's band_c; the rows' focus sits at band_focus_place times
    // it) and the focus strength.
    let (_, band_k, _) = sky_row_focus(s_deg, h);
    print("band_c_k", &[band_centre_deg(s_deg, h), band_k]);
    let (seg, row) = view_coord(theta, r, bottom, s_deg);
    let (lo, hi) = segment_rows(seg);
    let sv = Stencil::new(row, lo, hi, |i| i as f64, row);
    print("row", &[row]);
    stencil("row_stencil", &sv);
    let ya = altitude_coord(h, thickness);
    let sa = Stencil::new(
        ya,
        0,
        N_ALT - 1,
        altitude_node_x,
        altitude_abscissa(h, thickness),
    );
    let above = mu_s.clamp(-1.0, 1.0).asin() + shift;
    let centre = sun_warp_centre(h, bottom, top, seg, cos_phi);
    let deg = sun_unwarp(above.to_degrees(), warp_strength(h, thickness), centre)
        .clamp(SUN_MIN_DEG, sun_node_deg(N_SUN - 1));
    let ss_q = Stencil::new(sun_coord(deg), 0, N_SUN - 1, sun_node_deg, deg);
    print(
        "altitude_coord_sun_node_deg_sun_coord",
        &[ya, deg, sun_coord(deg)],
    );
    stencil("altitude_stencil", &sa);
    stencil("sun_stencil", &ss_q);
    let d = ray_length(r, mu, bottom, top, seg == 2);
    print("ray_length", &[d]);

    let eps = 90.0 - theta.to_degrees();
    let n_c = bundle.wavelengths_nm.len();
    let mut parts = [vec![0.0; n_c], vec![0.0; n_c]];
    for (part, out) in parts.iter_mut().enumerate() {
        let tex = if part == 0 {
            &bundle.rayleigh
        } else {
            &bundle.mie
        };
        let mut by_alt = vec![[0.0f64; 4]; n_c];
        for ka in 0..sa.len {
            let k = sa.first + ka;
            let h_n = altitude_node_m(k, thickness);
            // The node's columns (from the query's coordinate to the node's own map).
            let col_n = skybake_lut::skyview::node_column(phi, col, h, k, thickness);
            let sc = skybake_lut::skyview::column_stencil(col_n, 4);
            print(&format!("p{part}_k{k}_column"), &[col_n]);
            stencil(&format!("p{part}_k{k}_azimuth_stencil"), &sc);
            // On the limb rows, the node read at the query's sun coordinate formed with the
            // node's tangent-point weight (limb_node_shift), without the sun nodes read too deep.
            let (ss, s_k) = if seg == 1 {
                let shift_k = limb_node_shift(r, theta, cos_phi, bottom, h_n);
                let s_k = (mu_s.clamp(-1.0, 1.0).asin() + shift_k).to_degrees();
                let deg_k = sun_unwarp(s_k, warp_strength(h, thickness), centre)
                    .clamp(SUN_MIN_DEG, sun_node_deg(N_SUN - 1));
                let ss_k = Stencil::new(sun_coord(deg_k), 0, N_SUN - 1, sun_node_deg, deg_k);
                (
                    limb_sun_stencil(ss_k, limb_y, s_k, h, h_n, thickness, deg_k, 4),
                    s_k,
                )
            } else {
                (ss_q, s_deg)
            };
            print(&format!("p{part}_k{k}_sun_coordinate"), &[s_k]);
            stencil(&format!("p{part}_k{k}_sun_stencil"), &ss);
            let mut by_sun = vec![[0.0f64; 4]; n_c];
            for js in 0..ss.len {
                let j = ss.first + js;
                let zs = k * N_SUN + j;
                let s_n = sun_warp(sun_node_deg(j), warp_strength(h_n, thickness), 0.0);
                let focus_n = sky_row_focus(s_n, h_n);
                let band = seg < 2
                    && !(band_map_weight(s_deg, h) < 1e-6 && band_map_weight(s_n, h_n) < 1e-6);
                let tag = format!("p{part}_k{k}_j{j}");
                print(&format!("{tag}_hn_sn_band"), &[h_n, s_n, band as u8 as f64]);
                let scale = bundle.scale.texel(j, k, 0);
                // Per column m, the rows' stencil (the band's or the slice's limb rows).
                let rows: [Stencil; 4] = if band {
                    let e_n = band_slice_elevation(eps, s_deg, h, s_n, h_n, cos_phi);
                    print(&format!("{tag}_en"), &[e_n]);
                    std::array::from_fn(|m| {
                        let a = skybake_lut::skyview::column_texel(sc.first + m);
                        let e = band_relative_elevation(e_n, s_n, h_n, cos_phi, {
                            let [l0, l1] = skybake_lut::skyview::AZIMUTH_NODE_READ_M;
                            let t = ((h - l0) / (l1 - l0)).clamp(0.0, 1.0);
                            let lambda = t * t * (3.0 - 2.0 * t);
                            let q = skybake_lut::skyview::azimuth_node(a, h).cos();
                            if lambda > 0.0 {
                                (1.0 - lambda) * q
                                    + lambda * skybake_lut::skyview::azimuth_node(a, h_n).cos()
                            } else {
                                q
                            }
                        });
                        let (sg, y) = band_row(e, h, bottom, focus_n, [s_deg, s_n, h_n]);
                        let (lo, hi) = segment_rows(sg);
                        Stencil::new(y, lo, hi, |i| i as f64, y)
                    })
                } else {
                    let sv_n = if seg == 1 {
                        let y_n = limb_slice_depth(limb_y, s_k, h, s_n, h_n);
                        let y = N_VIEW_SKY as f64
                            + limb_row_focused(y_n, s_n, h_n) * (N_VIEW_LIMB - 1) as f64;
                        print(&format!("{tag}_yn_row"), &[y_n, y]);
                        Stencil::new(y, lo, hi, |i| i as f64, y)
                    } else {
                        sv
                    };
                    [sv_n; 4]
                };
                for (m, st) in rows.iter().enumerate().take(sc.len) {
                    stencil(&format!("{tag}_col{m}_rows"), st);
                }
                let mut value = vec![0.0; n_c];
                for (c, vc) in value.iter_mut().enumerate() {
                    let texel = |m: usize, y: usize| {
                        tex.texel(skybake_lut::skyview::column_texel(sc.first + m), y, zs)[c] as f64
                    };
                    if band {
                        // Over the rows within each column, then over the columns (fetch_band).
                        let mut v = [0.0; 4];
                        for (m, vm) in v.iter_mut().enumerate().take(sc.len) {
                            let st = &rows[m];
                            let w: [f64; 4] = std::array::from_fn(|n| {
                                if n < st.len {
                                    texel(m, st.first + n)
                                } else {
                                    0.0
                                }
                            });
                            *vm = st.mix(&w);
                        }
                        *vc = sc.mix(&v);
                    } else {
                        // Over the columns within each row, then over the rows (fetch).
                        let st = &rows[0];
                        let v: [f64; 4] = std::array::from_fn(|n| {
                            if n < st.len {
                                let w: [f64; 4] = std::array::from_fn(|m| {
                                    if m < sc.len {
                                        texel(m, st.first + n)
                                    } else {
                                        0.0
                                    }
                                });
                                sc.mix(&w)
                            } else {
                                0.0
                            }
                        });
                        *vc = st.mix(&v);
                    }
                }
                print(&format!("{tag}_value"), &value);
                let sl: Vec<f64> = (0..n_c).map(|c| scale[part * n_c + c] as f64).collect();
                print(&format!("{tag}_scale"), &sl);
                for c in 0..n_c {
                    by_sun[c][js] = value[c] * sl[c];
                }
            }
            let v: Vec<f64> = (0..n_c).map(|c| ss.mix(&by_sun[c])).collect();
            print(&format!("p{part}_k{k}_by_sun"), &v);
            for c in 0..n_c {
                by_alt[c][ka] = v[c];
            }
        }
        for c in 0..n_c {
            out[c] = sa.mix(&by_alt[c]) * d;
        }
        print(&format!("p{part}_total"), out);
    }
    let reader = SkyViewReader::new(&bundle);
    let (l, _) = reader.sky_radiance(camera, view, sun);
    let (s, m) = reader.scattering(r, mu, mu_s, nu);
    print("reader_rayleigh", &s);
    print("reader_mie", &m);
    print("reader_radiance", &l);
    let same = s.iter().zip(&parts[0]).all(|(a, b)| a == b)
        && m.iter().zip(&parts[1]).all(|(a, b)| a == b);
    if !same {
        eprintln!("the trace does not reproduce SkyViewReader::scattering");
        std::process::exit(1);
    }
}
