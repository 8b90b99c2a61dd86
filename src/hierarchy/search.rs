//! Breadth-first searches over the adjacency: the single-source search with reusable buffers
//! ([`Bfs`]), the bit-parallel one from up to 64 sources ([`MultiBfs`]), and generation-stamped
//! node marks ([`Marks`]).

use super::graph::Csr;
use alloc::vec;
use alloc::vec::Vec;

pub(super) const UNREACHED: u32 = u32::MAX;

/// Breadth-first search with reusable buffers; `queue` holds the nodes reached, so clearing costs
/// only what was visited.
pub(super) struct Bfs {
    pub(super) dist: Vec<u32>,
    pub(super) queue: Vec<u32>,
}

impl Bfs {
    pub(super) fn new(n: usize) -> Bfs {
        Bfs { dist: vec![UNREACHED; n], queue: Vec::with_capacity(n) }
    }

    /// Hop distances from `sources` to every node they reach (nodes reached by an earlier run
    /// stay as they are); returns the largest distance found by this run.
    pub(super) fn run(&mut self, adj: &Csr, sources: &[u32]) -> u32 {
        let start = self.queue.len();
        for &s in sources {
            if self.dist[s as usize] == UNREACHED {
                self.dist[s as usize] = 0;
                self.queue.push(s);
            }
        }
        let mut head = start;
        let mut far = 0;
        while head < self.queue.len() {
            let v = self.queue[head];
            head += 1;
            let d = self.dist[v as usize] + 1;
            for &w in adj.of(v) {
                if self.dist[w as usize] == UNREACHED {
                    self.dist[w as usize] = d;
                    far = d;
                    self.queue.push(w);
                }
            }
        }
        far
    }

    pub(super) fn clear(&mut self) {
        for &v in &self.queue {
            self.dist[v as usize] = UNREACHED;
        }
        self.queue.clear();
    }
}

/// Up to 64 breadth-first searches at once, one bit per source.
pub(super) struct MultiBfs {
    visited: Vec<u64>,
    front: Vec<u64>,
    next: Vec<u64>,
    list: Vec<u32>,
    next_list: Vec<u32>,
}

impl MultiBfs {
    pub(super) fn new(n: usize) -> MultiBfs {
        MultiBfs { visited: vec![0; n], front: vec![0; n], next: vec![0; n], list: Vec::new(), next_list: Vec::new() }
    }

    /// Searches from `sources` (at most 64, distinct, all in the component `nodes`) up to `depth`
    /// hops. Returns a mask with bit `k` set when `sources[k]` reaches every node within
    /// `depth`, and writes that source's eccentricity to `ecc[k]` (meaningless for unset bits).
    pub(super) fn within(&mut self, adj: &Csr, nodes: &[u32], sources: &[u32], depth: u32, ecc: &mut [u32; 64]) -> u64 {
        debug_assert!(sources.len() <= 64);
        self.list.clear();
        for (k, &s) in sources.iter().enumerate() {
            self.visited[s as usize] |= 1 << k;
            self.front[s as usize] |= 1 << k;
            self.list.push(s);
            ecc[k] = 0;
        }
        let mut level = 0;
        while level < depth && !self.list.is_empty() {
            level += 1;
            for &v in &self.list {
                let f = self.front[v as usize];
                for &w in adj.of(v) {
                    let new = f & !self.visited[w as usize];
                    if new != 0 {
                        if self.next[w as usize] == 0 {
                            self.next_list.push(w);
                        }
                        self.next[w as usize] |= new;
                    }
                }
            }
            for &v in &self.list {
                self.front[v as usize] = 0;
            }
            let mut arrived = 0u64;
            for &w in &self.next_list {
                let bits = self.next[w as usize];
                arrived |= bits;
                self.visited[w as usize] |= bits;
                self.front[w as usize] = bits;
                self.next[w as usize] = 0;
            }
            while arrived != 0 {
                ecc[arrived.trailing_zeros() as usize] = level;
                arrived &= arrived - 1;
            }
            core::mem::swap(&mut self.list, &mut self.next_list);
            self.next_list.clear();
        }
        let mut all = if sources.len() == 64 { u64::MAX } else { (1u64 << sources.len()) - 1 };
        for &w in nodes {
            all &= self.visited[w as usize];
            self.visited[w as usize] = 0;
            self.front[w as usize] = 0;
        }
        all
    }
}

/// Per-node marks stamped with a generation counter, so "is `w` marked" needs no clearing.
pub(super) struct Marks {
    stamp: Vec<u32>,
    now: u32,
}

impl Marks {
    pub(super) fn new(n: usize) -> Marks {
        Marks { stamp: vec![0; n], now: 0 }
    }

    pub(super) fn next(&mut self) {
        self.now = self.now.wrapping_add(1);
        if self.now == 0 {
            self.stamp.fill(0);
            self.now = 1;
        }
    }

    pub(super) fn set(&mut self, v: u32) {
        self.stamp[v as usize] = self.now;
    }

    pub(super) fn has(&self, v: u32) -> bool {
        self.stamp[v as usize] == self.now
    }
}
