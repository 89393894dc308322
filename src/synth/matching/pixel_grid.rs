//! Copies that sit on the example's pixel centres.
//!
//! Every method hands the writers one continuous source position per texel, and each map
//! is the example's bilinear sample there. Where a copy's positions are off the pixel
//! centres by a common fraction, that sample is a blend of neighbouring pixels: half a
//! pixel off averages two pixels, which removes the finest detail (no response at the
//! Nyquist frequency) — sand and gravel come out visibly soft beside the example. Such
//! fractions arise without any reason in the texture: random starting positions are
//! continuous, and the coarse-to-fine step of multilevel methods maps a coarse pixel's
//! centre onto the corner between four fine pixels, so every copy continued from a coarser
//! level sits exactly half a pixel off.
//!
//! Where a copy is laid on the pixel lattice — on a flat grid whose texels are one example
//! pixel apart along the field, the usual 2D setting, every texel of a patch is a whole
//! number of pixels from its centre — moving it by that common fraction makes every texel
//! an exact pixel of the example, without changing the layout by more than half a pixel.
//! Where it is not (a curved surface: texels fall anywhere between pixels), nothing here
//! applies, and the bilinear sample is the right reconstruction.

/// Largest distance (pixels, per axis) of a texel's position from the common lattice for
/// a copy to count as laid on it. Float error of the flat grid's coordinates is ~1e-5; a
/// copy 0.05 px off after the move is blurred by 5% at most.
pub const LATTICE_TOL: f32 = 0.05;

/// The pixel centre nearest to `z` (centres at k + 0.5).
pub fn centre(z: [f32; 2]) -> [f32; 2] {
    [(z[0] - 0.5).round() + 0.5, (z[1] - 0.5).round() + 0.5]
}

/// `z` moved so that `z + l` lands on pixel centres for every offset `l` of `offsets`,
/// when those positions share one sub-pixel fraction (within [`LATTICE_TOL`]); else `z`
/// unchanged. The move is at most half a pixel per axis.
pub fn align(z: [f32; 2], offsets: &[[f32; 2]]) -> [f32; 2] {
    let Some(first) = offsets.first() else {
        return centre(z);
    };
    let mut out = z;
    for a in 0..2 {
        // Fraction of the first position from its pixel centre, in [−0.5, 0.5).
        let p0 = z[a] + first[a] - 0.5;
        let shift = p0.round() - p0;
        let on = offsets.iter().all(|l| {
            let p = z[a] + l[a] - 0.5 + shift;
            (p - p.round()).abs() <= LATTICE_TOL
        });
        if !on {
            return z;
        }
        out[a] = z[a] + shift;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn centre_is_the_nearest_pixel_centre() {
        assert_eq!(centre([3.9, 0.2]), [3.5, 0.5]);
        assert_eq!(centre([4.1, 7.49]), [4.5, 7.5]);
    }

    #[test]
    fn a_copy_on_the_lattice_moves_onto_pixel_centres() {
        let offsets: Vec<[f32; 2]> = (-3..=3)
            .flat_map(|y| (-3..=3).map(move |x| [x as f32, y as f32]))
            .collect();
        let z = align([10.2, 20.8], &offsets);
        assert_eq!(z, [10.5, 20.5]);
        for l in &offsets {
            for a in 0..2 {
                let p = z[a] + l[a] - 0.5;
                assert_eq!(p, p.round());
            }
        }
        // Half-integer offsets (a patch centred between texels) land on centres too.
        let half: Vec<[f32; 2]> = offsets.iter().map(|l| [l[0] + 0.5, l[1] - 0.5]).collect();
        let z = align([10.2, 20.8], &half);
        assert_eq!((z[0] + half[0][0]).fract(), 0.5);
    }

    #[test]
    fn a_copy_off_the_lattice_is_left_alone() {
        // A rotated copy: texels fall between pixels.
        let (c, s) = (0.3f32.cos(), 0.3f32.sin());
        let offsets: Vec<[f32; 2]> = (-3..=3)
            .flat_map(|y| (-3..=3).map(move |x| [x as f32, y as f32]))
            .map(|[x, y]| [c * x - s * y, s * x + c * y])
            .collect();
        assert_eq!(align([10.2, 20.8], &offsets), [10.2, 20.8]);
    }
}
