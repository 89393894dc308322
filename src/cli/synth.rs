//! `surfsynth synth`: the main job (issues 4 and 5). The handler is
//! [`surfsynth::synthesizer::run_command`]; this module only maps the arguments.

use super::{parse_finite, parse_orient, parse_positive, parse_resolution};
use clap::{Args, ValueEnum};
use std::path::PathBuf;
use surfsynth::field::Orientation;
use surfsynth::method::Method;

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Appearance {
    /// PCA of every pixel's 5x5 neighbourhood (8 dimensions; Lefebvre & Hoppe 2006).
    Pca,
    /// The weighted channels themselves (colour, alpha, height).
    Rgb,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Search {
    /// PCA-projected kd-tree, re-ranked exactly.
    Ann,
    /// k-coherence candidate sets (003 §5.2).
    Kcoherence,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum NeighbourhoodSamples {
    /// Every sample of the level's own block.
    Full,
    /// The inner 5x5 of the 9x9 block and every other sample beyond (41 of 81).
    Sparse,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum FinestStart {
    /// Pass 1 matches every texel against the coarser level's block.
    Matched,
    /// Every texel continues its coarser texel's patch (no search).
    Continued,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum Handedness {
    /// Face maps show the example as stored.
    Tiles,
    /// The surface seen from outside shows the example as stored.
    Outside,
}

#[derive(ValueEnum, Clone, Copy, Debug, PartialEq, Eq)]
pub enum NormalConvention {
    /// Green points up the image (OpenGL, glTF, Blender).
    Opengl,
    /// Green points down the image (DirectX, Unreal).
    Directx,
}

/// `--map NAME=FILE`.
fn parse_map(s: &str) -> Result<(String, PathBuf), String> {
    let Some((name, file)) = s.split_once('=') else {
        return Err(format!("'{s}' is not NAME=FILE (e.g. --map normal=N.png)"));
    };
    surfsynth::example::check_map_name(name)?;
    if file.is_empty() {
        return Err(format!("'{s}': the file name after '=' is empty"));
    }
    Ok((name.to_string(), PathBuf::from(file)))
}

/// `--match NAME=WEIGHT`.
fn parse_match(s: &str) -> Result<(String, f32), String> {
    let Some((name, w)) = s.split_once('=') else {
        return Err(format!("'{s}' is not NAME=WEIGHT (e.g. --match normal=1)"));
    };
    surfsynth::example::check_map_name(name)?;
    let v: f32 = w
        .trim()
        .parse()
        .map_err(|_| format!("'{s}': '{w}' is not a number"))?;
    if !(v.is_finite() && v >= 0.0) {
        return Err(format!("'{s}': a weight is a finite number >= 0"));
    }
    Ok((name.to_string(), v))
}

#[derive(Args, Debug)]
pub struct SynthArgs {
    /// Control mesh (OBJ).
    #[arg(long, value_name = "M.obj")]
    pub mesh: PathBuf,
    /// Example texture (PNG or JPEG; sRGB; alpha kept).
    #[arg(
        long,
        value_name = "E.png",
        required_unless_present = "btf",
        conflicts_with = "btf"
    )]
    pub example: Option<PathBuf>,
    /// BTF sample: a btf.json naming images of one patch under several light directions
    /// (docs/btf.md); every image matched at once (one source per texel for all of them).
    #[arg(long, value_name = "B.json", conflicts_with_all = ["height", "maps"])]
    pub btf: Option<PathBuf>,
    /// Height example of the same size (grayscale, synthesized jointly; the same as
    /// --map height=H.png).
    #[arg(long, value_name = "H.png")]
    pub height: Option<PathBuf>,
    /// A further map of the material, the example's size, copied from the same source
    /// positions (repeatable): normal (tangent-space), roughness, metallic, height,
    /// ao/occlusion, or any name; names with colour/albedo/diffuse/emissive are sRGB.
    #[arg(long = "map", value_name = "NAME=FILE", value_parser = parse_map)]
    pub maps: Vec<(String, PathBuf)>,
    /// Match map NAME too, with WEIGHT per channel (colour channels weigh 1; height 3 by
    /// default; other maps are copied but not matched unless given here).
    #[arg(long = "match", value_name = "NAME=WEIGHT", value_parser = parse_match)]
    pub matches: Vec<(String, f32)>,
    /// Green axis of the normal map: opengl (+Y up the image, glTF and Blender) or directx
    /// (+Y down, Unreal).
    #[arg(long, value_enum, default_value_t = NormalConvention::Opengl)]
    pub normal_convention: NormalConvention,
    /// Synthesis method (default: optimise, also with --btf).
    #[arg(long, value_enum)]
    pub method: Option<Method>,
    /// What neighbourhoods are compared in: appearance space (pca) or raw channels (rgb).
    #[arg(long, value_enum, default_value_t = Appearance::Pca)]
    pub appearance: Appearance,
    /// Also match the signed distance to the example's bright/dark borders (mortar, grout,
    /// gaps), with this weight against colour's 1: keeps more thin joints on curved
    /// surfaces (e.g. 0.5 for bricks). Not with textons or --appearance rgb; 0: off.
    #[arg(long, value_name = "W", default_value_t = 0.0, value_parser = parse_feature_distance, allow_negative_numbers = true)]
    pub feature_distance: f32,
    /// Patch side in example pixels for --method patches and the start of optimise (default:
    /// 64, at most half the example's shorter side). Larger patches keep larger structure.
    #[arg(long, value_name = "PIXELS", value_parser = parse_patch_size, allow_negative_numbers = true)]
    pub patch_size: Option<usize>,
    /// Neighbourhood search of the multiscale method (default: kcoherence, the faster at
    /// equal quality).
    #[arg(long, value_enum)]
    pub search: Option<Search>,
    /// Side K of the level's own neighbourhood block of multiscale and textons (odd, 3 to
    /// 15; the coarser level's block stays 5x5).
    #[arg(long, value_name = "K", value_parser = parse_neighbourhood, allow_negative_numbers = true)]
    pub neighbourhood: Option<usize>,
    /// k-coherence: entries of each proposing neighbour's list that become candidates
    /// (paper 003's k; default 11).
    #[arg(long, value_name = "K", value_parser = parse_kcoherence_k, allow_negative_numbers = true)]
    pub kcoherence_k: Option<usize>,
    /// Multiscale: compare the level's own 9x9 block at every sample (full) or at its
    /// inner 5x5 and every other sample beyond (sparse, 41 of 81; faster).
    #[arg(long, value_enum, value_name = "WHICH")]
    pub neighbourhood_samples: Option<NeighbourhoodSamples>,
    /// Multiscale: what the finest level's refinement starts from — pass 1's matches
    /// against the coarser level, or each texel continuing its coarser texel's patch
    /// (faster).
    #[arg(long, value_enum, value_name = "HOW")]
    pub finest_start: Option<FinestStart>,
    /// Jump maps: texture blending across breaks (002 §4.4). Where a neighbour's
    /// continuation into a texel disagrees with the texel's own source (a jump, two growth
    /// fronts meeting), the example there is mixed into the texel's value, each neighbour
    /// weighing W against the texel's own 1; every channel alike, source.u/v unchanged.
    /// Default 0.5; 0: off (each value is the look-up at its source).
    #[arg(long, value_name = "W", value_parser = parse_jump_blend, allow_negative_numbers = true)]
    pub jump_blend: Option<f32>,
    /// Texels per side of every face map.
    #[arg(long, value_name = "N", default_value_t = 32, value_parser = parse_resolution, allow_negative_numbers = true)]
    pub resolution: usize,
    /// Surface length per texel: every face gets its own resolution (powers of two, u and v
    /// separately, 2 to 8192 per side) so that texel spacing varies at most ~2x over the
    /// surface; replaces --resolution.
    #[arg(long, value_name = "L", value_parser = parse_positive, allow_negative_numbers = true, conflicts_with = "resolution")]
    pub texel_size: Option<f64>,
    /// Surface length covered by one example pixel (default: median texel spacing).
    #[arg(long, value_name = "S", value_parser = parse_positive, allow_negative_numbers = true)]
    pub scale: Option<f64>,
    /// Spatially varying scale: a file of `vertex INDEX FACTOR` / `point X Y Z FACTOR` lines
    /// (docs/formats.md); the factors, interpolated over the surface, multiply the scale.
    #[arg(long, value_name = "FILE")]
    pub scale_map: Option<PathBuf>,
    /// Spatially varying scale from the orientation constraints file (--orient FILE): each
    /// `vertex I DX DY DZ` line's length |(DX, DY, DZ)| multiplies the scale at vertex I, as
    /// the scale-map line `vertex I LENGTH` would (docs/field.md); instead of --scale-map.
    #[arg(long)]
    pub scale_from_orient: bool,
    /// Orientation field: auto (the smoothest field), up[+-AXIS] (the example upright
    /// along an axis, +y by default: level brick courses), upright[+-AXIS] (`up`, unless
    /// more than half of the surface is level against the axis — terrain, a floor — then
    /// `auto`), straight, +x|-x|+y|-y|+z|-z (the example's x along an axis), or a
    /// constraints file. Default: `upright` for optimise (the default method), `auto` for
    /// the others.
    #[arg(long, value_name = "auto|up|upright|AXIS|FILE", value_parser = parse_orient, allow_hyphen_values = true)]
    pub orient: Option<Orientation>,
    /// Random seed; the same seed gives the same files for any thread count.
    #[arg(
        long,
        value_name = "K",
        default_value_t = 1,
        allow_negative_numbers = true
    )]
    pub seed: u64,
    /// Also write displaced.glb, moved along the normal by AMOUNT x (height - 0.5).
    #[arg(long, value_name = "AMOUNT", value_parser = parse_finite, allow_negative_numbers = true)]
    pub displace: Option<f64>,
    /// Decimate displaced.glb where the displaced surface is flat within TOL (mesh units).
    #[arg(long, value_name = "TOL", value_parser = parse_finite, allow_negative_numbers = true)]
    pub decimate: Option<f64>,
    /// Image rows along +v2 (tiles: face maps show the example as stored, so the surface
    /// seen from outside shows its mirror image) or along -v2 (outside: the texture reads
    /// correctly seen from outside, e.g. text; the tiles are mirrored).
    #[arg(long, value_enum, default_value_t = Handedness::Tiles)]
    pub handedness: Handedness,
    /// Output directory (created if missing).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Folder of saved per-example analysis (default: the user cache folder, or
    /// $SURFSYNTH_CACHE).
    #[arg(long, value_name = "DIR", conflicts_with = "no_cache")]
    pub cache: Option<PathBuf>,
    /// Neither load nor save per-example analysis.
    #[arg(long)]
    pub no_cache: bool,
    /// Refuse to start when the estimated peak memory is above this (e.g. 512M, 4G,
    /// unlimited; default: 75% of physical memory).
    #[arg(long, value_name = "SIZE", value_parser = surfsynth::memory::parse_size, allow_hyphen_values = true)]
    pub max_memory: Option<u64>,
}

