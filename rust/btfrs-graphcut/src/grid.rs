//! [`GridGraph`]: a 4-connected `H x W` grid. Node `(y, x)` is `y * W + x`; its four arcs are
//! `4 * node + dir` with `dir` right, left, down, up, so the head and the sister of an arc are
//! computed, never stored. A per-node mask says which of the four neighbours exist.

use crate::bk::{self, Topology, Work};
use crate::{bad_capacity, Capacity, Totals, MAX_NODES};
use btfrs_core::{Error, Result};

const RIGHT: usize = 0;
const LEFT: usize = 1;
const DOWN: usize = 2;
const UP: usize = 3;

struct Grid<'a> {
    width: u32,
    mask: &'a [u8],
}

/// The arcs of one grid node: the set bits of its neighbour mask.
struct GridArcs {
    node: u32,
    width: u32,
    mask: u8,
}

impl Iterator for GridArcs {
    type Item = (u32, u32);

    #[inline]
    fn next(&mut self) -> Option<(u32, u32)> {
        if self.mask == 0 {
            return None;
        }
        let dir = self.mask.trailing_zeros();
        self.mask &= self.mask - 1;
        let head = match dir as usize {
            RIGHT => self.node + 1,
            LEFT => self.node - 1,
            DOWN => self.node + self.width,
            _ => self.node - self.width,
        };
        Some((4 * self.node + dir, head))
    }
}

impl Topology for Grid<'_> {
    type Arcs<'b>
        = GridArcs
    where
        Self: 'b;

    #[inline]
    fn arcs(&self, node: u32) -> GridArcs {
        GridArcs { node, width: self.width, mask: self.mask[node as usize] }
    }

    #[inline]
    fn head(&self, arc: u32) -> u32 {
        let node = arc >> 2;
        match (arc & 3) as usize {
            RIGHT => node + 1,
            LEFT => node - 1,
            DOWN => node + self.width,
            _ => node - self.width,
        }
    }

    #[inline]
    fn sister(&self, arc: u32) -> u32 {
        // right <-> left and down <-> up differ in the lowest bit
        4 * self.head(arc) + ((arc & 3) ^ 1)
    }
}

/// Fast path: 4-connected H x W grid, neighbours implicit (no adjacency lists), same BK algorithm.
///
/// Edge capacities are *set* (a second call replaces the first), terminal capacities
/// accumulate. Reusable: after [`GridGraph::maxflow`] capacities may be changed and the grid
/// solved again from scratch.
#[derive(Debug)]
pub struct GridGraph<C: Capacity> {
    height: usize,
    width: usize,
    /// Capacity of arc `4 * node + dir` (0 for arcs leaving the grid).
    cap: Vec<C>,
    terminals: Vec<[C; 2]>,
    totals: Totals<C>,
    mask: Vec<u8>,
    work: Work<C>,
}

impl<C: Capacity> GridGraph<C> {
    /// A grid of `height x width` nodes, all capacities zero.
    ///
    /// Arc ids are `4 * node + dir` in a `u32`, so a grid holds at most `MAX_NODES / 4` nodes
    /// (about 2^30); a larger request makes an empty grid (`0 x 0`) and every later call that
    /// names a node returns an error.
    pub fn new(height: usize, width: usize) -> Self {
        let (height, width) = match height.checked_mul(width) {
            Some(n) if n <= MAX_NODES / 4 => (height, width),
            _ => (0, 0),
        };
        let n = height * width;
        let mask = (0..n)
            .map(|i| {
                let (y, x) = (i / width, i % width);
                (u8::from(x + 1 < width) << RIGHT)
                    | (u8::from(x > 0) << LEFT)
                    | (u8::from(y + 1 < height) << DOWN)
                    | (u8::from(y > 0) << UP)
            })
            .collect();
        GridGraph {
            height,
            width,
            cap: vec![C::ZERO; 4 * n],
            terminals: vec![[C::ZERO; 2]; n],
            totals: Totals::new(),
            mask,
            work: Work::default(),
        }
    }

    fn check_pos(&self, name: &str, y: usize, x: usize, dy: usize, dx: usize) -> Result<usize> {
        // `y + dy < height` written so that no sum can overflow
        if self.height <= dy || y >= self.height - dy || self.width <= dx || x >= self.width - dx {
            let (h, w) = (self.height.saturating_sub(dy), self.width.saturating_sub(dx));
            return Err(Error::arg(
                name,
                format!("position ({y}, {x}) is outside the {h} x {w} positions of this grid"),
            ));
        }
        Ok(y * self.width + x)
    }

    fn set_pair(&mut self, name: &str, i: usize, j: usize, dir: usize, forward: C, backward: C) -> Result<()> {
        let (y, x) = (i / self.width, i % self.width);
        if !forward.is_valid() {
            return Err(Error::arg(name, bad_capacity(format_args!("forward capacity at ({y}, {x})"), forward)));
        }
        if !backward.is_valid() {
            return Err(Error::arg(name, bad_capacity(format_args!("backward capacity at ({y}, {x})"), backward)));
        }
        if forward.checked_sum(backward).is_none() {
            return Err(Error::arg(
                name,
                format!(
                    "the two capacities at ({y}, {x}) ({forward:?} + {backward:?}) overflow {}",
                    std::any::type_name::<C>()
                ),
            ));
        }
        self.cap[4 * i + dir] = forward;
        self.cap[4 * j + (dir ^ 1)] = backward;
        Ok(())
    }

