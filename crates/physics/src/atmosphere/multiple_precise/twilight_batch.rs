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
            }
        }
    }
}
