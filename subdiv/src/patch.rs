//! Regular Catmull-Clark patches: bicubic uniform B-splines over 4x4 control points.
//!
//! A quad whose four corners are regular (see [`PolyMesh::corner_is_regular`]) is exactly a
//! bicubic B-spline patch. On a sharp boundary the missing row or column of control points
//! is a "ghost" extrapolated linearly (P_ghost = 2 P_boundary - P_inner); this reproduces the
//! EDGE_AND_CORNER boundary rules exactly, including corners (one face), which stay fixed.
//! An infinitely sharp edge is a boundary to each side (the limit surface on either side is
//! the one of the mesh cut open along it), so gathering never crosses one
//! ([`PolyMesh::smooth_twin`]) and the same ghosts make the patches along creases.

use crate::ids::FaceId;
use crate::topology::PolyMesh;
use glam::DVec3;

/// 4x4 control points, row-major: `cp[4 * row + col]`; columns run along s, rows along t.
/// The patch's quad has corners at (1,1), (2,1), (2,2), (1,2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BSplinePatch {
    pub cp: [DVec3; 16],
}

/// Position and parametric partial derivatives at a point of a patch.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PatchPoint {
    pub p: DVec3,
    pub ds: DVec3,
    pub dt: DVec3,
}

/// Uniform cubic B-spline basis and derivative at t.
#[inline]
pub fn basis(t: f64) -> ([f64; 4], [f64; 4]) {
    let s = 1.0 - t;
    let t2 = t * t;
    let t3 = t2 * t;
    let b = [
        s * s * s / 6.0,
        (3.0 * t3 - 6.0 * t2 + 4.0) / 6.0,
        (-3.0 * t3 + 3.0 * t2 + 3.0 * t + 1.0) / 6.0,
        t3 / 6.0,
    ];
    let d = [
        -0.5 * s * s,
        1.5 * t2 - 2.0 * t,
        -1.5 * t2 + t + 0.5,
        0.5 * t2,
    ];
    (b, d)
}

impl BSplinePatch {
    /// Evaluates at (s, t) in [0, 1]².
    #[inline]
    pub fn eval(&self, s: f64, t: f64) -> PatchPoint {
        let (bs, ds) = basis(s);
        let (bt, dt) = basis(t);
        self.eval_basis(&bs, &ds, &bt, &dt)
    }

    /// Evaluates with precomputed bases (for grids of points, where bases are separable).
    #[inline]
    pub fn eval_basis(
        &self,
        bs: &[f64; 4],
        ds: &[f64; 4],
        bt: &[f64; 4],
        dt: &[f64; 4],
    ) -> PatchPoint {
        let mut out = PatchPoint::default();
        for r in 0..4 {
            let row = &self.cp[4 * r..4 * r + 4];
            let rb = row[0] * bs[0] + row[1] * bs[1] + row[2] * bs[2] + row[3] * bs[3];
            let rd = row[0] * ds[0] + row[1] * ds[1] + row[2] * ds[2] + row[3] * ds[3];
            out.p += rb * bt[r];
            out.ds += rd * bt[r];
            out.dt += rb * dt[r];
        }
        out
    }

