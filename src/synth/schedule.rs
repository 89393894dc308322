//! The order domains are synthesized in, and how it is run in parallel without changing
//! the result.
//!
//! **Order** (Ying et al. 2001, §4: "our synthesis methods iterate over the surface texture
//! maps in breadth-first order"): breadth-first layers over edge adjacency, starting at
//! domain 0 (and at the lowest unvisited domain of every further connected component, whose
//! layers are merged with the first component's by depth). Inside a layer, domains are
//! greedily coloured so that no two of one colour *conflict* (one lists texels of the other
//! as neighbours, [`crate::texels::TexelGraph::domain_conflicts`]); the sequential order is
//! layer by layer, colour by colour, discovery order inside a colour.
//! [`Schedule::plan_weighted`] is the coherent synthesizer's default instead: a flood by
//! surface area, so that small, densely sampled domains do not become the place where
//! fronts meet (docs/coherent.md, "Domain order").
//!
//! **Waves**: a domain only reads texels of the domains it conflicts with. So a domain can
//! start as soon as every *earlier* conflicting domain is finished, and running the
//! schedule as waves with `wave(d) = 1 + max(wave(c))` over earlier conflicting c gives
//! exactly what the sequential order gives: every domain sees its earlier conflicting
//! domains finished and its later ones untouched, whatever the number of threads. Domains
//! of one wave never conflict, so they run in parallel; results are written back between
//! waves. Colouring inside a layer is what keeps the waves few: a breadth-first layer is a
//! ring, and a plain sequential order would chain every domain of the ring to its
//! predecessor.

/// Waves of domains; all domains of one wave can be synthesized at the same time.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Schedule {
    /// Domains per wave, in sequential order inside a wave.
    pub waves: Vec<Vec<u32>>,
    /// The sequential order (all domains).
    pub order: Vec<u32>,
    /// Number of breadth-first layers (over all components).
    pub layers: usize,
}

/// The shape of a schedule (reported).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
pub struct ScheduleInfo {
    /// Breadth-first layers.
    pub layers: usize,
    /// Parallel waves.
    pub waves: usize,
}

impl Schedule {
    /// Its shape, for reports.
    pub fn info(&self) -> ScheduleInfo {
        ScheduleInfo {
            layers: self.layers,
            waves: self.waves.len(),
        }
    }

    /// Plans the schedule from edge adjacency (for the breadth-first layers) and the
    /// symmetric conflict relation (for colouring and waves). Both are per-domain sorted
    /// lists.
    pub fn plan(edge_adjacency: &[Vec<u32>], conflicts: &[Vec<u32>]) -> Self {
        let nd = edge_adjacency.len();
        assert_eq!(conflicts.len(), nd);
        // Breadth-first layers, components merged by depth.
        let mut depth = vec![u32::MAX; nd];
        let mut by_layer: Vec<Vec<u32>> = Vec::new();
        let mut queue = std::collections::VecDeque::new();
        for root in 0..nd {
            if depth[root] != u32::MAX {
                continue;
            }
            depth[root] = 0;
            queue.push_back(root as u32);
            while let Some(d) = queue.pop_front() {
                let k = depth[d as usize] as usize;
                if by_layer.len() <= k {
                    by_layer.resize(k + 1, Vec::new());
                }
                by_layer[k].push(d);
                for &e in &edge_adjacency[d as usize] {
                    if depth[e as usize] == u32::MAX {
                        depth[e as usize] = depth[d as usize] + 1;
                        queue.push_back(e);
                    }
                }
            }
        }
        // Greedy colouring inside each layer, then the sequential order.
        let mut colour = vec![u32::MAX; nd];
        let mut order = Vec::with_capacity(nd);
        for layer in &by_layer {
            let mut classes: Vec<Vec<u32>> = Vec::new();
            for &d in layer {
                let used: Vec<u32> = conflicts[d as usize]
                    .iter()
                    .filter(|&&e| depth[e as usize] == depth[d as usize])
                    .map(|&e| colour[e as usize])
                    .filter(|&c| c != u32::MAX)
                    .collect();
                let c = (0..).find(|c| !used.contains(c)).expect("unbounded range");
                colour[d as usize] = c;
                if classes.len() <= c as usize {
                    classes.resize(c as usize + 1, Vec::new());
                }
                classes[c as usize].push(d);
            }
            for class in classes {
                order.extend(class);
            }
        }
        // As-early-as-possible waves for that order.
        let waves = waves_for(&order, conflicts);
        Self {
            waves,
            order,
            layers: by_layer.len(),
        }
    }
}