    /// capacities between (y, x) and (y, x + 1): forward = towards (y, x+1), backward = towards (y, x)
    ///
    /// Errors name the argument "right".
    pub fn set_right(&mut self, y: usize, x: usize, forward: C, backward: C) -> Result<()> {
        let i = self.check_pos("right", y, x, 0, 1)?;
        self.set_pair("right", i, i + 1, RIGHT, forward, backward)
    }

    /// between (y, x) and (y + 1, x)
    ///
    /// Forward is towards (y + 1, x). Errors name the argument "down".
    pub fn set_down(&mut self, y: usize, x: usize, forward: C, backward: C) -> Result<()> {
        let i = self.check_pos("down", y, x, 1, 0)?;
        self.set_pair("down", i, i + self.width, DOWN, forward, backward)
    }

    /// Add `source` to the source -> (y, x) capacity and `sink` to (y, x) -> sink (accumulates).
    ///
    /// Errors name the argument "terminal_caps".
    pub fn add_terminal(&mut self, y: usize, x: usize, source: C, sink: C) -> Result<()> {
        let i = self.check_pos("terminal_caps", y, x, 0, 0)?;
        if !source.is_valid() {
            return Err(Error::arg(
                "terminal_caps",
                bad_capacity(format_args!("source capacity at ({y}, {x})"), source),
            ));
        }
        if !sink.is_valid() {
            return Err(Error::arg("terminal_caps", bad_capacity(format_args!("sink capacity at ({y}, {x})"), sink)));
        }
        let [s0, t0] = self.terminals[i];
        let (Some(s), Some(t)) = (s0.checked_sum(source), t0.checked_sum(sink)) else {
            return Err(Error::arg(
                "terminal_caps",
                format!("the accumulated terminal capacities at ({y}, {x}) overflow {}", std::any::type_name::<C>()),
            ));
        };
        self.totals.add("terminal_caps", format_args!("({y}, {x})"), source, sink)?;
        self.terminals[i] = [s, t];
        Ok(())
    }

    /// Run the algorithm; returns the max flow value (= min cut capacity).
    pub fn maxflow(&mut self) -> C {
        self.work.rcap.clear();
        self.work.rcap.extend_from_slice(&self.cap);
        let mut flow = C::ZERO;
        // the common part of the two terminal links is flow that needs no search
        self.work.reset_nodes(self.terminals.iter().map(|&[s, t]| {
            flow = flow + if s > t { t } else { s };
            s - t
        }));
        let grid = Grid { width: self.width as u32, mask: &self.mask };
        flow + bk::maxflow(&grid, &mut self.work)
    }

    /// After maxflow: true if (y, x) is on the source side of the min cut (false outside the
    /// grid and before the first run).
    pub fn is_source_side(&self, y: usize, x: usize) -> bool {
        y < self.height && x < self.width && self.work.is_source(y * self.width + x)
    }

    /// Number of rows.
    pub fn height(&self) -> usize {
        self.height
    }

    /// Number of columns.
    pub fn width(&self) -> usize {
        self.width
    }
}

/// The grid counterpart of [`crate::min_cut`]: validate and solve in one call.
/// `right[y * (width - 1) + x]` is (towards (y, x + 1), towards (y, x)),
/// `down[y * width + x]` is (towards (y + 1, x), towards (y, x)), `terminals[y * width + x]` is
/// (source, sink). Returns (flow, source side in row-major order).
pub fn grid_min_cut<C: Capacity>(
    height: usize,
    width: usize,
    right: &[[C; 2]],
    down: &[[C; 2]],
    terminals: &[[C; 2]],
) -> Result<(C, Vec<bool>)> {
    let n = match height.checked_mul(width) {
        Some(n) if n <= MAX_NODES / 4 => n,
        _ => {
            return Err(Error::arg(
                "terminal_caps",
                format!("a {height} x {width} grid has more than the {} nodes supported", MAX_NODES / 4),
            ))
        }
    };
    let want = |name: &str, len: usize, h: usize, w: usize| {
        if len == h * w {
            Ok(())
        } else {
            Err(Error::arg(name, format!("expected {h} x {w} = {} capacity pairs, got {len}", h * w)))
        }
    };
    want("terminal_caps", terminals.len(), height, width)?;
    want("right", right.len(), height, width.saturating_sub(1))?;
    want("down", down.len(), height.saturating_sub(1), width)?;
    let mut g = GridGraph::new(height, width);
    for (k, &[f, b]) in right.iter().enumerate() {
        g.set_right(k / (width - 1), k % (width - 1), f, b)?;
    }
    for (k, &[f, b]) in down.iter().enumerate() {
        g.set_down(k / width, k % width, f, b)?;
    }
    for (k, &[s, t]) in terminals.iter().enumerate() {
        g.add_terminal(k / width, k % width, s, t)?;
    }
    let flow = g.maxflow();
    Ok((flow, (0..n).map(|i| g.work.is_source(i)).collect()))
}
