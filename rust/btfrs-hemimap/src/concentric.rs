//! Scalar forms of the concentric map `Phi`, the elevation map `Psi` and the elevated concentric
//! map `Omega = Psi o Phi`, with their inverses (paper 004, section 6.1; Shirley & Chiu 1997).
//!
//! Everything is built from two private kernels:
//!
//! * [`square_to_signed_polar`]: the forward concentric map in "signed radius" form
//!   `(r, phi)` with `r = +-rho`. Letting the radius carry the sign folds the paper's four
//!   regions into two branches (`|a| >= |b|` and `|a| < |b|`): region 3 is region 1 seen through
//!   `(r, phi) -> (-r, phi)`, which is the point reflection through the centre, and region 4 is
//!   region 2 likewise. `r cos phi`, `r sin phi` are then the disk point with no extra `+ pi`.
//! * [`radius_azimuth_to_square`]: the inverse, given the disk radius `rho` and any vector with
//!   the point's azimuth (the disk point itself, or the direction's `(x, y)`: the elevation map
//!   keeps the azimuth, so the inverse never has to form the disk point).

use crate::real::Real;

/// Forward concentric map in signed-radius form: `(s, t) in [0,1]^2 -> (r, phi)` with
/// `|r| = rho` the disk radius and `(r cos phi, r sin phi)` the disk point.
///
/// `phi` lies in `[-pi/4, pi/4]` on the branch `|a| >= |b|` and in `[pi/4, 3pi/4]` on the other.
#[inline(always)]
fn square_to_signed_polar<T: Real>(s: T, t: T) -> (T, T) {
    // To [-1, 1]^2. Inputs are clamped first so that rounding noise just outside the square
    // (1 + 1e-7, say) lands on the horizon instead of making sqrt(2 - r^2) grow toward NaN.
    let a = T::TWO * s.clamp(T::ZERO, T::ONE) - T::ONE;
    let b = T::TWO * t.clamp(T::ZERO, T::ONE) - T::ONE;
    // Split by the diagonals |a| = |b| and divide by the coordinate of larger magnitude: the
    // quotient is then always in [-1, 1], so nothing blows up near the axes (a polar-style
    // atan(b / a) would divide by a -> 0 on the whole line a = 0). The only 0/0 left is the
    // centre itself, where both coordinates vanish; it is the pole and is returned directly.
    if a.abs() >= b.abs() {
        // Regions 1 (a > 0) and 3 (a < 0): concentric square of half-width |a|, the side
        // coordinate b/a in [-1, 1] maps linearly onto an angle in [-pi/4, pi/4].
        if a == T::ZERO {
            return (T::ZERO, T::ZERO);
        }
        (a, T::FRAC_PI_4 * (b / a))
    } else {
        // Regions 2 (b > 0) and 4 (b < 0): the same with the roles of a and b swapped, measured
        // from +y (phi = pi/2) so that the two branches agree on the diagonals, where
        // a / b = +-1 gives phi = pi/4 or 3pi/4 exactly as the first branch's limit does.
        (b, T::FRAC_PI_2 - T::FRAC_PI_4 * (a / b))
    }
}

/// Inverse concentric map: disk radius `rho in [0, 1]` and a vector `(x, y)` with the point's
/// azimuth (its length does not matter) `-> (s, t) in [0, 1]^2`.
#[inline(always)]
fn radius_azimuth_to_square<T: Real>(rho: T, x: T, y: T) -> [T; 2] {
    // The region is decided by comparing |x| and |y| rather than by the value of an angle: the
    // concentric map sends the square's diagonals to the disk's diagonals (phi = pi/4 + k pi/2),
    // so "|x| >= |y|" is exactly "regions 1 or 3" and needs no trigonometry, and ties on the
    // diagonal go to the first branch in both directions of the map.
    //
    // Within a branch the point is reflected through the centre onto the positive half-axis
    // (x >= 0, resp. y >= 0), carrying the sign on the radius as the forward map does. The
    // angle from that half-axis is then in [-pi/4, pi/4], and it is computed with atan2 of the
    // reflected point rather than atan(y / x): atan2 needs no division, is accurate for tiny
    // arguments and returns 0 for (0, 0), so the pole (rho = 0, azimuth undefined) falls
    // through to (0.5, 0.5) exactly without a special case. Reflecting first also keeps us
    // away from atan2's branch cut at phi = pi, which would otherwise split region 3 in two.
    //
    // Both branches are written as one: u is the coordinate along the region's axis (x in
    // regions 1 and 3, y in 2 and 4) and v the one across it. In regions 2 and 4 the angle
    // atan2(x, y) is measured from +y towards +x, i.e. it is pi/2 - phi = atan(x / y), which is
    // what the forward map's a / b = (pi/2 - phi) / (pi/4) needs. Selecting the operands leaves a
    // single atan2 call and no data-dependent control flow around it.
    let swap = y.abs() > x.abs();
    let (u, v) = if swap { (y, x) } else { (x, y) };
    let (r, u, v) = if u < T::ZERO { (-rho, -u, -v) } else { (rho, u, v) };
    let side = r * (v.atan2(u) * T::FRAC_4_PI);
    let (a, b) = if swap { (side, r) } else { (r, side) };
    // phi * 4/pi can exceed 1 by an ulp on the diagonals; clamp so the result stays in the square.
    [((a + T::ONE) * T::HALF).clamp(T::ZERO, T::ONE), ((b + T::ONE) * T::HALF).clamp(T::ZERO, T::ONE)]
}

