//! [`MsField::inscatter_face`] with the wavelengths side by side.
//!
//! Towards each camera, every surface voxel seen through an empty neighbour reconstructs the
//! inward radiance at the face's 128 quadrature directions ([`MU_NODES`] × [`N_PHI`]), one
//! wavelength after the other: per node and wavelength a chain of (L + 1)² terms L_lm·Y_lm, then
//! the build-up ratio r(μ'). [`MsField::inscatter_face_lanes`] runs up to four wavelengths as
//! the lanes of one `[f64; 4]` per node (each lane the scalar function's operations in its
//! order, a lane's skipped nodes selected away rather than branched over: the same values),
//! without allocating, compiled a second time for AVX2 (`simd_dispatch!`, no fused
//! multiply-adds).

use super::super::{real_sh, MsField};
use super::{
    face_normal, outward_profiles, outward_ratio, phase_weight, profiles, sun_first_scattering,
    FaceQuadrature, SunAtVoxel, MU_NODES, N_PHI, N_SH, OUTWARD_MAX_DEPTH,
};
use glam::DVec3;
use std::f64::consts::PI;

/// Wavelengths side by side.
const LANES: usize = 4;
/// Quadrature directions per face.
const NODES: usize = MU_NODES.len() * N_PHI;

/// What the node loop reads, the wavelengths side by side (a lane per wavelength, unused lanes
/// inactive).
struct FaceLanes {
    /// The interpolated coefficients L_lm, `[(L + 1)²][lane]`.
    coef: [[f64; LANES]; N_SH],
    /// p*_l per order, `[order][lane]`.
    pm: [[f64; LANES]; 5],
    /// Per node: its weight times p*(ω_o·ω') / 4π, and the sun's first scattering towards it
    /// per unit irradiance, `[node][lane]`.
    w_phase: [[f64; LANES]; NODES],
    hg: [[f64; LANES]; NODES],
    /// The build-up profiles per inward cosine, `[μ'][profile][lane]`.
    prof: [[[f64; LANES]; 4]; MU_NODES.len()],
    /// The sun's first scattering per unit scaled optical depth at the face.
    e_face: [f64; LANES],
    /// Lanes whose wavelength runs the node loop.
    active: [bool; LANES],
    /// Per node: its weight times p*(ω_o·ω_out) / 4π for the outward mirror image, and the
    /// sun's first scattering towards ω_out per unit irradiance, `[node][lane]`.
    w_out: [[f64; LANES]; NODES],
    hg_out: [[f64; LANES]; NODES],
    /// The outward profiles per cosine node, `[μ][profile][lane]`.
    prof_out: [[[f64; LANES]; 3]; MU_NODES.len()],
    /// Lanes whose wavelength's voxel is thin enough for the outward profile.
    outward: [bool; LANES],
}

