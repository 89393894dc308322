//! The "constant neighbourhood" flag (`FaceInfo::flag_nbconstant`): a constant face whose
//! every neighbour around every corner is constant with the same value. Filters return the
//! face's value for such a face without looking at any texel, so the flag must be exactly
//! what the reference writer computes: this is `PtexMainWriter::flagConstantNeighorhoods`
//! transcribed, traversal order, subface "tee" stop and valence safety valve included.

use super::format::{FaceInfo, FLAG_CONSTANT};

/// Whether face `f` (which must be constant) has a constant neighbourhood. `flags[i]` has
/// FLAG_CONSTANT for constant faces; `same(a, b)`: faces a and b have bit-identical
/// constant values. Border modes are clamp.
pub fn constant_neighbourhood(
    infos: &[FaceInfo],
    flags: &[u8],
    f: usize,
    same: impl Fn(usize, usize) -> bool,
) -> bool {
    let constant = |i: usize| flags[i] & FLAG_CONSTANT != 0;
    let fi = &infos[f];
    let face = f as i32;
    for eid in 0..4usize {
        let mut prev_was_subface = fi.subface;
        let mut prev_fid = face;
        // Clockwise around the vertex.
        let mut afid = fi.adj_faces[eid];
        let mut aeid = fi.adj_edges[eid] as usize;
        let mut count = 0;
        const MAX_COUNT: i32 = 10;
        while afid != face && afid >= 0 && {
            count += 1;
            count < MAX_COUNT
        } {
            let a = afid as usize;
            if !constant(a) || !same(f, a) {
                return false;
            }
            let af = &infos[a];
            // A T vertex between a sub-face and a main face ends the walk.
            let is_t = prev_was_subface && !af.subface && af.adj_faces[aeid] == prev_fid;
            if is_t {
                break;
            }
            prev_was_subface = af.subface;
            prev_fid = afid;
            aeid = (aeid + 1) % 4;
            afid = af.adj_faces[aeid];
            aeid = af.adj_edges[aeid] as usize;
        }
        if afid < 0 {
            // A boundary: with clamp borders, walk the other way round too.
            aeid = (aeid + 3) % 4;
            afid = fi.adj_faces[aeid];
            aeid = fi.adj_edges[aeid] as usize;
            count = 0;
            while afid != face && afid >= 0 && {
                count += 1;
                count < MAX_COUNT
            } {
                let a = afid as usize;
                if !constant(a) || !same(f, a) {
                    return false;
                }
                let af = &infos[a];
                aeid = (aeid + 3) % 4;
                afid = af.adj_faces[aeid];
                aeid = af.adj_edges[aeid] as usize;
                // Entering sub-faces from a main face: switch to the secondary sub-face.
                // (As in the reference, this reads the face just left, `af`.)
                if af.subface && !prev_was_subface {
                    aeid = (aeid + 3) % 4;
                    afid = af.adj_faces[aeid];
                    aeid = (af.adj_edges[aeid] as usize + 3) % 4;
                }
                prev_was_subface = af.subface;
            }
        }
    }
    true
}
