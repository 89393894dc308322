//! Scratch buffers that live as long as a run, one per worker thread.
//!
//! The patch methods keep per-patch scratch state (a [`super::texel_table::TexelTable`]
//! of the patch's texels, heaps, cut graphs); allocating it per rayon task would cost
//! more than the work itself (`map_init` creates one per split). Each worker thread
//! instead borrows its own slot. Results never depend on which slot a task got: scratch
//! contents are reset before use.

use std::sync::Mutex;

/// One `T` per rayon worker thread of the current pool (plus one for callers outside it),
/// created on first use by `make`.
pub struct PerThread<T> {
    slots: Vec<Mutex<Option<T>>>,
}

impl<T> PerThread<T> {
    /// Slots for the current rayon pool.
    pub fn new() -> Self {
        let n = rayon::current_num_threads() + 1;
        Self {
            slots: (0..n).map(|_| Mutex::new(None)).collect(),
        }
    }

    /// Runs `f` with this thread's `T` (made by `make` the first time).
    pub fn with<R>(&self, make: impl FnOnce() -> T, f: impl FnOnce(&mut T) -> R) -> R {
        let i = rayon::current_thread_index()
            .map(|i| i.min(self.slots.len() - 2))
            .unwrap_or(self.slots.len() - 1);
        let mut slot = self.slots[i].lock().unwrap_or_else(|e| e.into_inner());
        f(slot.get_or_insert_with(make))
    }
}

impl<T> Default for PerThread<T> {
    fn default() -> Self {
        Self::new()
    }
}
