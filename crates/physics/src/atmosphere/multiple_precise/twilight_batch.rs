//! The precise table build's twilight cell (the sun-zenith interpolation, Catmull–Rom in ln Â
//! over four nodes, of a cell's two azimuth nodes) in whole AVX2 vectors: a run of 2 n_λ lanes
//! (6 for RGB) compiles to an 8-lane vector loop and a scalar remainder, so every lane ran one
//! at a time. Lane by lane the same IEEE operations and the same order of the sums, so the same
//! values.

use super::twilight_fixed;

/// Lanes of one azimuth node in [`twilight_cell_pair`]: one AVX2 vector of f32.
pub(super) const CELL_LANES: usize = 8;

/// The table build's twilight cell (`family_pass`, 2 n_λ = `n_j` ≤ [`CELL_LANES`]): `tv[i] +=`
/// (1 − `fp`) × azimuth node `jp` + `fp` × node `jp + 1`, each interpolated over sun zenith on the
/// Catmull–Rom `nodes` (weights `wq`, `fs`) from the slice's rows and their logarithms, in that
/// order: the operations of two [`super::twilight_lanes_f32`] calls, the same values, with both
/// nodes' lanes in two whole vectors (a run of `n_j` lanes compiles to scalar code).
#[cfg(test)]
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn twilight_cell_pair(
    slice: &[f32],
    ln_slice: &[f32],
    nodes: [usize; 4],
    n_phi: usize,
    n_j: usize,
    jp: usize,
    wq: [f32; 4],
    fs: f32,
    fp: f32,
    tv: &mut [f32],
) {
    const L: usize = 2 * CELL_LANES;
    let mut v = [[0.0f32; L]; 4];
    let mut ln = [[0.0f32; L]; 4];
    for q in 0..4 {
        for h in 0..2 {
            let x = (nodes[q] * n_phi + jp + h) * n_j;
            v[q][h * CELL_LANES..][..n_j].copy_from_slice(&slice[x..][..n_j]);
            ln[q][h * CELL_LANES..][..n_j].copy_from_slice(&ln_slice[x..][..n_j]);
        }
    }
    let x = twilight_fixed(
        [&v[0], &v[1], &v[2], &v[3]],
        [&ln[0], &ln[1], &ln[2], &ln[3]],
        wq,
        fs,
    );
    let tv = &mut tv[..n_j];
    for (h, we) in [(0, 1.0 - fp), (1, fp)] {
        for (o, x) in tv.iter_mut().zip(&x[h * CELL_LANES..][..n_j]) {
            *o += we * *x;
        }
    }
}

/// [`twilight_cell_pair`] into a zeroed `tv`, then `o[i] += tw[i] tv[i] + tw[n + i] tv[n + i]`
/// (n = `n_j` / 2, the Rayleigh-like and Mie halves): the table build's twilight cell added to
/// its output, `tv` kept in one vector instead of written and read back lane by lane; the same
/// operations on every lane, so the same values. `tw` holds the point's `n_j` weights padded to
/// a whole vector (read as one load: a copy of `n_j` lanes compiled to a `memcpy` whose small
/// stores the vector load then waited on).
#[inline(always)]
#[allow(clippy::too_many_arguments)]
pub(super) fn twilight_cell_pair_add(
    slice: &[f32],
    ln_slice: &[f32],
    nodes: [usize; 4],
    n_phi: usize,
    n_j: usize,
    jp: usize,
    wq: [f32; 4],
    fs: f32,
    fp: f32,
    tw: &[f32; CELL_LANES],
    o: &mut [f32],
) {
    const L: usize = 2 * CELL_LANES;
    let mut v = [[0.0f32; L]; 4];
    let mut ln = [[0.0f32; L]; 4];
    for q in 0..4 {
        for h in 0..2 {
            let x = (nodes[q] * n_phi + jp + h) * n_j;
            load_lanes(&mut v[q][h * CELL_LANES..], slice, x, n_j);
            load_lanes(&mut ln[q][h * CELL_LANES..], ln_slice, x, n_j);
        }
    }
    let x = twilight_fixed(
        [&v[0], &v[1], &v[2], &v[3]],
        [&ln[0], &ln[1], &ln[2], &ln[3]],
        wq,
        fs,
    );
    let mut tv = [0.0f32; CELL_LANES];
    for (h, we) in [(0, 1.0 - fp), (1, fp)] {
        for (o, x) in tv.iter_mut().zip(&x[h * CELL_LANES..][..CELL_LANES]) {
            *o += we * *x;
        }
    }
    let p: [f32; CELL_LANES] = std::array::from_fn(|i| tw[i] * tv[i]);
    let n = n_j / 2;
    for (i, o) in o[..n].iter_mut().enumerate() {
        *o += p[i] + p[n + i];
    }
}