impl MsField {
    /// [`Self::inscatter_face`] with the wavelengths side by side (module text): the same
    /// values, for up to four wavelengths (more: [`Self::inscatter_face`] itself).
    #[allow(clippy::too_many_arguments)]
    pub fn inscatter_face_lanes(
        &self,
        quad: &FaceQuadrature,
        p: DVec3,
        d: DVec3,
        face: usize,
        voxel_density_m: f64,
        k_true: &[f64],
        sun: Option<&SunAtVoxel>,
        out: &mut [f64],
    ) {
        let (n, n_l) = (self.moments, self.n_l);
        let nodes = &quad.faces[face];
        if n_l > LANES
            || n > N_SH
            || nodes.len() != NODES
            || self.phase_moments.iter().any(|pl| pl.len() * pl.len() != n)
        {
            return self.inscatter_face(quad, p, d, face, voxel_density_m, k_true, sun, out);
        }
        let wo = -d;
        let normal = face_normal(face);
        let mv = wo.dot(normal);
        let mut coef = [0.0; LANES * N_SH];
        self.coefficients(p, &mut coef[..n_l * n]);
        let cell_density_m = self.cell_density(p) * self.cell_m[face / 2];
        let mu0 = sun.map_or(0.0, |s| s.travel.dot(-normal));
        let sun = sun.filter(|_| mu0 > 0.05);
        let face_density_m = sun.map_or(0.0, |s| {
            (s.density_m - 0.5 * voxel_density_m / mu0.max(0.05)).max(0.0)
        });
        let mut ylm_o = [0.0; N_SH];
        real_sh(wo, self.angular_order, &mut ylm_o);
        let mut lanes = FaceLanes {
            coef: [[0.0; LANES]; N_SH],
            pm: [[0.0; LANES]; 5],
            w_phase: [[0.0; LANES]; NODES],
            hg: [[0.0; LANES]; NODES],
            prof: [[[0.0; LANES]; 4]; MU_NODES.len()],
            e_face: [0.0; LANES],
            active: [false; LANES],
            w_out: [[0.0; LANES]; NODES],
            hg_out: [[0.0; LANES]; NODES],
            prof_out: [[[0.0; LANES]; 3]; MU_NODES.len()],
            outward: [false; LANES],
        };
        // Per wavelength what does not depend on the node; the profiles and the node shapes
        // computed once for the wavelengths that share them (as the scalar function does).
        let mut prof = [[0.0f64; 4]; 8];
        let mut prof_of: Option<(f64, f64)> = None;
        let mut w_phase = [0.0f64; NODES];
        let mut first = [0.0f64; NODES];
        let mut shape_of: Option<&[f64]> = None;
        let mut out_shape = [(0.0f64, 0.0f64); NODES];
        let mut out_prof = [[0.0f64; 3]; MU_NODES.len()];
        let mut out_of: Option<(&[f64], f64, f64)> = None;
        for l in 0..n_l {
            let pl = &self.phase_moments[l][..];
            for m in 0..n {
                lanes.coef[m][l] = coef[l * n + m];
            }
            for (order, p_l) in pl.iter().enumerate() {
                lanes.pm[order][l] = *p_l;
            }
            let ks = k_true[l] * self.extinction_scale[l];
            let (t_v, t_c) = (ks * voxel_density_m, ks * cell_density_m);
            if mv <= 0.0 || t_v < 1e-4 {
                continue;
            }
            lanes.active[l] = true;
            if prof_of != Some((t_v, t_c)) {
                prof = std::array::from_fn(|i| profiles(MU_NODES[i].0, mv, mu0, t_v, t_c));
                prof_of = Some((t_v, t_c));
            }
            for (mu, pr) in prof.iter().enumerate() {
                for (q, v) in pr.iter().enumerate() {
                    lanes.prof[mu][q][l] = *v;
                }
            }
            if shape_of != Some(pl) {
                // The nodes' p*(ω_o·ω') all at once (the scalar function's operations per
                // node); the sun's first scattering, which depends on neither the voxel nor the
                // view, from the quadrature where it keeps it for this sun and g.
                node_phases(wo, &quad.arrays[face], pl, &mut w_phase);
                let g = pl.get(1).copied().unwrap_or(0.0);
                match sun {
                    Some(s) => match quad.sun_first(face, s.travel, g) {
                        Some(kept) => first.copy_from_slice(kept),
                        None => {
                            for (f, node) in first.iter_mut().zip(nodes) {
                                *f = sun_first_scattering(g, s.travel, node.dir);
                            }
                        }
                    },
                    None => first.fill(0.0),
                }
                shape_of = Some(pl);
            }
            for k in 0..NODES {
                lanes.w_phase[k][l] = w_phase[k];
                lanes.hg[k][l] = first[k];
            }
            lanes.e_face[l] = sun.map_or(0.0, |s| s.irradiance[l] * (-ks * face_density_m).exp());
            if t_v < OUTWARD_MAX_DEPTH {
                lanes.outward[l] = true;
                if out_of != Some((pl, t_v, t_c)) {
                    let g = pl.get(1).copied().unwrap_or(0.0);
                    for (i, r) in out_prof.iter_mut().enumerate() {
                        *r = outward_profiles(MU_NODES[i].0, mv, mu0, g, t_v, t_c);
                    }
                    for (w, node) in out_shape.iter_mut().zip(nodes) {
                        let first =
                            sun.map_or(0.0, |s| sun_first_scattering(g, s.travel, node.out_dir));
                        *w = (phase_weight(node.weight, wo, node.out_dir, pl), first);
                    }
                    out_of = Some((pl, t_v, t_c));
                }
                for (k, &(w, h)) in out_shape.iter().enumerate() {
                    lanes.w_out[k][l] = w;
                    lanes.hg_out[k][l] = h;
                }
                for (i, pr) in out_prof.iter().enumerate() {
                    for (q, &v) in pr.iter().enumerate() {
                        lanes.prof_out[i][q][l] = v;
                    }
                }
            }
        }
        let node_ylm: [&[f64; N_SH]; NODES] = std::array::from_fn(|k| &nodes[k].ylm);
        let node_mu: [usize; NODES] = std::array::from_fn(|k| nodes[k].mu);
        let (j, mut deficit) = face_sums(&lanes, &ylm_o, &node_ylm, &node_mu, self.angular_order);
        if lanes.outward.iter().any(|&o| o) {
            let node_ylm_out: [&[f64; N_SH]; NODES] = std::array::from_fn(|k| &nodes[k].ylm_out);
            let out = outward_sums(&lanes, &node_ylm_out, &node_mu, self.angular_order);
            for l in 0..LANES {
                if lanes.outward[l] {
                    deficit[l] += out[l];
                }
            }
        }
        for (l, o) in out.iter_mut().enumerate().take(n_l) {
            *o = if lanes.active[l] {
                (j[l] - deficit[l]).max(0.0)
            } else {
                j[l].max(0.0)
            };
        }
    }
}

