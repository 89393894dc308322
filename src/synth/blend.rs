//! Texture blending across breaks (paper 002 §4.4): extra source positions for some
//! texels, each with its share of the texel's value, that [`super::face_maps_blended`]
//! mixes into the value looked up at the texel's own source.
//!
//! A method gives every texel one source position; where two neighbouring texels' sources
//! do not continue each other (a jump, two growth fronts meeting) the texture breaks
//! sharply between them. 002 draws each triangle once per corner's texture coordinates,
//! alpha-ramped ("highest quality results"); its image method copies "each pixel with a
//! small blend kernel". The texel analogue: a texel's value is the kernel-weighted mean of
//! the example at the positions its neighbours' sources continue to (s proposes
//! source_s + d(s→t)), its own source weighing most. Only proposals that disagree with the
//! texel's own source are stored — inside a continued copy a texel has none and keeps its
//! looked-up value exactly — so the description costs memory in proportion to the breaks,
//! not to the texels.
//!
//! Every output channel (colour, alpha, height, maps) is mixed with the same shares;
//! `source.u/v` stays the texel's own source.

use std::ops::Range;

/// Extra sources of some texels, sorted by texel (global texel order).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Blend {
    /// (texel, extra source position in example pixels (centres at +0.5), its share of the
    /// texel's value), ascending by texel; the texel's own source keeps 1 − the sum of its
    /// entries' shares. 16 B an entry, sorted in place: no second copy is made.
    entries: Vec<(u32, [f32; 2], f32)>,
}

impl Blend {
    /// From entries (texel, position, share) in any order, sorted in place by texel, then
    /// by position and share (a total order on the contents, so the order — and the sum
    /// over a texel's entries — does not depend on the thread count).
    pub fn from_entries(mut entries: Vec<(u32, [f32; 2], f32)>) -> Self {
        use rayon::prelude::*;
        entries
            .par_sort_unstable_by_key(|e| (e.0, e.1[0].to_bits(), e.1[1].to_bits(), e.2.to_bits()));
        Blend { entries }
    }

    /// Number of entries (extra sources).
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether no texel has an extra source.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// Number of texels with at least one extra source.
    pub fn texels(&self) -> usize {
        self.entries.windows(2).filter(|w| w[0].0 != w[1].0).count() + !self.is_empty() as usize
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        std::mem::size_of_val(self.entries.as_slice())
    }

    /// The entries of the texels in `texels`.
    pub fn range(&self, texels: Range<usize>) -> Range<usize> {
        let lo = self
            .entries
            .partition_point(|e| (e.0 as usize) < texels.start);
        let hi = self
            .entries
            .partition_point(|e| (e.0 as usize) < texels.end);
        lo..hi
    }

    /// Entry `i`: (texel, position, share).
    pub fn entry(&self, i: usize) -> (usize, [f32; 2], f32) {
        let e = self.entries[i];
        (e.0 as usize, e.1, e.2)
    }

    /// Mirrors every position's v in an example `height` pixels high (p.v → height − p.v),
    /// as the synthesizer mirrors the sources for `--handedness tiles`. The order stays
    /// one the thread count does not change (by texel, then as it was).
    pub fn flip_v(&mut self, height: f32) {
        for e in &mut self.entries {
            e.1[1] = height - e.1[1];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_are_sorted_by_texel_then_by_position() {
        let b = Blend::from_entries(vec![
            (5, [3.0, 3.0], 0.3),
            (2, [2.0, 2.0], 0.2),
            (5, [1.0, 1.0], 0.1),
            (9, [4.0, 4.0], 0.4),
        ]);
        assert_eq!(b.len(), 4);
        assert_eq!(b.texels(), 3);
        assert_eq!(b.entry(0), (2, [2.0, 2.0], 0.2));
        assert_eq!(b.entry(1), (5, [1.0, 1.0], 0.1));
        assert_eq!(b.entry(2), (5, [3.0, 3.0], 0.3));
        assert_eq!(b.bytes(), 4 * 16);
        assert_eq!(b.range(0..5), 0..1);
        assert_eq!(b.range(5..6), 1..3);
        assert_eq!(b.range(6..9), 3..3);
        assert_eq!(b.range(0..100), 0..4);
        let mut f = b.clone();
        f.flip_v(10.0);
        assert_eq!(f.entry(0).1, [2.0, 8.0]);
        assert_eq!(Blend::default().texels(), 0);
    }
}
