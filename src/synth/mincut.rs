//! Minimum s–t cuts on small graphs (Dinic's max-flow), for joining overlapping patches
//! along the seam of least visible error (Kwatra et al. 2003, "Graphcut textures"; the
//! "minimum-error cut" of Efros & Freeman 2001 generalised from a path in a strip to an
//! arbitrary overlap region of the surface).
//!
//! Graphs here have a few hundred to a few thousand nodes with ~8 edges each (the overlap
//! of one patch), so a plain Dinic with BFS levels and DFS blocking flows is fast and has
//! no pathological cases at this size. Everything is deterministic: edges are visited in
//! insertion order.

/// An undirected capacitated graph with two terminals.
#[derive(Clone, Debug, Default)]
pub struct CutGraph {
    /// Per node: first edge index (adjacency as singly linked lists).
    head: Vec<u32>,
    /// Per edge: target node, next edge of the same source, residual capacity.
    to: Vec<u32>,
    next: Vec<u32>,
    cap: Vec<f32>,
    level: Vec<i32>,
    iter: Vec<u32>,
    queue: Vec<u32>,
}

const NONE: u32 = u32::MAX;

impl CutGraph {
    /// Clears the graph to `nodes` ordinary nodes plus the terminals
    /// [`CutGraph::source`] and [`CutGraph::sink`].
    pub fn reset(&mut self, nodes: usize) {
        self.head.clear();
        self.head.resize(nodes + 2, NONE);
        self.to.clear();
        self.next.clear();
        self.cap.clear();
    }

    /// The source terminal's index ("keeps the old texture").
    pub fn source(&self) -> usize {
        self.head.len() - 2
    }

    /// The sink terminal's index ("takes the new patch").
    pub fn sink(&self) -> usize {
        self.head.len() - 1
    }

    fn arc(&mut self, a: usize, b: usize, c: f32) {
        self.to.push(b as u32);
        self.next.push(self.head[a]);
        self.cap.push(c);
        self.head[a] = (self.to.len() - 1) as u32;
    }

    /// An undirected edge of capacity `c` between `a` and `b` (both directions `c`).
    pub fn edge(&mut self, a: usize, b: usize, c: f32) {
        self.arc(a, b, c);
        self.arc(b, a, c);
    }

    /// Ties `a` to a terminal with infinite capacity.
    pub fn tie(&mut self, a: usize, to_source: bool) {
        let t = if to_source {
            self.source()
        } else {
            self.sink()
        };
        self.edge(a, t, f32::INFINITY);
    }

    fn bfs(&mut self) -> bool {
        let (s, t) = (self.source(), self.sink());
        self.level.clear();
        self.level.resize(self.head.len(), -1);
        self.queue.clear();
        self.level[s] = 0;
        self.queue.push(s as u32);
        let mut i = 0;
        while i < self.queue.len() {
            let a = self.queue[i] as usize;
            i += 1;
            let mut e = self.head[a];
            while e != NONE {
                let b = self.to[e as usize] as usize;
                if self.cap[e as usize] > 0.0 && self.level[b] < 0 {
                    self.level[b] = self.level[a] + 1;
                    self.queue.push(b as u32);
                }
                e = self.next[e as usize];
            }
        }
        self.level[t] >= 0
    }

    /// Pushes flow along one augmenting path of the level graph (iterative DFS).
    fn augment(&mut self) -> f32 {
        let (s, t) = (self.source(), self.sink());
        let mut path: Vec<u32> = Vec::new(); // edges
        let mut a = s;
        loop {
            if a == t {
                let f = path
                    .iter()
                    .map(|&e| self.cap[e as usize])
                    .fold(f32::INFINITY, f32::min);
                for &e in &path {
                    self.cap[e as usize] -= f;
                    self.cap[(e ^ 1) as usize] += f;
                }
                return f;
            }
            let mut advanced = false;
            while self.iter[a] != NONE {
                let e = self.iter[a] as usize;
                let b = self.to[e] as usize;
                if self.cap[e] > 0.0 && self.level[b] == self.level[a] + 1 {
                    path.push(e as u32);
                    a = b;
                    advanced = true;
                    break;
                }
                self.iter[a] = self.next[e];
            }
            if !advanced {
                // Dead end: retreat and skip the edge that led here.
                self.level[a] = -1;
                match path.pop() {
                    None => return 0.0,
                    Some(e) => {
                        a = self.to[(e ^ 1) as usize] as usize;
                        self.iter[a] = self.next[self.iter[a] as usize];
                    }
                }
            }
        }
    }

    /// Computes a minimum cut; returns for every ordinary node whether it stays on the
    /// source side (reachable from the source in the residual graph).
    pub fn solve(&mut self, source_side: &mut Vec<bool>) {
        let nodes = self.head.len() - 2;
        // Infinite ties between the terminals through one node would never saturate.
        let mut guard = 0;
        while self.bfs() {
            self.iter.clear();
            self.iter.extend_from_slice(&self.head);
            loop {
                let f = self.augment();
                if f <= 0.0 || f.is_infinite() {
                    break;
                }
            }
            guard += 1;
            if guard > 4 * nodes + 16 {
                break;
            }
        }
        // Residual reachability from the source (the last BFS left `level` for exactly that).
        self.bfs();
        source_side.clear();
        source_side.extend((0..nodes).map(|a| self.level[a] >= 0));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A path s - 0 - 1 - 2 - 3 - t with one weak link: the cut is there.
    #[test]
    fn cuts_the_weakest_link() {
        let mut g = CutGraph::default();
        g.reset(4);
        g.tie(0, true);
        g.tie(3, false);
        g.edge(0, 1, 5.0);
        g.edge(1, 2, 0.5);
        g.edge(2, 3, 4.0);
        let mut side = Vec::new();
        g.solve(&mut side);
        assert_eq!(side, vec![true, true, false, false]);
    }

    /// A 4x4 grid with the left column tied to the source, the right one to the sink, and
    /// cheap vertical... the cut follows the cheap column boundary between x = 1 and 2.
    #[test]
    fn grid_cut_follows_cheap_edges() {
        let (w, h) = (4usize, 4usize);
        let mut g = CutGraph::default();
        g.reset(w * h);
        for y in 0..h {
            g.tie(y * w, true);
            g.tie(y * w + w - 1, false);
            for x in 0..w - 1 {
                let c = if x == 1 { 0.1 } else { 10.0 };
                g.edge(y * w + x, y * w + x + 1, c);
            }
        }
        for y in 0..h - 1 {
            for x in 0..w {
                g.edge(y * w + x, (y + 1) * w + x, 1.0);
            }
        }
        let mut side = Vec::new();
        g.solve(&mut side);
        for y in 0..h {
            for x in 0..w {
                assert_eq!(side[y * w + x], x <= 1, "({x},{y})");
            }
        }
    }
}