fn parse_patch_size(s: &str) -> Result<usize, String> {
    let v: usize = s
        .parse()
        .map_err(|_| format!("'{s}' is not a whole number of pixels"))?;
    if !(4..=1024).contains(&v) {
        return Err(format!(
            "patch size {v} is out of range: use 4 to 1024 pixels"
        ));
    }
    Ok(v)
}

fn parse_neighbourhood(s: &str) -> Result<usize, String> {
    let v: usize = s
        .parse()
        .map_err(|_| format!("'{s}' is not a whole number of samples"))?;
    if !(3..=15).contains(&v) || v.is_multiple_of(2) {
        return Err(format!(
            "neighbourhood side {v} is not valid: use an odd side from 3 to 15"
        ));
    }
    Ok(v)
}

fn parse_kcoherence_k(s: &str) -> Result<usize, String> {
    let v: usize = s
        .parse()
        .map_err(|_| format!("'{s}' is not a whole number"))?;
    if !(1..=64).contains(&v) {
        return Err(format!("k-coherence k {v} is out of range: use 1 to 64"));
    }
    Ok(v)
}

fn parse_feature_distance(s: &str) -> Result<f32, String> {
    parse_weight(s, "feature-distance", 16.0)
}

fn parse_jump_blend(s: &str) -> Result<f32, String> {
    parse_weight(s, "jump-blend", 4.0)
}