/// Scale a direction by its largest component so that squaring it can neither overflow (huge
/// vectors) nor underflow to zero (tiny ones); only the direction matters to the inverses.
#[inline]
fn rescale<T: Real>(d: [T; 3]) -> [T; 3] {
    let m = d[0].abs();
    let m = if d[1].abs() > m { d[1].abs() } else { m };
    let m = if d[2].abs() > m { d[2].abs() } else { m };
    if m > T::ZERO {
        [d[0] / m, d[1] / m, d[2] / m]
    } else {
        d
    }
}

/// Disk radius `rho` of the elevation map's preimage of direction `(x, y, z)`, i.e. the inverse
/// of `z = 1 - rho^2`, computed without cancellation and independent of the vector's length.
///
/// `1 - z` loses all precision near the pole (in `f32`, `z = 1 - 1e-8` rounds to 1). With
/// `n = |d|` and `h^2 = x^2 + y^2`, `1 - z/n = (n^2 - z^2) / (n (n + z)) = h^2 / (n^2 + n z)`,
/// which has no subtraction at all; dividing by `n` also makes slightly non-unit input harmless.
#[inline(always)]
fn elevation_radius<T: Real>(x: T, y: T, z: T) -> T {
    // On or below the horizon (z slightly negative from rounding, or a direction below the
    // tangent plane) the direction is taken to be on the horizon: rho = 1 exactly, so the
    // inverse lands exactly on the square's boundary. NaN z goes to the formula and stays NaN.
    if z <= T::ZERO {
        return T::ONE;
    }
    let h2 = x * x + y * y;
    let n2 = h2 + z * z;
    let n = n2.sqrt();
    // At the pole h2 = 0 and the denominator is 2 z^2 > 0: rho = 0 exactly, no 0/0.
    (h2 / (n2 + n * z)).sqrt().clamp(T::ZERO, T::ONE)
}

/// The concentric map `Phi`: unit square `(s, t) in [0,1]^2` to the unit disk `(x, y)`.
///
/// Concentric squares around `(0.5, 0.5)` map to concentric circles, the square's boundary to
/// the unit circle; `(1, 0.5) -> (1, 0)`, `(0.5, 1) -> (0, 1)`. Inputs outside `[0, 1]` are
/// clamped onto the square. The map is area-preserving up to the factor `pi / 4`.
#[inline]
pub fn square_to_disk<T: Real>(s: T, t: T) -> [T; 2] {
    let (r, phi) = square_to_signed_polar(s, t);
    let (sin, cos) = phi.sin_cos();
    [r * cos, r * sin]
}

/// Inverse of [`square_to_disk`]: unit disk `(x, y)` to the unit square `(s, t)`.
///
/// Points outside the unit disk are moved radially onto its boundary (so they land on the
/// square's boundary); the centre maps to `(0.5, 0.5)` exactly.
#[inline]
pub fn disk_to_square<T: Real>(x: T, y: T) -> [T; 2] {
    let rho = (x * x + y * y).sqrt().clamp(T::ZERO, T::ONE);
    radius_azimuth_to_square(rho, x, y)
}

