//! The control mesh: reading OBJ files and validating them into a [`PolyMesh`].
//!
//! We read OBJ ourselves instead of through `tobj`: tobj renumbers vertices per object/group
//! (by first use), which splits meshes whose groups share vertices and makes it impossible
//! to name the file's own vertex numbers in error messages (see docs/dependencies.md).
//! `v` and `f` lines make the mesh; OpenSubdiv's tag lines as its regression shapes write
//! them, `t crease N/M/0 v0 v1 v2 v3 ... s...` (sharpness of the edges (v0, v1), (v2, v3),
//! ...) and `t corner N/M/0 v ... s...` (vertex sharpness), give creases (0-based vertex
//! indices; one sharpness for all, or one per edge / vertex). Other tags are recorded in
//! [`ControlMesh::ignored_tags`]; `vt`, `vn`, `usemtl`, `mtllib`, `o`, `g`, `s` are ignored.

use crate::crease::Sharpness;
use crate::error::{MeshError, MeshProblem, TagProblem};
use crate::ids::VertexId;
use crate::topology::{Check, PolyMesh};
use glam::DVec3;
use std::path::{Path, PathBuf};

/// A validated control mesh (faces in OBJ order, vertices 0-based in OBJ order), with the
/// crease and corner sharpness of its tags in `mesh`.
#[derive(Clone, Debug)]
pub struct ControlMesh {
    pub mesh: PolyMesh,
    pub path: Option<PathBuf>,
    /// Tag lines that were read but not applied, one entry per tag name.
    pub ignored_tags: Vec<IgnoredTag>,
    /// `v` lines with values after x y z (a weight w, vertex colours r g b) that were read
    /// and ignored: the first such line and how many.
    pub ignored_vertex_values: Option<IgnoredTag>,
    /// Where the input was non-manifold and has been cut apart and made sharp as
    /// OpenSubdiv makes it ([`crate::nonmanifold`]); `None` for manifold input.
    pub non_manifold: Option<NonManifold>,
}

/// The non-manifold places of an input mesh, cut apart ([`crate::nonmanifold`]).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct NonManifold {
    /// Input edges shared by three or more faces.
    pub edges: usize,
    /// Input vertices on such edges or whose faces form several fans.
    pub vertices: usize,
    /// The input vertex of every vertex of [`ControlMesh::mesh`] (the copies are appended
    /// after the input's vertices): tags name input vertices and apply to all their copies.
    pub origin: Vec<u32>,
    /// What OpenSubdiv makes infinitely sharp: vertices and edges (vertex pairs), in the
    /// mesh's own indices. Applied after the tags, which it overrides, as in OpenSubdiv.
    corners: Vec<u32>,
    sharp_edges: Vec<(u32, u32)>,
}

/// A kind of tag line that was not applied (e.g. `interpolateboundary`: boundaries are
/// always EDGE_AND_CORNER here), with where it first occurred and how often.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct IgnoredTag {
    pub name: String,
    /// 1-based line of the first occurrence.
    pub first_line: usize,
    pub lines: usize,
}

impl IgnoredTag {
    /// Why the tag has no effect, in a few words.
    pub fn reason(&self) -> &'static str {
        match self.name.as_str() {
            "interpolateboundary" => "boundaries are always EDGE_AND_CORNER",
            "creasemethod" => "creases always use the uniform method",
            "smoothtriangles" => "triangles always use the Catmull-Clark rules",
            "facevaryinginterpolateboundary" | "facevaryingpropagatecorners" => {
                "no face-varying data is read"
            }
            "hole" => "holes are not supported (the faces are kept)",
            "vertexedit" | "edgeedit" | "faceedit" => "hierarchical edits are not supported",
            _ => "unknown tag",
        }
    }
}

/// One `t crease` / `t corner` line, parsed but not yet checked against the mesh.
#[derive(Clone, Debug)]
enum Tag {
    /// Sharpness per vertex pair.
    Crease(Vec<(i64, i64, Sharpness)>),
    Corner(Vec<(i64, Sharpness)>),
}

impl ControlMesh {
    /// Reads and validates an OBJ file. Errors name the file and the first bad element.
    pub fn load_obj(path: impl AsRef<Path>) -> Result<Self, MeshError> {
        Self::load_obj_limited(path, u64::MAX)
    }

