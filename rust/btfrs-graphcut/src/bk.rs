//! The Boykov-Kolmogorov algorithm (PAMI 2004, section 3), written once for any adjacency.
//!
//! Arcs are `u32` ids; every arc has a *sister* (the reverse arc of the same edge) and a
//! residual capacity in [`Work::rcap`]. A node's terminal links are folded into one signed
//! residual `tr_cap`: positive is residual capacity source -> node, negative node -> sink (the
//! common part of the two was pushed as flow before the search starts). A node's `parent` is the
//! arc from the node to its parent in its tree, or [`TERMINAL`] for a root, [`ORPHAN`] while it
//! waits for adoption, [`NONE`] when free.

use crate::Capacity;

/// `parent` of a tree root: its parent is the terminal itself.
pub(crate) const TERMINAL: u32 = u32::MAX - 1;
/// `parent` of a node that lost its parent arc in the last augmentation.
pub(crate) const ORPHAN: u32 = u32::MAX - 2;
/// `parent` of a free node; `next` of a node that is not in the active queue.
pub(crate) const NONE: u32 = u32::MAX;

pub(crate) const FREE: u8 = 0;
pub(crate) const SRC: u8 = 1;
pub(crate) const SNK: u8 = 2;

/// The adjacency the algorithm walks; the residual capacities live in [`Work`].
pub(crate) trait Topology {
    type Arcs<'a>: Iterator<Item = (u32, u32)>
    where
        Self: 'a;
    /// The arcs leaving `node`, as `(arc, head)`.
    fn arcs(&self, node: u32) -> Self::Arcs<'_>;
    /// The node an arc points to.
    fn head(&self, arc: u32) -> u32;
    /// The reverse arc of the same edge.
    fn sister(&self, arc: u32) -> u32;
}

#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Node<C> {
    /// Arc to the parent, or TERMINAL / ORPHAN / NONE.
    pub(crate) parent: u32,
    /// Next node in the active FIFO; the last one points to itself, NONE when not queued.
    pub(crate) next: u32,
    /// Round in which `dist` was last known to be right (the paper's timestamp).
    pub(crate) ts: u32,
    /// Number of arcs to the terminal along the tree (an estimate unless `ts` is current).
    pub(crate) dist: u32,
    /// Signed terminal residual: > 0 source -> node, < 0 node -> sink.
    pub(crate) tr_cap: C,
    /// FREE, SRC or SNK.
    pub(crate) tag: u8,
}

/// Everything a run mutates, kept by the graph so that repeated runs reuse the allocations.
#[derive(Debug, Default)]
pub(crate) struct Work<C> {
    pub(crate) nodes: Vec<Node<C>>,
    pub(crate) rcap: Vec<C>,
    /// Orphans waiting for adoption (a FIFO: `orphans[orphan_head..]`).
    orphans: Vec<u32>,
}

impl<C: Capacity> Work<C> {
    /// Reset the node states from the terminal residuals `tr` (the arcs' `rcap` must be set by
    /// the caller). Nodes with a terminal residual become roots of their tree.
    pub(crate) fn reset_nodes(&mut self, tr: impl ExactSizeIterator<Item = C>) {
        self.nodes.clear();
        self.nodes.reserve(tr.len());
        self.nodes.extend(tr.map(|tr_cap| Node { parent: NONE, next: NONE, ts: 0, dist: 0, tr_cap, tag: FREE }));
    }

    pub(crate) fn is_source(&self, i: usize) -> bool {
        self.nodes.get(i).is_some_and(|n| n.tag == SRC)
    }
}

/// The FIFO of active nodes, linked through `Node::next`.
struct Queue {
    first: u32,
    last: u32,
}

impl Queue {
    #[inline]
    fn push<C>(&mut self, nodes: &mut [Node<C>], i: u32) {
        if nodes[i as usize].next != NONE {
            return; // already queued
        }
        nodes[i as usize].next = i;
        if self.last == NONE {
            self.first = i;
        } else {
            nodes[self.last as usize].next = i;
        }
        self.last = i;
    }

    #[inline]
    fn pop<C>(&mut self, nodes: &mut [Node<C>]) -> Option<u32> {
        let i = self.first;
        if i == NONE {
            return None;
        }
        let next = nodes[i as usize].next;
        if next == i {
            self.first = NONE;
            self.last = NONE;
        } else {
            self.first = next;
        }
        nodes[i as usize].next = NONE;
        Some(i)
    }
}

