//! [`Graph`]: a general graph. Edges are recorded as given; [`Graph::maxflow`] packs them into
//! compressed per-node arc arrays (built once and rebuilt only after the graph changed).

use crate::bk::{self, Topology, Work};
use crate::{bad_capacity, Capacity, Totals, MAX_EDGES, MAX_NODES};
use btfrs_core::{Error, Result};

/// The compressed adjacency: the arcs leaving node `i` are `start[i]..start[i + 1]`.
#[derive(Debug, Default)]
struct Csr<C> {
    start: Vec<u32>,
    head: Vec<u32>,
    sister: Vec<u32>,
    /// Initial capacity of every arc, copied into the residuals at each run.
    cap: Vec<C>,
}

impl<C> Topology for Csr<C> {
    type Arcs<'a>
        = std::iter::Map<std::iter::Zip<std::ops::Range<u32>, std::slice::Iter<'a, u32>>, fn((u32, &u32)) -> (u32, u32)>
    where
        Self: 'a;

    #[inline]
    fn arcs(&self, node: u32) -> Self::Arcs<'_> {
        let (lo, hi) = (self.start[node as usize], self.start[node as usize + 1]);
        (lo..hi).zip(self.head[lo as usize..hi as usize].iter()).map(|(a, &h)| (a, h))
    }

    #[inline]
    fn head(&self, arc: u32) -> u32 {
        self.head[arc as usize]
    }

    #[inline]
    fn sister(&self, arc: u32) -> u32 {
        self.sister[arc as usize]
    }
}

/// A general graph for max-flow / min-cut: nodes `0..n_nodes()`, edges with a capacity each way,
/// terminal links to the source and the sink. Reusable: edges and terminal capacities may be
/// added after [`Graph::maxflow`], which then solves the changed graph from scratch.
#[derive(Debug)]
pub struct Graph<C: Capacity> {
    n: usize,
    /// Edges as given: `(a, b)` and `(a -> b, b -> a)`.
    ends: Vec<[u32; 2]>,
    caps: Vec<[C; 2]>,
    /// Accumulated terminal capacities per node: `(source, sink)`.
    terminals: Vec<[C; 2]>,
    totals: Totals<C>,
    csr: Csr<C>,
    /// `csr` reflects `ends` / `caps` / `n`.
    csr_fresh: bool,
    work: Work<C>,
}

impl<C: Capacity> Graph<C> {
    /// A graph with `n_nodes` nodes and no edges.
    pub fn new(n_nodes: usize) -> Self {
        Self::with_capacity(n_nodes, 0)
    }

    /// A graph with `n_nodes` nodes and room for `n_edges` edges without reallocation.
    pub fn with_capacity(n_nodes: usize, n_edges: usize) -> Self {
        // Reserve only what can be used; a request beyond the limits is not an error here
        // (the limits are checked when edges are added).
        let n_edges = n_edges.min(MAX_EDGES);
        Graph {
            n: n_nodes,
            ends: Vec::with_capacity(n_edges),
            caps: Vec::with_capacity(n_edges),
            terminals: Vec::new(),
            totals: Totals::new(),
            csr: Csr::default(),
            csr_fresh: false,
            work: Work::default(),
        }
    }

    /// Add a node; returns its id (nodes can be added before maxflow).
    pub fn add_node(&mut self) -> usize {
        self.n += 1;
        self.csr_fresh = false;
        self.n - 1
    }

    /// The number of nodes.
    pub fn n_nodes(&self) -> usize {
        self.n
    }

    fn check_node(&self, name: &str, what: impl std::fmt::Display, i: usize) -> Result<()> {
        if i >= self.n {
            return Err(Error::arg(name, format!("{what} names node {i} but the graph has {} nodes", self.n)));
        }
        if i >= MAX_NODES {
            return Err(Error::arg(name, format!("{what} names node {i}; at most {MAX_NODES} nodes are supported")));
        }
        Ok(())
    }