/// A weight from 0 (off) to `max`, named `what` in the message.
fn parse_weight(s: &str, what: &str, max: f32) -> Result<f32, String> {
    let v: f32 = s.parse().map_err(|_| format!("'{s}' is not a number"))?;
    if !(0.0..=max).contains(&v) {
        return Err(format!(
            "{what} weight {v} is out of range: use 0 (off) to {max}"
        ));
    }
    Ok(v)
}

pub fn run(mut a: SynthArgs) -> anyhow::Result<()> {
    // The handler lives in the library (surfsynth::synthesizer::run_command).
    let chosen = a.method.unwrap_or(Method::DEFAULT);
    if chosen == Method::Textons && a.btf.is_none() {
        return super::usage("--method textons needs a BTF sample: pass --btf B.json");
    }
    if let (Some(why), Some(_)) = (chosen.btf_refusal(), &a.btf) {
        return super::usage(why);
    }
    if a.search.is_some() && !matches!(chosen, Method::Multiscale | Method::Textons) {
        return super::usage(format!(
            "--search applies to --method multiscale and textons only (--method {} has no search structure)",
            chosen
                .to_possible_value()
                .map_or("?".into(), |v| v.get_name().to_string())
        ));
    }
    if (a.neighbourhood.is_some() || a.kcoherence_k.is_some())
        && !matches!(chosen, Method::Multiscale | Method::Textons)
    {
        return super::usage(
            "--neighbourhood and --kcoherence-k apply to --method multiscale and textons only",
        );
    }
    if (a.neighbourhood_samples.is_some() || a.finest_start.is_some())
        && chosen != Method::Multiscale
    {
        return super::usage(
            "--neighbourhood-samples and --finest-start apply to --method multiscale only",
        );
    }
    if a.jump_blend.is_some() && chosen != Method::Jump {
        return super::usage("--jump-blend applies to --method jump only");
    }
    if a.kcoherence_k.is_some() && matches!(a.search, Some(Search::Ann)) {
        return super::usage("--kcoherence-k applies to --search kcoherence only");
    }
    if a.decimate.is_some() && a.displace.is_none() {
        return super::usage("--decimate applies to the displaced mesh: pass --displace AMOUNT");
    }
    let has_height = a.height.is_some() || a.maps.iter().any(|(n, _)| n == "height");
    if a.height.is_some() && a.maps.iter().any(|(n, _)| n == "height") {
        return super::usage("--height is --map height=FILE: give one of them, not both");
    }
    if let Some((n, _)) = a
        .maps
        .iter()
        .enumerate()
        .find(|(i, (n, _))| a.maps[..*i].iter().any(|(m, _)| m == n))
        .map(|(_, m)| m)
    {
        return super::usage(format!(
            "--map {n}= is given twice; each map name must be unique"
        ));
    }
    if let Some((n, _)) = a.matches.iter().find(|(n, _)| {
        !(a.maps.iter().any(|(m, _)| m == n) || (n == "height" && a.height.is_some()))
    }) {
        let names: Vec<&str> = a
            .maps
            .iter()
            .map(|(m, _)| m.as_str())
            .chain(a.height.as_ref().map(|_| "height"))
            .collect();
        return super::usage(format!(
            "--match {n}: there is no map named '{n}' (maps given: {})",
            if names.is_empty() {
                "none; add --map NAME=FILE".to_string()
            } else {
                names.join(", ")
            }
        ));
    }
    if a.displace.is_some() && !has_height {
        return super::usage(format!(
            "--displace needs a height channel, and {} has none: pass --height H.png",
            a.example
                .as_ref()
                .or(a.btf.as_ref())
                .map_or(String::new(), |p| p.display().to_string())
        ));
    }
    if a.patch_size.is_some() && !matches!(chosen, Method::Patches | Method::Optimise) {
        return super::usage("--patch-size applies to --method patches and optimise only");
    }
    if a.scale_from_orient {
        if a.scale_map.is_some() {
            return super::usage(
                "--scale-from-orient and --scale-map both give the scale: pass one of them",
            );
        }
        if !matches!(a.orient, Some(Orientation::Constraints(_))) {
            return super::usage(
                "--scale-from-orient takes the scale from the lengths of the `vertex` directions of a constraints file: pass --orient FILE",
            );
        }
    }
    surfsynth::memory::set_limit(a.max_memory);
    use surfsynth::synthesizer::Search as S;
    let method = chosen;
    let cache = match (a.cache, a.no_cache) {
        (_, true) => surfsynth::synthesizer::CacheDir::Off,
        (Some(d), false) => surfsynth::synthesizer::CacheDir::Dir(d),
        (None, false) => surfsynth::synthesizer::CacheDir::Default,
    };
    surfsynth::synthesizer::run_command(&surfsynth::synthesizer::SynthCommand {
        mesh: a.mesh,
        example: a.example.take().unwrap_or_default(),
        btf: a.btf,
        height: a.height,
        maps: a.maps,
        matches: a.matches,
        normal_convention: match a.normal_convention {
            NormalConvention::Opengl => surfsynth::synthesizer::NormalConvention::OpenGl,
            NormalConvention::Directx => surfsynth::synthesizer::NormalConvention::DirectX,
        },
        method,
        resolution: a.resolution,
        texel_size: a.texel_size,
        scale: a.scale,
        scale_map: a.scale_map,
        scale_from_orient: a.scale_from_orient,
        orientation: a.orient,
        seed: a.seed,
        search: a.search.map(|s| match s {
            Search::Ann => S::Ann,
            Search::Kcoherence => S::KCoherence,
        }),
        neighbourhood: a.neighbourhood,
        kcoherence_k: a.kcoherence_k,
        sparse: a
            .neighbourhood_samples
            .map(|n| n == NeighbourhoodSamples::Sparse),
        continue_finest: a.finest_start.map(|f| f == FinestStart::Continued),
        jump_blend: a.jump_blend,
        displace: a.displace,
        appearance: match a.appearance {
            Appearance::Pca => surfsynth::synthesizer::AppearanceMode::Pca,
            Appearance::Rgb => surfsynth::synthesizer::AppearanceMode::Rgb,
        },
        feature_distance: a.feature_distance,
        decimate: a.decimate,
        patch_size: a.patch_size,
        handedness: match a.handedness {
            Handedness::Tiles => surfsynth::synthesizer::Handedness::Tiles,
            Handedness::Outside => surfsynth::synthesizer::Handedness::Outside,
        },
        cache,
        out: a.out,
    })?;
    Ok(())
}
