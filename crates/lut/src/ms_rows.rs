//! The multiple-scattering part of a view row's texels from the rows around it.
//!
//! The `skyview` rows of one altitude node are rays from one point at view zenith angles the
//! rows' maps place so that the stored radiance per metre of ray varies smoothly from row to
//! row (the reader interpolates it linearly over the row coordinate). The multiple scattering
//! along those rays varies more slowly still (its source is the precise table's J, smooth in
//! the view direction: Bruneton & Neyret 2008, §4). So in each segment of rows (sky, limb,
//! ground) the multiple scattering per metre of ray is computed on every other row and the
//! last ([`computed`]), and on the others interpolated by the Lagrange cubic in ln over the row
//! coordinate through the 4 nearest computed rows, as [`crate::ms_columns`] does over φ and
//! the sun's elevation; it is computed after all where the neighbours say the interpolation
//! may be off (the same roughness test, [`TOLERANCE`]), where a neighbour row has no value for
//! that sun (the sun's own ray there: the focused sky and limb rows in twilight), or where a
//! value is not positive. Only the suns a row would compute itself are taken from the rows
//! around (every other sun node and column, [`crate::ms_columns`]); the others are then
//! interpolated from them within the row as before.

use crate::ms_columns::{self, Stencil};

/// The largest roughness times the multiple scattering's share of the texel for which a row's
/// value is interpolated from the rows around it.
pub const TOLERANCE: f64 = 0.05;

/// Whether row `i` of the segment of rows `first ..= last` is computed.
pub fn computed(i: usize, first: usize, last: usize) -> bool {
    ms_columns::computed(i - first, last - first + 1)
}

/// The stencils of the rows `first ..= last` over the row coordinate, `None` where computed;
/// their nodes count from `first`.
pub fn stencils(first: usize, last: usize) -> Vec<Option<Stencil>> {
    let coords: Vec<f64> = (first..=last).map(|i| i as f64).collect();
    ms_columns::stencils(&coords)
}

/// The interpolated value at stencil `s` from the computed rows' values `v(node)` (NaN where a
/// row has none), and its roughness (the larger of [`ms_columns::interpolate`]'s two parts, as
/// the columns' test takes it); `None` where a node's value is not positive or missing.
pub fn guess(s: &Stencil, v: impl Fn(usize) -> f64) -> Option<(f64, f64)> {
    let (y, step, curv) = ms_columns::interpolate(s, v)?;
    Some((y, step.max(curv)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_between_are_interpolated_from_the_segments_computed_rows() {
        // A segment of rows 22..=37 (the limb's 16): 9 computed, 7 between.
        let (first, last) = (22, 37);
        let st = stencils(first, last);
        assert_eq!(st.iter().filter(|s| s.is_none()).count(), 9);
        for (c, s) in st.iter().enumerate() {
            assert_eq!(
                s.is_none(),
                computed(first + c, first, last),
                "row {}",
                first + c
            );
        }
        assert!(computed(last, first, last) && !computed(last - 2, first, last));
        // The exponential of a cubic in the row index: exact, rough only by its slope between
        // the two rows around (measured ≤ 0.062).
        let f = |c: usize| {
            let x = c as f64 / 15.0;
            (-2.0 + 0.5 * x - 0.3 * x * x + 0.1 * x * x * x).exp()
        };
        for (c, s) in st.iter().enumerate() {
            let Some(s) = s else { continue };
            let (y, rough) = guess(s, f).expect("positive");
            assert!((y / f(c) - 1.0).abs() < 1e-12, "row {c}");
            assert!(rough < 0.07, "{rough}");
        }
        // A computed row without a value for the sun (its own ray there): no guess.
        let s = st[3].expect("row 25 is between");
        assert!(guess(&s, |c| if c == s.nodes[0] { f64::NAN } else { f(c) }).is_none());
        // A step of a factor 2 between the two rows around: rough beyond the tolerance.
        let (_, rough) = guess(&s, |c| if c > 3 { 0.5 * f(c) } else { f(c) }).expect("positive");
        assert!(rough > 0.5, "{rough}");
    }
}
