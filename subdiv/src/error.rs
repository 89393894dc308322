//! Errors for reading and validating control meshes. Every message names the file (when
//! there is one) and the first offending element, on one line.

use std::path::PathBuf;

/// What is wrong with a control mesh.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum MeshProblem {
    #[error("cannot read file: {0}")]
    Unreadable(String),
    #[error("not a valid OBJ file: {0}")]
    Parse(String),
    #[error("mesh has zero faces")]
    NoFaces,
    #[error("face {face} has {count} vertices; at least 3 are required")]
    TooFewVertices { face: usize, count: usize },
    #[error("face {face} refers to vertex {vertex}, but the mesh has only {count} vertices")]
    IndexOutOfRange {
        face: usize,
        vertex: usize,
        count: usize,
    },
    #[error("face {face} repeats vertex {vertex}")]
    RepeatedVertex { face: usize, vertex: usize },
    #[error("vertex {vertex} has a non-finite coordinate")]
    NonFiniteCoordinate { vertex: usize },
    #[error("non-manifold edge ({a}, {b}): shared by 3 or more faces (face {face} is the third)")]
    NonManifoldEdge { a: usize, b: usize, face: usize },
    #[error(
        "inconsistent face orientation: faces {face_a} and {face_b} both traverse edge ({a}, {b}) in the same direction"
    )]
    InconsistentOrientation {
        a: usize,
        b: usize,
        face_a: usize,
        face_b: usize,
    },
    #[error("non-manifold vertex {vertex}: its faces form {fans} separate fans")]
    NonManifoldVertex { vertex: usize, fans: usize },
    #[error("vertex {vertex} has valence {valence}; at most {max} is supported")]
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
