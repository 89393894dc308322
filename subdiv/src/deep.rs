//! Per-thread cache of the patch-tree levels below the stored depth.
//!
//! A point of a base quad deeper than `SurfaceOptions::max_depth` next to an extraordinary
//! vertex lies under a `Deep` node of the stored tree. Its value needs the 1-ring submesh of
//! the Deep node's quad (refined from the base mesh along the descent path) and then one
//! refinement per further level until the point's quad is regular. Geodesics integrated
//! next to an extraordinary vertex evaluate there thousands of times per pattern, always
//! under the same few Deep nodes, so the refinements are kept here: per Deep node, a small
//! tree of the levels below it, grown on demand (the four children of a refined quad at
//! once), each node either the bicubic patch of a regular quad or the submesh of an
//! irregular one.
//!
//! Every cached value is computed by exactly the operations the uncached evaluation
//! performs (`extract_submesh`, `refine`, `BSplinePatch::gather`, in the same order on the
//! same inputs), so results are bit-identical whether or not a value came from the cache,
//! whatever the thread count and call order. The cache is per thread (no locks) and
//! bounded: when it holds more than [`CAPACITY`] nodes it is emptied.

use crate::ids::FaceId;
use crate::patch::BSplinePatch;
use crate::refine::refine;
use crate::topology::PolyMesh;
use std::cell::RefCell;
use std::collections::HashMap;
use std::sync::atomic::{AtomicU64, Ordering};

/// Most nodes kept per thread (a patch is ~0.4 KB, a submesh 1–3 KB: ≤ ~2 MB per thread).
pub(crate) const CAPACITY: usize = 1536;

/// Absent child.
const NO_CHILD: u32 = u32::MAX;

/// Identifies one built surface in the caches. A clone gets a fresh id (its public fields
/// may be changed independently of the original).
#[derive(Debug)]
pub(crate) struct CacheId(pub(crate) u64);

impl CacheId {
    pub(crate) fn fresh() -> Self {
        static NEXT: AtomicU64 = AtomicU64::new(0);
        CacheId(NEXT.fetch_add(1, Ordering::Relaxed))
    }
}

impl Clone for CacheId {
    fn clone(&self) -> Self {
        Self::fresh()
    }
}

/// One quad below a Deep node (node 0 of a [`DeepTree`] is the Deep node's own quad).
pub(crate) enum DeepNode {
    /// All four corners regular: the quad's bicubic patch.
    Patch(BSplinePatch),
    /// Otherwise: its 1-ring submesh (face 0 is the quad) and its children once refined.
    Mesh { m: PolyMesh, children: [u32; 4] },
}

impl DeepNode {
    /// What the uncached evaluation does with submesh `m` first: a regular quad whose patch
    /// can be gathered is evaluated as that patch.
    pub(crate) fn classify(m: PolyMesh) -> Self {
        let q = FaceId(0);
        if crate::submesh::is_regular_quad(&m, q) {
            if let Some(p) = BSplinePatch::gather(&m, q) {
                return DeepNode::Patch(p);
            }
        }
        DeepNode::Mesh {
            m,
            children: [NO_CHILD; 4],
        }
    }
}

/// The levels below one Deep node built so far.
pub(crate) struct DeepTree {
    pub(crate) nodes: Vec<DeepNode>,
}

impl DeepTree {
    /// Index of child `c` of node `i` (a `Mesh` node), refining node `i` if needed.
    /// Returns the index and the number of nodes added.
    pub(crate) fn child(&mut self, i: usize, c: usize) -> (usize, usize) {
        let DeepNode::Mesh { m, children } = &self.nodes[i] else {
            unreachable!("only submesh nodes have children")
        };
        if children[c] != NO_CHILD {
            return (children[c] as usize, 0);
        }
        let r = refine(m);
        let first = self.nodes.len() as u32;
        let kids = [0, 1, 2, 3]
            .map(|k| DeepNode::classify(crate::submesh::extract_submesh(&r, FaceId::from_idx(k))));
        if let DeepNode::Mesh { children, .. } = &mut self.nodes[i] {
            *children = [first, first + 1, first + 2, first + 3];
        }
        self.nodes.extend(kids);
        (first as usize + c, 4)
    }
}

/// The per-thread cache: Deep trees by (surface, Deep node index).
#[derive(Default)]
pub(crate) struct DeepCache {
    pub(crate) trees: HashMap<(u64, u32), DeepTree>,
    pub(crate) nodes: usize,
}

thread_local! {
    pub(crate) static DEEP_CACHE: RefCell<DeepCache> = RefCell::new(DeepCache::default());
}
