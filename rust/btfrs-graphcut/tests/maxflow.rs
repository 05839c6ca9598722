//! Max-flow values against brute force, cut capacities against flows, the grid against the
//! general graph, and the errors of bad input.

use btfrs_core::rng::Rng;
use btfrs_core::Error;
use btfrs_graphcut::{min_cut, Capacity, Graph, GridGraph};

/// A random problem: edges (a != b), capacity pairs, terminal pairs.
struct Problem<C> {
    n: usize,
    edges: Vec<[usize; 2]>,
    caps: Vec<[C; 2]>,
    terminals: Vec<[C; 2]>,
}

/// Capacity drawn from `draw`, zero with probability `p_zero` (sparse residual graphs make the
/// adoption stage work harder).
fn cap<C>(rng: &mut Rng, p_zero: f64, draw: &impl Fn(&mut Rng) -> C, zero: C) -> C {
    if rng.next_f64() < p_zero {
        zero
    } else {
        draw(rng)
    }
}

fn random_problem<C: Capacity>(rng: &mut Rng, n: usize, m: usize, draw: impl Fn(&mut Rng) -> C) -> Problem<C> {
    let mut edges = Vec::new();
    let mut caps = Vec::new();
    if n >= 2 {
        for _ in 0..m {
            let a = rng.below(n);
            let mut b = rng.below(n - 1);
            if b >= a {
                b += 1;
            }
            edges.push([a, b]);
            caps.push([cap(rng, 0.3, &draw, C::ZERO), cap(rng, 0.5, &draw, C::ZERO)]);
        }
    }
    let terminals = (0..n).map(|_| [cap(rng, 0.5, &draw, C::ZERO), cap(rng, 0.5, &draw, C::ZERO)]).collect();
    Problem { n, edges, caps, terminals }
}

/// Capacity of the cut whose source side is `side`, in f64.
fn cut_capacity<C: Capacity>(p: &Problem<C>, side: &[bool]) -> f64 {
    let mut c = 0.0;
    for (&[a, b], &[ab, ba]) in p.edges.iter().zip(&p.caps) {
        if side[a] && !side[b] {
            c += ab.to_f64();
        }
        if side[b] && !side[a] {
            c += ba.to_f64();
        }
    }
    for (i, &[s, t]) in p.terminals.iter().enumerate() {
        c += if side[i] { t.to_f64() } else { s.to_f64() };
    }
    c
}

/// The minimum over all 2^n cuts.
fn brute_force<C: Capacity>(p: &Problem<C>) -> f64 {
    let mut best = f64::INFINITY;
    for mask in 0u32..(1 << p.n) {
        let side: Vec<bool> = (0..p.n).map(|i| mask >> i & 1 == 1).collect();
        best = best.min(cut_capacity(p, &side));
    }
    best
}

fn solve<C: Capacity>(p: &Problem<C>) -> (C, Vec<bool>) {
    min_cut(p.n, &p.edges, &p.caps, &p.terminals).expect("valid problem")
}

#[test]
fn integer_flow_equals_brute_force_min_cut() {
    let mut rng = Rng::new(1);
    for trial in 0..400 {
        let n = 1 + rng.below(12);
        let m = rng.below(3 * n + 1);
        let p = random_problem(&mut rng, n, m, |r| r.below(10) as i64 + 1);
        let (flow, side) = solve(&p);
        let want = brute_force(&p);
        assert_eq!(flow as f64, want, "trial {trial}: n {n} m {m}");
        assert_eq!(cut_capacity(&p, &side), want, "trial {trial}: the returned cut is not minimal");
        // the i32 path agrees
        let p32 = Problem {
            n,
            edges: p.edges.clone(),
            caps: p.caps.iter().map(|&[a, b]| [a as i32, b as i32]).collect(),
            terminals: p.terminals.iter().map(|&[a, b]| [a as i32, b as i32]).collect(),
        };
        let (f32_, side32) = solve(&p32);
        assert_eq!(f32_ as i64, flow, "trial {trial}");
        assert_eq!(side32, side, "trial {trial}");
    }
}