/// The concentric map in the paper's polar form: `(s, t) -> [rho, phi]`, `rho in [0, 1]`,
/// `phi in [0, 2 pi]` measured from `+x` towards `+y` (`phi = 0` at the centre).
#[inline]
pub fn square_to_polar<T: Real>(s: T, t: T) -> [T; 2] {
    let (r, phi) = square_to_signed_polar(s, t);
    // Undo the signed-radius folding: a negative radius is the same point at phi + pi.
    let (rho, phi) = if r < T::ZERO { (-r, phi + T::PI) } else { (r, phi) };
    // phi is now in [-pi/4, 7pi/4]; move the sliver below 0 up by a full turn.
    let phi = if phi < T::ZERO { phi + T::TAU } else { phi };
    [rho, phi]
}

/// Inverse of [`square_to_polar`]: `(rho, phi) -> (s, t)`. Any real `phi` is accepted (it is
/// only used through its sine and cosine); `rho` is clamped to `[0, 1]`.
#[inline]
pub fn polar_to_square<T: Real>(rho: T, phi: T) -> [T; 2] {
    let (sin, cos) = phi.sin_cos();
    radius_azimuth_to_square(rho.clamp(T::ZERO, T::ONE), cos, sin)
}

/// The elevation map `Psi` in Cartesian form: unit disk `(x, y)` to the unit upper hemisphere,
/// `rho -> (rho sqrt(2 - rho^2) cos phi, rho sqrt(2 - rho^2) sin phi, 1 - rho^2)`.
///
/// It is equal-area (up to the factor `2`): `z = 1 - rho^2` is uniform when the point is uniform
/// on the disk. Points outside the disk are moved radially onto its boundary (the horizon).
#[inline]
pub fn disk_to_hemisphere<T: Real>(x: T, y: T) -> [T; 3] {
    let r2 = x * x + y * y;
    let (x, y, r2) = if r2 > T::ONE {
        let r = r2.sqrt();
        (x / r, y / r, T::ONE)
    } else {
        (x, y, r2)
    };
    let k = (T::TWO - r2).sqrt();
    [k * x, k * y, T::ONE - r2]
}

/// Inverse of [`disk_to_hemisphere`]: direction `d = (x, y, z)` to the unit disk.
///
/// `d` need not be exactly unit (only its direction is used). Directions with `z <= 0` are
/// treated as on the horizon and map onto the unit circle; the pole maps to `(0, 0)` exactly.
/// For `d = (0, 0, z <= 0)`, whose azimuth is undefined, the result is `(1, 0)`.
#[inline]
pub fn hemisphere_to_disk<T: Real>(d: [T; 3]) -> [T; 2] {
    let [x, y, z] = rescale(d);
    let rho = elevation_radius(x, y, z);
    let h2 = x * x + y * y;
    if h2 > T::ZERO {
        let scale = rho / h2.sqrt();
        [x * scale, y * scale]
    } else {
        [rho, T::ZERO]
    }
}

/// The elevated concentric map `Omega = Psi o Phi`: unit square to unit hemisphere (z = normal).
///
/// Equal-area: a uniform sampling of the square gives a uniform sampling of the hemisphere.
/// `(0.5, 0.5)` maps to the pole `(0, 0, 1)`, the square's boundary to the horizon `z = 0`,
/// `(1, 0.5)` to `+x` and `(0.5, 1)` to `+y`. Inputs outside `[0, 1]` are clamped.
#[inline]
pub fn square_to_hemisphere<T: Real>(s: T, t: T) -> [T; 3] {
    let (r, phi) = square_to_signed_polar(s, t);
    let r2 = r * r;
    // The signed radius carries the point reflection of regions 3 and 4 into x and y; z only
    // sees r^2. On the boundary r = +-1 gives z = 0 exactly, at the centre z = 1 exactly.
    let k = r * (T::TWO - r2).sqrt();
    let (sin, cos) = phi.sin_cos();
    [k * cos, k * sin, T::ONE - r2]
}

/// Inverse of [`square_to_hemisphere`]: direction `d = (x, y, z)` to `(s, t) in [0, 1]^2`.
///
/// `d` need not be exactly unit (only its direction is used). Directions with `z <= 0` (e.g.
/// slightly negative from rounding) are treated as on the horizon and land exactly on the
/// square's boundary; the pole `(0, 0, z > 0)` maps to `(0.5, 0.5)` exactly. For
/// `d = (0, 0, z <= 0)`, whose azimuth is undefined, the result is `(1, 0.5)`.
#[inline]
pub fn hemisphere_to_square<T: Real>(d: [T; 3]) -> [T; 2] {
    let [x, y, z] = rescale(d);
    // The elevation map keeps the azimuth, so the direction's own (x, y) serves as the
    // azimuth vector: no need to build the disk point.
    radius_azimuth_to_square(elevation_radius(x, y, z), x, y)
}
