//! Output conventions a run is made with and its report records: which way round the
//! example lies on the surface ([`Handedness`]), which way a normal map's green points
//! ([`NormalConvention`]) and whether a material map stores light or data ([`MapKind`],
//! which the loader decodes by and the atlas writers encode by). Below the builder, the
//! report, the loader and the writers, which all name them ([`crate::synthesizer`]
//! re-exports the first two).

/// Which way round the example is laid on the surface (`--handedness`).
///
/// Image columns always run along v1. Image rows can run along +v2 or −v2 (v2 = n × v1),
/// and the two choices are mirror images of each other; BRIEF's tiles (u to the right, v
/// downwards) and the surface seen from outside (v1 to the right, v2 up) are themselves
/// mirror images, so exactly one of them shows the example unmirrored:
///
/// - [`Handedness::Tiles`] (default): rows along +v2. Where v1 runs along u, a face map is
///   the example as stored (on a flat grid with `--orient +x`, or `auto`, whose free
///   rotation follows +x, the tiles are crops of the example), which is what tile-based
///   measures such as `eval`'s patch fidelity compare. Seen from outside, the texture is
///   mirrored: invisible for stochastic or symmetric examples, visible for text.
/// - [`Handedness::Outside`]: rows along −v2. Seen from the side the normals point to, the
///   texture reads exactly as the example (text stays readable); the tiles are mirrored.
///
/// Both synthesizers work in the `Outside` frame; for `Tiles` the builder hands them the
/// example upside down and turns the source positions back (exact: bilinear lookups agree).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Handedness {
    #[default]
    Tiles,
    Outside,
}

/// How a tangent-space normal map's green channel points (`--normal-convention`).
///
/// Both conventions put red along the image's columns (+X to the right) and blue out of the
/// surface; they differ in green: OpenGL's (Blender, glTF, Substance's "OpenGL" export)
/// points up the image, DirectX's (Unreal, 3ds Max) down. Read the wrong way round, every
/// bump looks like a dent under light from above or below.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum NormalConvention {
    /// +Y up the image (the default, glTF's).
    #[default]
    OpenGl,
    /// +Y down the image.
    DirectX,
}

impl Handedness {
    /// geometry.exr's `tangentHandedness`: +1 when the example's up (toward its top row)
    /// runs along +(N x T) on the surface (`outside`: (T, up, N) is right-handed, as glTF's
    /// w = +1), -1 when it runs along -(N x T) (`tiles`: the texture is mirrored). The
    /// normal map in facemaps.exr is already in (T, N x T, N) either way; this tells
    /// readers how the other maps' image axes lie.
    pub fn bitangent_sign(self) -> i32 {
        match self {
            Handedness::Outside => 1,
            Handedness::Tiles => -1,
        }
    }
}

/// Whether a map's file stores light or data.
///
/// Light (colour) is sRGB-encoded in 8- and 16-bit files and must be decoded before it is
/// compared or blended; data (normals, roughness, heights) is stored linearly, and decoding
/// it would bend every value.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum MapKind {
    /// sRGB-decoded; written to the atlas sRGB-encoded (8 bit, like `atlas.png`).
    Colour,
    /// Stored values scaled to 0..1; written to the atlas linearly (16 bit).
    Data,
}

impl MapKind {
    /// The kind a map named `name` has: colour when the name says so (`basecolor`,
    /// `base_colour`, `albedo`, `diffuse`, `emissive`, `emission`, `specular_color`, ...),
    /// data otherwise (normal, roughness, metallic, height, ao, occlusion, any other name).
    pub fn for_name(name: &str) -> Self {
        let n = name.to_ascii_lowercase();
        let colour = [
            "color", "colour", "albedo", "diffuse", "emissive", "emission",
        ];
        if colour.iter().any(|c| n.contains(c)) {
            MapKind::Colour
        } else {
            MapKind::Data
        }
    }
}
