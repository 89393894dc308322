//! The orientation field's frames (v1, v2) at every texel centre, in f32 as synthesis
//! stores them. Mesh-side data like the texel geometry: the prepared session, the
//! synthesizers and relighting all take them from here ([`crate::synth`] re-exports them).

use crate::field::{Frame, OrientationField};
use glam::Vec3;
use rayon::prelude::*;
use subdiv::Surface;

/// The field's frames at every texel centre of `layout`, as the synthesizer stores them. A
/// uniform layout takes [`texel_frames_f32`] (the same values as always); either way the
/// frames are computed in f32 directly, without holding the f64 frames.
pub fn layout_frames(
    field: &OrientationField,
    surface: &Surface,
    layout: &crate::layout::TexelLayout,
) -> Vec<[Vec3; 2]> {
    if let Some(n) = layout.uniform_n() {
        return texel_frames_f32(field, surface, n);
    }
    (0..layout.len())
        .into_par_iter()
        .map(|t| {
            let l = layout.location(t);
            let f = field.frame(surface, l.domain, l.u, l.v);
            [f.v1.as_vec3(), f.v2.as_vec3()]
        })
        .collect()
}

/// The field's frames at every texel centre of `n`×`n` maps, as the synthesizer stores
/// them: the same values as `frames_f32(&field.texel_frames(surface, n))` (same order,
/// same rounding), without holding the f64 frames (48 B per texel) at the same time.
pub fn texel_frames_f32(field: &OrientationField, surface: &Surface, n: usize) -> Vec<[Vec3; 2]> {
    let mut out = vec![[Vec3::ZERO; 2]; surface.num_domains() * n * n];
    each_texel_centre(
        &mut out,
        n,
        subdiv::surface::LeafHint::default,
        |hint, d, u, v, o| {
            let f = field.frame_hinted(surface, d, u, v, hint);
            *o = [f.v1.as_vec3(), f.v2.as_vec3()];
        },
    );
    out
}

/// Calls `f(state, domain, u, v, slot)` for every texel centre of `n`×`n` maps, `out`
/// holding one slot per texel (domain-major, then row, then column); in parallel per
/// domain, `state` made by `init` once per domain. The centres are `(x + 0.5) · (1 / n)`,
/// the points the geometry pass evaluates on a uniform layout (so a slot's kept normal,
/// [`frames_from_slots`], is the one of its very centre).
fn each_texel_centre<S>(
    out: &mut [[Vec3; 2]],
    n: usize,
    init: impl Fn() -> S + Sync,
    f: impl Fn(&mut S, subdiv::DomainId, f64, f64, &mut [Vec3; 2]) + Sync,
) {
    if n == 0 {
        return;
    }
    let inv = 1.0 / n as f64;
    out.par_chunks_mut(n * n)
        .enumerate()
        .for_each(|(d, chunk)| {
            let d = subdiv::DomainId::from_idx(d);
            let mut state = init();
            for (i, o) in chunk.iter_mut().enumerate() {
                let (x, y) = (i % n, i / n);
                let (u, v) = ((x as f64 + 0.5) * inv, (y as f64 + 0.5) * inv);
                f(&mut state, d, u, v, o);
            }
        });
}

/// [`texel_frames_f32`] from the exact normals the geometry pass kept
/// ([`crate::texels::TexelGeometry::compute_keeping_normals`]): the same frames, bit for bit, without
/// evaluating the surface again, written over the slots in place (no second array).
pub fn frames_from_slots(
    field: &OrientationField,
    surface: &Surface,
    slots: crate::texels::FrameSlots,
) -> Vec<[Vec3; 2]> {
    use crate::texels::FrameSlots;
    let n = slots.resolution();
    let mut out = slots.into_inner();
    assert_eq!(out.len(), surface.num_domains() * n * n);
    each_texel_centre(
        &mut out,
        n,
        || (),
        |_, d, u, v, o| {
            let f = field.frame_with_normal(surface, d, u, v, FrameSlots::decode(o));
            *o = [f.v1.as_vec3(), f.v2.as_vec3()];
        },
    );
    out
}

/// Frames as the synthesizer stores them: (v1, v2) in f32.
pub fn frames_f32(frames: &[Frame]) -> Vec<[Vec3; 2]> {
    frames
        .par_iter()
        .map(|f| [f.v1.as_vec3(), f.v2.as_vec3()])
        .collect()
}
