//! A small map from texel index to per-texel scratch state, for work that touches one
//! patch's texels at a time (a footprint's flood, a patch's minimum cut).
//!
//! Such work used to index arrays of one entry per texel of the level, one set per worker
//! thread, reset by generation stamps: 36 B per texel and thread for the floods, 8 for the
//! cuts — on two threads 74 MB at 1 M texels, and eight times that on sixteen, while one
//! patch reaches a few hundred to a few thousand texels. The table holds only those, is
//! reused by every patch of the thread and stays in the caches; memory no longer grows
//! with the thread count or the level's size. Open addressing with linear probing,
//! emptied lazily by a generation stamp (nothing is removed between two [`TexelTable::clear`]s).

/// Texel → `V`, for the texels entered since the last [`TexelTable::clear`].
pub struct TexelTable<V> {
    slots: Vec<Slot<V>>,
    gen: u32,
    len: usize,
}

#[derive(Clone, Copy)]
struct Slot<V> {
    /// The generation that wrote this slot; other slots are empty.
    stamp: u32,
    key: u32,
    value: V,
}

impl<V: Copy + Default> TexelTable<V> {
    /// An empty table (4,096 slots, doubled when half full).
    pub fn new() -> Self {
        Self {
            slots: vec![Self::empty(); 1 << 12],
            gen: 1,
            len: 0,
        }
    }

    fn empty() -> Slot<V> {
        Slot {
            stamp: 0,
            key: 0,
            value: V::default(),
        }
    }

    /// Forgets every entry.
    pub fn clear(&mut self) {
        self.gen = self.gen.wrapping_add(1);
        if self.gen == 0 {
            self.slots.iter_mut().for_each(|s| s.stamp = 0);
            self.gen = 1;
        }
        self.len = 0;
    }

    #[inline]
    fn home(&self, t: u32) -> usize {
        // Fibonacci hashing: a patch's texels are runs of nearby indices, which the
        // multiplication spreads over the table.
        (t.wrapping_mul(0x9E37_79B1) as usize >> 8) & (self.slots.len() - 1)
    }

    /// Texel `t`'s value, if entered.
    #[inline]
    pub fn get(&self, t: u32) -> Option<&V> {
        let mask = self.slots.len() - 1;
        let mut i = self.home(t);
        loop {
            let s = &self.slots[i];
            if s.stamp != self.gen {
                return None;
            }
            if s.key == t {
                return Some(&s.value);
            }
            i = (i + 1) & mask;
        }
    }

    /// True if texel `t` was entered.
    #[inline]
    pub fn contains(&self, t: u32) -> bool {
        self.get(t).is_some()
    }

    /// Texel `t`'s value, which must have been entered.
    #[inline]
    pub fn at(&mut self, t: u32) -> &mut V {
        let mask = self.slots.len() - 1;
        let mut i = self.home(t);
        while self.slots[i].key != t || self.slots[i].stamp != self.gen {
            assert_eq!(self.slots[i].stamp, self.gen, "texel {t} not in the table");
            i = (i + 1) & mask;
        }
        &mut self.slots[i].value
    }

    /// Texel `t`'s value, entered as `V::default()` if new; the flag says it was.
    #[inline]
    pub fn entry(&mut self, t: u32) -> (&mut V, bool) {
        if 2 * (self.len + 1) > self.slots.len() {
            self.grow();
        }
        let mask = self.slots.len() - 1;
        let mut i = self.home(t);
        loop {
            if self.slots[i].stamp != self.gen {
                self.len += 1;
                self.slots[i] = Slot {
                    stamp: self.gen,
                    key: t,
                    value: V::default(),
                };
                return (&mut self.slots[i].value, true);
            }
            if self.slots[i].key == t {
                return (&mut self.slots[i].value, false);
            }
            i = (i + 1) & mask;
        }
    }

    /// Sets texel `t`'s value.
    #[inline]
    pub fn insert(&mut self, t: u32, v: V) {
        *self.entry(t).0 = v;
    }

    /// Doubles the table, keeping the current entries.
    fn grow(&mut self) {
        let bigger = vec![Self::empty(); 2 * self.slots.len()];
        let old = std::mem::replace(&mut self.slots, bigger);
        let mask = self.slots.len() - 1;
        for s in old.into_iter().filter(|s| s.stamp == self.gen) {
            let mut i = self.home(s.key);
            while self.slots[i].stamp == self.gen {
                i = (i + 1) & mask;
            }
            self.slots[i] = s;
        }
    }
}

impl<V: Copy + Default> Default for TexelTable<V> {
    fn default() -> Self {
        Self::new()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn entries_survive_growth_and_vanish_on_clear() {
        let mut t = TexelTable::<u32>::new();
        // Enough keys to double the table several times, with runs of nearby indices.
        let keys: Vec<u32> = (0..20_000u32).map(|i| (i / 7) * 1_000 + i % 7).collect();
        for (i, &k) in keys.iter().enumerate() {
            let (v, fresh) = t.entry(k);
            assert!(fresh);
            *v = i as u32;
        }
        for (i, &k) in keys.iter().enumerate() {
            assert_eq!(t.get(k), Some(&(i as u32)));
            assert!(!t.entry(k).1, "entered twice");
        }
        assert!(!t.contains(999_999));
        *t.at(keys[5]) += 1;
        assert_eq!(t.get(keys[5]), Some(&6));
        t.clear();
        assert!(keys.iter().all(|&k| !t.contains(k)));
        t.insert(keys[3], 42);
        assert_eq!(t.get(keys[3]), Some(&42));
        assert!(!t.contains(keys[4]));
    }
}
