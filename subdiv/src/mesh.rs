//! The control mesh: reading OBJ files and validating them into a [`PolyMesh`].
//!
//! We read OBJ ourselves instead of through `tobj`: tobj renumbers vertices per object/group
//! (by first use), which splits meshes whose groups share vertices and makes it impossible
//! to name the file's own vertex numbers in error messages (see docs/dependencies.md).
//! Only `v` and `f` lines matter; `vt`, `vn`, `usemtl`, `mtllib`, `o`, `g`, `s` and
//! OpenSubdiv's `t` tag lines are ignored.

use crate::error::{MeshError, MeshProblem};
use crate::topology::{Check, PolyMesh};
use glam::DVec3;
use std::path::{Path, PathBuf};

/// A validated control mesh (faces in OBJ order, vertices 0-based in OBJ order).
#[derive(Clone, Debug)]
pub struct ControlMesh {
    pub mesh: PolyMesh,
    pub path: Option<PathBuf>,
}

impl ControlMesh {
    /// Reads and validates an OBJ file. Errors name the file and the first bad element.
    pub fn load_obj(path: impl AsRef<Path>) -> Result<Self, MeshError> {
        let path = path.as_ref();
        let bytes = std::fs::read(path)
            .map_err(|e| MeshError::new(MeshProblem::Unreadable(e.to_string())).in_file(path))?;
        let text = String::from_utf8_lossy(&bytes);
        let mut m = Self::parse_obj(&text).map_err(|e| e.in_file(path))?;
        m.path = Some(path.to_path_buf());
        Ok(m)
    }

    /// Parses OBJ text (see [`Self::load_obj`]).
    pub fn parse_obj(text: &str) -> Result<Self, MeshError> {
        // A UTF-8 byte order mark would otherwise glue onto the first keyword ("\u{feff}v")
        // and silently drop that line.
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut positions = Vec::new();
        let mut face_start = vec![0u32];
        let mut face_verts: Vec<u32> = Vec::new();
        for (lineno, raw) in text.lines().enumerate() {
            let line = raw.split('#').next().unwrap_or("").trim();
            let mut it = line.split_ascii_whitespace();
            match it.next() {
                Some("v") => {
                    let mut c = [0.0f64; 3];
                    for (k, slot) in c.iter_mut().enumerate() {
                        let tok = it.next().ok_or_else(|| {
                            parse_err(lineno, format!("vertex has {k} coordinates, expected 3"))
                        })?;
                        *slot = tok
                            .parse::<f64>()
                            .map_err(|_| parse_err(lineno, format!("bad coordinate '{tok}'")))?;
                    }
                    positions.push(DVec3::from_array(c));
                }
                Some("f") => {
                    let face = face_start.len() - 1;
                    for tok in it {
                        let idx = tok.split('/').next().unwrap_or("");
                        let i: i64 = idx.parse().map_err(|_| {
                            parse_err(lineno, format!("bad vertex reference '{tok}'"))
                        })?;
                        // OBJ indices are 1-based; negative ones count back from the last vertex.
                        let zero_based = if i > 0 {
                            i - 1
                        } else if i < 0 {
                            positions.len() as i64 + i
                        } else {
                            return Err(parse_err(
                                lineno,
                                "vertex index 0 is not valid in OBJ".into(),
                            ));
                        };
                        if zero_based < 0 || zero_based >= u32::MAX as i64 {
                            return Err(parse_err(
                                lineno,
                                format!(
                                    "face {} refers to vertex {i}, which does not exist",
                                    face + 1
                                ),
                            ));
                        }
                        face_verts.push(zero_based as u32);
                    }
                    face_start.push(face_verts.len() as u32);
                }
                _ => {}
            }
        }
        Self::from_polygons(positions, face_start, face_verts)
    }

    /// Builds a control mesh from positions and polygons (`face_start` has F+1 offsets).
    pub fn from_polygons(
        positions: Vec<DVec3>,
        face_start: Vec<u32>,
        face_verts: Vec<u32>,
    ) -> Result<Self, MeshError> {
        let mesh = PolyMesh::new(positions, face_start, face_verts, Check::Strict)?;
        Ok(Self { mesh, path: None })
    }

