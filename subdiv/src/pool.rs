//! Per-thread reuse of the buffers of the small meshes the patch trees build and drop by
//! the hundred thousand (a submesh and its refinement per split): taking a vector here
//! instead of from the allocator, and giving it back when the mesh is done with
//! ([`crate::topology::PolyMesh::recycle`]), saves most of the allocation and freeing
//! that was a fifth of building the trees of an all-triangle mesh. Contents are never
//! reused, only capacity: a vector comes back empty.

use glam::DVec3;
use std::cell::RefCell;

/// Vectors kept per kind and thread.
const KEPT: usize = 48;
/// Larger vectors go back to the allocator (the pool is for small meshes).
const LARGEST: usize = 1 << 16;

#[derive(Default)]
struct Pool {
    ints: Vec<Vec<u32>>,
    points: Vec<Vec<DVec3>>,
    flags: Vec<Vec<bool>>,
}

thread_local! {
    static POOL: RefCell<Pool> = RefCell::default();
}

fn take<T>(capacity: usize, kind: fn(&mut Pool) -> &mut Vec<Vec<T>>) -> Vec<T> {
    let kept = POOL
        .try_with(|p| p.try_borrow_mut().ok().and_then(|mut p| kind(&mut p).pop()))
        .ok()
        .flatten();
    match kept {
        Some(mut v) => {
            v.reserve(capacity);
            v
        }
        None => Vec::with_capacity(capacity),
    }
}

fn give<T>(mut v: Vec<T>, kind: fn(&mut Pool) -> &mut Vec<Vec<T>>) {
    if v.capacity() == 0 || v.capacity() > LARGEST {
        return;
    }
    v.clear();
    let _ = POOL.try_with(|p| {
        if let Ok(mut p) = p.try_borrow_mut() {
            let list = kind(&mut p);
            if list.len() < KEPT {
                list.push(v);
            }
        }
    });
}

/// An empty vector with room for `capacity`.
pub(crate) fn ints(capacity: usize) -> Vec<u32> {
    take(capacity, |p| &mut p.ints)
}

/// `len` copies of `value`.
pub(crate) fn ints_filled(len: usize, value: u32) -> Vec<u32> {
    let mut v = ints(len);
    v.resize(len, value);
    v
}

pub(crate) fn points(capacity: usize) -> Vec<DVec3> {
    take(capacity, |p| &mut p.points)
}

pub(crate) fn flags(capacity: usize) -> Vec<bool> {
    take(capacity, |p| &mut p.flags)
}

pub(crate) fn give_ints(v: Vec<u32>) {
    give(v, |p| &mut p.ints)
}

pub(crate) fn give_points(v: Vec<DVec3>) {
    give(v, |p| &mut p.points)
}

pub(crate) fn give_flags(v: Vec<bool>) {
    give(v, |p| &mut p.flags)
}
