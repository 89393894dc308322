//! Typed indices, so a face index can never be passed where a vertex index is expected.

macro_rules! id_type {
    ($(#[$doc:meta])* $name:ident) => {
        $(#[$doc])*
        #[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
        pub struct $name(pub u32);

        impl $name {
            #[inline]
            pub fn idx(self) -> usize {
                self.0 as usize
            }
            #[inline]
            pub fn from_idx(i: usize) -> Self {
                Self(i as u32)
            }
        }

        impl std::fmt::Display for $name {
            fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
                write!(f, "{}", self.0)
            }
        }
    };
}

id_type!(
    /// A vertex of a polygon mesh (control mesh or a refined level).
    VertexId
);
id_type!(
    /// A face of a polygon mesh, in the mesh's own order (OBJ order for the control mesh).
    FaceId
);
id_type!(
    /// A Ptex face domain: one per control quad, n per control n-gon (n != 4).
    DomainId
);
id_type!(
    /// A quad of the once-refined (level-1) mesh. Every Ptex domain is one or four of these.
    BaseQuadId
);
