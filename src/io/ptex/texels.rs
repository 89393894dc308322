//! Texel arithmetic of the Ptex writer — constant test, alpha premultiplication, 2×2
//! reductions, averages — on one face's *planar* f32 data (channel-major, each channel
//! row-major with u fastest), operation for operation as `PtexUtils` does it on
//! interleaved data, so that the mip levels and constant values match what the reference
//! writer would store for the same texels.

use super::format::Res;

/// Whether every texel of the face is bit-for-bit the same (`PtexUtils::isConstant`
/// compares bytes).
pub fn is_constant(data: &[f32], npix: usize) -> bool {
    data.chunks_exact(npix)
        .all(|plane| plane.iter().all(|v| v.to_bits() == plane[0].to_bits()))
}

/// The channels `alpha` scales (`PtexUtils::multalpha`): those before the alpha channel,
/// or all after it when alpha is channel 0.
fn scaled_channels(nch: usize, alpha: usize) -> std::ops::Range<usize> {
    if alpha == 0 {
        1..nch
    } else {
        0..alpha
    }
}

/// Multiplies the colour channels by alpha, in place (reductions are made, and stored,
/// premultiplied: a transparent texel must not tint its neighbours at coarser levels).
pub fn premultiply(data: &mut [f32], npix: usize, nch: usize, alpha: usize) {
    let (before, rest) = data.split_at_mut(alpha * npix);
    let (a, after) = rest.split_at_mut(npix);
    debug_assert!(alpha < nch);
    let planes = if alpha == 0 { after } else { before };
    for plane in planes.chunks_exact_mut(npix) {
        for (c, &w) in plane.iter_mut().zip(a.iter()) {
            *c *= w;
        }
    }
}

/// One 2×2 box reduction (`PtexUtils::reduce`: `0.25 * (a + b + c + d)` summed left to
/// right) of a face of `res`.
pub fn reduce(src: &[f32], res: Res, nch: usize) -> Vec<f32> {
    let (u, v) = (res.u(), res.v());
    let (hu, hv) = (u / 2, v / 2);
    let mut dst = Vec::with_capacity(hu * hv * nch);
    for plane in src.chunks_exact(u * v).take(nch) {
        for y in 0..hv {
            let r0 = &plane[2 * y * u..(2 * y + 1) * u];
            let r1 = &plane[(2 * y + 1) * u..(2 * y + 2) * u];
            for x in 0..hu {
                dst.push(0.25 * (r0[2 * x] + r0[2 * x + 1] + r1[2 * x] + r1[2 * x + 1]));
            }
        }
    }
    dst
}

/// Per-channel mean (`PtexUtils::average`: an f32 running sum in texel order, times
/// 1/count).
pub fn average(data: &[f32], npix: usize) -> Vec<f32> {
    let scale = 1.0f32 / npix as f32;
    data.chunks_exact(npix)
        .map(|plane| plane.iter().fold(0.0f32, |s, &v| s + v) * scale)
        .collect()
}

/// Undoes [`premultiply`] on one pixel (`PtexUtils::divalpha`; alpha 0 is left alone).
pub fn divide_alpha(px: &mut [f32], alpha: usize) {
    let a = px[alpha];
    if a == 0.0 {
        return;
    }
    let w = 1.0f32 / a;
    for c in scaled_channels(px.len(), alpha) {
        px[c] *= w;
    }
}

/// One pixel of planar data (the layout of a constant block and of the const-data array).
pub fn pixel(data: &[f32], npix: usize, i: usize) -> Vec<f32> {
    data.chunks_exact(npix).map(|p| p[i]).collect()
}

/// Little-endian bytes of f32 values.
/// The little-endian bytes of `data` without a copy where the machine is little-endian
/// (the file's order): a face's texels at N = 128 are ~0.3 MiB, and a copy of that size
/// per face was a fresh mapping to fault in and give back (docs/benchmarks.md, "Ptex
/// writing without fresh buffers").
pub fn le_bytes(data: &[f32]) -> std::borrow::Cow<'_, [u8]> {
    if cfg!(target_endian = "little") {
        std::borrow::Cow::Borrowed(bytemuck::cast_slice(data))
    } else {
        std::borrow::Cow::Owned(bytes(data))
    }
}

pub fn bytes(data: &[f32]) -> Vec<u8> {
    let mut out = vec![0u8; data.len() * 4];
    for (o, v) in out.chunks_exact_mut(4).zip(data) {
        o.copy_from_slice(&v.to_le_bytes());
    }
    out
}

/// The planar data of tile (tu, tv) of size `tile` of a face of `res`.
pub fn tile(data: &[f32], res: Res, tile: Res, tu: usize, tv: usize) -> Vec<f32> {
    let (u, v) = (res.u(), res.v());
    let (w, h) = (tile.u(), tile.v());
    let mut out = Vec::with_capacity(data.len() / (u * v) * w * h);
    for plane in data.chunks_exact(u * v) {
        for y in tv * h..(tv + 1) * h {
            out.extend_from_slice(&plane[y * u + tu * w..y * u + (tu + 1) * w]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn arithmetic_matches_the_reference_order() {
        // Two channels of a 4x2 face; alpha is channel 1.
        let res = Res::new(2, 1);
        let mut d = vec![
            1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 0.5, 0.5, 1.0, 1.0, 0.0, 0.0, 1.0, 1.0,
        ];
        assert!(!is_constant(&d, 8));
        premultiply(&mut d, 8, 2, 1);
        assert_eq!(&d[..8], &[0.5, 1.0, 3.0, 4.0, 0.0, 0.0, 7.0, 8.0]);
        let r = reduce(&d, res, 2);
        assert_eq!(
            r,
            vec![
                0.25 * (0.5 + 1.0 + 0.0 + 0.0),
                0.25 * (3.0 + 4.0 + 7.0 + 8.0),
                0.25,
                1.0
            ]
        );
        let mut m = average(&r, 2);
        assert_eq!(m, vec![(0.375 + 5.5) * 0.5, 0.625]);
        divide_alpha(&mut m, 1);
        assert_eq!(m[0], (0.375f32 + 5.5) * 0.5 * (1.0 / 0.625));
        assert!(is_constant(&[3.0, 3.0, 1.0, 1.0], 2));
        assert!(
            !is_constant(&[0.0, -0.0], 2),
            "constant means bit-identical"
        );
        assert_eq!(pixel(&d, 8, 2), vec![3.0, 1.0]);
        let t = tile(
            &(0..16).map(|i| i as f32).collect::<Vec<_>>(),
            Res::new(2, 2),
            Res::new(1, 1),
            1,
            1,
        );
        assert_eq!(t, vec![10.0, 11.0, 14.0, 15.0]);
    }

    #[test]
    fn alpha_first_scales_the_channels_after_it() {
        let mut d = vec![0.5, 0.25, 2.0, 4.0, 3.0, 3.0];
        premultiply(&mut d, 2, 3, 0);
        assert_eq!(d, vec![0.5, 0.25, 1.0, 1.0, 1.5, 0.75]);
        let mut px = vec![0.5, 1.0, 1.5];
        divide_alpha(&mut px, 0);
        assert_eq!(px, vec![0.5, 2.0, 3.0]);
    }
}