    /// Convenience for tests and generators: polygons as slices of vertex indices.
    pub fn from_faces(positions: Vec<DVec3>, faces: &[&[u32]]) -> Result<Self, MeshError> {
        let mut fs = vec![0u32];
        let mut fv = Vec::new();
        for f in faces {
            fv.extend_from_slice(f);
            fs.push(fv.len() as u32);
        }
        Self::from_polygons(positions, fs, fv)
    }

    /// A planar n x n grid of unit quads in the z = 0 plane, counter-clockwise seen from +z
    /// (faces row by row from the origin). Handy as a flat test surface: away from its
    /// border the limit surface is exactly the plane with (u, v) affine.
    pub fn grid(n: usize) -> Self {
        let mut pos = Vec::with_capacity((n + 1) * (n + 1));
        for y in 0..=n {
            for x in 0..=n {
                pos.push(DVec3::new(x as f64, y as f64, 0.0));
            }
        }
        let w = (n + 1) as u32;
        let mut fs = vec![0u32];
        let mut fv = Vec::with_capacity(4 * n * n);
        for y in 0..n as u32 {
            for x in 0..n as u32 {
                let i = y * w + x;
                fv.extend([i, i + 1, i + 1 + w, i + w]);
                fs.push(fv.len() as u32);
            }
        }
        Self::from_polygons(pos, fs, fv).expect("a grid is a valid mesh")
    }

    /// An axis-aligned box from `min` to `max`: 8 vertices (vertex i has bit 0, 1, 2 of i
    /// choosing max over min in x, y, z), 6 outward-facing quads. Every vertex has valence
    /// 3, so its limit surface is a rounded box with eight extraordinary corners.
    pub fn cuboid(min: DVec3, max: DVec3) -> Self {
        let pos = (0..8)
            .map(|i| {
                DVec3::new(
                    if i & 1 == 0 { min.x } else { max.x },
                    if i & 2 == 0 { min.y } else { max.y },
                    if i & 4 == 0 { min.z } else { max.z },
                )
            })
            .collect();
        let faces: [&[u32]; 6] = [
            &[0, 2, 3, 1],
            &[4, 5, 7, 6],
            &[0, 1, 5, 4],
            &[2, 6, 7, 3],
            &[0, 4, 6, 2],
            &[1, 3, 7, 5],
        ];
        Self::from_faces(pos, &faces).expect("a box is a valid mesh")
    }

    /// Number of Ptex face domains: 1 per quad, n per n-gon.
    pub fn num_domains(&self) -> usize {
        (0..self.mesh.num_faces())
            .map(|f| ptex_count(self.mesh.face_size(crate::FaceId::from_idx(f))))
            .sum()
    }

    /// Axis-aligned bounding box (min, max) of the control points.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        self.mesh.positions.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        )
    }
}

/// Ptex domains of an n-sided face.
#[inline]
pub fn ptex_count(n: usize) -> usize {
    if n == 4 {
        1
    } else {
        n
    }
}