    /// [`Self::load_obj`], reading at most `max_bytes` (the memory guard's share for the
    /// file: pipes and devices have no size to check beforehand, `/dev/zero` never ends).
    /// A NUL byte stops reading at once: OBJ is text, so the file is binary data.
    pub fn load_obj_limited(path: impl AsRef<Path>, max_bytes: u64) -> Result<Self, MeshError> {
        let path = path.as_ref();
        let bytes = read_text(path, max_bytes).map_err(|p| MeshError::new(p).in_file(path))?;
        let text = String::from_utf8_lossy(&bytes);
        let mut m = Self::parse_obj(&text).map_err(|e| e.in_file(path))?;
        m.path = Some(path.to_path_buf());
        for note in m.notes() {
            eprintln!("note: {note}");
        }
        Ok(m)
    }

    /// One line per ignored tag name, naming the file (printed by [`Self::load_obj`]).
    pub fn notes(&self) -> Vec<String> {
        let file = self
            .path
            .as_ref()
            .map(|p| p.display().to_string())
            .unwrap_or_else(|| "<mesh>".into());
        let more = |t: &IgnoredTag| match t.lines {
            1 => String::new(),
            n => format!(", and {} more line{}", n - 1, if n == 2 { "" } else { "s" }),
        };
        let mut notes: Vec<String> = self
            .ignored_tags
            .iter()
            .map(|t| {
                format!(
                    "{file}: line {}: tag '{}' ignored ({}{})",
                    t.first_line,
                    t.name,
                    t.reason(),
                    more(t)
                )
            })
            .collect();
        if let Some(n) = &self.non_manifold {
            let mut what = Vec::new();
            match n.edges {
                0 => {}
                1 => what.push("1 non-manifold edge".to_string()),
                k => what.push(format!("{k} non-manifold edges")),
            }
            match n.vertices {
                0 => {}
                1 => what.push("1 non-manifold vertex".to_string()),
                k => what.push(format!("{k} non-manifold vertices")),
            }
            notes.push(format!(
                "{file}: {} cut apart and made sharp, as OpenSubdiv treats non-manifold input",
                what.join(" and ")
            ));
        }
        if let Some(t) = &self.ignored_vertex_values {
            notes.push(format!(
                "{file}: line {}: vertex values after x y z ({}) ignored{}",
                t.first_line,
                t.name,
                match t.lines {
                    1 => String::new(),
                    n => format!(
                        " (and on {} more line{})",
                        n - 1,
                        if n == 2 { "" } else { "s" }
                    ),
                }
            ));
        }
        notes
    }

    /// Parses OBJ text (see [`Self::load_obj`]).
    pub fn parse_obj(text: &str) -> Result<Self, MeshError> {
        // A UTF-8 byte order mark would otherwise glue onto the first keyword ("\u{feff}v")
        // and silently drop that line.
        let text = text.strip_prefix('\u{feff}').unwrap_or(text);
        let mut positions = Vec::new();
        let mut face_start = vec![0u32];
        let mut face_verts: Vec<u32> = Vec::new();
        let mut tags: Vec<(Option<usize>, Tag)> = Vec::new();
        let mut ignored: Vec<IgnoredTag> = Vec::new();
        let mut extras: Option<IgnoredTag> = None;
        for (lineno, logical) in logical_lines(text) {
            let line = logical.split('#').next().unwrap_or("").trim();
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
                    // Optional values after x y z, as exporters write them: a weight w
                    // (rational curves; meaningless for polygons), colours r g b (MeshLab,
                    // ZBrush), or both. Anything else is not a vertex line we understand.
                    let rest: Vec<&str> = it.collect();
                    if !rest.is_empty() {
                        let what = match rest.len() {
                            1 => "a weight w",
                            3 => "colours r g b",
                            4 => "a weight and colours",
                            n => {
                                return Err(parse_err(
                                    lineno,
                                    format!(
                                        "vertex has {} values; expected x y z, optionally followed by w, r g b or w r g b",
                                        n + 3
                                    ),
                                ))
                            }
                        };
                        if let Some(tok) = rest.iter().find(|t| t.parse::<f64>().is_err()) {
                            return Err(parse_err(lineno, format!("bad vertex value '{tok}'")));
                        }
                        match &mut extras {
                            Some(t) => t.lines += 1,
                            None => {
                                extras = Some(IgnoredTag {
                                    name: what.into(),
                                    first_line: lineno + 1,
                                    lines: 1,
                                })
                            }
                        }
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
                Some("t") => {
                    let toks: Vec<&str> = it.collect();
                    match parse_tag(&toks).map_err(|problem| tag_err(Some(lineno), problem))? {
                        ParsedTag::Applied(t) => tags.push((Some(lineno), t)),
                        ParsedTag::Ignored(name) => {
                            match ignored.iter_mut().find(|t| t.name == name) {
                                Some(t) => t.lines += 1,
                                None => ignored.push(IgnoredTag {
                                    name,
                                    first_line: lineno + 1,
                                    lines: 1,
                                }),
                            }
                        }
                    }
                }
                _ => {}
            }
        }
        let mut m = Self::from_polygons(positions, face_start, face_verts)?;
        apply_tags(&mut m.mesh, &tags, m.non_manifold.as_ref())?;
        m.ignored_tags = ignored;
        m.ignored_vertex_values = extras;
        Ok(m)
    }