#[test]
fn float_flow_equals_brute_force_min_cut() {
    let mut rng = Rng::new(2);
    for trial in 0..400 {
        let n = 1 + rng.below(12);
        let m = rng.below(3 * n + 1);
        let p = random_problem(&mut rng, n, m, |r| r.next_f64() * 5.0);
        let (flow, side) = solve(&p);
        let want = brute_force(&p);
        let tol = 1e-9 * (1.0 + want);
        assert!((flow - want).abs() <= tol, "trial {trial}: flow {flow} brute force {want}");
        assert!((cut_capacity(&p, &side) - want).abs() <= tol, "trial {trial}");
        // f32 as well, with f32 rounding
        let p32 = Problem {
            n,
            edges: p.edges.clone(),
            caps: p.caps.iter().map(|&[a, b]| [a as f32, b as f32]).collect(),
            terminals: p.terminals.iter().map(|&[a, b]| [a as f32, b as f32]).collect(),
        };
        let (f, s) = solve(&p32);
        let want32 = brute_force(&p32);
        assert!((f as f64 - want32).abs() <= 1e-4 * (1.0 + want32), "trial {trial}: {f} vs {want32}");
        assert!((cut_capacity(&p32, &s) - want32).abs() <= 1e-4 * (1.0 + want32), "trial {trial}");
    }
}

#[test]
fn known_cut_clrs_network() {
    // The network of Cormen et al. (fig. 26.1): s->v1 16, s->v2 13, v1->v3 12, v2->v1 4,
    // v2->v4 14, v3->v2 9, v3->t 20, v4->v3 7, v4->t 4. Max flow 23; the only minimum cut
    // is {s, v1, v2, v4} | {v3, t}.
    let mut g = Graph::<i32>::new(4);
    for (a, b, c) in [(0, 2, 12), (1, 0, 4), (1, 3, 14), (2, 1, 9), (3, 2, 7)] {
        g.add_edge(a, b, c, 0).unwrap();
    }
    g.add_terminal(0, 16, 0).unwrap();
    g.add_terminal(1, 13, 0).unwrap();
    g.add_terminal(2, 0, 20).unwrap();
    g.add_terminal(3, 0, 4).unwrap();
    assert_eq!(g.maxflow(), 23);
    assert_eq!(g.source_side(), vec![true, true, false, true]);
    // running again gives the same answer (the graph is reusable)
    assert_eq!(g.maxflow(), 23);
    assert_eq!(g.source_side(), vec![true, true, false, true]);
    // widening v4 -> t to 104 after a run: now {s, v1} | {v2, v3, v4, t} is the only
    // minimum cut, s->v2 13 + v1->v3 12 = 25 ({s} is 29, {s, v1, v2} 26, {s, v2} 34)
    g.add_terminal(3, 0, 100).unwrap();
    assert_eq!(g.maxflow(), 25);
    assert_eq!(g.source_side(), vec![true, false, false, false]);
    assert!(!g.is_source_side(4), "out of range is sink side");
}

#[test]
fn known_cut_chain_and_common_terminal_part() {
    // s -5-> 0 -3-> 1 -4-> t, plus node 2 with both terminal links (7 source, 2 sink): its
    // common part 2 is flow, the rest keeps it on the source side.
    let mut g = Graph::<f64>::new(2);
    let two = g.add_node();
    assert_eq!(two, 2);
    assert_eq!(g.n_nodes(), 3);
    g.add_edge(0, 1, 3.0, 1.0).unwrap();
    g.add_terminal(0, 5.0, 0.0).unwrap();
    g.add_terminal(1, 0.0, 4.0).unwrap();
    g.add_terminal(2, 7.0, 2.0).unwrap();
    assert_eq!(g.maxflow(), 5.0);
    assert_eq!(g.source_side(), vec![true, false, true]);
    // an empty graph
    let mut e = Graph::<i64>::new(0);
    assert_eq!(e.maxflow(), 0);
    assert!(e.source_side().is_empty());
}