fn parse_err(lineno: usize, msg: String) -> MeshError {
    MeshProblem::Parse(format!("line {}: {msg}", lineno + 1)).into()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> MeshProblem {
        ControlMesh::parse_obj(text).unwrap_err().problem
    }

    const QUAD: &str = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n";

    /// The box is closed, its faces point outward (each face's normal, by Newell's
    /// formula, points away from the centre) and it spans min..max.
    #[test]
    fn cuboid_is_a_closed_outward_box() {
        let (min, max) = (DVec3::new(-2.0, -1.0, -0.5), DVec3::new(2.0, 1.0, 0.5));
        let m = ControlMesh::cuboid(min, max);
        assert_eq!(m.num_domains(), 6);
        assert_eq!(m.bounds(), (min, max));
        let centre = (min + max) * 0.5;
        for f in 0..m.mesh.num_faces() {
            let vs = m.mesh.face_vertices(crate::FaceId::from_idx(f));
            let p: Vec<DVec3> = vs.iter().map(|&v| m.mesh.positions[v as usize]).collect();
            let n = (0..4).fold(DVec3::ZERO, |a, i| a + p[i].cross(p[(i + 1) % 4]));
            let c = p.iter().sum::<DVec3>() / 4.0;
            assert!(n.dot(c - centre) > 0.0, "face {f} points inward");
        }
        for v in 0..8 {
            assert!(!m.mesh.is_boundary_vertex(crate::VertexId::from_idx(v)));
        }
    }

    #[test]
    fn reads_ngons_groups_and_negative_indices() {
        let m = ControlMesh::parse_obj(
            "# c\nmtllib x.mtl\no a\nv 0 0 0\nv 1 0 0\nv 1 1 0\nvt 0 0\nv 0 1 0\nv 2 0 0\ng b\nusemtl m\ns off\nt interpolateboundary 1/0/0 1\nf 1/1 2/1 3/1 4/1\nf -4 5 3\n",
        )
        .unwrap();
        assert_eq!(m.mesh.num_faces(), 2);
        assert_eq!(m.mesh.face_vertices(crate::FaceId(1)), &[1, 4, 2]);
        assert_eq!(m.num_domains(), 4);
    }

    #[test]
    fn rejects_each_error_class() {
        assert_eq!(err(QUAD), MeshProblem::NoFaces);
        assert!(matches!(
            err(&format!("{QUAD}f 1 2\n")),
            MeshProblem::TooFewVertices { face: 0, count: 2 }
        ));
        assert!(matches!(
            err(&format!("{QUAD}f 1 2 9\n")),
            MeshProblem::IndexOutOfRange {
                face: 0,
                vertex: 8,
                ..
            }
        ));
        assert!(matches!(
            err(&format!("{QUAD}f 1 2 2 3\n")),
            MeshProblem::RepeatedVertex { face: 0, vertex: 1 }
        ));
        assert!(matches!(
            err("v 0 nan 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
            MeshProblem::NonFiniteCoordinate { vertex: 0 }
        ));
        assert!(matches!(
            err("v 0 inf 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"),
            MeshProblem::NonFiniteCoordinate { vertex: 0 }
        ));
        // Three triangles on edge 1-2.
        let fan = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n";
        assert!(matches!(
            err(fan),
            MeshProblem::NonManifoldEdge {
                a: 0,
                b: 1,
                face: 2
            }
        ));
        let flipped = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 3 4\n";
        assert!(matches!(
            err(flipped),
            MeshProblem::InconsistentOrientation {
                face_a: 0,
                face_b: 1,
                ..
            }
        ));
        // Two triangles touching only at vertex 1 (a bow tie).
        let bowtie = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv -1 0 0\nv -1 -1 0\nf 1 2 3\nf 1 4 5\n";
        assert!(matches!(
            err(bowtie),
            MeshProblem::NonManifoldVertex { vertex: 0, fans: 2 }
        ));
        assert!(matches!(err("v 0 0\n"), MeshProblem::Parse(_)));
        assert!(matches!(err("v 0 0 0\nf 1 a 2\n"), MeshProblem::Parse(_)));
    }

    /// A cube (8 vertices, 6 quads) as OBJ text.
    const CUBE: &str = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 0 0 1\nv 1 0 1\nv 0 1 1\nv 1 1 1\n\
                        f 1 3 4 2\nf 5 6 8 7\nf 1 2 6 5\nf 3 7 8 4\nf 1 5 7 3\nf 2 4 8 6\n";

    /// Issue 18: a UTF-8 byte order mark used to glue onto the first `v` and drop that line
    /// ("face 2 refers to vertex 8, but the mesh has only 7 vertices").
    #[test]
    fn byte_order_mark_is_skipped() {
        let m = ControlMesh::parse_obj(&format!("\u{feff}{CUBE}")).unwrap();
        assert_eq!(m.mesh.num_vertices(), 8);
        assert_eq!(m.mesh.pos(crate::VertexId(0)), DVec3::ZERO);
        let dir = std::env::temp_dir().join(format!("surfsynth-bom-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("cube.obj");
        std::fs::write(
            &path,
            [b"\xef\xbb\xbf".as_slice(), CUBE.as_bytes()].concat(),
        )
        .unwrap();
        let m = ControlMesh::load_obj(&path).unwrap();
        assert_eq!(m.mesh.num_faces(), 6);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn error_message_names_file() {
        let e = ControlMesh::load_obj("/nonexistent/dir/m.obj").unwrap_err();
        let s = e.to_string();
        assert!(
            s.starts_with("/nonexistent/dir/m.obj: cannot read file"),
            "{s}"
        );
        assert!(!s.contains('\n'));
    }
}