/// The table build's day cell (`family_pass`, `n_j` ≤ [`CELL_LANES`]) added to its output:
/// `o[i] += tw[i] v[i] + tw[n + i] v[n + i]` (n = `n_j` / 2), v the bilinear interpolation with
/// weights `c` of the slice's rows from `x0` (sun-zenith node, azimuth nodes `jp` and `jp + 1`)
/// and `x1` (the next sun-zenith node), in whole vectors instead of lane by lane; the same
/// operations on every lane, so the same values. `tw` padded as for [`twilight_cell_pair_add`].
#[inline(always)]
pub(super) fn day_cell_add(
    slice: &[f32],
    x0: usize,
    x1: usize,
    n_j: usize,
    c: [f32; 4],
    tw: &[f32; CELL_LANES],
    o: &mut [f32],
) {
    let mut s = [[0.0f32; CELL_LANES]; 4];
    for (s, x) in s.iter_mut().zip([x0, x0 + n_j, x1, x1 + n_j]) {
        load_lanes(s, slice, x, n_j);
    }
    let p: [f32; CELL_LANES] = std::array::from_fn(|i| {
        tw[i] * (c[0] * s[0][i] + c[1] * s[1][i] + c[2] * s[2][i] + c[3] * s[3][i])
    });
    let n = n_j / 2;
    for (i, o) in o[..n].iter_mut().enumerate() {
        *o += p[i] + p[n + i];
    }
}

/// `dst[..n]` = `src[x..x + n]` (n ≤ [`CELL_LANES`]): one whole vector where `src` holds
/// [`CELL_LANES`] values from `x` (the lanes from n on then hold the values after, which no lane
/// below n reads), else lane by lane. A run of n lanes copied as such compiles to a call of
/// `memcpy` (7 % of the table build's samples, 16 calls a twilight cell).
#[inline(always)]
fn load_lanes(dst: &mut [f32], src: &[f32], x: usize, n: usize) {
    match src.get(x..x + CELL_LANES) {
        Some(s) => dst[..CELL_LANES].copy_from_slice(s),
        None => dst[..n].copy_from_slice(&src[x..][..n]),
    }
}

#[cfg(test)]
mod tests {
    use super::super::twilight_lanes_f32;
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Random node values spanning many decades, some zero or subnormal (the linear branch).
    fn node_value(rng: &mut rand_pcg::Pcg64) -> f32 {
        match rng.random_range(0..10) {
            0 => 0.0,
            1 => 1e-39,
            _ => 10f32.powf(rng.random_range(-30.0..2.0)),
        }
    }

    /// `tw` padded with zeros to a whole vector, as `family_pass` stores it.
    fn padded(tw: &[f32]) -> [f32; CELL_LANES] {
        let mut p = [0.0; CELL_LANES];
        p[..tw.len()].copy_from_slice(tw);
        p
    }

