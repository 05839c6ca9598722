//! Max-flow / min-cut with the Boykov-Kolmogorov algorithm.
//!
//! Written from Y. Boykov and V. Kolmogorov, "An experimental comparison of min-cut/max-flow
//! algorithms for energy minimization in vision", IEEE PAMI 26(9), 2004 (section 3). The
//! algorithm keeps two search trees of non-saturated arcs, `S` rooted at the source and `T`
//! rooted at the sink, and repeats three stages until the trees cannot grow:
//!
//! * **growth**: an *active* node (taken from a FIFO queue) acquires the free neighbours it has
//!   residual capacity to (towards them for `S`, from them for `T`); when it touches a node of
//!   the other tree an augmenting path source -> ... -> sink has been found;
//! * **augmentation**: the bottleneck capacity of that path is pushed along it; the arcs (and
//!   terminal links) it saturates leave their tree, and the nodes below them become *orphans*;
//! * **adoption**: each orphan looks for a new parent among its neighbours of the same tree,
//!   through an arc with residual capacity in the tree's direction and with a parent chain that
//!   still ends at the terminal (not at another orphan). Among the valid ones the closest to the
//!   terminal is taken; the chains are checked with the paper's distance / timestamp heuristic
//!   (a node's distance is trusted when it was verified during the current adoption round).
//!   An orphan without a valid parent becomes free, its children become orphans and its
//!   neighbours that could reach it become active again.
//!
//! When no active node is left, the `S` tree is exactly the set of nodes reachable from the
//! source in the residual graph: that is the source side of a minimum cut (free nodes belong to
//! the sink side).
//!
//! The algorithm is written once (`bk.rs`, generic over the adjacency) and used by two graphs:
//! [`Graph`], a general graph whose adjacency is packed into compressed arrays when
//! [`Graph::maxflow`] runs, and [`GridGraph`], a 4-connected `H x W` grid whose neighbours are
//! computed from the node index. [`min_cut`] validates and solves in one call (the Python
//! binding uses it).
//!
//! Capacities are `f32`, `f64`, `i32` or `i64` ([`Capacity`]). Integer capacities are exact.
//! Float capacities need no tolerance: the bottleneck arc of a path becomes exactly zero
//! (`x - x == 0` in IEEE arithmetic, and `x - y > 0` whenever `x > y`), so every augmentation
//! saturates at least one arc or terminal link and no rounding residue keeps a path alive; the
//! flow value itself carries the usual rounding of a sum of floats.
//!
//! Sizes: node ids and arc ids are `u32` internally, so a graph holds at most [`MAX_NODES`]
//! nodes and [`MAX_EDGES`] edges; [`Graph::add_edge`] rejects anything beyond. Integer sums
//! that could overflow (a pair of opposite capacities, the total terminal capacity bounding the
//! flow) are rejected when they are added, so [`Graph::maxflow`] cannot overflow.

mod bk;
mod graph;
mod grid;

pub use graph::Graph;
pub use grid::{grid_min_cut, GridGraph};

use btfrs_core::{Error, Result};

/// The most nodes a [`Graph`] or [`GridGraph`] can hold (ids are `u32`, a few values are tags).
pub const MAX_NODES: usize = (u32::MAX - 8) as usize;
/// The most edges a [`Graph`] can hold (each edge is two `u32`-indexed arcs).
pub const MAX_EDGES: usize = ((u32::MAX - 8) / 2) as usize;

/// Capacities: f32, f64, i32, i64.
pub trait Capacity:
    Copy
    + PartialOrd
    + std::ops::Add<Output = Self>
    + std::ops::Sub<Output = Self>
    + Default
    + Send
    + Sync
    + std::fmt::Debug
    + 'static
{
    const ZERO: Self;
    /// finite and >= 0
    fn is_valid(self) -> bool;
    fn to_f64(self) -> f64;
    /// `self + rhs` when the sum is representable and finite, else `None`. Used to reject inputs
    /// whose sums would overflow; the default suits types whose `+` does not panic.
    #[doc(hidden)]
    fn checked_sum(self, rhs: Self) -> Option<Self> {
        let s = self + rhs;
        (s.is_valid() && s >= self).then_some(s)
    }
}

