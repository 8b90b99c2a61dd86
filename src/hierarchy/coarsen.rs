//! One coarsening step of Algorithm 1: the next level's adjacency from the current one and the
//! hop distances from the centres.

use super::graph::{edge_key, Csr};
use super::search::{Marks, UNREACHED};
use alloc::vec;
use alloc::vec::Vec;

/// Buffers reused across levels.
pub(super) struct Scratch {
    marks: Marks,
    keys: Vec<u64>,
    closer: Vec<u32>,
    /// Edges added by step 4, as singly linked lists per node (head, then next/to per entry).
    head: Vec<u32>,
    next: Vec<u32>,
    to: Vec<u32>,
}

impl Scratch {
    pub(super) fn new(n: usize) -> Scratch {
        Scratch {
            marks: Marks::new(n),
            keys: Vec::new(),
            closer: Vec::new(),
            head: vec![UNREACHED; n],
            next: Vec::new(),
            to: Vec::new(),
        }
    }
}

/// One coarsening step (Algorithm 1, steps 2 to 4) of the graph `adj` whose hop distances from
/// the centres are `dist` (`UNREACHED` for nodes not in the graph). Returns the new level's
/// adjacency. Built node by node, so no global sort of the edge list is needed.
pub(super) fn coarsen(adj: &Csr, dist: &[u32], s: &mut Scratch) -> Csr {
    let n = adj.n();
    let odd = |v: u32| dist[v as usize] != UNREACHED && dist[v as usize] & 1 == 1;
    let even = |v: u32| dist[v as usize] != UNREACHED && dist[v as usize] & 1 == 0;

    // Step 2: across every odd node, join each neighbour one hop closer to each one hop farther
    // (such a pair is always exactly two hops apart). Seen from an even node x, its partners are
    // the nodes two levels up or down behind its odd neighbours.
    let mut offsets = Vec::with_capacity(n + 1);
    offsets.push(0u32);
    let mut nbrs = Vec::with_capacity(adj.nbrs.len());
    for x in 0..n as u32 {
        if even(x) {
            let dx = dist[x as usize];
            let start = nbrs.len();
            s.marks.next();
            for &u in adj.of(x) {
                if !odd(u) {
                    continue;
                }
                let target = if dist[u as usize] > dx { dx + 2 } else { dx - 2 };
                for &w in adj.of(u) {
                    if dist[w as usize] == target && !s.marks.has(w) {
                        s.marks.set(w);
                        nbrs.push(w);
                    }
                }
            }
            nbrs[start..].sort_unstable();
        }
        offsets.push(nbrs.len() as u32);
    }
    let g2 = Csr { offsets, nbrs };

    // Step 3: where the front ends at an odd node, join its closer neighbours that are not within
    // two hops in the step-2 graph (checked against step 2 only, as the reference does, so the
    // result does not depend on the visiting order).
    s.keys.clear();
    for v in 0..n as u32 {
        if !odd(v) {
            continue;
        }
        let d = dist[v as usize];
        if adj.of(v).iter().any(|&w| dist[w as usize] == d + 1) {
            continue;
        }
        s.closer.clear();
        s.closer.extend(adj.of(v).iter().copied().filter(|&w| dist[w as usize] == d - 1));
        for (i, &a) in s.closer.iter().enumerate() {
            s.marks.next();
            for &w in g2.of(a) {
                s.marks.set(w);
            }
            for &b in &s.closer[i + 1..] {
                if !s.marks.has(b) && !g2.of(b).iter().any(|&w| s.marks.has(w)) {
                    s.keys.push(edge_key(a, b));
                }
            }
        }
    }
    let g3 = g2.union_keys(&mut s.keys);

    // Step 4: join even nodes that were adjacent (hence at the same distance) unless already
    // within two hops, counting the edges this step has added so far.
    s.keys.clear();
    s.head.fill(UNREACHED);
    s.next.clear();
    s.to.clear();
    for v in 0..n as u32 {
        if !even(v) {
            continue;
        }
        let d = dist[v as usize];
        s.marks.next();
        s.marks.set(v);
        for &w in g3.of(v) {
            s.marks.set(w);
        }
        let mut e = s.head[v as usize];
        while e != UNREACHED {
            s.marks.set(s.to[e as usize]);
            e = s.next[e as usize];
        }
        for &a in adj.of(v) {
            if dist[a as usize] != d || s.marks.has(a) {
                continue;
            }
            let mut near = g3.of(a).iter().any(|&w| s.marks.has(w));
            let mut e = s.head[a as usize];
            while !near && e != UNREACHED {
                near = s.marks.has(s.to[e as usize]);
                e = s.next[e as usize];
            }
            if near {
                continue;
            }
            for (from, to) in [(v, a), (a, v)] {
                s.next.push(s.head[from as usize]);
                s.to.push(to);
                s.head[from as usize] = s.to.len() as u32 - 1;
            }
            s.marks.set(a);
            s.keys.push(edge_key(v, a));
        }
    }
    g3.union_keys(&mut s.keys)
}
