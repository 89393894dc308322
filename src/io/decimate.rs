//! Decimation of a displaced tessellation where it is flat: per face domain, a quadtree
//! over the domain's vertex grid keeps a cell whole when the surface inside it is flat
//! within a tolerance, and the cells are triangulated without cracks.
//!
//! - *Flat*: every grid vertex of the cell lies within `tol` of the bilinear patch of the
//!   cell's four corners at its own (u, v), after adding a quarter of the corners' twist
//!   (how far that patch is from the two triangles that replace it). The error is measured
//!   at the same parameter, so the texture, interpolated linearly in (u, v) over the big
//!   triangles, stays on the same surface points to within about `tol`.
//! - *No cracks*: a vertex is kept when it is a corner of any leaf cell, on any domain
//!   (grid vertices on a shared edge are the same surface vertex on both sides). A leaf
//!   becomes the polygon of the kept vertices on its border — its corners plus those its
//!   finer neighbours added — triangulated as two triangles when there are only the four
//!   corners, else as a fan from the cell's centre vertex. Both sides of every edge thus
//!   use the same vertices.

use glam::DVec3;

/// A domain's square vertex grid: `(m+1)²` vertices, vertex (i, j) (i along u, j along v)
/// at `vertex(first + j(m+1) + i)`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DomainGrid {
    pub first: u32,
    /// Segments per side (a power of two).
    pub m: u32,
}

/// A cell of a domain's quadtree: lower-left grid vertex (i, j) and side in segments.
#[derive(Clone, Copy, Debug)]
struct Cell {
    i: u32,
    j: u32,
    s: u32,
}

/// What [`decimate`] returns: the kept grid vertices (indices into the grid numbering,
/// i.e. the input's texture-coordinate numbering) and triangles over them.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Decimated {
    pub vertices: Vec<u32>,
    pub triangles: Vec<[u32; 3]>,
}

/// Decimates the grids. `position(g)` is the position of grid vertex g; `surface_vertex(g)`
/// names the surface point it is (equal on both sides of a shared edge).
pub fn decimate(
    grids: &[DomainGrid],
    position: impl Fn(u32) -> DVec3 + Sync,
    surface_vertex: impl Fn(u32) -> u32 + Sync,
    surface_vertices: usize,
    tol: f64,
) -> Decimated {
    use rayon::prelude::*;
    let at = |g: &DomainGrid, i: u32, j: u32| g.first + j * (g.m + 1) + i;
    let flat = |g: &DomainGrid, c: Cell| -> bool {
        let p = |i, j| position(at(g, i, j));
        let (p00, p10, p11, p01) = (
            p(c.i, c.j),
            p(c.i + c.s, c.j),
            p(c.i + c.s, c.j + c.s),
            p(c.i, c.j + c.s),
        );
        let twist = 0.25 * (p00 + p11 - p10 - p01).length();
        if twist > tol {
            return false;
        }
        let inv = 1.0 / c.s as f64;
        for j in c.j..=c.j + c.s {
            let b = (j - c.j) as f64 * inv;
            for i in c.i..=c.i + c.s {
                let a = (i - c.i) as f64 * inv;
                let q = p00 * ((1.0 - a) * (1.0 - b))
                    + p10 * (a * (1.0 - b))
                    + p11 * (a * b)
                    + p01 * ((1.0 - a) * b);
                if (p(i, j) - q).length() + twist > tol {
                    return false;
                }
            }
        }
        true
    };
    // Leaves per domain, top-down.
    let leaves: Vec<Vec<Cell>> = grids
        .par_iter()
        .map(|g| {
            let mut out = Vec::new();
            let mut stack = vec![Cell { i: 0, j: 0, s: g.m }];
            while let Some(c) = stack.pop() {
                if c.s == 1 || flat(g, c) {
                    out.push(c);
                } else {
                    let h = c.s / 2;
                    for (di, dj) in [(0, 0), (h, 0), (h, h), (0, h)] {
                        stack.push(Cell {
                            i: c.i + di,
                            j: c.j + dj,
                            s: h,
                        });
                    }
                }
            }
            // A fixed order, whatever the stack did.
            out.sort_by_key(|c| (c.j, c.i));
            out
        })
        .collect();
    let mut kept = vec![false; surface_vertices];
    for (g, cells) in grids.iter().zip(&leaves) {
        for c in cells {
            for (i, j) in [
                (c.i, c.j),
                (c.i + c.s, c.j),
                (c.i + c.s, c.j + c.s),
                (c.i, c.j + c.s),
            ] {
                kept[surface_vertex(at(g, i, j)) as usize] = true;
            }
        }
    }
    // Triangulate, numbering output vertices by first use per domain.
    let per_domain: Vec<(Vec<u32>, Vec<[u32; 3]>)> = grids
        .par_iter()
        .zip(&leaves)
        .map(|(g, cells)| {
            let mut used: Vec<u32> = Vec::new();
            let mut tris = Vec::new();
            let mut ring = Vec::new();
            for c in cells {
                ring.clear();
                let (i1, j1) = (c.i + c.s, c.j + c.s);
                // Counter-clockwise in (u, v): bottom, right, top, left; each side without
                // its last vertex.
                for i in c.i..i1 {
                    ring.push((i, c.j));
                }
                for j in c.j..j1 {
                    ring.push((i1, j));
                }
                for i in (c.i + 1..=i1).rev() {
                    ring.push((i, j1));
                }
                for j in (c.j + 1..=j1).rev() {
                    ring.push((c.i, j));
                }
                ring.retain(|&(i, j)| kept[surface_vertex(at(g, i, j)) as usize]);
                let id = |i, j| at(g, i, j);
                if ring.len() == 4 {
                    let q = ring.iter().map(|&(i, j)| id(i, j)).collect::<Vec<_>>();
                    tris.push([q[0], q[1], q[2]]);
                    tris.push([q[0], q[2], q[3]]);
                } else {
                    let centre = id(c.i + c.s / 2, c.j + c.s / 2);
                    for k in 0..ring.len() {
                        let (a, b) = (ring[k], ring[(k + 1) % ring.len()]);
                        tris.push([centre, id(a.0, a.1), id(b.0, b.1)]);
                    }
                }
            }
            for t in &tris {
                used.extend_from_slice(t);
            }
            used.sort_unstable();
            used.dedup();
            (used, tris)
        })
        .collect();
    let mut out = Decimated::default();
    for (used, tris) in per_domain {
        let base = out.vertices.len() as u32;
        out.triangles.extend(
            tris.iter()
                .map(|t| t.map(|v| base + used.binary_search(&v).expect("used vertex") as u32)),
        );
        out.vertices.extend(used);
    }
    out
}