#[test]
fn cut_capacity_equals_flow_on_larger_random_graphs() {
    let mut rng = Rng::new(3);
    for trial in 0..30 {
        let n = 50 + rng.below(400);
        let m = n * (1 + rng.below(6));
        let p = random_problem(&mut rng, n, m, |r| r.below(1000) as i64);
        let (flow, side) = solve(&p);
        assert_eq!(cut_capacity(&p, &side), flow as f64, "trial {trial}");
        let q = random_problem(&mut rng, n, m, |r| r.next_f64() * 100.0);
        let (flow, side) = solve(&q);
        assert!((cut_capacity(&q, &side) - flow).abs() <= 1e-9 * (1.0 + flow), "trial {trial}");
    }
}

/// A random H x W grid problem as (right, down, terminals) arrays, also as a general problem.
struct GridProblem<C> {
    h: usize,
    w: usize,
    right: Vec<[C; 2]>,
    down: Vec<[C; 2]>,
    general: Problem<C>,
}

fn random_grid<C: Capacity>(rng: &mut Rng, h: usize, w: usize, draw: impl Fn(&mut Rng) -> C) -> GridProblem<C> {
    let mut edges = Vec::new();
    let mut caps = Vec::new();
    let mut right = Vec::new();
    let mut down = Vec::new();
    for y in 0..h {
        for x in 0..w {
            if x + 1 < w {
                let c = [cap(rng, 0.1, &draw, C::ZERO), cap(rng, 0.1, &draw, C::ZERO)];
                right.push(c);
                edges.push([y * w + x, y * w + x + 1]);
                caps.push(c);
            }
            if y + 1 < h {
                let c = [cap(rng, 0.1, &draw, C::ZERO), cap(rng, 0.1, &draw, C::ZERO)];
                down.push(c);
                edges.push([y * w + x, (y + 1) * w + x]);
                caps.push(c);
            }
        }
    }
    // right/down were pushed in row-major order of their own layouts, which is what set_* need
    let terminals = (0..h * w).map(|_| [cap(rng, 0.6, &draw, C::ZERO), cap(rng, 0.6, &draw, C::ZERO)]).collect();
    GridProblem { h, w, right, down, general: Problem { n: h * w, edges, caps, terminals } }
}

fn solve_grid<C: Capacity>(p: &GridProblem<C>) -> (C, Vec<bool>) {
    let (h, w) = (p.h, p.w);
    let mut g = GridGraph::<C>::new(h, w);
    let (mut r, mut d) = (p.right.iter(), p.down.iter());
    for y in 0..h {
        for x in 0..w {
            if x + 1 < w {
                let &[f, b] = r.next().unwrap();
                g.set_right(y, x, f, b).unwrap();
            }
            if y + 1 < h {
                let &[f, b] = d.next().unwrap();
                g.set_down(y, x, f, b).unwrap();
            }
            let [s, t] = p.general.terminals[y * w + x];
            g.add_terminal(y, x, s, t).unwrap();
        }
    }
    let flow = g.maxflow();
    let side = (0..h * w).map(|i| g.is_source_side(i / w, i % w)).collect();
    (flow, side)
}

#[test]
fn grid_equals_general_graph() {
    let mut rng = Rng::new(4);
    for trial in 0..60 {
        let h = 1 + rng.below(40);
        let w = 1 + rng.below(40);
        let p = random_grid(&mut rng, h, w, |r| r.below(50) as i64);
        let (fg, sg) = solve_grid(&p);
        let (f, s) = solve(&p.general);
        assert_eq!(fg, f, "trial {trial}: {h} x {w}");
        // the residual-reachable set is the same for every maximum flow
        assert_eq!(sg, s, "trial {trial}");
        assert_eq!(cut_capacity(&p.general, &sg), fg as f64, "trial {trial}");

        let q = random_grid(&mut rng, h, w, |r| r.next_f64());
        let (fg, sg) = solve_grid(&q);
        let (f, _) = solve(&q.general);
        assert!((fg - f).abs() <= 1e-9 * (1.0 + f), "trial {trial}: {fg} vs {f}");
        assert!((cut_capacity(&q.general, &sg) - fg).abs() <= 1e-9 * (1.0 + fg), "trial {trial}");
    }
}

