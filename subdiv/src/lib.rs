//! Catmull-Clark subdivision surfaces for surfsynth.
//!
//! Data flows one way:
//! [`mesh`] (OBJ → validated polygon mesh with half-edge [`topology`]) →
//! [`refine`] (one Catmull-Clark step, EDGE_AND_CORNER boundaries) →
//! [`surface`] (the level-1 *base quads*, an exact [`patch`] tree per base quad, [`limit`]
//! masks at extraordinary points) → [`domains`] (Ptex face domains on top of base quads) →
//! [`charts`] (characteristic-map vertex charts Φ, DΦ, Φ⁻¹ of Ying et al. 2001, §4.2).
//!
//! This crate knows nothing about textures.

pub mod adjacency;
pub mod charts;
pub mod crease;
mod deep;
pub mod domains;
pub mod error;
pub mod ids;
pub mod levels;
pub mod limit;
pub mod mesh;
pub mod nonmanifold;
pub mod patch;
mod pool;
pub mod refine;
mod submesh;
pub mod surface;
#[cfg(test)]
mod test_data;
pub mod topology;

pub use adjacency::BaseLocation;
pub use charts::{ChartHint, ChartPoint, Charts, VertexChart};
pub use crease::{Rule, Sharpness};
pub use domains::{Domain, DomainLocation};
pub use error::{MeshError, MeshProblem, TagProblem};
pub use ids::{BaseQuadId, DomainId, FaceId, VertexId};
pub use levels::LimitMesh;
pub use mesh::{ControlMesh, IgnoredTag, NonManifold};
pub use surface::{LimitSample, Surface};
