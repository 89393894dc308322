//! `surfsynth probe`: the sampling pattern around one surface point, as one JSON object —
//! the validation tool for chart sampling and marching (issue 3).
//!
//! Output (all lengths in mesh units, positions are exact limit positions):
//! ```json
//! { "mesh": "...", "domains": F, "sampler": "chart", "size": K, "step": δ,
//!   "orient": "auto", "field_level": L,
//!   "centre": { "domain": d, "u": u, "v": v, "position": [x,y,z],
//!               "v1": [..], "v2": [..], "normal": [..] },
//!   "method": "chart" | "march", "chart_vertex": i | null, "fallback": false,
//!   "missing": 0,
//!   "samples": [ { "l": -h, "m": -h, "domain": d | null, "u": u | null, "v": v | null,
//!                  "position": [x,y,z] | null }, ... ] }
//! ```
//! Samples are listed row by row (m outer, l inner, both −h..h); sample (l, m) is the point
//! reached by l·δ·v1 + m·δ·v2.

use crate::field::{Orientation, OrientationField};
use crate::sampling::{Method, Sampler, SamplerKind};
use anyhow::{bail, Context};
use glam::DVec3;
use serde_json::{json, Value};
use std::path::PathBuf;
use subdiv::{DomainId, DomainLocation, Surface};

/// What to probe.
#[derive(Clone, Debug)]
pub struct ProbeRequest {
    pub mesh: PathBuf,
    /// Face domain (Ptex index).
    pub face: usize,
    pub u: f64,
    pub v: f64,
    /// δ, the surface distance between adjacent samples.
    pub step: f64,
    /// K (odd).
    pub size: usize,
    pub sampler: SamplerKind,
    pub orient: Orientation,
}

fn v3(p: DVec3) -> Value {
    json!([p.x, p.y, p.z])
}

/// Runs the probe and returns the JSON text (one line).
pub fn run_probe(req: &ProbeRequest) -> anyhow::Result<String> {
    if req.size.is_multiple_of(2) {
        bail!("pattern size {} must be odd", req.size);
    }
    if !(req.step.is_finite() && req.step > 0.0) {
        bail!("step {} must be a positive number", req.step);
    }
    for (name, x) in [("u", req.u), ("v", req.v)] {
        if !(0.0..=1.0).contains(&x) {
            bail!("{name} = {x} is outside the domain range 0..1");
        }
    }
    let surface = Surface::load_obj(&req.mesh)
        .with_context(|| format!("{}: cannot load mesh", req.mesh.display()))?;
    let nd = surface.num_domains();
    if req.face >= nd {
        bail!(
            "face {} does not exist: {} has {nd} face domains (0..{})",
            req.face,
            req.mesh.display(),
            nd - 1
        );
    }
    let field = OrientationField::compute(&surface, &req.orient)?;
    let sampler = Sampler::new(&surface, &field);
    let centre = DomainLocation {
        domain: DomainId::from_idx(req.face),
        u: req.u,
        v: req.v,
    };
    let k = req.size;
    let h = (k / 2) as i64;
    let mut out = vec![None; k * k];
    let info = sampler.sample(centre, req.step, k, req.sampler, &mut out);
    let e = surface.eval(centre.domain, centre.u, centre.v);
    let frame = sampler.frame(centre);
    let mut samples = Vec::with_capacity(k * k);
    for m in -h..=h {
        for l in -h..=h {
            let s = out[((m + h) as usize) * k + (l + h) as usize];
            samples.push(match s {
                Some(loc) => json!({
                    "l": l, "m": m, "domain": loc.domain.0, "u": loc.u, "v": loc.v,
                    "position": v3(surface.eval(loc.domain, loc.u, loc.v).p),
                }),
                None => json!({
                    "l": l, "m": m, "domain": null, "u": null, "v": null, "position": null,
                }),
            });
        }
    }
    let (method, vertex) = match info.method {
        Method::Chart(v) => ("chart", Some(v.0)),
        Method::March => ("march", None),
    };
    let doc = json!({
        "mesh": req.mesh.display().to_string(),
        "domains": nd,
        "sampler": req.sampler.name(),
        "size": k,
        "step": req.step,
        "orient": req.orient.label(),
        "field_level": field.level(),
        "centre": {
            "domain": centre.domain.0, "u": centre.u, "v": centre.v,
            "position": v3(e.p), "v1": v3(frame.v1), "v2": v3(frame.v2), "normal": v3(e.n),
        },
        "method": method,
        "chart_vertex": vertex,
        "fallback": info.fallback,
        "missing": info.missing,
        "samples": samples,
    });
    Ok(serde_json::to_string(&doc)?)
}