    /// Gives edges and vertices sharpness, as `t crease` / `t corner` lines would (vertex
    /// indices 0-based; later entries win). For generators and tests.
    pub fn with_sharpness(
        mut self,
        edges: &[(u32, u32, f32)],
        vertices: &[(u32, f32)],
    ) -> Result<Self, MeshError> {
        let sharp = |s: f32, tag| {
            Sharpness::new(s).ok_or_else(|| TagProblem::BadSharpness {
                tag,
                value: s.to_string(),
            })
        };
        let mut crease = Vec::new();
        for &(a, b, s) in edges {
            let s = sharp(s, "crease").map_err(|p| tag_err(None, p))?;
            crease.push((a as i64, b as i64, s));
        }
        let mut corner = Vec::new();
        for &(v, s) in vertices {
            let s = sharp(s, "corner").map_err(|p| tag_err(None, p))?;
            corner.push((v as i64, s));
        }
        let tags = [(None, Tag::Crease(crease)), (None, Tag::Corner(corner))];
        apply_tags(&mut self.mesh, &tags, self.non_manifold.as_ref())?;
        Ok(self)
    }

    /// Builds a control mesh from positions and polygons (`face_start` has F+1 offsets).
    /// Non-manifold edges and vertices are cut apart and made sharp as OpenSubdiv makes
    /// them ([`crate::nonmanifold`]; [`Self::non_manifold`] says where).
    pub fn from_polygons(
        positions: Vec<DVec3>,
        face_start: Vec<u32>,
        face_verts: Vec<u32>,
    ) -> Result<Self, MeshError> {
        let first = match PolyMesh::new(
            positions.clone(),
            face_start.clone(),
            face_verts.clone(),
            Check::Strict,
        ) {
            Ok(mesh) => {
                return Ok(Self {
                    mesh,
                    path: None,
                    ignored_tags: Vec::new(),
                    ignored_vertex_values: None,
                    non_manifold: None,
                })
            }
            Err(e) => e,
        };
        if !matches!(
            first.problem,
            MeshProblem::NonManifoldEdge { .. } | MeshProblem::NonManifoldVertex { .. }
        ) {
            return Err(first);
        }
        let Some(split) = crate::nonmanifold::split(&positions, &face_start, &face_verts) else {
            return Err(first);
        };
        // What the cut cannot make manifold (fins that still meet, faces flipped against
        // each other) is reported as the input's own problem.
        let mut mesh = PolyMesh::new(
            split.positions.clone(),
            face_start,
            split.face_verts.clone(),
            Check::Strict,
        )
        .map_err(|_| first)?;
        let nm = NonManifold {
            edges: split.edges,
            vertices: split.vertices,
            origin: split.origin,
            corners: split.corners,
            sharp_edges: split.sharp_edges,
        };
        sharpen_non_manifold(&mut mesh, &nm);
        Ok(Self {
            mesh,
            path: None,
            ignored_tags: Vec::new(),
            ignored_vertex_values: None,
            non_manifold: Some(nm),
        })
    }