macro_rules! int_capacity {
    ($t:ty) => {
        impl Capacity for $t {
            const ZERO: Self = 0;
            #[inline]
            fn is_valid(self) -> bool {
                self >= 0
            }
            #[inline]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline]
            fn checked_sum(self, rhs: Self) -> Option<Self> {
                self.checked_add(rhs)
            }
        }
    };
}
macro_rules! float_capacity {
    ($t:ty) => {
        impl Capacity for $t {
            const ZERO: Self = 0.0;
            #[inline]
            fn is_valid(self) -> bool {
                self.is_finite() && self >= 0.0
            }
            #[inline]
            fn to_f64(self) -> f64 {
                self as f64
            }
            #[inline]
            fn checked_sum(self, rhs: Self) -> Option<Self> {
                let s = self + rhs;
                s.is_finite().then_some(s)
            }
        }
    };
}
int_capacity!(i32);
int_capacity!(i64);
float_capacity!(f32);
float_capacity!(f64);

/// The message for an invalid capacity, e.g. "capacity of edge 5 is NaN; expected finite and >= 0".
pub(crate) fn bad_capacity<C: Capacity>(what: impl std::fmt::Display, c: C) -> String {
    format!("{what} is {c:?}; expected finite and >= 0")
}

/// Running totals of the source and sink terminal capacities. The flow never exceeds the
/// smaller of the two, so as long as one of them fits in `C` the flow does too.
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct Totals<C> {
    source: Option<C>,
    sink: Option<C>,
}

impl<C: Capacity> Totals<C> {
    pub(crate) fn new() -> Self {
        Totals { source: Some(C::ZERO), sink: Some(C::ZERO) }
    }

    /// Add a terminal pair; an error (argument `name`) when both totals would overflow.
    pub(crate) fn add(&mut self, name: &str, node: impl std::fmt::Display, source: C, sink: C) -> Result<()> {
        let s = self.source.and_then(|t| t.checked_sum(source));
        let k = self.sink.and_then(|t| t.checked_sum(sink));
        if s.is_none() && k.is_none() {
            return Err(Error::arg(
                name,
                format!(
                    "adding the terminal capacities of node {node} makes both the total source and the total \
                     sink capacity overflow {}; the flow could not be represented",
                    std::any::type_name::<C>()
                ),
            ));
        }
        self.source = s;
        self.sink = k;
        Ok(())
    }
}

/// Convenience used by the bindings: validate and solve in one call. edges[k] = (a, b), caps[k] = (a->b, b->a), terminals[i] = (source, sink). Returns (flow, source_side).
pub fn min_cut<C: Capacity>(
    n: usize,
    edges: &[[usize; 2]],
    caps: &[[C; 2]],
    terminals: &[[C; 2]],
) -> Result<(C, Vec<bool>)> {
    if n > MAX_NODES {
        return Err(Error::arg("n", format!("expected at most {MAX_NODES} nodes, got {n}")));
    }
    if caps.len() != edges.len() {
        return Err(Error::arg(
            "capacities",
            format!("expected one capacity pair per edge ({} edges), got {}", edges.len(), caps.len()),
        ));
    }
    if terminals.len() != n {
        return Err(Error::arg(
            "terminal_caps",
            format!("expected one (source, sink) pair per node ({n} nodes), got {}", terminals.len()),
        ));
    }
    let mut g = Graph::with_capacity(n, edges.len());
    for (&[a, b], &[ab, ba]) in edges.iter().zip(caps) {
        g.add_edge(a, b, ab, ba)?;
    }
    for (i, &[s, t]) in terminals.iter().enumerate() {
        g.add_terminal(i, s, t)?;
    }
    let flow = g.maxflow();
    Ok((flow, g.source_side()))
}