impl Schedule {
    /// The order by *surface area* instead of by domain count: a Dijkstra flood over
    /// `adjacency` where entering domain d costs `cost[d]` (its area), starting in every
    /// connected component at its cheapest domain (lowest index on ties), with the
    /// as-early-as-possible waves of [`Schedule::plan`] for that order (so the result is
    /// still exactly the sequential one for any number of threads).
    ///
    /// Why: where two independently grown patches meet there is a junction, and a junction
    /// shows (and weighs in the seam measure) in proportion to how densely it is sampled.
    /// Breadth-first over domains advances one domain per step whatever its size, so a
    /// cluster of small, densely sampled domains (an n-gon's sub-faces, small faces at an
    /// extraordinary vertex) is reached by several fronts at once and becomes their
    /// meeting place. Advancing by area, the first front to touch a small cluster crosses
    /// it at once, and fronts meet in large, coarsely sampled domains.
    ///
    /// `layers` is the depth (in domains) of the flood's tree.
    pub fn plan_weighted(adjacency: &[Vec<u32>], conflicts: &[Vec<u32>], cost: &[f64]) -> Self {
        use std::cmp::{Ordering, Reverse};
        use std::collections::BinaryHeap;
        let nd = adjacency.len();
        assert_eq!(conflicts.len(), nd);
        assert_eq!(cost.len(), nd);
        /// Heap key: distance, then domain index (a total order, so the flood is
        /// deterministic on ties).
        #[derive(PartialEq)]
        struct Key(f64, u32);
        impl Eq for Key {}
        impl PartialOrd for Key {
            fn partial_cmp(&self, o: &Self) -> Option<Ordering> {
                Some(self.cmp(o))
            }
        }
        impl Ord for Key {
            fn cmp(&self, o: &Self) -> Ordering {
                self.0.total_cmp(&o.0).then(self.1.cmp(&o.1))
            }
        }
        let mut roots: Vec<usize> = (0..nd).collect();
        roots.sort_by(|&a, &b| cost[a].total_cmp(&cost[b]).then(a.cmp(&b)));
        let mut dist = vec![f64::INFINITY; nd];
        let mut depth = vec![0u32; nd];
        let mut done = vec![false; nd];
        let mut order = Vec::with_capacity(nd);
        let mut heap = BinaryHeap::new();
        for root in roots {
            if done[root] {
                continue;
            }
            dist[root] = 0.0;
            heap.push(Reverse(Key(0.0, root as u32)));
            while let Some(Reverse(Key(dd, d))) = heap.pop() {
                let d = d as usize;
                if done[d] {
                    continue;
                }
                done[d] = true;
                order.push(d as u32);
                for &e in &adjacency[d] {
                    let e = e as usize;
                    let de = dd + cost[e];
                    if !done[e] && de < dist[e] {
                        dist[e] = de;
                        depth[e] = depth[d] + 1;
                        heap.push(Reverse(Key(de, e as u32)));
                    }
                }
            }
        }
        let layers = depth.iter().max().map_or(0, |&m| m as usize + 1);
        let waves = waves_for(&order, conflicts);
        Self {
            waves,
            order,
            layers,
        }
    }
}

