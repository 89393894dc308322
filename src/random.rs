//! Counter-based random streams. Every random choice of synthesis and of the measures is a
//! pure function of the seed and of what is drawn (a texel, a patch, a draw number), never
//! of a generator's state shared between threads, so parallel schedules cannot change a
//! result (same inputs and seed ⇒ the same bits for any thread count).

/// The golden-ratio increment of SplitMix64.
const GOLDEN: u64 = 0x9E37_79B9_7F4A_7C15;

/// SplitMix64's output function applied to `z + GOLDEN` (Steele, Lea & Flood 2014): a good
/// 64-bit mix, the step every stream below is made of.
#[inline]
pub fn mix(z: u64) -> u64 {
    let mut z = z.wrapping_add(GOLDEN);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A hash of `seed` and `parts`, [`mix`] chained over them: the random number of one
/// draw named by its parts.
#[inline]
pub fn hash(seed: u64, parts: &[u64]) -> u64 {
    let mut h = mix(seed);
    for &p in parts {
        h = mix(h ^ p);
    }
    h
}

/// Two uniform numbers in [0, 1) (24 bits each) for draw `k` of texel `t`.
#[inline]
pub fn random2(seed: u64, t: u64, k: u64) -> (f32, f32) {
    let h = hash(seed, &[t, k.wrapping_mul(0xD1B5_4A32_D192_ED03)]);
    let a = (h >> 40) as f32 / (1u64 << 24) as f32;
    let b = ((h >> 8) & 0xFF_FFFF) as f32 / (1u64 << 24) as f32;
    (a, b)
}

/// Sequential SplitMix64: the next number of the stream whose state is `state` (for
/// sampling in one thread, where a stream is simpler than naming every draw).
#[inline]
pub fn splitmix(state: &mut u64) -> u64 {
    let z = mix(*state);
    *state = state.wrapping_add(GOLDEN);
    z
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The streams keep the values they had where they were defined before (coherent's
    /// `random2`, the search's `hash`, the measure's `splitmix`): outputs depend on them.
    #[test]
    fn streams_keep_their_values() {
        assert_eq!(mix(0), 0xE220_A839_7B1D_CDAF);
        let mut s = 0u64;
        assert_eq!(splitmix(&mut s), 0xE220_A839_7B1D_CDAF);
        assert_eq!(splitmix(&mut s), 0x6E78_9E6A_A1B9_65F4);
        assert_eq!(hash(1, &[]), mix(1));
        assert_eq!(hash(1, &[2, 3]), mix(mix(mix(1) ^ 2) ^ 3));
        let (a, b) = random2(7, 3, 1);
        let h = mix(mix(mix(7) ^ 3) ^ 0xD1B5_4A32_D192_ED03);
        assert_eq!(a, (h >> 40) as f32 / (1u64 << 24) as f32);
        assert_eq!(b, ((h >> 8) & 0xFF_FFFF) as f32 / (1u64 << 24) as f32);
    }

    #[test]
    fn random2_is_uniform_and_counter_based() {
        let n = 20_000;
        let mut sum = [0.0f64; 2];
        for t in 0..n {
            let (a, b) = random2(7, t, 0);
            assert!((0.0..1.0).contains(&a) && (0.0..1.0).contains(&b));
            sum[0] += a as f64;
            sum[1] += b as f64;
        }
        assert!((sum[0] / n as f64 - 0.5).abs() < 0.01);
        assert!((sum[1] / n as f64 - 0.5).abs() < 0.01);
        assert_eq!(random2(7, 3, 1), random2(7, 3, 1));
        assert_ne!(random2(7, 3, 1), random2(8, 3, 1));
        assert_ne!(random2(7, 3, 1), random2(7, 3, 2));
    }
}