#[test]
fn small_grids_against_brute_force() {
    let mut rng = Rng::new(5);
    for trial in 0..200 {
        let (h, w) = [(1, 1), (1, 5), (2, 3), (3, 3), (3, 4), (2, 6), (4, 3)][trial % 7];
        let p = random_grid(&mut rng, h, w, |r| r.below(8) as i32);
        let (flow, side) = solve_grid(&p);
        let want = brute_force(&p.general);
        assert_eq!(flow as f64, want, "trial {trial}");
        assert_eq!(cut_capacity(&p.general, &side), want, "trial {trial}");
    }
}

fn arg_error<T: std::fmt::Debug>(r: btfrs_core::Result<T>) -> (String, String) {
    match r {
        Err(Error::InvalidArgument { name, msg, .. }) => (name, msg),
        other => panic!("expected an InvalidArgument error, got {other:?}"),
    }
}

#[test]
fn bad_input_errors() {
    // min_cut: sizes
    let (name, msg) = arg_error(min_cut::<i64>(3, &[[0, 1]], &[], &[[0, 0]; 3]));
    assert_eq!(name, "capacities");
    assert!(msg.contains("1 edges"), "{msg}");
    let (name, msg) = arg_error(min_cut::<i64>(3, &[], &[], &[[0, 0]; 2]));
    assert_eq!(name, "terminal_caps");
    assert!(msg.contains("3 nodes"), "{msg}");
    let (name, _) = arg_error(min_cut::<i64>(usize::MAX, &[], &[], &[]));
    assert_eq!(name, "n");
    // unknown node, self-loop
    let edges = [[0, 1], [1, 2], [2, 0], [17, 1]];
    let (name, msg) = arg_error(min_cut::<i64>(10, &edges, &[[1, 1]; 4], &[[0, 0]; 10]));
    assert_eq!((name.as_str(), msg.as_str()), ("edges", "edge 3 names node 17 but the graph has 10 nodes"));
    let (name, msg) = arg_error(min_cut::<i64>(10, &[[4, 4]], &[[1, 1]], &[[0, 0]; 10]));
    assert_eq!(name, "edges");
    assert!(msg.contains("itself"), "{msg}");
    // bad capacities
    let mut caps = [[1.0f64, 1.0]; 6];
    caps[5][0] = f64::NAN;
    let e6 = [[0, 1]; 6];
    let (name, msg) = arg_error(min_cut(2, &e6, &caps, &[[0.0, 0.0]; 2]));
    assert_eq!((name.as_str(), msg.as_str()), ("capacities", "capacity of edge 5 is NaN; expected finite and >= 0"));
    caps[5] = [1.0, f64::INFINITY];
    let (name, msg) = arg_error(min_cut(2, &e6, &caps, &[[0.0, 0.0]; 2]));
    assert_eq!(name, "capacities");
    assert!(msg.contains("reverse capacity of edge 5 is inf"), "{msg}");
    let (name, msg) = arg_error(min_cut::<i32>(2, &[[0, 1]], &[[-3, 1]], &[[0, 0]; 2]));
    assert_eq!(name, "capacities");
    assert!(msg.contains("-3"), "{msg}");
    let (name, msg) = arg_error(min_cut::<f32>(2, &[], &[], &[[0.0, 0.0], [-0.5, 0.0]]));
    assert_eq!(
        (name.as_str(), msg.as_str()),
        ("terminal_caps", "source capacity of node 1 is -0.5; expected finite and >= 0")
    );
    // integer overflow of a capacity pair, of a node's accumulated terminals, of the totals
    let (name, msg) = arg_error(min_cut::<i32>(2, &[[0, 1]], &[[i32::MAX, 1]], &[[0, 0]; 2]));
    assert_eq!(name, "capacities");
    assert!(msg.contains("overflow"), "{msg}");
    let mut g = Graph::<i32>::new(3);
    g.add_terminal(0, i32::MAX, i32::MAX).unwrap();
    assert_eq!(arg_error(g.add_terminal(0, 1, 0)).0, "terminal_caps");
    let (name, msg) = arg_error(g.add_terminal(1, 1, 1));
    assert_eq!(name, "terminal_caps");
    assert!(msg.contains("total"), "{msg}");
    assert_eq!(arg_error(g.add_terminal(5, 1, 1)).0, "terminal_caps");
    // the graph still works after rejected input
    assert_eq!(g.maxflow(), i32::MAX);
    let mut f = Graph::<f64>::new(2);
    assert_eq!(arg_error(f.add_edge(0, 1, f64::MAX, f64::MAX)).0, "capacities");
    assert_eq!(arg_error(f.add_edge(0, 2, 1.0, 1.0)).0, "edges");

    // grid
    let mut g = GridGraph::<i64>::new(3, 4);
    let (name, msg) = arg_error(g.set_right(0, 3, 1, 1));
    assert_eq!(name, "right");
    assert!(msg.contains("(0, 3)"), "{msg}");
    assert_eq!(arg_error(g.set_down(2, 0, 1, 1)).0, "down");
    assert_eq!(arg_error(g.set_down(0, 0, -1, 1)).0, "down");
    assert_eq!(arg_error(g.set_right(0, 0, 1, -1)).0, "right");
    assert_eq!(arg_error(g.add_terminal(3, 0, 1, 1)).0, "terminal_caps");
    assert_eq!(arg_error(g.add_terminal(0, 0, -1, 1)).0, "terminal_caps");
    assert_eq!(arg_error(g.set_right(0, 0, i64::MAX, 1)).0, "right");
    assert_eq!(arg_error(g.set_right(usize::MAX, usize::MAX, 1, 1)).0, "right");
    assert_eq!(arg_error(g.set_down(usize::MAX, 0, 1, 1)).0, "down");
    assert_eq!(arg_error(g.add_terminal(0, usize::MAX, 1, 1)).0, "terminal_caps");
    assert!(!g.is_source_side(usize::MAX, usize::MAX));
    let mut f = GridGraph::<f32>::new(2, 2);
    assert_eq!(arg_error(f.set_right(0, 0, f32::NAN, 1.0)).0, "right");
    assert_eq!(arg_error(f.add_terminal(1, 1, 0.0, f32::INFINITY)).0, "terminal_caps");
    // a grid too large for u32 arc ids is empty, every call errors, nothing panics
    let mut huge = GridGraph::<f64>::new(1 << 20, 1 << 20);
    assert_eq!((huge.height(), huge.width()), (0, 0));
    assert_eq!(arg_error(huge.add_terminal(0, 0, 1.0, 0.0)).0, "terminal_caps");
    assert_eq!(huge.maxflow(), 0.0);
    assert!(!huge.is_source_side(0, 0));
}

#[test]
fn grid_reuse_and_side_queries() {
    // 1 x 3: s -> (0,0) -2-> (0,1) -1-> (0,2) -> t; the cut is after (0,1)
    let mut g = GridGraph::<i64>::new(1, 3);
    g.set_right(0, 0, 2, 0).unwrap();
    g.set_right(0, 1, 1, 0).unwrap();
    g.add_terminal(0, 0, 10, 0).unwrap();
    g.add_terminal(0, 2, 0, 10).unwrap();
    assert_eq!(g.maxflow(), 1);
    assert_eq!((0..3).map(|x| g.is_source_side(0, x)).collect::<Vec<_>>(), [true, true, false]);
    assert!(!g.is_source_side(1, 0));
    // replacing a capacity moves the cut
    g.set_right(0, 1, 5, 0).unwrap();
    assert_eq!(g.maxflow(), 2);
    assert_eq!((0..3).map(|x| g.is_source_side(0, x)).collect::<Vec<_>>(), [true, false, false]);
}
