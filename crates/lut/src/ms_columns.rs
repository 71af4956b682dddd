//! The multiple-scattering part of a ray's texels on a coarser set of azimuth columns.
//!
//! Along one view ray the texels of a sun node differ only in the sun's azimuth φ. Their
//! single scattering carries the sharp structure (the aureole, the earth's shadow on the ray);
//! the multiple-scattering source varies slowly with φ: the precise table holds it on a few
//! azimuth nodes, linearly interpolated (Bruneton & Neyret 2008, §4, the 4-D table
//! J(r, μ, μs, ν)).
//! So its integral along the ray is computed on every [`STEP`]-th column and the last, and
//! interpolated to the others by the Lagrange polynomial through the 4 nearest computed columns
//! in ln J over φ (exact for the exponential of a cubic in φ; J is even in φ about the sun and
//! the antisun, so near either end it is nearly the exponential of a quadratic). It is not
//! smooth everywhere: aloft in twilight the integral has kinks and steps between columns (a
//! limb texel lit by multiple scattering alone falls 10× between two), likely where the sun of
//! some of the ray's points crosses the table's last sun zenith. So a column is computed after all where its computed neighbours say the
//! interpolation may be off ([`roughness`]: the change of ln J between the two columns around
//! it, or twice the largest second difference of ln J over the 4, times the multiple
//! scattering's share of the texel, above [`TOLERANCE`]), or where a node's value is not
//! positive. Measured on the `skyview` bundle (`earth`, RGB, `standard`, against every column
//! computed): texels within 0.7 %, 99 % of them within 7·10⁻⁴ (the half floats' rounding);
//! without the test 22 % of the interpolated texels are off by more than 2·10⁻³.
//!
//! The same holds along the sun axis at a fixed column (the integral over the sun node
//! coordinate; the precise table interpolates J over sun zenith in ln, Catmull–Rom, in twilight):
//! on a ray with enough sun nodes the integral is computed on every other node as well, and the
//! computed columns' other nodes are interpolated first over the sun coordinate (the test on the
//! curvature alone: the integral's slope in ln is steep in twilight, and smooth), then every
//! node's other columns over φ. Measured on the `skyview` bundle against the columns alone:
//! texels within 0.72 %, 99 % within 8·10⁻⁴.

/// Every `STEP`-th azimuth column (and the last) is computed.
pub const STEP: usize = 2;

/// The largest [`roughness`] times the multiple scattering's share of the texel for which a
/// column is interpolated (measured: 0.05 keeps every texel within 0.7 %; 0.08: 5 %).
pub const TOLERANCE: f64 = 0.05;

/// [`TOLERANCE`] for the interpolation over the sun coordinate (before the one over φ, whose
/// computed columns it fills), applied to the curvature part of the roughness alone
/// ([`interpolate`]): along the sun axis the integral falls steeply but smoothly in
/// twilight, which the cubic in ln follows (measured: every texel within 0.72 %).
pub const SUN_TOLERANCE: f64 = 0.05;

/// Whether column `a` of `n` is computed.
pub fn computed(a: usize, n: usize) -> bool {
    a % STEP == 0 || a + 1 == n
}

/// How an interpolated column is formed from the computed ones: up to 4 computed columns
/// (`nodes[..len]`) and their Lagrange weights over φ, and the two around it (`lo`, `hi`).
#[derive(Debug, Clone, Copy)]
pub struct Stencil {
    pub nodes: [usize; 4],
    pub len: usize,
    pub w: [f64; 4],
    pub lo: usize,
    pub hi: usize,
}

/// The stencils of the columns at azimuths `phis` (increasing): `None` where computed.
pub fn stencils(phis: &[f64]) -> Vec<Option<Stencil>> {
    let n = phis.len();
    let coarse: Vec<usize> = (0..n).filter(|&a| computed(a, n)).collect();
    (0..n)
        .map(|a| {
            if computed(a, n) {
                return None;
            }
            // The computed columns around `a`: coarse[k] < a < coarse[k + 1].
            let k = coarse.iter().rposition(|&c| c < a)?;
            let (lo, hi) = (coarse[k], *coarse.get(k + 1)?);
            // Two on each side where there are, else the 4 nearest at that end.
            let first = k.saturating_sub(1).min(coarse.len().saturating_sub(4));
            let len = (coarse.len() - first).min(4);
            let mut nodes = [0usize; 4];
            nodes[..len].copy_from_slice(&coarse[first..first + len]);
            let x = phis[a];
            let mut w = [0.0f64; 4];
            for i in 0..len {
                let mut p = 1.0;
                for j in 0..len {
                    if j != i {
                        p *= (x - phis[nodes[j]]) / (phis[nodes[i]] - phis[nodes[j]]);
                    }
                }
                w[i] = p;
            }
            Some(Stencil {
                nodes,
                len,
                w,
                lo,
                hi,
            })
        })
        .collect()
}

