//! Tangent orientation field (v1, v2 = n × v1) over the surface (Ying et al. 2001, §3
//! "Surface orientation" and footnote 2).
//!
//! SKELETON: the public API below is fixed; the optimisation is being implemented.
//! Until then `compute` projects the hint axis (or the domain's u direction) on the
//! tangent plane.

use glam::DVec3;
use subdiv::{DomainId, Surface};

/// How the field is chosen.
#[derive(Clone, Debug, PartialEq)]
pub enum Orientation {
    /// The smoothest field (singularities only where topology forces them).
    Auto,
    /// Closest to a world axis projected on the tangent planes, then smoothed.
    Axis(DVec3),
    /// Constraints from a file (see docs/field.md).
    Constraints(std::path::PathBuf),
}

/// An orthonormal tangent frame: v1, v2 tangent, n the unit normal, v2 = n × v1.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Frame {
    pub v1: DVec3,
    pub v2: DVec3,
    pub n: DVec3,
}

/// A tangent field, defined at every (domain, u, v).
#[derive(Clone, Debug)]
pub struct OrientationField {
    hint: Option<DVec3>,
}

impl OrientationField {
    /// Computes the field for `surface`.
    pub fn compute(surface: &Surface, orientation: &Orientation) -> anyhow::Result<Self> {
        let _ = surface;
        let hint = match orientation {
            Orientation::Axis(a) => Some(*a),
            _ => None,
        };
        Ok(Self { hint })
    }

    /// The frame at a domain point.
    pub fn frame(&self, surface: &Surface, d: DomainId, u: f64, v: f64) -> Frame {
        let e = surface.eval(d, u, v);
        let mut dir = self.hint.unwrap_or(e.du);
        dir -= e.n * e.n.dot(dir);
        if dir.length_squared() < 1e-20 {
            dir = e.du - e.n * e.n.dot(e.du);
        }
        let v1 = dir.normalize_or_zero();
        Frame { v1, v2: e.n.cross(v1), n: e.n }
    }
}