    /// edge a->b with capacity cap_ab and reverse capacity cap_ba; errors (argument "edges") for unknown nodes, a == b is allowed to be rejected; (argument "capacities") for negative / NaN / infinite-for-float capacities.
    ///
    /// Self-loops (`a == b`) are rejected: they never carry flow across a cut. Parallel edges
    /// are kept as separate arcs. The error messages call this edge by the index it would get
    /// (the number of edges added before it).
    pub fn add_edge(&mut self, a: usize, b: usize, cap_ab: C, cap_ba: C) -> Result<()> {
        let k = self.ends.len();
        if k >= MAX_EDGES {
            return Err(Error::arg("edges", format!("at most {MAX_EDGES} edges are supported")));
        }
        self.check_node("edges", format_args!("edge {k}"), a)?;
        self.check_node("edges", format_args!("edge {k}"), b)?;
        if a == b {
            return Err(Error::arg(
                "edges",
                format!("edge {k} connects node {a} to itself; expected two different nodes"),
            ));
        }
        if !cap_ab.is_valid() {
            return Err(Error::arg("capacities", bad_capacity(format_args!("capacity of edge {k}"), cap_ab)));
        }
        if !cap_ba.is_valid() {
            return Err(Error::arg("capacities", bad_capacity(format_args!("reverse capacity of edge {k}"), cap_ba)));
        }
        // The two residuals of an edge always sum to cap_ab + cap_ba, which must fit.
        if cap_ab.checked_sum(cap_ba).is_none() {
            return Err(Error::arg(
                "capacities",
                format!(
                    "the two capacities of edge {k} ({cap_ab:?} + {cap_ba:?}) overflow {}",
                    std::any::type_name::<C>()
                ),
            ));
        }
        self.ends.push([a as u32, b as u32]);
        self.caps.push([cap_ab, cap_ba]);
        self.csr_fresh = false;
        Ok(())
    }

    /// adds `source` to the source->i capacity and `sink` to i->sink (accumulates; internally you may cancel the common part, counting it into the flow)
    ///
    /// Errors name the argument "terminal_caps".
    pub fn add_terminal(&mut self, i: usize, source: C, sink: C) -> Result<()> {
        self.check_node("terminal_caps", "a terminal capacity", i)?;
        if !source.is_valid() {
            return Err(Error::arg("terminal_caps", bad_capacity(format_args!("source capacity of node {i}"), source)));
        }
        if !sink.is_valid() {
            return Err(Error::arg("terminal_caps", bad_capacity(format_args!("sink capacity of node {i}"), sink)));
        }
        if self.terminals.len() <= i {
            self.terminals.resize(i + 1, [C::ZERO; 2]);
        }
        let [s0, t0] = self.terminals[i];
        let s = s0.checked_sum(source);
        let t = t0.checked_sum(sink);
        let (Some(s), Some(t)) = (s, t) else {
            return Err(Error::arg(
                "terminal_caps",
                format!("the accumulated terminal capacities of node {i} overflow {}", std::any::type_name::<C>()),
            ));
        };
        self.totals.add("terminal_caps", i, source, sink)?;
        self.terminals[i] = [s, t];
        Ok(())
    }

    fn build_csr(&mut self) {
        let n = self.n;
        let m = self.ends.len();
        let csr = &mut self.csr;
        csr.start.clear();
        csr.start.resize(n + 1, 0);
        for &[a, b] in &self.ends {
            csr.start[a as usize + 1] += 1;
            csr.start[b as usize + 1] += 1;
        }
        for i in 0..n {
            csr.start[i + 1] += csr.start[i];
        }
        // fill positions: `next[i]` is the next free slot of node i
        let mut next: Vec<u32> = csr.start[..n].to_vec();
        csr.head.clear();
        csr.head.resize(2 * m, 0);
        csr.sister.clear();
        csr.sister.resize(2 * m, 0);
        csr.cap.clear();
        csr.cap.resize(2 * m, C::ZERO);
        for (&[a, b], &[ab, ba]) in self.ends.iter().zip(&self.caps) {
            let pa = next[a as usize];
            next[a as usize] += 1;
            let pb = next[b as usize];
            next[b as usize] += 1;
            csr.head[pa as usize] = b;
            csr.head[pb as usize] = a;
            csr.sister[pa as usize] = pb;
            csr.sister[pb as usize] = pa;
            csr.cap[pa as usize] = ab;
            csr.cap[pb as usize] = ba;
        }
        self.csr_fresh = true;
    }

    /// runs BK, returns the max flow value (= min cut capacity)
    pub fn maxflow(&mut self) -> C {
        if !self.csr_fresh {
            self.build_csr();
        }
        self.work.rcap.clear();
        self.work.rcap.extend_from_slice(&self.csr.cap);
        // Cancel the common part of the two terminal links: it is flow source -> i -> sink
        // that needs no search.
        let mut flow = C::ZERO;
        let terminals = &self.terminals;
        let tr = (0..self.n).map(|i| {
            let [s, t] = terminals.get(i).copied().unwrap_or([C::ZERO; 2]);
            if s > t {
                flow = flow + t;
            } else {
                flow = flow + s;
            }
            s - t
        });
        self.work.reset_nodes(tr);
        flow + bk::maxflow(&self.csr, &mut self.work)
    }

    /// after maxflow: true if i is on the source side of the min cut (reachable from S in the residual graph; free nodes count as sink side)
    ///
    /// False for ids out of range and for nodes added after the last run.
    pub fn is_source_side(&self, i: usize) -> bool {
        self.work.is_source(i)
    }

    /// [`Graph::is_source_side`] for every node.
    pub fn source_side(&self) -> Vec<bool> {
        (0..self.n).map(|i| self.is_source_side(i)).collect()
    }
}
