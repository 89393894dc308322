//! A result's texels under one light (`render DIR --light X,Y,Z`): what the surface looks
//! like lit from a direction, per texel, before the picture is ray-cast.
//!
//! - **BTF results** (report.json `inputs.btf`): the surface BTF is the sample indexed by
//!   `source.u/v` (paper 003 §3), so a texel lit from world direction l shows the sample at
//!   its source position under l expressed in the texel's frame — the field frame (v1, v2,
//!   n), turned as the example was laid ([`crate::btf::local_light`]) — blended between the
//!   nearest sample lights (003 §6, [`BtfSample::blend_weights`]). Shadows and occlusion of
//!   the mesostructure come from the sample's own images; nothing is recomputed.
//! - **Material sets** with `normal.R/G/B` (a tangent-space normal map in the field's frame
//!   (T, n × T, n), encoded 0..1 as PNGs are) and optionally `roughness.Y`: Lambert with the
//!   mapped normal plus a Blinn–Phong highlight whose exponent follows the roughness
//!   (2/r⁴ − 2), seen from `view`.
//! - Anything else: Lambert with the limit normal.
//!
//! The frame comes from geometry.exr's `T.X T.Y T.Z` when present, else the orientation field
//! is computed again from report.json's `orientation` (deterministic: the same field).

use crate::btf::BtfSample;
use crate::error::{Error, Result};
use crate::field::{Orientation, OrientationField};
use crate::io::exr::FaceMaps;
use glam::DVec3;
use rayon::prelude::*;
use std::path::Path;
use subdiv::Surface;

/// What report.json says about how a result was made, as far as lighting needs it.
#[derive(Clone, Debug, PartialEq)]
pub struct RunInfo {
    /// `inputs.btf`: the sample's btf.json.
    pub btf: Option<std::path::PathBuf>,
    /// `orientation` (as [`Orientation::parse`] or `axis (x, y, z)`).
    pub orientation: Orientation,
    /// `handedness` is `tiles` (the default) rather than `outside`.
    pub tiles: bool,
}

impl RunInfo {
    /// Reads DIR/report.json (a missing report: defaults, no BTF).
    pub fn read(dir: &Path) -> Result<Self> {
        let p = dir.join(crate::io::names::REPORT_FILE);
        let Ok(text) = std::fs::read_to_string(&p) else {
            return Ok(Self {
                btf: None,
                orientation: Orientation::Auto,
                tiles: true,
            });
        };
        let v: serde_json::Value = serde_json::from_str(&text)
            .map_err(|e| Error::file(&p, format!("not valid JSON: {e}")))?;
        let btf = v
            .pointer("/inputs/btf")
            .and_then(|b| b.as_str())
            .map(std::path::PathBuf::from);
        let orientation = match v.get("orientation").and_then(|o| o.as_str()) {
            None => Orientation::Auto,
            Some(s) => parse_orientation(s),
        };
        let tiles = v.get("handedness").and_then(|h| h.as_str()) != Some("outside");
        Ok(Self {
            btf,
            orientation,
            tiles,
        })
    }
}

/// report.json's orientation label back into an [`Orientation`].
fn parse_orientation(s: &str) -> Orientation {
    for (prefix, make) in [
        ("axis (", Orientation::Axis as fn(DVec3) -> Orientation),
        ("up (", Orientation::Up),
        ("upright (", Orientation::Upright),
    ] {
        if let Some(inner) = s.strip_prefix(prefix).and_then(|r| r.strip_suffix(')')) {
            let v: Vec<f64> = inner
                .split(',')
                .filter_map(|x| x.trim().parse().ok())
                .collect();
            if let [x, y, z] = v[..] {
                return make(DVec3::new(x, y, z));
            }
        }
    }
    Orientation::parse(s)
}

/// Per texel (global order) the field's unit tangent v1: geometry.exr's `T` channels when
/// `geometry` has them, else the field computed from `orientation`.
pub fn tangents(
    surface: &Surface,
    layout: &crate::layout::TexelLayout,
    geometry: Option<&FaceMaps>,
    orientation: &Orientation,
) -> Result<Vec<DVec3>> {
    if let Some(g) = geometry {
        if let (Some(x), Some(y), Some(z)) = (g.channel("T.X"), g.channel("T.Y"), g.channel("T.Z"))
        {
            return Ok(x
                .iter()
                .zip(y)
                .zip(z)
                .map(|((&x, &y), &z)| DVec3::new(x as f64, y as f64, z as f64))
                .collect());
        }
    }
    let field = OrientationField::compute(surface, orientation)
        .map_err(|e| Error::invalid(format!("orientation field: {e:#}")))?;
    Ok(crate::texel_frames::layout_frames(&field, surface, layout)
        .into_iter()
        .map(|f| f[0].as_dvec3())
        .collect())
}

