//! Sharpness and the vertex rules of Catmull-Clark with creases, as OpenSubdiv's
//! `Sdc::Crease` (DeRose, Kass & Truong 1998, with OpenSubdiv's "uniform" creasing method).
//!
//! Every edge and vertex carries a sharpness s ≥ 0: 0 is smooth, s ≥ 10
//! ([`Sharpness::INFINITE`]) is infinitely sharp, anything between is *semi-sharp*: the sharp
//! rules apply for the first ⌊s⌋ refinement levels (the sharpness drops by exactly one per
//! level), the last fraction is a blend, and from then on the smooth rules. Boundary edges
//! and the one-face corners of a boundary are infinitely sharp (EDGE_AND_CORNER); the
//! topology supplies those implicitly ([`crate::topology::PolyMesh::edge_sharpness`]).
//!
//! Values are `f32` because OpenSubdiv stores and subdivides them in `float`: a non-dyadic
//! sharpness such as 1.4 is really 1.39999997615814208984375 there, and the fractional
//! weights of [`fractional_weight`] are computed in `float` too. Doing the same here makes
//! our surfaces agree with OpenSubdiv's to rounding instead of to ~1e-9.

/// A sharpness value: finite, in [0, 10]. Values of 10 and above are all "infinitely
/// sharp" (they never decay), so they are stored as exactly 10.
#[derive(Clone, Copy, Debug, Default, PartialEq, PartialOrd)]
pub struct Sharpness(f32);

impl Sharpness {
    /// Smooth (0).
    pub const SMOOTH: Sharpness = Sharpness(0.0);
    /// Infinitely sharp (OpenSubdiv's `Crease::SHARPNESS_INFINITE`).
    pub const INFINITE: Sharpness = Sharpness(10.0);

    /// `None` for NaN and negative values; +∞ and everything ≥ 10 is [`Self::INFINITE`].
    pub fn new(s: f32) -> Option<Sharpness> {
        if s.is_nan() || s < 0.0 {
            None
        } else if s >= Self::INFINITE.0 {
            Some(Self::INFINITE)
        } else {
            // -0.0 becomes +0.0, so that smooth is one bit pattern.
            Some(Sharpness(s + 0.0))
        }
    }

    #[inline]
    pub fn value(self) -> f32 {
        self.0
    }
    #[inline]
    pub fn is_smooth(self) -> bool {
        self.0 <= 0.0
    }
    #[inline]
    pub fn is_sharp(self) -> bool {
        self.0 > 0.0
    }
    #[inline]
    pub fn is_infinite(self) -> bool {
        self.0 >= Self::INFINITE.0
    }
    /// Sharp but not infinitely: decays with refinement.
    #[inline]
    pub fn is_semi_sharp(self) -> bool {
        self.0 > 0.0 && self.0 < Self::INFINITE.0
    }

    /// The sharpness one refinement level down (uniform creasing: minus one, never below
    /// zero; infinite stays infinite). OpenSubdiv's `Crease::decrementSharpness`.
    #[inline]
    pub fn decremented(self) -> Sharpness {
        if self.is_smooth() {
            Self::SMOOTH
        } else if self.is_infinite() {
            Self::INFINITE
        } else if self.0 > 1.0 {
            Sharpness(self.0 - 1.0)
        } else {
            Self::SMOOTH
        }
    }
}

/// Which refinement mask a vertex point uses (OpenSubdiv's `Crease::Rule`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rule {
    /// No sharp edge, vertex not sharp: the Catmull-Clark vertex rule.
    Smooth,
    /// One sharp edge (a crease ending here): the smooth rule.
    Dart,
    /// Two sharp edges: the cubic B-spline rule along them, (a + 6v + b) / 8.
    Crease,
    /// Sharp vertex, or three or more sharp edges: the vertex stays where it is.
    Corner,
}

impl Rule {
    /// The rule of a vertex with sharpness `vertex` and `sharp_edges` sharp incident edges
    /// (OpenSubdiv's `Crease::DetermineVertexVertexRule`).
    #[inline]
    pub fn of(vertex: Sharpness, sharp_edges: usize) -> Rule {
        if vertex.is_sharp() {
            return Rule::Corner;
        }
        match sharp_edges {
            0 => Rule::Smooth,
            1 => Rule::Dart,
            2 => Rule::Crease,
            _ => Rule::Corner,
        }
    }

    /// Dart and smooth vertices use the same mask.
    #[inline]
    pub fn is_smooth_mask(self) -> bool {
        matches!(self, Rule::Smooth | Rule::Dart)
    }
}

/// The weight of the parent's (sharper) mask where a vertex's rule changes from one level
/// to the next because sharpness decayed (OpenSubdiv's
/// `Crease::ComputeFractionalWeightAtVertex`, uniform method): the mean of the parent
/// sharpness values that decay to zero — a vertex sharpness that does, and every incident
/// edge sharpness in (0, 1] — clamped to 1. Computed in `f32`, as OpenSubdiv does.
pub fn fractional_weight(vertex: Sharpness, edges: impl IntoIterator<Item = Sharpness>) -> f32 {
    let (mut count, mut sum) = (0u32, 0.0f32);
    if vertex.is_sharp() && vertex.decremented().is_smooth() {
        count = 1;
        sum = vertex.0;
    }
    for e in edges {
        if e.is_sharp() && e.0 <= 1.0 {
            sum += e.0;
            count += 1;
        }
    }
    if count == 0 {
        return 0.0;
    }
    let w = sum / count as f32;
    w.min(1.0)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sharpness_values_classes_and_decay() {
        assert_eq!(Sharpness::new(-1.0), None);
        assert_eq!(Sharpness::new(f32::NAN), None);
        assert_eq!(Sharpness::new(f32::INFINITY), Some(Sharpness::INFINITE));
        assert_eq!(Sharpness::new(12.5), Some(Sharpness::INFINITE));
        assert_eq!(Sharpness::new(-0.0).unwrap().value().to_bits(), 0);
        let s = Sharpness::new(2.5).unwrap();
        assert!(s.is_semi_sharp() && !s.is_infinite());
        assert_eq!(s.decremented().value(), 1.5);
        assert_eq!(s.decremented().decremented().value(), 0.5);
        assert!(s.decremented().decremented().decremented().is_smooth());
        assert_eq!(
            Sharpness::new(1.0).unwrap().decremented(),
            Sharpness::SMOOTH
        );
        assert_eq!(Sharpness::INFINITE.decremented(), Sharpness::INFINITE);
    }

    #[test]
    fn rules_and_fractional_weights() {
        let z = Sharpness::SMOOTH;
        assert_eq!(Rule::of(z, 0), Rule::Smooth);
        assert_eq!(Rule::of(z, 1), Rule::Dart);
        assert_eq!(Rule::of(z, 2), Rule::Crease);
        assert_eq!(Rule::of(z, 3), Rule::Corner);
        assert_eq!(Rule::of(Sharpness::new(0.3).unwrap(), 0), Rule::Corner);
        let s = |x| Sharpness::new(x).unwrap();
        assert_eq!(fractional_weight(z, [s(0.5), s(0.25), z, s(3.0)]), 0.375);
        assert_eq!(fractional_weight(s(0.5), []), 0.5);
        assert_eq!(fractional_weight(s(1.5), [s(0.5)]), 0.5);
        assert_eq!(fractional_weight(z, [s(2.0), Sharpness::INFINITE]), 0.0);
    }
}