/// Run the algorithm on `topo` from the state in `work` (see [`Work::reset_nodes`]); returns
/// the flow pushed (not counting what the caller cancelled between the terminals beforehand).
pub(crate) fn maxflow<C: Capacity, T: Topology>(topo: &T, work: &mut Work<C>) -> C {
    let Work { nodes, rcap, orphans } = work;
    let nodes = nodes.as_mut_slice();
    let rcap = rcap.as_mut_slice();
    orphans.clear();
    let mut queue = Queue { first: NONE, last: NONE };
    // The roots: every node with a terminal residual. Timestamps start at 0, the round counter
    // at 1, so a root's distance counts as known in no round until it is verified again.
    for i in 0..nodes.len() {
        let n = &mut nodes[i];
        if n.tr_cap != C::ZERO {
            n.tag = if n.tr_cap > C::ZERO { SRC } else { SNK };
            n.parent = TERMINAL;
            n.dist = 1;
            queue.push(nodes, i as u32);
        }
    }
    let mut flow = C::ZERO;
    let mut time: u32 = 0;
    // The growth-stage shortcut below (re-hanging a neighbour under a closer parent) relies on
    // timestamps never repeating; after a wrap of `time` (2^32 augmentations) it is switched off.
    let mut shortcut = true;
    let mut current = NONE;
    loop {
        // ---- growth ----
        // Keep growing from the same node after an augmentation: it may touch the other tree
        // again through another arc (the paper's implementation does the same).
        if current == NONE || nodes[current as usize].tag == FREE {
            current = NONE;
            while let Some(i) = queue.pop(nodes) {
                if nodes[i as usize].tag != FREE {
                    current = i;
                    break;
                }
            }
            if current == NONE {
                break;
            }
        }
        let p = current;
        let (ptag, pts, pdist) = {
            let n = &nodes[p as usize];
            (n.tag, n.ts, n.dist)
        };
        // `bridge`: an arc from an S node to a T node with residual capacity.
        let mut bridge = NONE;
        for (a, q) in topo.arcs(p) {
            // residual capacity in the direction the tree grows: away from the source in S,
            // towards the sink (i.e. from q to p) in T
            let arc = if ptag == SRC { a } else { topo.sister(a) };
            if rcap[arc as usize] <= C::ZERO {
                continue;
            }
            let qn = &mut nodes[q as usize];
            if qn.tag == FREE {
                qn.tag = ptag;
                qn.parent = topo.sister(a);
                qn.ts = pts;
                qn.dist = pdist.saturating_add(1);
                queue.push(nodes, q);
            } else if qn.tag != ptag {
                bridge = arc;
                break;
            } else if shortcut && qn.ts <= pts && qn.dist > pdist {
                // q is in the same tree but further from the terminal than through p: hang it
                // under p so that later paths and orphan checks are shorter. Equal timestamps
                // make distances strictly grow down a chain, so q cannot be an ancestor of p.
                qn.parent = topo.sister(a);
                qn.ts = pts;
                qn.dist = pdist + 1;
            }
        }
        if bridge == NONE {
            current = NONE; // p is passive now
            continue;
        }
        time = time.wrapping_add(1);
        if time == 0 {
            for n in nodes.iter_mut() {
                n.ts = 0;
            }
            time = 1;
            shortcut = false;
        }
        // ---- augmentation ----
        flow = flow + augment(topo, nodes, rcap, orphans, bridge);
        // ---- adoption ----
        adopt(topo, nodes, rcap, orphans, &mut queue, time);
    }
    flow
}

/// Push the bottleneck along source -> ... -> s -> t -> ... -> sink, where `bridge` is s -> t;
/// nodes whose parent link is saturated become orphans.
fn augment<C: Capacity, T: Topology>(
    topo: &T,
    nodes: &mut [Node<C>],
    rcap: &mut [C],
    orphans: &mut Vec<u32>,
    bridge: u32,
) -> C {
    let s = topo.head(topo.sister(bridge));
    let t = topo.head(bridge);
    let mut b = rcap[bridge as usize];
    // bottleneck on the S side: flow runs parent -> child, i.e. along sister(parent arc)
    let mut x = s;
    loop {
        let pa = nodes[x as usize].parent;
        if pa == TERMINAL {
            b = min(b, nodes[x as usize].tr_cap);
            break;
        }
        b = min(b, rcap[topo.sister(pa) as usize]);
        x = topo.head(pa);
    }
    // on the T side: flow runs child -> parent, along the parent arc
    let mut x = t;
    loop {
        let pa = nodes[x as usize].parent;
        if pa == TERMINAL {
            b = min(b, C::ZERO - nodes[x as usize].tr_cap);
            break;
        }
        b = min(b, rcap[pa as usize]);
        x = topo.head(pa);
    }

    rcap[bridge as usize] = rcap[bridge as usize] - b;
    let sb = topo.sister(bridge) as usize;
    rcap[sb] = rcap[sb] + b;
    // `<= ZERO` rather than `== ZERO`: for floats the bottleneck arc is exactly zero, the
    // comparison only guards against ever keeping a non-positive arc in a tree. Capacities are
    // validated (never NaN), so the comparisons are total.
    let mut x = s;
    loop {
        let pa = nodes[x as usize].parent;
        if pa == TERMINAL {
            let n = &mut nodes[x as usize];
            n.tr_cap = n.tr_cap - b;
            if n.tr_cap <= C::ZERO {
                make_orphan(nodes, orphans, x);
            }
            break;
        }
        let sa = topo.sister(pa) as usize;
        rcap[pa as usize] = rcap[pa as usize] + b;
        rcap[sa] = rcap[sa] - b;
        let up = topo.head(pa);
        if rcap[sa] <= C::ZERO {
            make_orphan(nodes, orphans, x);
        }
        x = up;
    }
    let mut x = t;
    loop {
        let pa = nodes[x as usize].parent;
        if pa == TERMINAL {
            let n = &mut nodes[x as usize];
            n.tr_cap = n.tr_cap + b;
            if n.tr_cap >= C::ZERO {
                make_orphan(nodes, orphans, x);
            }
            break;
        }
        let sa = topo.sister(pa) as usize;
        rcap[sa] = rcap[sa] + b;
        rcap[pa as usize] = rcap[pa as usize] - b;
        let up = topo.head(pa);
        if rcap[pa as usize] <= C::ZERO {
            make_orphan(nodes, orphans, x);
        }
        x = up;
    }
    b
}