/// One light and the viewer, for [`lit_texels`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lighting {
    /// Unit world direction towards the light.
    pub light: DVec3,
    /// Unit world direction towards the viewer (highlights).
    pub view: DVec3,
    /// The result's handedness is `tiles` ([`crate::btf::local_light`]).
    pub tiles: bool,
}

/// Lit colour of every texel (global order) of `maps` under world light `light` (unit,
/// towards the light), seen from direction `view` (unit, towards the viewer), with texel
/// normals `normals` and field tangents `tangent` (see the module docs for the three
/// cases). `sample` is the BTF of a BTF result.
pub fn lit_texels(
    maps: &FaceMaps,
    normals: &[DVec3],
    tangent: &[DVec3],
    lighting: &Lighting,
    sample: Option<&BtfSample>,
    path: &Path,
) -> Result<Vec<[f32; 3]>> {
    let Lighting { light, view, tiles } = *lighting;
    let texels = maps.layout.len();
    let ch = |name: &str| {
        maps.channel(name)
            .ok_or_else(|| Error::file(path, format!("has no '{name}' channel")))
    };
    let (r, g, b) = (ch("R")?, ch("G")?, ch("B")?);
    let frame = |i: usize| {
        let n = normals[i];
        let t = tangent[i] - n * n.dot(tangent[i]);
        let t = t
            .try_normalize()
            .unwrap_or_else(|| n.any_orthonormal_vector());
        (t, n.cross(t), n)
    };
    if let Some(s) = sample {
        let (su, sv) = (ch("source.u")?, ch("source.v")?);
        return Ok((0..texels)
            .into_par_iter()
            .map(|i| {
                let (v1, v2, n) = frame(i);
                let l = crate::btf::local_light(light, v1, v2, n, tiles);
                s.shade(l, su[i], sv[i])
            })
            .collect());
    }
    let nm = match (
        maps.channel("normal.R"),
        maps.channel("normal.G"),
        maps.channel("normal.B"),
    ) {
        (Some(x), Some(y), Some(z)) => Some((x, y, z)),
        _ => None,
    };
    // Encoded 0..1 (as the PNG it came from) unless some value is negative.
    let encoded = nm.is_some_and(|(x, y, _)| x.iter().chain(y).all(|&v| v >= 0.0));
    let rough = maps.channel("roughness.Y");
    let half = (light + view).try_normalize().unwrap_or(light);
    Ok((0..texels)
        .into_par_iter()
        .map(|i| {
            let (t, bt, n) = frame(i);
            let nn = match nm {
                Some((x, y, z)) => {
                    let d = |v: f32| {
                        if encoded {
                            2.0 * v as f64 - 1.0
                        } else {
                            v as f64
                        }
                    };
                    (t * d(x[i]) + bt * d(y[i]) + n * d(z[i]))
                        .try_normalize()
                        .unwrap_or(n)
                }
                None => n,
            };
            let diffuse = nn.dot(light).max(0.0) as f32;
            let spec = match rough {
                Some(rg) if nm.is_some() || rough.is_some() => {
                    let a = (rg[i] as f64).clamp(0.03, 1.0);
                    let e = 2.0 / a.powi(4) - 2.0;
                    let s =
                        nn.dot(half).max(0.0).powf(e) * (e + 8.0) / (8.0 * std::f64::consts::PI);
                    (0.04 * s * diffuse.min(1.0) as f64) as f32
                }
                _ => 0.0,
            };
            [
                r[i].max(0.0) * diffuse + spec,
                g[i].max(0.0) * diffuse + spec,
                b[i].max(0.0) * diffuse + spec,
            ]
        })
        .collect())
}

/// The BTF of a result, if report.json names one.
pub fn load_btf(info: &RunInfo) -> Result<Option<BtfSample>> {
    match &info.btf {
        None => Ok(None),
        Some(p) => BtfSample::load(p).map(Some).map_err(|e| match e {
            Error::File { path, problem } => Error::file(
                path,
                format!("{problem} (the BTF sample named by report.json inputs.btf)"),
            ),
            other => other,
        }),
    }
}
