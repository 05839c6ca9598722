//! btfrs-hemimap: parameterising the hemisphere of directions by the unit square.
//!
//! A BTF is sampled at a few view and light directions; to resample it on a regular grid (and to
//! let texture hardware interpolate it, as the revised LPCA renderer does) each hemisphere of
//! directions is reparameterised by the unit square `[0, 1]^2`. Paper 004 (Schneider, "Real-time
//! BTF Rendering"), section 6.1 "Reparameterization", uses the *elevated concentric map*
//! `Omega = Psi o Phi`, because it preserves fractional area (a uniform grid on the square is a
//! fair sampling of the hemisphere), is bicontinuous and has low distortion:
//!
//! * `Phi`, the concentric map of Shirley & Chiu ("A Low Distortion Map between Disk and
//!   Square", Journal of Graphics Tools 2(3), 1997): the square is moved to `[-1, 1]^2`, split
//!   into four regions by its diagonals, and concentric squares are sent to concentric circles;
//!   in the first region `rho = s`, `phi = (pi/4) t/s`. See [`square_to_disk`],
//!   [`square_to_polar`] and their inverses.
//! * `Psi`, the elevation map `(rho, phi) -> (rho sqrt(2 - rho^2) cos phi,
//!   rho sqrt(2 - rho^2) sin phi, 1 - rho^2)`, equal-area from the disk to the hemisphere
//!   (a uniform point on the disk has uniform `rho^2`, hence uniform `z`). See
//!   [`disk_to_hemisphere`].
//! * `Omega` and its inverse: [`square_to_hemisphere`], [`hemisphere_to_square`].
//!
//! Conventions (shared by all btfrs crates): square coordinates `(s, t) in [0, 1]^2`; disk and
//! hemisphere in the local tangent frame with `z` the normal and the azimuth `phi` measured from
//! `+x` towards `+y`; directions are unit vectors with `z >= 0`. The square's centre
//! `(0.5, 0.5)` maps to the pole `(0, 0, 1)`, its boundary to the horizon `z = 0`, `(1, 0.5)` to
//! `+x` and `(0.5, 1)` to `+y`.
//!
//! All maps are generic over `f32` and `f64` through the sealed [`Real`] trait, never panic, and
//! have slice versions (`*_batch`) that run in parallel with rayon for large inputs and report a
//! length mismatch as a [`LengthMismatch`] error.

#![warn(missing_docs)]

mod concentric;
mod real;

pub use concentric::{
    disk_to_hemisphere, disk_to_square, hemisphere_to_disk, hemisphere_to_square, polar_to_square, square_to_disk,
    square_to_hemisphere, square_to_polar,
};
pub use real::Real;

use rayon::prelude::*;

/// Batches at least this long are processed in parallel. Each map costs tens of nanoseconds per
/// point, so below a few ten thousand points the thread hand-off costs more than it saves.
pub const PARALLEL_THRESHOLD: usize = 1 << 15;

/// Points per rayon task: large enough to amortise task overhead, small enough to balance.
const CHUNK: usize = 1 << 12;

/// The input and output slices of a batch function have different lengths.
///
/// Returned instead of panicking; the output slice is left untouched.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct LengthMismatch {
    /// Number of input points.
    pub input: usize,
    /// Length of the output slice.
    pub output: usize,
}

impl core::fmt::Display for LengthMismatch {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(f, "length mismatch: {} input points but an output slice of length {}", self.input, self.output)
    }
}

impl std::error::Error for LengthMismatch {}

/// Applies `f` element-wise from `input` into `out`, in parallel above [`PARALLEL_THRESHOLD`].
#[inline]
fn map_into<I, O, F>(input: &[I], out: &mut [O], f: F) -> Result<(), LengthMismatch>
where
    I: Sync,
    O: Send,
    F: Fn(&I) -> O + Sync,
{
    if input.len() != out.len() {
        return Err(LengthMismatch { input: input.len(), output: out.len() });
    }
    if input.len() < PARALLEL_THRESHOLD {
        for (o, i) in out.iter_mut().zip(input) {
            *o = f(i);
        }
    } else {
        out.par_chunks_mut(CHUNK).zip(input.par_chunks(CHUNK)).for_each(|(o, i)| {
            for (o, i) in o.iter_mut().zip(i) {
                *o = f(i);
            }
        });
    }
    Ok(())
}

/// [`square_to_hemisphere`] over a slice: `out[i] = square_to_hemisphere(st[i][0], st[i][1])`.
///
/// # Errors
/// [`LengthMismatch`] if `st.len() != out.len()` (then `out` is not modified).
pub fn square_to_hemisphere_batch<T: Real + Send + Sync>(
    st: &[[T; 2]],
    out: &mut [[T; 3]],
) -> Result<(), LengthMismatch> {
    map_into(st, out, |&[s, t]| square_to_hemisphere(s, t))
}

/// [`hemisphere_to_square`] over a slice: `out[i] = hemisphere_to_square(dirs[i])`.
///
/// # Errors
/// [`LengthMismatch`] if `dirs.len() != out.len()` (then `out` is not modified).
pub fn hemisphere_to_square_batch<T: Real + Send + Sync>(
    dirs: &[[T; 3]],
    out: &mut [[T; 2]],
) -> Result<(), LengthMismatch> {
    map_into(dirs, out, |&d| hemisphere_to_square(d))
}

/// [`square_to_disk`] over a slice: `out[i] = square_to_disk(st[i][0], st[i][1])`.
///
/// # Errors
/// [`LengthMismatch`] if `st.len() != out.len()` (then `out` is not modified).
pub fn square_to_disk_batch<T: Real + Send + Sync>(st: &[[T; 2]], out: &mut [[T; 2]]) -> Result<(), LengthMismatch> {
    map_into(st, out, |&[s, t]| square_to_disk(s, t))
}

/// [`disk_to_square`] over a slice: `out[i] = disk_to_square(xy[i][0], xy[i][1])`.
///
/// # Errors
/// [`LengthMismatch`] if `xy.len() != out.len()` (then `out` is not modified).
pub fn disk_to_square_batch<T: Real + Send + Sync>(xy: &[[T; 2]], out: &mut [[T; 2]]) -> Result<(), LengthMismatch> {
    map_into(xy, out, |&[x, y]| disk_to_square(x, y))
}

#[cfg(test)]
mod tests;
