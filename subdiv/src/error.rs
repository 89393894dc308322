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