skybake_physics::simd_dispatch! {
    /// Per node of a face, its weight times p*(ω_o·ω')/4π, p*(cos θ) = Σ_l (2l + 1) p*_l
    /// P_l(cos θ) (`pl` the p*_l, at most 5), into `out`: the operations of
    /// [`MsField::inscatter_face`] per node, the nodes side by side (`arrays`: the nodes'
    /// x, y, z and weights).
    fn node_phases(wo: DVec3, arrays: &[Vec<f64>; 4], pl: &[f64], out: &mut [f64; NODES]) {
        let (x, y, z, w) = (
            &arrays[0][..NODES],
            &arrays[1][..NODES],
            &arrays[2][..NODES],
            &arrays[3][..NODES],
        );
        let mut c = [0.0f64; NODES];
        for k in 0..NODES {
            c[k] = (wo.x * x[k]) + (wo.y * y[k]) + (wo.z * z[k]);
        }
        let mut phase = [0.0f64; NODES];
        for (order, p_l) in pl.iter().enumerate() {
            let f = (2 * order + 1) as f64 * p_l;
            match order {
                0 => phase.iter_mut().for_each(|v| *v += f * 1.0),
                1 => {
                    for k in 0..NODES {
                        phase[k] += f * c[k];
                    }
                }
                2 => {
                    for k in 0..NODES {
                        let c = c[k];
                        phase[k] += f * (0.5 * (3.0 * c * c - 1.0));
                    }
                }
                3 => {
                    for k in 0..NODES {
                        let c = c[k];
                        phase[k] += f * (0.5 * c * (5.0 * c * c - 3.0));
                    }
                }
                _ => {
                    for k in 0..NODES {
                        let c = c[k];
                        phase[k] += f * (0.125 * (35.0 * c.powi(4) - 30.0 * c * c + 3.0));
                    }
                }
            }
        }
        for k in 0..NODES {
            out[k] = w[k] * phase[k] / (4.0 * PI);
        }
    }
}