    /// [`Self::from_faces`] for meshes built by the library itself (chart nets), valid by
    /// construction: without the input checks, in particular without the cap on vertex
    /// valence ([`crate::topology::MAX_VALENCE`]), which input meshes obey but whose
    /// n-gon face points (valence n after one refinement) do not.
    pub(crate) fn from_faces_trusted(positions: Vec<DVec3>, faces: &[&[u32]]) -> Self {
        let mut fs = vec![0u32];
        let mut fv = Vec::new();
        for f in faces {
            fv.extend_from_slice(f);
            fs.push(fv.len() as u32);
        }
        let mesh = PolyMesh::new(positions, fs, fv, Check::Trusted)
            .expect("trusted construction does not fail");
        Self {
            mesh,
            path: None,
            ignored_tags: Vec::new(),
            ignored_vertex_values: None,
            non_manifold: None,
        }
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

    /// The mesh refined once (Catmull-Clark with its creases, whose sharpness drops by one):
    /// the same limit surface, with four times the quads. Tags carry over, as OpenSubdiv's
    /// refined levels do.
    pub fn refined(&self) -> ControlMesh {
        ControlMesh {
            mesh: crate::refine::refine(&self.mesh),
            path: self.path.clone(),
            ignored_tags: self.ignored_tags.clone(),
            ignored_vertex_values: self.ignored_vertex_values.clone(),
            // Refinement renumbers vertices; the sharpness is in the refined mesh.
            non_manifold: None,
        }
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

/// Reads a text file of at most `max_bytes`, refusing binary data (a NUL byte) as soon as
/// it is seen.
fn read_text(path: &Path, max_bytes: u64) -> Result<Vec<u8>, MeshProblem> {
    use std::io::Read;
    let unreadable = |e: std::io::Error| MeshProblem::Unreadable(e.to_string());
    let mut f = std::fs::File::open(path).map_err(unreadable)?;
    let meta = f.metadata().map_err(unreadable)?;
    if meta.is_dir() {
        return Err(MeshProblem::Unreadable(
            std::io::Error::from_raw_os_error(21).to_string(), // EISDIR, as read(2) says
        ));
    }
    let mut bytes = Vec::with_capacity(if meta.is_file() {
        meta.len().min(max_bytes).min(1 << 30) as usize
    } else {
        0
    });
    let mut chunk = vec![0u8; 1 << 16];
    loop {
        let k = match f.read(&mut chunk) {
            Ok(0) => break,
            Ok(k) => k,
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => continue,
            Err(e) => return Err(unreadable(e)),
        };
        if let Some(i) = chunk[..k].iter().position(|&b| b == 0) {
            return Err(MeshProblem::Parse(format!(
                "byte {} is NUL: this is binary data, not OBJ text",
                bytes.len() + i + 1
            )));
        }
        if (bytes.len() + k) as u64 > max_bytes {
            return Err(MeshProblem::Unreadable(format!(
                "the file is larger than the {} bytes the memory limit leaves for reading a mesh (see --max-memory)",
                max_bytes
            )));
        }
        bytes.extend_from_slice(&chunk[..k]);
    }
    Ok(bytes)
}

/// The logical lines of OBJ text with their 0-based physical line numbers (of the first
/// physical line): lines end at `\n`, `\r\n` or a lone `\r` (classic Mac OS files), and a
/// line ending in a backslash continues on the next one (the OBJ specification's line
/// continuation), except in comments.
fn logical_lines(text: &str) -> impl Iterator<Item = (usize, std::borrow::Cow<'_, str>)> {
    let mut physical = text
        .split('\n')
        .flat_map(|l| l.strip_suffix('\r').unwrap_or(l).split('\r'))
        .enumerate()
        .peekable();
    std::iter::from_fn(move || {
        let (n, first) = physical.next()?;
        // A comment ends at its line, backslash or not (Windows paths in comments).
        if !first.trim_end().ends_with('\\') || first.trim_start().starts_with('#') {
            return Some((n, std::borrow::Cow::Borrowed(first)));
        }
        let mut joined = String::new();
        let mut cur = first;
        loop {
            let t = cur.trim_end();
            match t.strip_suffix('\\') {
                Some(head) => {
                    joined.push_str(head);
                    joined.push(' ');
                    match physical.next() {
                        Some((_, next)) => cur = next,
                        None => break,
                    }
                }
                None => {
                    joined.push_str(cur);
                    break;
                }
            }
        }
        Some((n, std::borrow::Cow::Owned(joined)))
    })
}

fn parse_err(lineno: usize, msg: String) -> MeshError {
    MeshProblem::Parse(format!("line {}: {msg}", lineno + 1)).into()
}

fn tag_err(line: Option<usize>, problem: TagProblem) -> MeshError {
    MeshProblem::Tag { line, problem }.into()
}

enum ParsedTag {
    Applied(Tag),
    /// The tag's name (not applied).
    Ignored(String),
}

/// Parses the tokens after `t`: `NAME nint/nfloat/nstring ints... floats... strings...`,
/// as OpenSubdiv's `shape_utils.cpp` reads them (sharpness as `f32`). Only `crease` and
/// `corner` are checked and kept.
fn parse_tag(toks: &[&str]) -> Result<ParsedTag, TagProblem> {
    let Some(&name) = toks.first() else {
        return Err(TagProblem::NoName);
    };
    let tag: &'static str = match name {
        "crease" => "crease",
        "corner" => "corner",
        other => {
            // Names are quoted in notes: keep them short and printable.
            let clean: String = other
                .chars()
                .take(40)
                .map(|c| if c.is_control() { '\u{fffd}' } else { c })
                .collect();
            return Ok(ParsedTag::Ignored(clean));
        }
    };
    let count = toks.get(1).copied().unwrap_or("");
    let malformed = || TagProblem::MalformedCount {
        tag,
        count: count.chars().take(40).collect(),
    };
    let parts: Vec<&str> = count.split('/').collect();
    if parts.len() != 3 {
        return Err(malformed());
    }
    let mut n = [0usize; 3];
    for (slot, p) in n.iter_mut().zip(&parts) {
        *slot = p.parse().map_err(|_| malformed())?;
    }
    let [ni, nf, ns] = n;
    let values = &toks[2..];
    let declared = ni.saturating_add(nf).saturating_add(ns);
    if values.len() != declared {
        return Err(TagProblem::CountMismatch {
            tag,
            count: count.to_string(),
            declared,
            found: values.len(),
        });
    }
    let bad = |what, token: &str| TagProblem::BadValue {
        tag,
        what,
        token: token.chars().take(40).collect(),
    };
    let ints = values[..ni]
        .iter()
        .map(|t| t.parse::<i64>().map_err(|_| bad("vertex index", t)))
        .collect::<Result<Vec<_>, _>>()?;
    let floats = values[ni..ni + nf]
        .iter()
        .map(|t| {
            let x = t.parse::<f32>().map_err(|_| bad("sharpness", t))?;
            Sharpness::new(x).ok_or_else(|| TagProblem::BadSharpness {
                tag,
                value: t.chars().take(40).collect(),
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    // Strings (the third count) carry nothing for creases and corners.
    let items = if tag == "crease" {
        if ni < 2 || ni % 2 != 0 {
            return Err(TagProblem::CreaseVertexCount(ni));
        }
        ni / 2
    } else {
        if ni == 0 {
            return Err(TagProblem::CornerVertexCount);
        }
        ni
    };
    // One sharpness for all items, or one each. (OpenSubdiv's far_utils reads a crease's
    // j-th pair from floats[2j] when there are several, past the end of a list of one per
    // pair; one per pair is what the format means.)
    if nf != 1 && nf != items {
        return Err(TagProblem::SharpnessCount {
            tag,
            values: nf,
            items,
            item: if tag == "crease" { "edge" } else { "vertex" },
        });
    }
    let s = |i: usize| floats[if nf == 1 { 0 } else { i }];
    Ok(ParsedTag::Applied(if tag == "crease" {
        Tag::Crease(
            (0..items)
                .map(|i| (ints[2 * i], ints[2 * i + 1], s(i)))
                .collect(),
        )
    } else {
        Tag::Corner((0..items).map(|i| (ints[i], s(i))).collect())
    }))
}

/// The sharpness OpenSubdiv gives non-manifold edges and vertices, over what is there.
fn sharpen_non_manifold(mesh: &mut PolyMesh, nm: &NonManifold) {
    let mut edges: Vec<Sharpness> = (0..mesh.num_edges())
        .map(|e| mesh.tagged_edge_sharpness(e))
        .collect();
    let mut verts: Vec<Sharpness> = (0..mesh.num_vertices())
        .map(|v| mesh.tagged_vertex_sharpness(VertexId::from_idx(v)))
        .collect();
    for &(a, b) in &nm.sharp_edges {
        if let Some(h) = mesh.find_edge(VertexId(a), VertexId(b)) {
            edges[mesh.edge_of(h)] = Sharpness::INFINITE;
        }
    }
    for &v in &nm.corners {
        verts[v as usize] = Sharpness::INFINITE;
    }
    mesh.set_sharpness(edges, verts);
}

/// Checks tags against the mesh and stores their sharpness in it (in file order: a later
/// tag on the same edge or vertex wins, as in OpenSubdiv). Tags name input vertices: on a
/// mesh cut apart at non-manifold places (`nm`) they apply to every copy, and the
/// non-manifold sharpness is applied again afterwards (OpenSubdiv sharpens after tags).
fn apply_tags(
    mesh: &mut PolyMesh,
    tags: &[(Option<usize>, Tag)],
    nm: Option<&NonManifold>,
) -> Result<(), MeshError> {
    if tags.iter().all(|(_, t)| match t {
        Tag::Crease(v) => v.is_empty(),
        Tag::Corner(v) => v.is_empty(),
    }) {
        return Ok(());
    }
    // Copies of each input vertex (itself first).
    let mut copies: Vec<Vec<u32>> = Vec::new();
    if let Some(nm) = nm {
        let inputs = nm
            .origin
            .iter()
            .enumerate()
            .take_while(|&(i, &o)| i as u32 == o)
            .count();
        copies = (0..inputs as u32).map(|v| vec![v]).collect();
        for (c, &o) in nm.origin.iter().enumerate().skip(inputs) {
            copies[o as usize].push(c as u32);
        }
    }
    let copies_of = |v: VertexId| -> Vec<VertexId> {
        match copies.get(v.idx()) {
            Some(c) => c.iter().map(|&i| VertexId(i)).collect(),
            None => vec![v],
        }
    };
    let nv = if nm.is_some() {
        copies.len()
    } else {
        mesh.num_vertices()
    };
    let vertex = |line: Option<usize>, tag: &'static str, i: i64| {
        if i < 0 || i as u64 >= nv as u64 {
            Err(tag_err(
                line,
                TagProblem::VertexOutOfRange {
                    tag,
                    index: i,
                    count: nv,
                },
            ))
        } else {
            Ok(VertexId(i as u32))
        }
    };
    let mut edges: Vec<Sharpness> = (0..mesh.num_edges())
        .map(|e| mesh.tagged_edge_sharpness(e))
        .collect();
    let mut verts: Vec<Sharpness> = (0..nv)
        .map(|v| mesh.tagged_vertex_sharpness(VertexId::from_idx(v)))
        .collect();
    for (line, tag) in tags {
        match tag {
            Tag::Crease(pairs) => {
                for &(a, b, s) in pairs {
                    let (va, vb) = (vertex(*line, "crease", a)?, vertex(*line, "crease", b)?);
                    let mut found = false;
                    for &ca in &copies_of(va) {
                        for &cb in &copies_of(vb) {
                            if let Some(h) = mesh.find_edge(ca, cb) {
                                edges[mesh.edge_of(h)] = s;
                                found = true;
                            }
                        }
                    }
                    if !found {
                        return Err(tag_err(*line, TagProblem::NoEdge { a, b }));
                    }
                }
            }
            Tag::Corner(vs) => {
                for &(v, s) in vs {
                    for c in copies_of(vertex(*line, "corner", v)?) {
                        verts[c.idx()] = s;
                    }
                }
            }
        }
    }
    mesh.set_sharpness(edges, verts);
    if let Some(nm) = nm {
        sharpen_non_manifold(mesh, nm);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::error::TagProblem;

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
    fn line_endings_continuations_and_vertex_extras() {
        let cube = ControlMesh::cuboid(DVec3::ZERO, DVec3::ONE);
        let mut obj = String::new();
        for p in &cube.mesh.positions {
            obj.push_str(&format!("v {} {} {}\n", p.x, p.y, p.z));
        }
        for f in 0..6 {
            let vs = cube.mesh.face_vertices(crate::FaceId::from_idx(f));
            obj.push_str(&format!(
                "f {} {} {} {}\n",
                vs[0] + 1,
                vs[1] + 1,
                vs[2] + 1,
                vs[3] + 1
            ));
        }
        let faces = |t: &str| ControlMesh::parse_obj(t).unwrap().mesh.num_faces();
        assert_eq!(faces(&obj), 6);
        assert_eq!(
            faces(&obj.replace('\n', "\r")),
            6,
            "classic Mac OS line ends"
        );
        assert_eq!(faces(&obj.replace('\n', "\r\n")), 6);
        // A backslash continues a face on the next line; comments do not continue.
        let cont = obj.replacen("f 1 ", "# C:\\models\\\nf 1 \\\n", 1);
        assert_eq!(faces(&cont), 6, "{cont}");
        // Errors after a continuation count physical lines.
        let bad = cont.replacen("v 0 0 0", "v 0 0 x", 1);
        assert!(err(&bad).to_string().contains("line 1: bad coordinate 'x'"));
        // w, r g b and w r g b after x y z are read and reported once; other counts fail.
        let m = ControlMesh::parse_obj(&obj.replace("v 1 1 1", "v 1 1 1 0.5 0.2 0.1")).unwrap();
        let t = m.ignored_vertex_values.unwrap();
        assert_eq!((t.name.as_str(), t.lines), ("colours r g b", 1));
        assert!(ControlMesh::parse_obj(&obj.replace("v 1 1 1", "v 1 1 1 1")).is_ok());
        let e = err(&obj.replace("v 1 1 1", "v 1 1 1 1 2")).to_string();
        assert!(e.contains("line 8: vertex has 5 values"), "{e}");
        let e = err(&obj.replace("v 1 1 1", "v 1 1 1 red")).to_string();
        assert!(e.contains("bad vertex value 'red'"), "{e}");
    }

    #[test]
    fn binary_and_oversized_files_are_refused_while_reading() {
        let d = std::env::temp_dir().join(format!("subdiv-read-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        let p = d.join("m.obj");
        std::fs::write(&p, b"v 0 0 0\n\0\0\0").unwrap();
        let e = ControlMesh::load_obj(&p).unwrap_err().to_string();
        assert!(e.contains("byte 9 is NUL"), "{e}");
        std::fs::write(&p, format!("{QUAD}f 1 2 3 4\n")).unwrap();
        let e = ControlMesh::load_obj_limited(&p, 10)
            .unwrap_err()
            .to_string();
        assert!(e.contains("larger than the 10 bytes"), "{e}");
        assert!(ControlMesh::load_obj_limited(&p, 1000).is_ok());
        if std::path::Path::new("/dev/zero").exists() {
            let e = ControlMesh::load_obj("/dev/zero").unwrap_err().to_string();
            assert!(e.contains("byte 1 is NUL"), "{e}");
        }
        let _ = std::fs::remove_dir_all(&d);
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
        let flipped = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 3 4\n";
        assert!(matches!(
            err(flipped),
            MeshProblem::InconsistentOrientation {
                face_a: 0,
                face_b: 1,
                ..
            }
        ));
        assert!(matches!(err("v 0 0\n"), MeshProblem::Parse(_)));
        assert!(matches!(err("v 0 0 0\nf 1 a 2\n"), MeshProblem::Parse(_)));
    }

    /// Non-manifold input is cut apart and made sharp as OpenSubdiv makes it
    /// (`crate::nonmanifold`; the surface against OpenSubdiv's in
    /// `tests/opensubdiv_creases.rs`), with one note.
    #[test]
    fn non_manifold_input_is_cut_apart_and_noted() {
        // Three triangles on edge 1-2.
        let fan = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n";
        let m = ControlMesh::parse_obj(fan).unwrap();
        let nm = m.non_manifold.as_ref().unwrap();
        assert_eq!((nm.edges, nm.vertices), (1, 2));
        assert_eq!(m.mesh.num_vertices(), 5 + 4);
        assert_eq!(nm.origin[5..], [1, 0, 0, 1]);
        // Every copy of 1 and 2 is a sharp corner (each has boundary edges).
        for v in [0, 1, 5, 6, 7, 8] {
            assert!(m.mesh.tagged_vertex_sharpness(VertexId(v)).is_infinite());
        }
        assert_eq!(
            m.notes(),
            vec!["<mesh>: 1 non-manifold edge and 2 non-manifold vertices cut apart and made sharp, as OpenSubdiv treats non-manifold input"]
        );
        // Two triangles touching only at vertex 1 (a bow tie); a tag on vertex 1 reaches
        // both copies.
        let bowtie = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv -1 0 0\nv -1 -1 0\nf 1 2 3\nf 1 4 5\n\
                      t crease 2/1/0 0 1 2.5\n";
        let m = ControlMesh::parse_obj(bowtie).unwrap();
        let nm = m.non_manifold.as_ref().unwrap();
        assert_eq!((nm.edges, nm.vertices), (0, 1));
        assert_eq!(m.notes(), vec!["<mesh>: 1 non-manifold vertex cut apart and made sharp, as OpenSubdiv treats non-manifold input"]);
        assert_eq!(m.mesh.num_vertices(), 6);
        let h = m.mesh.find_edge(VertexId(0), VertexId(1)).unwrap();
        assert_eq!(
            m.mesh.tagged_edge_sharpness(m.mesh.edge_of(h)),
            Sharpness::new(2.5).unwrap()
        );
        // Three triangles on one edge and one third vertex come apart into three.
        let fins = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 2 1 3\nf 1 2 3\n";
        let m = ControlMesh::parse_obj(fins).unwrap();
        assert_eq!(m.mesh.num_vertices(), 9);
        assert_eq!(m.mesh.num_edges(), 9);
        // Manifold input has no such note.
        assert!(ControlMesh::parse_obj(CUBE).unwrap().non_manifold.is_none());
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
        assert_eq!(m.mesh.pos(VertexId(0)), DVec3::ZERO);
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

    fn edge_sharpness(m: &ControlMesh, a: u32, b: u32) -> f32 {
        let h = m.mesh.find_edge(VertexId(a), VertexId(b)).unwrap();
        m.mesh.tagged_edge_sharpness(m.mesh.edge_of(h)).value()
    }

    #[test]
    fn reads_crease_and_corner_tags_as_opensubdiv_writes_them() {
        let text = format!(
            "{CUBE}t crease 2/1/0 0 1 10.0\nt crease 4/1/0 1 3 3 2 2.5\nt crease 4/2/0 4 5 5 7 0.5 1.4\n\
             t corner 1/1/0 6 3.0\nt interpolateboundary 1/0/0 1\nt interpolateboundary 1/0/0 2\n\
             t creasemethod 0/0/1 chaikin\nt crease 2/1/0 1 0 0.25\n"
        );
        let m = ControlMesh::parse_obj(&text).unwrap();
        // A later tag on the same edge wins (either direction names it).
        assert_eq!(edge_sharpness(&m, 0, 1), 0.25);
        assert_eq!(edge_sharpness(&m, 3, 1), 2.5);
        assert_eq!(edge_sharpness(&m, 2, 3), 2.5);
        assert_eq!(edge_sharpness(&m, 4, 5), 0.5);
        // Sharpness is OpenSubdiv's float.
        assert_eq!(edge_sharpness(&m, 5, 7), 1.4f32);
        assert_eq!(edge_sharpness(&m, 0, 2), 0.0);
        assert_eq!(m.mesh.tagged_vertex_sharpness(VertexId(6)).value(), 3.0);
        assert_eq!(
            m.ignored_tags,
            vec![
                IgnoredTag {
                    name: "interpolateboundary".into(),
                    first_line: 19,
                    lines: 2
                },
                IgnoredTag {
                    name: "creasemethod".into(),
                    first_line: 21,
                    lines: 1
                }
            ]
        );
        let notes = m.notes();
        assert_eq!(notes.len(), 2);
        assert!(
            notes[0].starts_with("<mesh>: line 19: tag 'interpolateboundary' ignored"),
            "{}",
            notes[0]
        );
        // Sharpness 0 everywhere is the untagged mesh.
        let zero = ControlMesh::parse_obj(&format!(
            "{CUBE}t crease 2/1/0 0 1 0\nt corner 1/1/0 3 0.0\n"
        ))
        .unwrap();
        assert!(!zero.mesh.has_tags());
    }

    /// Bad tags: one line naming the line and the problem.
    #[test]
    fn rejects_bad_tags() {
        let bad = |tag: &str| {
            let e = ControlMesh::parse_obj(&format!("{CUBE}{tag}\n")).unwrap_err();
            let s = e.to_string();
            assert!(s.starts_with("<mesh>: line 15: t "), "{tag}: {s}");
            assert!(!s.contains('\n'));
            match e.problem {
                MeshProblem::Tag {
                    line: Some(14),
                    problem,
                } => problem,
                p => panic!("{tag}: {p:?}"),
            }
        };
        assert_eq!(
            bad("t crease 2/1/0 0 8 1.0"),
            TagProblem::VertexOutOfRange {
                tag: "crease",
                index: 8,
                count: 8
            }
        );
        assert!(matches!(
            bad("t corner 1/1/0 -1 1.0"),
            TagProblem::VertexOutOfRange { index: -1, .. }
        ));
        assert_eq!(
            bad("t crease 2/1/0 0 7 1.0"),
            TagProblem::NoEdge { a: 0, b: 7 }
        );
        assert_eq!(
            bad("t crease 2/1/0 3 3 1.0"),
            TagProblem::NoEdge { a: 3, b: 3 }
        );
        assert!(matches!(
            bad("t crease 2/1/0 0 1 -2"),
            TagProblem::BadSharpness { .. }
        ));
        assert!(matches!(
            bad("t corner 1/1/0 0 nan"),
            TagProblem::BadSharpness { .. }
        ));
        assert!(matches!(
            bad("t crease 2/1 0 1 2"),
            TagProblem::MalformedCount { .. }
        ));
        assert!(matches!(
            bad("t crease x/1/0 0 1 2"),
            TagProblem::MalformedCount { .. }
        ));
        assert!(matches!(bad("t crease"), TagProblem::MalformedCount { .. }));
        assert!(matches!(
            bad("t crease 2/1/0 0 1"),
            TagProblem::CountMismatch {
                declared: 3,
                found: 2,
                ..
            }
        ));
        assert!(matches!(
            bad("t crease 2/1/0 0 1 2 3"),
            TagProblem::CountMismatch { .. }
        ));
        assert_eq!(
            bad("t crease 3/1/0 0 1 3 2"),
            TagProblem::CreaseVertexCount(3)
        );
        assert!(matches!(
            bad("t crease 4/3/0 0 1 1 3 2 2 2"),
            TagProblem::SharpnessCount {
                values: 3,
                items: 2,
                ..
            }
        ));
        assert!(matches!(
            bad("t corner 0/1/0 2"),
            TagProblem::CornerVertexCount
        ));
        assert!(matches!(
            bad("t crease 2/1/0 0 1.5 2"),
            TagProblem::BadValue {
                what: "vertex index",
                ..
            }
        ));
        assert!(matches!(
            bad("t corner 1/1/0 0 2x"),
            TagProblem::BadValue {
                what: "sharpness",
                ..
            }
        ));
        // Through a file: the message names it.
        let e = ControlMesh::parse_obj(&format!("{CUBE}t crease 2/1/0 0 7 1.0\n"))
            .unwrap_err()
            .in_file("/m/cube.obj");
        assert_eq!(
            e.to_string(),
            "/m/cube.obj: line 15: t crease: vertices 0 and 7 share no edge (tags count vertices from 0)"
        );
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