/// The interpolated value of one wavelength at a stencil from the computed columns' values
/// `v(column)`, and the roughness of those values there in its two parts: |ln(v_hi / v_lo)|
/// between the two columns around it and twice the largest |second difference| of ln v over
/// the stencil's nodes (the column test takes the larger, the sun axis's the second). `None`
/// where a node's value is not positive (the column is then computed).
pub fn interpolate(s: &Stencil, v: impl Fn(usize) -> f64) -> Option<(f64, f64, f64)> {
    let mut l = [0.0f64; 4];
    let (mut ln, mut lo, mut hi) = (0.0, f64::INFINITY, f64::NEG_INFINITY);
    for i in 0..s.len {
        let x = v(s.nodes[i]);
        if !(x > 0.0 && x.is_finite()) {
            return None;
        }
        l[i] = x.ln();
        ln += s.w[i] * l[i];
        lo = lo.min(l[i]);
        hi = hi.max(l[i]);
    }
    // Bounded by the nodes' range (the cubic cannot overshoot across a sharp change).
    let ln = ln.clamp(lo, hi);
    let (step, curv) = roughness(s, &l[..s.len], v(s.lo).ln(), v(s.hi).ln());
    Some((ln.exp(), step, curv))
}

/// See [`interpolate`]: `l` the logarithms at the stencil's nodes, `l_lo`, `l_hi` at the two
/// columns around the interpolated one.
fn roughness(s: &Stencil, l: &[f64], l_lo: f64, l_hi: f64) -> (f64, f64) {
    let mut curvature = 0.0f64;
    for i in 1..s.len.saturating_sub(1) {
        curvature = curvature.max((l[i - 1] - 2.0 * l[i] + l[i + 1]).abs());
    }
    ((l_hi - l_lo).abs(), 2.0 * curvature)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_exponential_of_a_cubic_is_interpolated_exactly() {
        let phis: Vec<f64> = (0..20)
            .map(|a| std::f64::consts::PI * (a as f64 / 19.0).powi(2))
            .collect();
        let f = |x: f64| (0.3 - 0.8 * x + 0.25 * x * x - 0.04 * x * x * x).exp();
        let st = stencils(&phis);
        let st9 = st[9].expect("column 9 is interpolated");
        let st11 = st[11].expect("column 11 is interpolated");
        let mut n = 0;
        for (a, s) in st.iter().enumerate() {
            let Some(s) = s else {
                assert!(computed(a, phis.len()));
                continue;
            };
            n += 1;
            assert_eq!(s.len, 4);
            let (y, _, _) = interpolate(s, |c| f(phis[c])).expect("positive");
            assert!((y / f(phis[a]) - 1.0).abs() < 1e-12, "column {a}");
        }
        assert_eq!(n, 9);
        // Smooth: rough only by its slope between the two columns around (< 0.3 here).
        let (_, step, curv) = interpolate(&st9, |c| f(phis[c])).expect("positive");
        let rough = step.max(curv);
        assert!(rough < 0.3, "{rough}");
        // A step of 10 % between two computed columns beyond the interval: rough.
        let step = |c: usize| if c >= 14 { 0.9 } else { 1.0 };
        let (_, s_part, c_part) = interpolate(&st11, step).expect("positive");
        let rough = s_part.max(c_part);
        assert!(rough > 0.15, "{rough}");
        // A steep but smooth exponential in the sun coordinate: rough by its step, not by its
        // curvature (the sun axis's test), and interpolated to 10⁻¹² all the same.
        let suns: Vec<f64> = (0..12).map(|n| n as f64 * 0.5).collect();
        let st = stencils(&suns);
        let s5 = st[5].expect("node 5 is interpolated");
        let g = |x: f64| (-3.0 * x).exp();
        let (y, step, curv) = interpolate(&s5, |c| g(suns[c])).expect("positive");
        assert!((y / g(suns[5]) - 1.0).abs() < 1e-12);
        assert!(step > 1.0 && curv < 1e-9, "{step} {curv}");
        // A kink in the interval: rough by its curvature too.
        let kink = |c: usize| if c <= 4 { g(suns[c]) } else { g(suns[4]) };
        let (_, _, curv) = interpolate(&s5, kink).expect("positive");
        assert!(curv > 1.0, "{curv}");
        // A node at zero: computed instead.
        let s = st[1].expect("column 1 is interpolated");
        assert!(interpolate(&s, |c| if c == 0 { 0.0 } else { 1.0 }).is_none());
    }
}
