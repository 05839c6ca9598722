//! Property tests of the scalar maps, run in both `f32` and `f64`.
//!
//! Errors are always measured in `f64` after converting the outputs, so the `f32` tolerances
//! measure the map's own rounding and not the test's.

use crate::*;
use core::f64::consts::{FRAC_PI_2, FRAC_PI_4, PI, TAU};

// ---------------------------------------------------------------------------------------------
// helpers

/// `n` points `0, 1/(n-1), ..., 1`; with `n = 2^k + 1` all are exact in f32 and f64 and the
/// grid contains the centre 0.5, so a 2-D grid contains the boundary and both diagonals.
fn unit_grid(n: usize) -> Vec<f64> {
    (0..n).map(|i| i as f64 / (n - 1) as f64).collect()
}

/// A small deterministic generator (splitmix64) for extra scattered test points.
struct SplitMix(u64);
impl SplitMix {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Square points for round trips: a 257 x 257 grid (boundary, both diagonals and the centre
/// included), points a hair away from the centre, the diagonals and the boundary, and scattered
/// pseudo-random points.
fn square_test_points() -> Vec<[f64; 2]> {
    let g = unit_grid(257);
    let mut pts: Vec<[f64; 2]> = g.iter().flat_map(|&s| g.iter().map(move |&t| [s, t])).collect();
    for &e in &[1e-9, 1e-6, 1e-4, 1e-2] {
        for &(ds, dt) in &[(1.0, 0.0), (0.0, 1.0), (1.0, 1.0), (1.0, -1.0), (0.3, -0.7)] {
            for &sign in &[1.0, -1.0] {
                pts.push([0.5 + sign * e * ds, 0.5 + sign * e * dt]);
            }
        }
        for &u in &g {
            pts.push([u, (u + e).min(1.0)]);
            pts.push([u, (1.0 - u - e).max(0.0)]);
            pts.push([1.0 - e, u]);
            pts.push([u, e]);
        }
    }
    let mut rng = SplitMix(7);
    for _ in 0..20_000 {
        pts.push([rng.next_f64(), rng.next_f64()]);
    }
    pts
}

fn dir_from_angles(theta: f64, phi: f64) -> [f64; 3] {
    [theta.sin() * phi.cos(), theta.sin() * phi.sin(), theta.cos()]
}

fn normalize(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

/// Angle between two directions, accurate for tiny angles (unlike acos of the dot product).
fn angle_between(u: [f64; 3], v: [f64; 3]) -> f64 {
    let (u, v) = (normalize(u), normalize(v));
    let d = ((u[0] - v[0]).powi(2) + (u[1] - v[1]).powi(2) + (u[2] - v[2]).powi(2)).sqrt();
    2.0 * (0.5 * d).min(1.0).asin()
}

fn dist2(p: [f64; 2], q: [f64; 2]) -> f64 {
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2)).sqrt()
}

fn dist3(p: [f64; 3], q: [f64; 3]) -> f64 {
    ((p[0] - q[0]).powi(2) + (p[1] - q[1]).powi(2) + (p[2] - q[2]).powi(2)).sqrt()
}

fn fwd<T: Real>(s: f64, t: f64) -> [f64; 3] {
    square_to_hemisphere(T::from_f64(s), T::from_f64(t)).map(T::to_f64)
}

fn inv<T: Real>(d: [f64; 3]) -> [f64; 2] {
    hemisphere_to_square(d.map(T::from_f64)).map(T::to_f64)
}

fn fwd_disk<T: Real>(s: f64, t: f64) -> [f64; 2] {
    square_to_disk(T::from_f64(s), T::from_f64(t)).map(T::to_f64)
}

fn inv_disk<T: Real>(p: [f64; 2]) -> [f64; 2] {
    disk_to_square(T::from_f64(p[0]), T::from_f64(p[1])).map(T::to_f64)
}

/// Maximum of `|s' - s|, |t' - t|` over the test points, the inputs rounded to `T` first.
fn max_square_round_trip_error<T: Real>(f: impl Fn([T; 2]) -> [T; 2]) -> f64 {
    let mut worst: f64 = 0.0;
    for p in square_test_points() {
        let pt = p.map(T::from_f64);
        let q = f(pt).map(T::to_f64);
        let p = pt.map(T::to_f64);
        worst = worst.max((q[0] - p[0]).abs()).max((q[1] - p[1]).abs());
    }
    worst
}

/// Directions for inverse round trips: a (theta, phi) grid with the pole, the horizon and the
/// region borders, plus tiny polar angles.
fn hemisphere_test_dirs() -> Vec<[f64; 3]> {
    let mut dirs = Vec::new();
    for i in 0..=180 {
        let theta = FRAC_PI_2 * i as f64 / 180.0;
        for j in 0..720 {
            dirs.push(dir_from_angles(theta, TAU * j as f64 / 720.0));
        }
    }
    for &theta in &[1e-9, 1e-6, 1e-4, FRAC_PI_2 - 1e-6, FRAC_PI_2 - 1e-9] {
        for j in 0..64 {
            dirs.push(dir_from_angles(theta, TAU * j as f64 / 64.0 + 0.01));
        }
    }
    dirs.push([0.0, 0.0, 1.0]);
    dirs
}

// ---------------------------------------------------------------------------------------------
// 1. round trips

#[test]
fn round_trip_square_hemisphere_square() {
    let e32 = max_square_round_trip_error::<f32>(|[s, t]| hemisphere_to_square(square_to_hemisphere(s, t)));
    let e64 = max_square_round_trip_error::<f64>(|[s, t]| hemisphere_to_square(square_to_hemisphere(s, t)));
    assert!(e32 < 1e-5, "f32 square->hemisphere->square max error {e32:e}");
    assert!(e64 < 1e-12, "f64 square->hemisphere->square max error {e64:e}");
}

#[test]
fn round_trip_square_disk_square() {
    let e32 = max_square_round_trip_error::<f32>(|[s, t]| {
        let [x, y] = square_to_disk(s, t);
        disk_to_square(x, y)
    });
    let e64 = max_square_round_trip_error::<f64>(|[s, t]| {
        let [x, y] = square_to_disk(s, t);
        disk_to_square(x, y)
    });
    assert!(e32 < 1e-5, "f32 square->disk->square max error {e32:e}");
    assert!(e64 < 1e-12, "f64 square->disk->square max error {e64:e}");
}

#[test]
fn round_trip_square_polar_square() {
    let e32 = max_square_round_trip_error::<f32>(|[s, t]| {
        let [rho, phi] = square_to_polar(s, t);
        polar_to_square(rho, phi)
    });
    let e64 = max_square_round_trip_error::<f64>(|[s, t]| {
        let [rho, phi] = square_to_polar(s, t);
        polar_to_square(rho, phi)
    });
    assert!(e32 < 1e-5, "f32 square->polar->square max error {e32:e}");
    assert!(e64 < 1e-12, "f64 square->polar->square max error {e64:e}");
}

#[test]
fn polar_form_agrees_with_disk_form() {
    for p in square_test_points() {
        let [rho, phi] = square_to_polar(p[0], p[1]);
        assert!((0.0..=1.0).contains(&rho), "rho {rho} out of range at {p:?}");
        assert!((0.0..=TAU).contains(&phi), "phi {phi} out of range at {p:?}");
        let [x, y] = square_to_disk(p[0], p[1]);
        assert!(dist2([rho * phi.cos(), rho * phi.sin()], [x, y]) < 1e-14, "at {p:?}");
    }
}

fn max_hemisphere_round_trip_angle<T: Real>() -> f64 {
    let mut worst: f64 = 0.0;
    for d in hemisphere_test_dirs() {
        let dt = d.map(T::from_f64);
        let [s, t] = hemisphere_to_square(dt);
        let back = square_to_hemisphere(s, t).map(T::to_f64);
        worst = worst.max(angle_between(dt.map(T::to_f64), back));
    }
    worst
}

#[test]
fn round_trip_hemisphere_square_hemisphere() {
    let a32 = max_hemisphere_round_trip_angle::<f32>();
    let a64 = max_hemisphere_round_trip_angle::<f64>();
    assert!(a32 < 1e-5, "f32 hemisphere->square->hemisphere max angle {a32:e} rad");
    assert!(a64 < 1e-12, "f64 hemisphere->square->hemisphere max angle {a64:e} rad");
}

#[test]
fn round_trip_disk_square_disk() {
    let mut worst: f64 = 0.0;
    for d in hemisphere_test_dirs() {
        // Disk points with the directions' azimuths and radius sin(theta) (covers 0 and 1).
        let p = [d[0], d[1]];
        let [s, t] = disk_to_square(p[0], p[1]);
        let q = square_to_disk(s, t);
        worst = worst.max(dist2(p, q));
    }
    assert!(worst < 1e-12, "f64 disk->square->disk max error {worst:e}");
}

#[test]
fn forward_output_is_unit_and_upper() {
    for p in square_test_points() {
        for d in [fwd::<f64>(p[0], p[1]), fwd::<f32>(p[0], p[1])] {
            let n = dist3(d, [0.0; 3]);
            assert!((n - 1.0).abs() < 1e-6, "|d| = {n} at {p:?}");
            assert!(d[2] >= 0.0, "z < 0 at {p:?}");
        }
        let q = fwd_disk::<f64>(p[0], p[1]);
        assert!(dist2(q, [0.0; 2]) <= 1.0 + 1e-15, "outside disk at {p:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// 2. equal area

/// Maps the centres of an `n x n` grid of square cells through `map` and bins the directions
/// into `bands` bands of equal height in z times `sectors` equal azimuth sectors. Area on the
/// unit sphere is dz * dphi, so all bins have equal area; returns max |count - mean| / mean.
fn max_bin_deviation(map: impl Fn(f64, f64) -> [f64; 3], n: usize, bands: usize, sectors: usize) -> f64 {
    let mut counts = vec![0usize; bands * sectors];
    for i in 0..n {
        for j in 0..n {
            let d = map((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
            let band = ((d[2] * bands as f64) as usize).min(bands - 1);
            let phi = d[1].atan2(d[0]).rem_euclid(TAU);
            let sector = ((phi / TAU * sectors as f64) as usize).min(sectors - 1);
            counts[band * sectors + sector] += 1;
        }
    }
    let mean = (n * n) as f64 / counts.len() as f64;
    counts.iter().map(|&c| (c as f64 - mean).abs() / mean).fold(0.0, f64::max)
}

const EQUAL_AREA_N: usize = 2048;

#[test]
fn equal_area_hemisphere_bins() {
    // 2048^2 points into 8 x 16 bins: 32768 per bin on average (max deviation seen: 0.8%).
    //
    // Why not 512^2: the preimage of a z-band is the ring between two concentric squares whose
    // edges are parallel to the grid, so its point count is a step function of the band's
    // edge, off from the exact area by up to about half a grid row along the whole perimeter.
    // At N = 512 that lattice error alone reaches 4.7% for the second band (the map is exactly
    // equal-area; the count is not), at N = 2048 it is 0.8%.
    let dev64 = max_bin_deviation(fwd::<f64>, EQUAL_AREA_N, 8, 16);
    let dev32 = max_bin_deviation(fwd::<f32>, EQUAL_AREA_N, 8, 16);
    assert!(dev64 < 0.02, "f64: a bin deviates {:.2}% from the mean", 100.0 * dev64);
    assert!(dev32 < 0.02, "f32: a bin deviates {:.2}% from the mean", 100.0 * dev32);
}

#[test]
fn equal_area_check_rejects_a_map_that_is_not_equal_area() {
    // Control for the test above: the same concentric map lifted with z = 1 - rho (instead of
    // 1 - rho^2) is continuous and bijective but not equal-area; the bin check must notice.
    let not_equal_area = |s: f64, t: f64| {
        let [rho, phi] = square_to_polar(s, t);
        let z = 1.0 - rho;
        let h = (1.0 - z * z).max(0.0).sqrt();
        [h * phi.cos(), h * phi.sin(), z]
    };
    let dev = max_bin_deviation(not_equal_area, EQUAL_AREA_N, 8, 16);
    assert!(dev > 0.02, "the control map passed the equal-area check ({dev})");
}

#[test]
fn concentric_map_is_equal_area_on_the_disk() {
    // The same check one step earlier: rho^2 bands of equal width are equal-area disk annuli.
    let as_dir = |s: f64, t: f64| {
        let [x, y] = square_to_disk(s, t);
        [x, y, 1.0 - (x * x + y * y)]
    };
    let dev = max_bin_deviation(as_dir, EQUAL_AREA_N, 8, 16);
    assert!(dev < 0.02, "a disk bin deviates {:.2}% from the mean", 100.0 * dev);
}

// ---------------------------------------------------------------------------------------------
// 3. continuity

/// Largest `|f(p) - f(q)| / |p - q|` over the given pairs.
fn max_ratio<P: Copy, Q>(
    pairs: &[(P, P)],
    f: impl Fn(P) -> Q,
    dp: impl Fn(P, P) -> f64,
    dq: impl Fn(&Q, &Q) -> f64,
) -> f64 {
    pairs.iter().map(|&(p, q)| dq(&f(p), &f(q)) / dp(p, q)).fold(0.0, f64::max)
}

/// Pairs of square points `eps` either side of the region borders s = t and s = 1 - t, and of
/// the axes through the centre, all along their length.
fn square_border_pairs(eps: f64) -> Vec<([f64; 2], [f64; 2])> {
    let mut pairs = Vec::new();
    for u in unit_grid(201) {
        pairs.push(([u + eps, u - eps], [u - eps, u + eps])); // across s = t
        pairs.push(([u + eps, 1.0 - u + eps], [u - eps, 1.0 - u - eps])); // across s = 1 - t
        pairs.push(([0.5 + eps, u], [0.5 - eps, u])); // across s = 1/2
        pairs.push(([u, 0.5 + eps], [u, 0.5 - eps])); // across t = 1/2
    }
    pairs
}

/// Pairs of square points straddling the centre in many directions, and each with the centre.
fn square_centre_pairs(eps: f64) -> Vec<([f64; 2], [f64; 2])> {
    let mut pairs = Vec::new();
    for k in 0..64 {
        let a = TAU * k as f64 / 64.0 + 0.003;
        let p = [0.5 + eps * a.cos(), 0.5 + eps * a.sin()];
        let q = [0.5 - eps * a.cos(), 0.5 - eps * a.sin()];
        pairs.push((p, q));
        pairs.push((p, [0.5, 0.5]));
        let b = a + 0.1;
        pairs.push((p, [0.5 + eps * b.cos(), 0.5 + eps * b.sin()]));
    }
    pairs
}

// Lipschitz bounds. The elevated concentric map stretches lengths in (s, t) by at most about
// 4.3, at the square's corners: 2 from [0,1] -> [-1,1], times 2 from dz/drho = -2 rho at the
// horizon, with the azimuthal term (pi/4 per unit of a at b/a = 1) on top. The inverse
// stretches by at most about 0.7 per radian. `interior_lipschitz_constant_is_below_the_bound`
// measures both. A discontinuity (a wrong sign or offset in one region) gives ratios of order
// 1 / eps instead.
const C_FORWARD: f64 = 6.0;
const C_INVERSE: f64 = 2.0;

fn forward_continuity<T: Real>(eps: f64) {
    let sq = |p: [f64; 2], q: [f64; 2]| dist2(p, q);
    for (name, pairs) in [("borders", square_border_pairs(eps)), ("centre", square_centre_pairs(eps))] {
        let r = max_ratio(&pairs, |p| fwd::<T>(p[0], p[1]), sq, |a, b| dist3(*a, *b));
        assert!(r < C_FORWARD, "{} forward ratio {r} at the {name}", core::any::type_name::<T>());
        let r = max_ratio(&pairs, |p| fwd_disk::<T>(p[0], p[1]), sq, |a, b| dist2(*a, *b));
        assert!(r < C_FORWARD, "{} disk ratio {r} at the {name}", core::any::type_name::<T>());
    }
}

#[test]
fn continuity_forward_across_region_borders_and_centre() {
    forward_continuity::<f64>(1e-9);
    forward_continuity::<f32>(1e-4);
}

#[test]
fn interior_lipschitz_constant_is_below_the_bound() {
    // Makes sure C_FORWARD / C_INVERSE are not so loose that they would hide a jump of the size
    // an epsilon-pair could see: away from the borders the ratio is well below them.
    let mut rng = SplitMix(11);
    let (mut fwd_max, mut inv_max): (f64, f64) = (0.0, 0.0);
    for _ in 0..20_000 {
        let p = [rng.next_f64(), rng.next_f64()];
        let q = [p[0] + 1e-7 * (rng.next_f64() - 0.5), p[1] + 1e-7 * (rng.next_f64() - 0.5)];
        let (dp, dq) = (fwd::<f64>(p[0], p[1]), fwd::<f64>(q[0], q[1]));
        fwd_max = fwd_max.max(dist3(dp, dq) / dist2(p, q));
        inv_max = inv_max.max(dist2(inv::<f64>(dp), inv::<f64>(dq)) / angle_between(dp, dq));
    }
    assert!(fwd_max > 3.0 && fwd_max < C_FORWARD, "forward Lipschitz estimate {fwd_max}");
    assert!(inv_max > 0.5 && inv_max < C_INVERSE, "inverse Lipschitz estimate {inv_max}");
}

/// Direction pairs `eps` (in azimuth) either side of the inverse's region borders (the disk
/// diagonals phi = pi/4 + k pi/2) and of the axes (phi = k pi/2, where the reflection and the
/// atan2 branch cut at phi = pi sit), at many polar angles; and pairs straddling the pole.
fn direction_pairs(eps: f64) -> Vec<([f64; 3], [f64; 3])> {
    let mut pairs = Vec::new();
    for k in 0..8 {
        let phi = FRAC_PI_4 * k as f64;
        for i in 1..=90 {
            let theta = FRAC_PI_2 * i as f64 / 90.0;
            pairs.push((dir_from_angles(theta, phi - eps), dir_from_angles(theta, phi + eps)));
        }
    }
    for k in 0..64 {
        let phi = TAU * k as f64 / 64.0 + 0.003;
        pairs.push((dir_from_angles(eps, phi), dir_from_angles(eps, phi + PI)));
        pairs.push((dir_from_angles(eps, phi), [0.0, 0.0, 1.0]));
    }
    pairs
}

fn inverse_continuity<T: Real>(eps: f64) {
    let pairs = direction_pairs(eps);
    let r = max_ratio(&pairs, inv::<T>, angle_between, |a, b| dist2(*a, *b));
    assert!(r < C_INVERSE, "{} inverse ratio {r}", core::any::type_name::<T>());
    let r = max_ratio(
        &pairs,
        |d| inv_disk::<T>([d[0], d[1]]),
        |p, q| dist2([p[0], p[1]], [q[0], q[1]]),
        |a, b| dist2(*a, *b),
    );
    // The disk inverse is Lipschitz with constant 4/pi * sqrt(1 + (pi/4)^2)/2 ~ 0.81 per unit.
    assert!(r < C_INVERSE, "{} disk inverse ratio {r}", core::any::type_name::<T>());
}

#[test]
fn continuity_inverse_across_region_borders_and_pole() {
    inverse_continuity::<f64>(1e-9);
    inverse_continuity::<f32>(1e-3);
}

// ---------------------------------------------------------------------------------------------
// 4. inverse at the pole and the horizon

#[test]
fn inverse_pole_is_exact() {
    assert_eq!(hemisphere_to_square([0.0f64, 0.0, 1.0]), [0.5, 0.5]);
    assert_eq!(hemisphere_to_square([0.0f32, 0.0, 1.0]), [0.5, 0.5]);
    // Non-unit and signed-zero poles too: no 0/0 anywhere.
    assert_eq!(hemisphere_to_square([-0.0f64, -0.0, 1.0 + 1e-9]), [0.5, 0.5]);
    assert_eq!(hemisphere_to_square([0.0f32, -0.0, 0.999_999]), [0.5, 0.5]);
    assert_eq!(hemisphere_to_disk([0.0f64, 0.0, 1.0]), [0.0, 0.0]);
    assert_eq!(disk_to_square(0.0f64, 0.0), [0.5, 0.5]);
    assert_eq!(disk_to_square(-0.0f32, -0.0), [0.5, 0.5]);
    // and the forward centre is exactly the pole
    assert_eq!(square_to_hemisphere(0.5f64, 0.5), [0.0, 0.0, 1.0]);
    assert_eq!(square_to_hemisphere(0.5f32, 0.5), [0.0, 0.0, 1.0]);
    assert_eq!(square_to_disk(0.5f64, 0.5), [0.0, 0.0]);
}

fn boundary_distance(st: [f64; 2]) -> f64 {
    // max(|2s - 1|, |2t - 1|) is 1 exactly on the square's boundary
    (2.0 * st[0] - 1.0).abs().max((2.0 * st[1] - 1.0).abs())
}

fn horizon_maps_to_boundary<T: Real>() {
    let mut phis: Vec<f64> = (0..16).map(|k| FRAC_PI_4 / 2.0 * k as f64).collect();
    let mut rng = SplitMix(3);
    phis.extend((0..200).map(|_| TAU * rng.next_f64()));
    for phi in phis {
        // exact horizon, z slightly negative, slightly non-unit, and a below-horizon direction
        for (scale, z) in [(1.0, 0.0), (1.0, -1e-7), (1.0 + 1e-6, 0.0), (1.0 - 1e-6, -0.0), (1.0, -0.3)] {
            let d = [scale * phi.cos(), scale * phi.sin(), z];
            let st = inv::<T>(d);
            let m = boundary_distance(st);
            assert!(
                (m - 1.0).abs() <= 1e-6,
                "{}: phi {phi}, z {z}: max(|2s-1|,|2t-1|) = {m}",
                core::any::type_name::<T>()
            );
            assert!(st.iter().all(|v| (0.0..=1.0).contains(v)));
            // and it is the boundary point with that azimuth
            let back = fwd::<T>(st[0], st[1]);
            assert!(angle_between(back, [phi.cos(), phi.sin(), 0.0]) < 1e-5, "phi {phi}: back to {back:?}");
        }
    }
}

#[test]
fn inverse_horizon_lands_on_square_boundary() {
    horizon_maps_to_boundary::<f32>();
    horizon_maps_to_boundary::<f64>();
}

#[test]
fn inverse_horizon_cardinal_points() {
    let cases = [(0.0, [1.0, 0.5]), (FRAC_PI_2, [0.5, 1.0]), (PI, [0.0, 0.5]), (3.0 * FRAC_PI_2, [0.5, 0.0])];
    for (phi, want) in cases {
        let d = [phi.cos(), phi.sin(), 0.0];
        for got in [inv::<f64>(d), inv::<f32>(d)] {
            assert!(dist2(got, want) < 1e-6, "phi {phi}: {got:?}, want {want:?}");
        }
    }
    // The diagonals reach the corners.
    for (k, want) in [(1.0, [1.0, 1.0]), (3.0, [0.0, 1.0]), (5.0, [0.0, 0.0]), (7.0, [1.0, 0.0])] {
        let phi = FRAC_PI_4 * k;
        let got = inv::<f64>([phi.cos(), phi.sin(), 0.0]);
        assert!(dist2(got, want) < 1e-12, "phi {phi}: {got:?}, want {want:?}");
    }
}

#[test]
fn forward_boundary_is_exactly_the_horizon() {
    for u in unit_grid(257) {
        for p in [[0.0, u], [1.0, u], [u, 0.0], [u, 1.0]] {
            assert_eq!(fwd::<f64>(p[0], p[1])[2], 0.0, "at {p:?}");
            assert_eq!(fwd::<f32>(p[0], p[1])[2], 0.0, "at {p:?}");
        }
    }
}

// ---------------------------------------------------------------------------------------------
// 5. orientation

#[test]
fn orientation_of_the_tangent_frame() {
    let cases: [([f64; 2], [f64; 3]); 5] = [
        ([1.0, 0.5], [1.0, 0.0, 0.0]),
        ([0.5, 1.0], [0.0, 1.0, 0.0]),
        ([0.0, 0.5], [-1.0, 0.0, 0.0]),
        ([0.5, 0.0], [0.0, -1.0, 0.0]),
        ([0.5, 0.5], [0.0, 0.0, 1.0]),
    ];
    for (p, want) in cases {
        for got in [fwd::<f64>(p[0], p[1]), fwd::<f32>(p[0], p[1])] {
            assert!(dist3(got, want) < 1e-7, "{p:?} -> {got:?}, want {want:?}");
        }
        let disk = fwd_disk::<f64>(p[0], p[1]);
        assert!(dist2(disk, [want[0], want[1]]) < 1e-15, "disk {p:?} -> {disk:?}");
    }
    // phi grows from +x towards +y (counter-clockwise seen from +z): along the right edge,
    // t = 0.75 is a quarter of the way from +x to the corner, i.e. phi = pi/8.
    let [rho, phi] = square_to_polar(1.0f64, 0.75);
    assert!((rho - 1.0).abs() < 1e-15 && (phi - PI / 8.0).abs() < 1e-15, "{rho} {phi}");
    let d = fwd::<f64>(0.75, 0.6);
    assert!(d[0] > 0.0 && d[1] > 0.0 && d[0] > d[1], "{d:?}");
}

// ---------------------------------------------------------------------------------------------
// robustness: no panics, sensible handling of junk

#[test]
fn out_of_range_and_non_finite_inputs_do_not_panic() {
    // Outside the square: clamped.
    assert_eq!(square_to_hemisphere(1.5f64, 0.5), square_to_hemisphere(1.0, 0.5));
    assert_eq!(square_to_disk(-0.1f32, 2.0), square_to_disk(0.0, 1.0));
    // Outside the disk: radially onto the circle.
    let st = disk_to_square(2.0f64, 0.0);
    assert_eq!(st, [1.0, 0.5]);
    let st = disk_to_square(1.0f64 + 1e-9, 1e-12);
    assert!(boundary_distance(st) == 1.0, "{st:?}");
    let d = disk_to_hemisphere(3.0f64, 4.0);
    assert!(dist3(d, [0.6, 0.8, 0.0]) < 1e-15, "{d:?}");
    // Degenerate directions.
    assert_eq!(hemisphere_to_square([0.0f64, 0.0, -1.0]), [1.0, 0.5]);
    assert_eq!(hemisphere_to_square([0.0f64, 0.0, 0.0]), [1.0, 0.5]);
    assert_eq!(hemisphere_to_disk([0.0f64, 0.0, 0.0]), [1.0, 0.0]);
    // NaN in, NaN out (no panic, no silent valid-looking value).
    assert!(square_to_hemisphere(f64::NAN, 0.5).iter().any(|v| v.is_nan()));
    assert!(hemisphere_to_square([f32::NAN, 0.0, 1.0]).iter().any(|v| v.is_nan()));
    assert!(hemisphere_to_square([0.1f64, 0.0, f64::NAN]).iter().any(|v| v.is_nan()));
    assert!(disk_to_square(f64::NAN, f64::NAN).iter().any(|v| v.is_nan()));
    let _ = polar_to_square(f64::INFINITY, f64::INFINITY);
    let _ = hemisphere_to_square([f64::INFINITY, 1.0, 1.0]);
}

#[test]
fn hemisphere_to_disk_inverts_disk_to_hemisphere() {
    for d in hemisphere_test_dirs() {
        let p = hemisphere_to_disk(d);
        let back = disk_to_hemisphere(p[0], p[1]);
        assert!(angle_between(d, back) < 1e-12, "{d:?} -> {p:?} -> {back:?}");
        let st = hemisphere_to_square(d);
        let via_disk = disk_to_square(p[0], p[1]);
        assert!(dist2(st, via_disk) < 1e-12, "{d:?}: {st:?} vs {via_disk:?}");
    }
}

// ---------------------------------------------------------------------------------------------
// 6. batches

fn batch_equals_scalar<T: Real + PartialEq>(n: usize) {
    let mut rng = SplitMix(n as u64);
    let st: Vec<[T; 2]> = (0..n).map(|_| [T::from_f64(rng.next_f64()), T::from_f64(rng.next_f64())]).collect();
    let mut dirs = vec![[T::ZERO; 3]; n];
    square_to_hemisphere_batch(&st, &mut dirs).expect("same lengths");
    let mut back = vec![[T::ZERO; 2]; n];
    hemisphere_to_square_batch(&dirs, &mut back).expect("same lengths");
    let mut disk = vec![[T::ZERO; 2]; n];
    square_to_disk_batch(&st, &mut disk).expect("same lengths");
    let mut back_disk = vec![[T::ZERO; 2]; n];
    disk_to_square_batch(&disk, &mut back_disk).expect("same lengths");
    for i in 0..n {
        let [s, t] = st[i];
        assert_eq!(dirs[i], square_to_hemisphere(s, t), "element {i}");
        assert_eq!(back[i], hemisphere_to_square(dirs[i]), "element {i}");
        assert_eq!(disk[i], square_to_disk(s, t), "element {i}");
        assert_eq!(back_disk[i], disk_to_square(disk[i][0], disk[i][1]), "element {i}");
    }
}

#[test]
fn batches_equal_scalar_maps() {
    for n in [0, 1, 1000, PARALLEL_THRESHOLD - 1, PARALLEL_THRESHOLD, 3 * PARALLEL_THRESHOLD + 17] {
        batch_equals_scalar::<f32>(n);
        batch_equals_scalar::<f64>(n);
    }
}

#[test]
fn batch_length_mismatch_is_an_error_and_leaves_output_alone() {
    let st = vec![[0.25f64, 0.75]; 10];
    let mut out3 = vec![[7.0f64; 3]; 9];
    let err = square_to_hemisphere_batch(&st, &mut out3).unwrap_err();
    assert_eq!(err, LengthMismatch { input: 10, output: 9 });
    assert!(out3.iter().all(|v| *v == [7.0; 3]), "output was modified");

    let dirs = vec![[0.0f32, 0.0, 1.0]; 3];
    let mut out2 = vec![[7.0f32; 2]; 4];
    assert_eq!(hemisphere_to_square_batch(&dirs, &mut out2), Err(LengthMismatch { input: 3, output: 4 }));
    assert!(out2.iter().all(|v| *v == [7.0; 2]));

    let big = vec![[0.5f64, 0.5]; PARALLEL_THRESHOLD + 1];
    let mut out = vec![[0.0f64; 2]; PARALLEL_THRESHOLD];
    assert!(square_to_disk_batch(&big, &mut out).is_err());
    assert!(disk_to_square_batch(&big[..5], &mut out).is_err());
    assert!(disk_to_square_batch(&big[..0], &mut out[..0]).is_ok());

    let msg = err.to_string();
    assert!(msg.contains("10") && msg.contains('9'), "{msg}");
    let _: &dyn std::error::Error = &err;
}

#[test]
fn inverse_is_scale_invariant_even_for_extreme_lengths() {
    // Only the direction counts: tiny and huge vectors must not underflow or overflow to NaN.
    for k in [1e-30f32, 1e-20, 1.0, 1e20, 3e37] {
        let st = hemisphere_to_square([k, 0.5 * k, k]);
        let want = hemisphere_to_square([1.0f32, 0.5, 1.0]);
        assert!((st[0] - want[0]).abs() < 1e-6 && (st[1] - want[1]).abs() < 1e-6, "{k}: {st:?} vs {want:?}");
        let xy = hemisphere_to_disk([k, 0.5 * k, k]);
        assert!(xy.iter().all(|v| v.is_finite()));
    }
    for k in [1e-300f64, 1e300] {
        let st = hemisphere_to_square([k, k, k]);
        let want = hemisphere_to_square([1.0f64, 1.0, 1.0]);
        assert!((st[0] - want[0]).abs() < 1e-12 && (st[1] - want[1]).abs() < 1e-12, "{k}: {st:?}");
    }
}

#[test]
fn map_apply_matches_the_scalar_maps_in_both_precisions() {
    // Flat arrays on both sides of the parallel threshold, each value compared with the scalar map
    // (bit for bit: the batch must be the same function, only applied many times).
    fn check<T: Real>(n: usize) {
        let mut rng = SplitMix(11);
        let st: Vec<T> = (0..2 * n).map(|_| T::from_f64(rng.next_f64())).collect();
        let disk = Map::SquareToDisk.apply(&st).unwrap();
        let dirs = Map::SquareToHemisphere.apply(&st).unwrap();
        assert_eq!((disk.len(), dirs.len()), (2 * n, 3 * n));
        for i in 0..n {
            let (s, t) = (st[2 * i], st[2 * i + 1]);
            let d = square_to_disk(s, t);
            assert!(disk[2 * i].to_f64() == d[0].to_f64() && disk[2 * i + 1].to_f64() == d[1].to_f64());
            let h = square_to_hemisphere(s, t);
            for k in 0..3 {
                assert!(dirs[3 * i + k].to_f64() == h[k].to_f64(), "point {i}");
            }
        }
        let back = Map::HemisphereToSquare.apply(&dirs).unwrap();
        let back_disk = Map::DiskToSquare.apply(&disk).unwrap();
        for i in 0..n {
            let want = hemisphere_to_square([dirs[3 * i], dirs[3 * i + 1], dirs[3 * i + 2]]);
            assert!(back[2 * i].to_f64() == want[0].to_f64() && back[2 * i + 1].to_f64() == want[1].to_f64());
            let want = disk_to_square(disk[2 * i], disk[2 * i + 1]);
            assert!(back_disk[2 * i].to_f64() == want[0].to_f64() && back_disk[2 * i + 1].to_f64() == want[1].to_f64());
        }
    }
    for n in [0, 1, 1000, PARALLEL_THRESHOLD + 17] {
        check::<f32>(n);
        check::<f64>(n);
    }
    // Known values, independent of the code above: the centre is the pole, (1, 0.5) is +x.
    assert_eq!(Map::SquareToHemisphere.apply(&[0.5f64, 0.5, 1.0, 0.5]).unwrap()[..3], [0.0, 0.0, 1.0]);
    let px = Map::SquareToHemisphere.apply(&[1.0f64, 0.5]).unwrap();
    assert!((px[0] - 1.0).abs() < 1e-15 && px[1].abs() < 1e-15 && px[2].abs() < 1e-15, "{px:?}");
    assert_eq!(Map::HemisphereToSquare.apply(&[0.0f32, 0.0, 1.0]).unwrap(), vec![0.5, 0.5]);
}

#[test]
fn map_apply_rejects_ragged_and_non_finite_input() {
    assert_eq!(Map::SquareToDisk.apply(&[0.5f64; 3]), Err(BatchError::Length { len: 3, dim: 2 }));
    assert_eq!(Map::HemisphereToSquare.apply(&[0.0f32; 4]), Err(BatchError::Length { len: 4, dim: 3 }));
    assert_eq!(Map::DiskToSquare.apply(&[0.1f64, 0.2, f64::NAN, 0.0]), Err(BatchError::NotFinite { index: 2 }));
    assert_eq!(
        Map::SquareToHemisphere.apply(&[0.5f32, f32::INFINITY, f32::NAN, 0.5]),
        Err(BatchError::NotFinite { index: 1 })
    );
    assert_eq!(Map::SquareToDisk.apply::<f64>(&[]), Ok(Vec::new()));
    assert_eq!((Map::HemisphereToSquare.input_dim(), Map::HemisphereToSquare.output_dim()), (3, 2));
    assert_eq!((Map::SquareToHemisphere.input_dim(), Map::SquareToHemisphere.output_dim()), (2, 3));
    let msg = BatchError::NotFinite { index: 7 }.to_string();
    assert!(msg.contains("flat index 7"), "{msg}");
    assert!(BatchError::Length { len: 5, dim: 3 }.to_string().contains("5 values"));
}
