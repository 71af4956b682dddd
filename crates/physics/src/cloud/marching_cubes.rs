//! Isosurface extraction by marching cubes (Lorensen & Cline 1987), as used by the fractal
//! cloud growth of Nishita et al. 1996, §4 ("the isosurface is extracted by the marching-cubes algorithm
//! and triangulated").
//!
//! The lattice is the voxel centres of a [`DensityGrid`]; a corner is *inside* when its density
//! exceeds the iso level. The case table is derived at start-up rather than typed in: on each
//! cube face the edge crossings are joined into segments (entry crossing to exit crossing,
//! walking the face counter-clockwise seen from outside), an ambiguous face separates its two
//! inside corners, and the segments are chained into loops that are fanned into triangles.
//! Because the face rule depends only on that face's corners, neighbouring cubes agree and the
//! surface is closed wherever the grid border is outside. Triangles wind counter-clockwise
//! seen from outside, so their normals point towards lower density.

use super::grid::DensityGrid;
use crate::{Error, Result};
use glam::DVec3;
use rayon::prelude::*;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::OnceLock;

/// A triangle soup, vertices in metres, wound counter-clockwise seen from outside.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriangleMesh {
    /// Triangles as vertex triples.
    pub triangles: Vec<[DVec3; 3]>,
}

impl TriangleMesh {
    /// Total area, m².
    pub fn area_m2(&self) -> f64 {
        self.triangles.iter().map(triangle_area_m2).sum()
    }

    /// Enclosed volume by the divergence theorem, m³ (meaningful for a closed surface).
    pub fn enclosed_volume_m3(&self) -> f64 {
        self.triangles
            .iter()
            .map(|t| t[0].dot(t[1].cross(t[2])) / 6.0)
            .sum()
    }
}

/// Area of a triangle, m².
pub fn triangle_area_m2(t: &[DVec3; 3]) -> f64 {
    0.5 * (t[1] - t[0]).cross(t[2] - t[0]).length()
}

/// Unit outward normal of a triangle (zero for a degenerate one).
pub fn triangle_normal(t: &[DVec3; 3]) -> DVec3 {
    (t[1] - t[0]).cross(t[2] - t[0]).normalize_or_zero()
}

/// Corner `k` of the unit cube sits at `(k & 1, (k >> 1) & 1, (k >> 2) & 1)`.
fn corner_offset(k: usize) -> [usize; 3] {
    [k & 1, (k >> 1) & 1, (k >> 2) & 1]
}

/// The 12 cube edges as (lower corner, upper corner) pairs.
fn edges() -> Vec<(usize, usize)> {
    let mut e = Vec::with_capacity(12);
    for a in 0..8 {
        for bit in [1, 2, 4] {
            if a & bit == 0 {
                e.push((a, a | bit));
            }
        }
    }
    e
}

/// Case table: for each 8-bit inside mask, triangles as triples of edge indices.
struct CaseTable {
    edges: Vec<(usize, usize)>,
    cases: Vec<Vec<[u8; 3]>>,
}

fn case_table() -> &'static CaseTable {
    static TABLE: OnceLock<CaseTable> = OnceLock::new();
    TABLE.get_or_init(build_case_table)
}

fn build_case_table() -> CaseTable {
    let edges = edges();
    let edge_index = |a: usize, b: usize| {
        let (lo, hi) = if a < b { (a, b) } else { (b, a) };
        edges
            .iter()
            .position(|&e| e == (lo, hi))
            .expect("adjacent corners share an edge")
    };
    // Faces as corner cycles, counter-clockwise seen from outside.
    let mut faces = Vec::with_capacity(6);
    for axis in 0..3 {
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        for side in 0..2 {
            let corner = |cu: usize, cv: usize| (side << axis) | (cu << u) | (cv << v);
            let mut cycle = [corner(0, 0), corner(1, 0), corner(1, 1), corner(0, 1)];
            // e_u × e_v = +e_axis for the cyclic (u, v); reverse on the minus side.
            if side == 0 {
                cycle.reverse();
            }
            faces.push(cycle);
        }
    }
    let cases = (0..256usize)
        .map(|mask| {
            let inside = |k: usize| mask & (1 << k) != 0;
            // Segments (start edge, end edge) on every face.
            let mut segments: Vec<(usize, usize)> = Vec::new();
            for cycle in &faces {
                let mut crossings = Vec::with_capacity(4);
                for i in 0..4 {
                    let (a, b) = (cycle[i], cycle[(i + 1) % 4]);
                    if inside(a) != inside(b) {
                        crossings.push((edge_index(a, b), inside(a)));
                    }
                }
                // Pair each entry with the next exit counter-clockwise: this cuts off the
                // inside corner between them (an ambiguous face separates its inside corners).
                let n = crossings.len();
                for i in 0..n {
                    let (e, is_exit) = crossings[i];
                    if !is_exit {
                        segments.push((e, crossings[(i + 1) % n].0));
                    }
                }
            }
            let mut used = vec![false; segments.len()];
            let mut triangles = Vec::new();
            for s0 in 0..segments.len() {
                if used[s0] {
                    continue;
                }
                let mut ring = Vec::new();
                let mut s = s0;
                while !used[s] {
                    used[s] = true;
                    ring.push(segments[s].0);
                    let end = segments[s].1;
                    s = segments
                        .iter()
                        .position(|seg| seg.0 == end)
                        .expect("every exit edge is the entry of another face");
                }
                for i in 1..ring.len() - 1 {
                    triangles.push([ring[0] as u8, ring[i] as u8, ring[i + 1] as u8]);
                }
            }
            triangles
        })
        .collect();
    CaseTable { edges, cases }
}