skybake_physics::simd_dispatch! {
    /// The lanes' J* towards the viewer, Σ_l Σ_m p*_l·L_lm·Y_lm(ω_o), and the deficit of the
    /// inward radiance seen through the face, Σ_nodes w_phase·(1 − r)·L (see
    /// [`MsField::inscatter_face`]), each lane's terms in the scalar function's order.
    fn face_sums(
        lanes: &FaceLanes,
        ylm_o: &[f64; N_SH],
        node_ylm: &[&[f64; N_SH]; NODES],
        node_mu: &[usize; NODES],
        order_max: usize,
    ) -> ([f64; LANES], [f64; LANES]) {
        let mut j = [0.0f64; LANES];
        for order in 0..=order_max {
            let p = &lanes.pm[order];
            for m in order * order..(order + 1) * (order + 1) {
                let (c, y) = (&lanes.coef[m], ylm_o[m]);
                for l in 0..LANES {
                    j[l] += p[l] * c[l] * y;
                }
            }
        }
        let mut deficit = [0.0f64; LANES];
        for k in 0..NODES {
            let ylm = node_ylm[k];
            let (mut radiance, mut source) = ([0.0f64; LANES], [0.0f64; LANES]);
            for order in 0..=order_max {
                let p = &lanes.pm[order];
                let mut sum = [0.0f64; LANES];
                for m in order * order..(order + 1) * (order + 1) {
                    let (c, y) = (&lanes.coef[m], ylm[m]);
                    for l in 0..LANES {
                        sum[l] += c[l] * y;
                    }
                }
                for l in 0..LANES {
                    radiance[l] += sum[l];
                    source[l] += p[l] * sum[l];
                }
            }
            let [u_c, u_v, e_c, e_v] = &lanes.prof[node_mu[k]];
            let (w_phase, hg) = (&lanes.w_phase[k], &lanes.hg[k]);
            for l in 0..LANES {
                let source = source[l].max(0.0);
                let first = lanes.e_face[l] * hg[l];
                let den = source * u_c[l] + first * e_c[l];
                let r = ((source * u_v[l] + first * e_v[l]) / den).clamp(0.0, 2.0);
                let term = deficit[l] + w_phase[l] * (1.0 - r) * radiance[l];
                // The scalar function's `radiance <= 0.0` and `den <= 0.0` skips (NaN not skipped).
                let keep = lanes.active[l]
                    && (radiance[l] > 0.0 || radiance[l].is_nan())
                    && (den > 0.0 || den.is_nan());
                deficit[l] = if keep { term } else { deficit[l] };
            }
        }
        (j, deficit)
    }
}