/// As-early-as-possible waves for a sequential `order`: wave(d) = 1 + max wave of the
/// earlier domains d conflicts with.
fn waves_for(order: &[u32], conflicts: &[Vec<u32>]) -> Vec<Vec<u32>> {
    let nd = conflicts.len();
    let mut rank = vec![0u32; nd];
    for (i, &d) in order.iter().enumerate() {
        rank[d as usize] = i as u32;
    }
    let mut wave = vec![0u32; nd];
    let mut waves: Vec<Vec<u32>> = Vec::new();
    for &d in order {
        let w = conflicts[d as usize]
            .iter()
            .filter(|&&e| rank[e as usize] < rank[d as usize])
            .map(|&e| wave[e as usize] + 1)
            .max()
            .unwrap_or(0);
        wave[d as usize] = w;
        if waves.len() <= w as usize {
            waves.resize(w as usize + 1, Vec::new());
        }
        waves[w as usize].push(d);
    }
    waves
}

/// A domain's texels (local indices, rows of `nu`) by 4-neighbour grid distance from its
/// border texels for which `touches(x, y)` holds — those next to texels already
/// synthesized in other domains — scan-line order within one distance; `None` when no
/// border texel touches. Grown this way, a domain continues its finished neighbours'
/// patches across the shared edges instead of growing its own from a corner and meeting
/// theirs along every edge (coherent synthesis, docs/coherent.md; multiscale's finest
/// level, docs/multiscale.md).
pub fn inward_order(
    nu: usize,
    nv: usize,
    mut touches: impl FnMut(usize, usize) -> bool,
) -> Option<Vec<u32>> {
    let nn = nu * nv;
    let mut dist = vec![u32::MAX; nn];
    let mut queue = std::collections::VecDeque::new();
    for y in 0..nv {
        for x in 0..nu {
            if (x == 0 || y == 0 || x + 1 == nu || y + 1 == nv) && touches(x, y) {
                dist[y * nu + x] = 0;
                queue.push_back(y * nu + x);
            }
        }
    }
    if queue.is_empty() {
        return None;
    }
    let mut max = 0;
    while let Some(i) = queue.pop_front() {
        let (x, y) = (i % nu, i / nu);
        let dn = dist[i] + 1;
        let mut visit = |j: usize| {
            if dist[j] == u32::MAX {
                dist[j] = dn;
                max = max.max(dn);
                queue.push_back(j);
            }
        };
        if x > 0 {
            visit(i - 1);
        }
        if x + 1 < nu {
            visit(i + 1);
        }
        if y > 0 {
            visit(i - nu);
        }
        if y + 1 < nv {
            visit(i + nu);
        }
    }
    // Counting sort by distance keeps scan-line order inside a front.
    let mut start = vec![0u32; max as usize + 2];
    for &k in &dist {
        start[k as usize + 1] += 1;
    }
    for k in 1..start.len() {
        start[k] += start[k - 1];
    }
    let mut order = vec![0u32; nn];
    for (i, &k) in dist.iter().enumerate() {
        order[start[k as usize] as usize] = i as u32;
        start[k as usize] += 1;
    }
    Some(order)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A ring of `n` domains, each conflicting with its two neighbours.
    fn ring(n: u32) -> Vec<Vec<u32>> {
        (0..n)
            .map(|i| {
                let mut v = vec![(i + 1) % n, (i + n - 1) % n];
                v.sort_unstable();
                v
            })
            .collect()
    }

    #[test]
    fn waves_never_hold_conflicting_domains_and_respect_the_order() {
        let adj = ring(12);
        let s = Schedule::plan(&adj, &adj);
        let mut seen: Vec<u32> = s.waves.concat();
        seen.sort_unstable();
        assert_eq!(seen, (0..12).collect::<Vec<_>>());
        let mut wave_of = [0usize; 12];
        for (w, ds) in s.waves.iter().enumerate() {
            for &d in ds {
                wave_of[d as usize] = w;
            }
        }
        let rank: Vec<usize> = (0..12)
            .map(|d| s.order.iter().position(|&x| x == d).unwrap())
            .collect();
        for d in 0..12 {
            for &e in &adj[d] {
                let e = e as usize;
                assert_ne!(wave_of[d], wave_of[e]);
                // Earlier in the sequential order => earlier wave.
                assert_eq!(rank[d] < rank[e], wave_of[d] < wave_of[e]);
            }
        }
        // Breadth-first from 0: 0 first; layers of the ring: {0}, {1,11}, ..., {6}.
        assert_eq!(s.order[0], 0);
        assert_eq!(s.layers, 7);
        // Colouring keeps the wave count at the number of layers (1 and 11 do not
        // conflict, so each layer is one colour), not the number of domains.
        assert_eq!(s.waves.len(), 7);
    }

    #[test]
    fn separate_components_start_at_their_lowest_domain_together() {
        // Two disjoint rings 0..5 and 5..10.
        let mut adj = ring(5);
        adj.extend(
            ring(5)
                .into_iter()
                .map(|v| v.into_iter().map(|e| e + 5).collect()),
        );
        let s = Schedule::plan(&adj, &adj);
        assert_eq!(s.waves[0], vec![0, 5]);
        assert_eq!(s.layers, 3);
    }

    #[test]
    fn weighted_flood_crosses_a_cheap_cluster_before_fronts_meet_there() {
        // A ring of 8 (each domain conflicting with its two neighbours), all of cost 1
        // except the root 0 and a cheap pair {3, 4}. Breadth-first, 4 is the last domain,
        // reached by the fronts through 3 and 5 at once; by area, the front through 3
        // crosses the pair before 5 is done.
        let adj = ring(8);
        let mut cost = vec![1.0; 8];
        cost[0] = 0.001;
        cost[3] = 0.01;
        cost[4] = 0.01;
        let bfs = Schedule::plan(&adj, &adj);
        assert_eq!(*bfs.order.last().unwrap(), 4);
        let s = Schedule::plan_weighted(&adj, &adj, &cost);
        assert_eq!(s.order[0], 0);
        let pos = |d: u32| s.order.iter().position(|&x| x == d).unwrap();
        assert!(pos(3) < pos(4) && pos(4) < pos(5));
        // Waves: every domain once, conflicting domains in different waves, earlier in
        // the order => earlier wave.
        let mut seen: Vec<u32> = s.waves.concat();
        seen.sort_unstable();
        assert_eq!(seen, (0..8).collect::<Vec<_>>());
        let mut wave_of = [0usize; 8];
        for (w, ds) in s.waves.iter().enumerate() {
            for &d in ds {
                wave_of[d as usize] = w;
            }
        }
        for d in 0..8u32 {
            for &e in &adj[d as usize] {
                assert_eq!(pos(d) < pos(e), wave_of[d as usize] < wave_of[e as usize]);
            }
        }
        // Unit costs: the breadth-first layers again, from the lowest domain.
        let u = Schedule::plan_weighted(&adj, &adj, &[1.0; 8]);
        assert_eq!(u.order[0], 0);
        assert_eq!(u.layers, 5);
        // Every component starts at its cheapest domain.
        let mut two = ring(4);
        two.extend(
            ring(4)
                .into_iter()
                .map(|v| v.into_iter().map(|e| e + 4).collect()),
        );
        let s = Schedule::plan_weighted(&two, &two, &[1.0, 1.0, 0.5, 1.0, 1.0, 0.2, 1.0, 1.0]);
        assert_eq!(s.waves[0], vec![5, 2]);
    }

    #[test]
    fn inward_order_grows_from_the_touching_border_in_scan_order() {
        // 3x2, the left column touches: distance 0, 1, 2 by column, rows inside each.
        assert_eq!(
            inward_order(3, 2, |x, _| x == 0),
            Some(vec![0, 3, 1, 4, 2, 5])
        );
        assert_eq!(inward_order(3, 2, |_, _| false), None);
    }
}
