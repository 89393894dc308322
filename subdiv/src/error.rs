//! Errors for reading and validating control meshes. Every message names the file (when
//! there is one) and the first offending element, on one line.

use std::path::PathBuf;

/// What is wrong with a control mesh. Fields are 0-based indices; messages count faces and
/// vertices from 1, as OBJ files do (`f 1 2 3` names vertices 1, 2, 3).
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshProblem {
    #[error("cannot read file: {0}")]
    Unreadable(String),
    #[error("not a valid OBJ file: {0}")]
    Parse(String),
    #[error("mesh has zero faces")]
    NoFaces,
    #[error("face {} has {count} vertices; at least 3 are required", face + 1)]
    TooFewVertices { face: usize, count: usize },
    #[error("face {} refers to vertex {}, but the mesh has only {count} vertices", face + 1, vertex + 1)]
    IndexOutOfRange {
        face: usize,
        vertex: usize,
        count: usize,
    },
    #[error("face {} repeats vertex {}", face + 1, vertex + 1)]
    RepeatedVertex { face: usize, vertex: usize },
    #[error("vertex {} has a non-finite coordinate", vertex + 1)]
    NonFiniteCoordinate { vertex: usize },
    #[error("non-manifold edge ({}, {}): shared by 3 or more faces (face {} is the third)", a + 1, b + 1, face + 1)]
    NonManifoldEdge { a: usize, b: usize, face: usize },
    #[error(
        "inconsistent face orientation: faces {} and {} both traverse edge ({}, {}) in the same direction",
        face_a + 1, face_b + 1, a + 1, b + 1
    )]
    InconsistentOrientation {
        a: usize,
        b: usize,
        face_a: usize,
        face_b: usize,
    },
    #[error("non-manifold vertex {}: its faces form {fans} separate fans", vertex + 1)]
    NonManifoldVertex { vertex: usize, fans: usize },
    #[error("vertex {} has valence {valence}; at most {max} is supported", vertex + 1)]
    ValenceTooHigh {
        vertex: usize,
        valence: usize,
        max: usize,
    },
    /// A bad `t crease` / `t corner` line (`line` is 0-based; `None` for sharpness given
    /// through [`crate::ControlMesh::with_sharpness`]).
    #[error("{}{problem}", line.map(|l| format!("line {}: ", l + 1)).unwrap_or_default())]
    Tag {
        line: Option<usize>,
        problem: TagProblem,
    },
}

/// What is wrong with an OpenSubdiv tag line (`t NAME nint/nfloat/nstring ints floats
/// strings`). Vertex indices in tags count from 0, as OpenSubdiv's shape files do, and are
/// quoted that way.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum TagProblem {
    #[error("tag line without a name")]
    NoName,
    #[error("t {tag}: malformed count '{count}' (expected nint/nfloat/nstring, e.g. 2/1/0)")]
    MalformedCount { tag: &'static str, count: String },
    #[error("t {tag}: the count {count} declares {declared} values but the line has {found}")]
    CountMismatch {
        tag: &'static str,
        count: String,
        declared: usize,
        found: usize,
    },
    #[error("t {tag}: bad {what} '{token}'")]
    BadValue {
        tag: &'static str,
        what: &'static str,
        token: String,
    },
    #[error("t crease: needs vertex pairs, i.e. an even number (at least 2) of vertices, not {0}")]
    CreaseVertexCount(usize),
    #[error("t corner: needs at least one vertex")]
    CornerVertexCount,
    #[error(
        "t {tag}: {values} sharpness values for {items} {item}s (give one for all, or one per {item})"
    )]
    SharpnessCount {
        tag: &'static str,
        values: usize,
        items: usize,
        item: &'static str,
    },
    #[error(
        "t {tag}: vertex index {index} is out of range (tags count vertices from 0; the mesh has {count})"
    )]
    VertexOutOfRange {
        tag: &'static str,
        index: i64,
        count: usize,
    },
    #[error("t crease: vertices {a} and {b} share no edge (tags count vertices from 0)")]
    NoEdge { a: i64, b: i64 },
    #[error("t {tag}: sharpness {value} is negative or NaN")]
    BadSharpness { tag: &'static str, value: String },
}

/// A [`MeshProblem`] with the file it was found in.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{}: {problem}", path.as_ref().map(|p| p.display().to_string()).unwrap_or_else(|| "<mesh>".into()))]
pub struct MeshError {
    pub path: Option<PathBuf>,
    pub problem: MeshProblem,
}

impl MeshError {
    pub fn new(problem: MeshProblem) -> Self {
        Self {
            path: None,
            problem,
        }
    }
    pub fn in_file(mut self, path: impl Into<PathBuf>) -> Self {
        self.path = Some(path.into());
        self
    }
}

impl From<MeshProblem> for MeshError {
    fn from(problem: MeshProblem) -> Self {
        Self::new(problem)
    }
}