skybake_physics::simd_dispatch! {
    /// The lanes' outward part of the deficit, Σ_nodes w_out·(1 − r)·L(ω_out) (see
    /// `face::outward_deficit`), each lane's terms in the scalar function's order.
    fn outward_sums(
        lanes: &FaceLanes,
        node_ylm: &[&[f64; N_SH]; NODES],
        node_mu: &[usize; NODES],
        order_max: usize,
    ) -> [f64; LANES] {
        let mut deficit = [0.0f64; LANES];
        for k in 0..NODES {
            let ylm = node_ylm[k];
            let mut radiance = [0.0f64; LANES];
            for order in 0..=order_max {
                let mut sum = [0.0f64; LANES];
                for m in order * order..(order + 1) * (order + 1) {
                    let (c, y) = (&lanes.coef[m], ylm[m]);
                    for l in 0..LANES {
                        sum[l] += c[l] * y;
                    }
                }
                for l in 0..LANES {
                    radiance[l] += sum[l];
                }
            }
            let (w, hg, pr) = (&lanes.w_out[k], &lanes.hg_out[k], &lanes.prof_out[node_mu[k]]);
            for l in 0..LANES {
                let first = lanes.e_face[l] * hg[l];
                let r = outward_ratio(radiance[l], first, [pr[0][l], pr[1][l], pr[2][l]]);
                let term = deficit[l] + w[l] * (1.0 - r) * radiance[l];
                // The scalar function's `radiance <= 0.0` skip (NaN not skipped).
                let keep = lanes.outward[l] && (radiance[l] > 0.0 || radiance[l].is_nan());
                deficit[l] = if keep { term } else { deficit[l] };
            }
        }
        deficit
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// The side-by-side reconstruction through a face gives [`MsField::inscatter_face`]'s
    /// values bit for bit: every face, views from all sides (those along the face included),
    /// with and without the sun (a third of the cases with the sun whose first scattering the
    /// quadrature keeps), voxels thin and thick, 1, 3 and 4 wavelengths of different phase
    /// moments and extinctions.
    #[test]
    fn the_side_by_side_face_is_the_field_s() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(11);
        let quad = FaceQuadrature::new(3);
        for n_l in [1, 3, 4] {
            let order = 3;
            let n = (order + 1) * (order + 1);
            let cells = 27;
            let field = MsField {
                dims: [3, 3, 3],
                cell_m: DVec3::new(10.0, 12.0, 9.0),
                origin_m: DVec3::new(-5.0, 2.0, 100.0),
                n_l,
                data: (0..cells * n_l * n)
                    .map(|_| rng.random_range(-0.5f32..3.0))
                    .collect(),
                phase_moments: (0..n_l)
                    .map(|l| {
                        (0..=order)
                            .map(|o| (0.8f64 - 0.1 * (l / 2) as f64).powi(o as i32))
                            .collect()
                    })
                    .collect(),
                extinction_scale: (0..n_l).map(|l| 0.3 + 0.1 * (l % 2) as f64).collect(),
                albedo_scaled: vec![1.0; n_l],
                rho: (0..cells)
                    .map(|c| if c % 3 == 1 { 0.0 } else { 0.2 + c as f32 })
                    .collect(),
                skin: None,
                angular_order: order,
                moments: n,
                once: None,
            };
            let irradiance: Vec<f64> = (0..n_l).map(|l| 1.5 + l as f64).collect();
            let k_true: Vec<f64> = (0..n_l).map(|l| 0.04 + 0.01 * (l / 2) as f64).collect();
            // A third of the cases with the sun the quadrature keeps the first scattering for.
            let kept_travel = DVec3::new(0.3, -0.5, -0.8).normalize();
            let gs: Vec<f64> = field.phase_moments.iter().map(|pl| pl[1]).collect();
            let quad_sun = FaceQuadrature::new(3).with_sun(kept_travel, &gs);
            let (mut a, mut b) = (vec![0.0; n_l], vec![0.0; n_l]);
            let (mut positive, mut clamped, mut cases) = (0, 0, 0);
            for i in 0..1500 {
                let p = field.origin_m
                    + DVec3::new(
                        rng.random_range(-3.0..33.0),
                        rng.random_range(-3.0..39.0),
                        rng.random_range(-3.0..30.0),
                    );
                let d = DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
                .normalize_or(DVec3::Z);
                let face = i % 6;
                let travel = DVec3::new(
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                    rng.random_range(-1.0..1.0),
                )
                .normalize_or(-DVec3::Z);
                let travel = if i % 3 == 0 { kept_travel } else { travel };
                let s = SunAtVoxel {
                    travel,
                    irradiance: &irradiance,
                    density_m: rng.random_range(0.0..300.0),
                };
                let sun = (i % 4 != 0).then_some(&s);
                let voxel_density_m = if i % 5 == 0 {
                    1e-4
                } else {
                    rng.random_range(0.0..80.0)
                };
                field.inscatter_face(&quad, p, d, face, voxel_density_m, &k_true, sun, &mut a);
                field.inscatter_face_lanes(
                    &quad_sun,
                    p,
                    d,
                    face,
                    voxel_density_m,
                    &k_true,
                    sun,
                    &mut b,
                );
                cases += 1;
                for l in 0..n_l {
                    assert_eq!(
                        a[l].to_bits(),
                        b[l].to_bits(),
                        "{p} {d} face {face} λ{l}: {a:?} {b:?}"
                    );
                    if a[l] > 0.0 {
                        positive += 1;
                    } else {
                        clamped += 1;
                    }
                }
            }
            assert!(
                cases == 1500 && positive > 100 && clamped > 10,
                "{positive} {clamped}"
            );
        }
    }
}
