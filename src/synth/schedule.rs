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

impl Schedule {
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
        let mut rank = vec![0u32; nd];
        for (i, &d) in order.iter().enumerate() {
            rank[d as usize] = i as u32;
        }
        let mut wave = vec![0u32; nd];
        let mut waves: Vec<Vec<u32>> = Vec::new();
        for &d in &order {
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
        Self {
            waves,
            order,
            layers: by_layer.len(),
        }
    }
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
}