/// Extracts the `iso` isosurface of `grid` sampled at voxel centres (Nishita et al. 1996, §4). Fails with
/// an error naming `max_triangles` if the surface would need more triangles.
pub fn extract(grid: &DensityGrid, iso: f32, max_triangles: usize) -> Result<TriangleMesh> {
    if !iso.is_finite() {
        return Err(Error::out_of_range("iso_level", iso, "a finite value"));
    }
    let [nx, ny, nz] = grid.dims;
    if nx < 2 || ny < 2 || nz < 2 {
        return Ok(TriangleMesh::default());
    }
    let table = case_table();
    let total = AtomicUsize::new(0);
    let slabs: Vec<Result<Vec<[DVec3; 3]>>> = (0..nz - 1)
        .into_par_iter()
        .map(|z| {
            let mut out = Vec::new();
            let mut values = [0f32; 8];
            let mut points = [DVec3::ZERO; 8];
            for y in 0..ny - 1 {
                for x in 0..nx - 1 {
                    let mut mask = 0usize;
                    for (k, (v, p)) in values.iter_mut().zip(points.iter_mut()).enumerate() {
                        let o = corner_offset(k);
                        *v = grid.at(x + o[0], y + o[1], z + o[2]);
                        *p = grid.voxel_centre(x + o[0], y + o[1], z + o[2]);
                        if *v > iso {
                            mask |= 1 << k;
                        }
                    }
                    let tris = &table.cases[mask];
                    if tris.is_empty() {
                        continue;
                    }
                    let vertex = |e: u8| {
                        let (a, b) = table.edges[e as usize];
                        let (va, vb) = (values[a] as f64, values[b] as f64);
                        let t = ((iso as f64 - va) / (vb - va)).clamp(0.0, 1.0);
                        points[a] + (points[b] - points[a]) * t
                    };
                    for t in tris {
                        out.push([vertex(t[0]), vertex(t[1]), vertex(t[2])]);
                    }
                }
            }
            let so_far = total.fetch_add(out.len(), Ordering::Relaxed) + out.len();
            if so_far > max_triangles {
                return Err(Error::too_large(
                    "max_triangles",
                    format!("the isosurface needs more than {max_triangles} triangles"),
                    max_triangles,
                ));
            }
            Ok(out)
        })
        .collect();
    let mut triangles = Vec::with_capacity(total.load(Ordering::Relaxed).min(max_triangles));
    for slab in slabs {
        triangles.extend(slab?);
    }
    Ok(TriangleMesh { triangles })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn case_table_is_complementary_and_bounded() {
        let table = case_table();
        assert!(table.cases[0].is_empty() && table.cases[255].is_empty());
        // A single inside corner gives one triangle; one loop has at most 12 crossing edges.
        assert_eq!(table.cases[1].len(), 1);
        let most = table.cases.iter().map(Vec::len).max().unwrap();
        assert!(most <= 10, "{most} triangles in one cube");
        for (mask, tris) in table.cases.iter().enumerate() {
            // Complementary cases cut the same edges.
            let mut a: Vec<u8> = tris.iter().flatten().copied().collect();
            let mut b: Vec<u8> = table.cases[255 - mask].iter().flatten().copied().collect();
            a.sort_unstable();
            a.dedup();
            b.sort_unstable();
            b.dedup();
            assert_eq!(a, b, "case {mask}");
            let crossing_edges = table
                .edges
                .iter()
                .filter(|&&(a, b)| (mask >> a & 1) != (mask >> b & 1))
                .count();
            // Every crossing edge is used by at least one triangle.
            let used: std::collections::BTreeSet<u8> = tris.iter().flatten().copied().collect();
            assert_eq!(used.len(), crossing_edges, "case {mask}");
        }
    }

    #[test]
    fn single_corner_triangle_faces_away_from_the_inside_corner() {
        let mut g = DensityGrid::zeros([2, 2, 2], 1.0, DVec3::ZERO).unwrap();
        g.data[0] = 1.0;
        let mesh = extract(&g, 0.5, 100).unwrap();
        assert_eq!(mesh.triangles.len(), 1);
        let n = triangle_normal(&mesh.triangles[0]);
        assert!(n.dot(DVec3::ONE) > 0.0, "normal {n}");
    }
}