    /// Bit for bit `family_pass`'s day cell written lane by lane, for every even lane count,
    /// the cells read at the slice's end too (where a whole vector would run past it).
    #[test]
    fn the_day_cell_equals_its_lanes() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(29);
        let n_phi = 6;
        for n_j in (2..=CELL_LANES).step_by(2) {
            let n = 7 * n_phi * n_j;
            let slice: Vec<f32> = (0..n).map(|_| node_value(&mut rng)).collect();
            for k in 0..300 {
                let js = if k % 3 == 0 {
                    5
                } else {
                    rng.random_range(0..6)
                };
                let jp = if k % 3 == 0 {
                    n_phi - 2
                } else {
                    rng.random_range(0..n_phi - 1)
                };
                let (fs, fp) = (rng.random_range(0.0f32..1.0), rng.random_range(0.0f32..1.0));
                let c = [
                    (1.0 - fs) * (1.0 - fp),
                    (1.0 - fs) * fp,
                    fs * (1.0 - fp),
                    fs * fp,
                ];
                let (x0, x1) = ((js * n_phi + jp) * n_j, ((js + 1) * n_phi + jp) * n_j);
                let tw: Vec<f32> = (0..n_j).map(|_| rng.random_range(0.0f32..2.0)).collect();
                let half = n_j / 2;
                let start: Vec<f32> = (0..half).map(|_| rng.random_range(0.0f32..1.0)).collect();
                let mut want = start.clone();
                let v = |q: usize| {
                    c[0] * slice[x0 + q]
                        + c[1] * slice[x0 + n_j + q]
                        + c[2] * slice[x1 + q]
                        + c[3] * slice[x1 + n_j + q]
                };
                for i in 0..half {
                    want[i] += tw[i] * v(i) + tw[half + i] * v(half + i);
                }
                let mut got = start.clone();
                day_cell_add(&slice, x0, x1, n_j, c, &padded(&tw), &mut got);
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&want), bits(&got), "{n_j}");
            }
        }
    }

    /// Bit for bit two [`twilight_lanes_f32`] calls, for every lane count it serves.
    #[test]
    fn the_cell_pair_equals_two_runs_of_lanes() {
        let mut rng = rand_pcg::Pcg64::seed_from_u64(28);
        let n_phi = 6;
        for n_j in 1..=CELL_LANES {
            let n = 7 * n_phi * n_j;
            let slice: Vec<f32> = (0..n).map(|_| node_value(&mut rng)).collect();
            let ln_slice: Vec<f32> = slice
                .iter()
                .map(|&x| if x >= f32::MIN_POSITIVE { x.ln() } else { 0.0 })
                .collect();
            for _ in 0..200 {
                let is = rng.random_range(1..4);
                let nodes = [is - 1, is, is + 1, is + 2];
                let wq = std::array::from_fn(|_| rng.random_range(-0.2f32..1.0));
                let fs = rng.random_range(0.0f32..1.0);
                let fp = rng.random_range(0.0f32..1.0);
                let jp = rng.random_range(0..n_phi - 1);
                let mut want = vec![0.0f32; n_j];
                for (e, we) in [(jp, 1.0 - fp), (jp + 1, fp)] {
                    let row = nodes.map(|b| (b * n_phi + e) * n_j);
                    twilight_lanes_f32(
                        row.map(|x| &slice[x..][..n_j]),
                        row.map(|x| &ln_slice[x..][..n_j]),
                        wq,
                        fs,
                        we,
                        &mut want,
                    );
                }
                let mut got = vec![0.0f32; n_j];
                twilight_cell_pair(
                    &slice, &ln_slice, nodes, n_phi, n_j, jp, wq, fs, fp, &mut got,
                );
                let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                assert_eq!(bits(&want), bits(&got), "{n_j}");
                // Added to an output as `family_pass` adds a twilight cell.
                if n_j % 2 == 0 {
                    let n = n_j / 2;
                    let tw: Vec<f32> = (0..n_j).map(|_| rng.random_range(0.0f32..2.0)).collect();
                    let start: Vec<f32> = (0..n).map(|_| rng.random_range(0.0f32..1.0)).collect();
                    let mut want_o = start.clone();
                    for i in 0..n {
                        want_o[i] += tw[i] * want[i] + tw[n + i] * want[n + i];
                    }
                    let mut got_o = start.clone();
                    twilight_cell_pair_add(
                        &slice,
                        &ln_slice,
                        nodes,
                        n_phi,
                        n_j,
                        jp,
                        wq,
                        fs,
                        fp,
                        &padded(&tw),
                        &mut got_o,
                    );
                    assert_eq!(bits(&want_o), bits(&got_o), "{n_j}");
                }
            }
        }
    }
}