    /// Gathers the patch of quad `q` of an all-quad mesh whose corners are all regular.
    /// Returns `None` if some control point cannot be found or extrapolated.
    pub fn gather(m: &PolyMesh, q: FaceId) -> Option<Self> {
        debug_assert_eq!(m.face_size(q), 4);
        let mut grid: [Option<DVec3>; 16] = [None; 16];
        let at = |x: i32, y: i32| (4 * y + x) as usize;
        // Corner i sits at CORNER[i]; DIR_NEXT[i] is the grid direction toward corner i+1.
        const CORNER: [(i32, i32); 4] = [(1, 1), (2, 1), (2, 2), (1, 2)];
        const DIR_NEXT: [(i32, i32); 4] = [(1, 0), (0, 1), (-1, 0), (0, -1)];
        let h0 = m.face_he(q);
        for i in 0..4usize {
            let h = h0 + i as u32;
            let (cx, cy) = CORNER[i];
            grid[at(cx, cy)] = Some(m.pos(m.origin(h)));
            let (nx, ny) = DIR_NEXT[i];
            let (px, py) = DIR_NEXT[(i + 3) % 4];
            let (px, py) = (-px, -py); // direction toward corner i-1
                                       // A: across edge (i, i+1), opposite corner i-1. B: across edge (i-1, i).
            let a_at = at(cx - px, cy - py);
            let b_at = at(cx - nx, cy - ny);
            let d_at = at(cx - px - nx, cy - py - ny);
            if let Some(t) = m.smooth_twin(h) {
                let ha = m.next(t); // corner i -> A
                grid[a_at] = Some(m.pos(m.dest(ha)));
                if let Some(t2) = m.smooth_twin(ha) {
                    let hb = m.next(t2); // corner i -> B in the opposite face
                    grid[b_at] = Some(m.pos(m.dest(hb)));
                    grid[d_at] = Some(m.pos(m.dest(m.next(hb))));
                }
            }
            if let Some(t) = m.smooth_twin(m.prev(h)) {
                let hb = m.prev(t); // B -> corner i
                grid[b_at] = Some(m.pos(m.origin(hb)));
                if let Some(t3) = m.smooth_twin(hb) {
                    grid[d_at] = Some(m.pos(m.dest(m.next(t3))));
                }
            }
        }
        // Ghost points mirror real points across the boundary: first every missing border
        // point from two *real* points of its row or column, then (corner ghosts only) from
        // the ghosts just made. Extrapolating from fresh ghosts along the boundary would be
        // wrong where the next row or column is real.
        for pass in 0..2 {
            let src = grid;
            let lookup = |g: &[Option<DVec3>; 16], x: i32, y: i32| {
                if pass == 0 {
                    src[at(x, y)]
                } else {
                    g[at(x, y)]
                }
            };
            for y in 0..4i32 {
                for x in 0..4i32 {
                    if grid[at(x, y)].is_some() {
                        continue;
                    }
                    let horiz = match x {
                        0 => lookup(&grid, 1, y).zip(lookup(&grid, 2, y)),
                        3 => lookup(&grid, 2, y).zip(lookup(&grid, 1, y)),
                        _ => None,
                    };
                    let vert = match y {
                        0 => lookup(&grid, x, 1).zip(lookup(&grid, x, 2)),
                        3 => lookup(&grid, x, 2).zip(lookup(&grid, x, 1)),
                        _ => None,
                    };
                    if let Some((near, far)) = horiz.or(vert) {
                        grid[at(x, y)] = Some(2.0 * near - far);
                    }
                }
            }
        }
        let mut cp = [DVec3::ZERO; 16];
        for (c, g) in cp.iter_mut().zip(grid.iter()) {
            *c = (*g)?;
        }
        Some(Self { cp })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basis_partitions_unity_and_derivative_sums_to_zero() {
        for i in 0..=10 {
            let t = i as f64 / 10.0;
            let (b, d) = basis(t);
            assert!((b.iter().sum::<f64>() - 1.0).abs() < 1e-15);
            assert!(d.iter().sum::<f64>().abs() < 1e-15);
        }
    }

    #[test]
    fn linear_control_grid_reproduces_plane() {
        let mut cp = [DVec3::ZERO; 16];
        for r in 0..4 {
            for c in 0..4 {
                cp[4 * r + c] = DVec3::new(c as f64 - 1.0, r as f64 - 1.0, 0.0);
            }
        }
        let p = BSplinePatch { cp }.eval(0.3, 0.7);
        assert!((p.p - DVec3::new(0.3, 0.7, 0.0)).length() < 1e-15);
        assert!((p.ds - DVec3::X).length() < 1e-15);
        assert!((p.dt - DVec3::Y).length() < 1e-15);
    }
}