#[inline]
fn min<C: Capacity>(a: C, b: C) -> C {
    if b < a {
        b
    } else {
        a
    }
}

#[inline]
fn make_orphan<C>(nodes: &mut [Node<C>], orphans: &mut Vec<u32>, x: u32) {
    nodes[x as usize].parent = ORPHAN;
    orphans.push(x);
}

/// Find each orphan a new parent or free it (section 3.3 of the paper).
fn adopt<C: Capacity, T: Topology>(
    topo: &T,
    nodes: &mut [Node<C>],
    rcap: &[C],
    orphans: &mut Vec<u32>,
    queue: &mut Queue,
    time: u32,
) {
    // FIFO over the growing vector: orphans freed here append their children.
    let mut k = 0;
    while k < orphans.len() {
        let p = orphans[k];
        k += 1;
        let ptag = nodes[p as usize].tag;
        let tr = nodes[p as usize].tr_cap;
        // A terminal link of the right direction is always the best parent (distance 1).
        if (ptag == SRC && tr > C::ZERO) || (ptag == SNK && tr < C::ZERO) {
            let n = &mut nodes[p as usize];
            n.parent = TERMINAL;
            n.ts = time;
            n.dist = 1;
            continue;
        }
        let mut best_arc = NONE;
        let mut best_d = u32::MAX;
        for (a, q) in topo.arcs(p) {
            if nodes[q as usize].tag != ptag {
                continue;
            }
            // the candidate arc must carry residual capacity in the tree's direction:
            // q -> p for S, p -> q for T
            let res = if ptag == SRC { rcap[topo.sister(a) as usize] } else { rcap[a as usize] };
            if res <= C::ZERO {
                continue;
            }
            // Is q's chain rooted at the terminal? Walk up until the terminal, an orphan, or a
            // node whose distance was verified in this round.
            let mut d: u32 = 0;
            let mut x = q;
            let valid = loop {
                let n = &nodes[x as usize];
                if n.ts == time {
                    d = d.saturating_add(n.dist);
                    break true;
                }
                d += 1;
                match n.parent {
                    TERMINAL => {
                        let n = &mut nodes[x as usize];
                        n.ts = time;
                        n.dist = 1;
                        break true;
                    }
                    ORPHAN | NONE => break false,
                    pa => x = topo.head(pa),
                }
            };
            if !valid {
                continue;
            }
            if d < best_d {
                best_d = d;
                best_arc = a;
            }
            // Remember the verified distances along the chain, so that the next walks through
            // it stop early.
            let mut x = q;
            let mut dx = d;
            while nodes[x as usize].ts != time {
                let n = &mut nodes[x as usize];
                n.ts = time;
                n.dist = dx;
                dx = dx.saturating_sub(1);
                x = topo.head(n.parent);
            }
        }
        if best_arc != NONE {
            let n = &mut nodes[p as usize];
            n.parent = best_arc;
            n.ts = time;
            n.dist = best_d.saturating_add(1);
            continue;
        }
        // No valid parent: p becomes free. Its children are orphans now; neighbours of its tree
        // that have residual capacity towards it become active, so that the tree can grow into
        // p again through them.
        for (a, q) in topo.arcs(p) {
            let qn = &nodes[q as usize];
            if qn.tag != ptag {
                continue;
            }
            let res = if ptag == SRC { rcap[topo.sister(a) as usize] } else { rcap[a as usize] };
            if res > C::ZERO {
                queue.push(nodes, q);
            }
            let qp = nodes[q as usize].parent;
            if qp != TERMINAL && qp != ORPHAN && qp != NONE && topo.head(qp) == p {
                make_orphan(nodes, orphans, q);
            }
        }
        let n = &mut nodes[p as usize];
        n.tag = FREE;
        n.parent = NONE;
    }
    orphans.clear();
}
