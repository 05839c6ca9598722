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
//! length mismatch as a [`LengthMismatch`] error. [`Map`] names each map at run time and applies
//! it to a flat coordinate array (`[n, 2]` or `[n, 3]` values), rejecting NaN and infinite
//! coordinates with a [`BatchError`]: the form bindings and file readers need.

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
    fill(input, out, f);
    Ok(())
}

/// [`map_into`] for slices of equal length (the caller checked).
#[inline]
fn fill<I, O, F>(input: &[I], out: &mut [O], f: F)
where
    I: Sync,
    O: Send,
    F: Fn(&I) -> O + Sync,
{
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

/// One of the maps of this crate, named at run time, for flat coordinate arrays: a `[..., 2]` or
/// `[..., 3]` array of any batch shape is, row-major, `n` points of [`Map::input_dim`] values.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Map {
    /// [`square_to_disk`]: square `(s, t)` to disk `(x, y)`.
    SquareToDisk,
    /// [`disk_to_square`]: disk `(x, y)` to square `(s, t)`.
    DiskToSquare,
    /// [`square_to_hemisphere`]: square `(s, t)` to a unit direction `(x, y, z)`.
    SquareToHemisphere,
    /// [`hemisphere_to_square`]: a direction `(x, y, z)` to square `(s, t)`.
    HemisphereToSquare,
}

/// Why [`Map::apply`] rejected a flat array.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BatchError {
    /// The array's length is not a multiple of the map's [`Map::input_dim`].
    Length {
        /// Values in the array.
        len: usize,
        /// Values per point the map takes.
        dim: usize,
    },
    /// A coordinate is NaN or infinite: the maps would carry it into the output unnoticed.
    NotFinite {
        /// Its flat index in the array (the first such one).
        index: usize,
    },
}

impl core::fmt::Display for BatchError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match *self {
            BatchError::Length { len, dim } => {
                write!(f, "expected points of {dim} values, got {len} values (not a multiple of {dim})")
            }
            BatchError::NotFinite { index } => write!(f, "value at flat index {index} is not finite"),
        }
    }
}

impl std::error::Error for BatchError {}

impl Map {
    /// Values per input point: 3 for [`Map::HemisphereToSquare`], else 2.
    pub const fn input_dim(self) -> usize {
        match self {
            Map::HemisphereToSquare => 3,
            _ => 2,
        }
    }

    /// Values per output point: 3 for [`Map::SquareToHemisphere`], else 2.
    pub const fn output_dim(self) -> usize {
        match self {
            Map::SquareToHemisphere => 3,
            _ => 2,
        }
    }

    /// The map applied to every point of the flat array `input` (`n * input_dim()` values, point
    /// after point), giving `n * output_dim()` values in the same order; in parallel above
    /// [`PARALLEL_THRESHOLD`] points.
    ///
    /// # Errors
    /// [`BatchError::Length`] if `input.len()` is not a multiple of [`Map::input_dim`],
    /// [`BatchError::NotFinite`] for the first NaN or infinite value.
    pub fn apply<T: Real>(self, input: &[T]) -> Result<Vec<T>, BatchError> {
        let dim = self.input_dim();
        if !input.len().is_multiple_of(dim) {
            return Err(BatchError::Length { len: input.len(), dim });
        }
        if let Some(index) = input.iter().position(|v| !v.is_finite()) {
            return Err(BatchError::NotFinite { index });
        }
        Ok(match self {
            Map::SquareToDisk => flat(input, |&[s, t]: &[T; 2]| square_to_disk(s, t)),
            Map::DiskToSquare => flat(input, |&[x, y]: &[T; 2]| disk_to_square(x, y)),
            Map::SquareToHemisphere => flat(input, |&[s, t]: &[T; 2]| square_to_hemisphere(s, t)),
            Map::HemisphereToSquare => flat(input, |&d: &[T; 3]| hemisphere_to_square(d)),
        })
    }
}

/// `f` over the `I`-value points of `input` (whose length is a multiple of `I`), flattened.
fn flat<T: Real, const I: usize, const O: usize>(input: &[T], f: impl Fn(&[T; I]) -> [T; O] + Sync) -> Vec<T> {
    let (points, _) = input.as_chunks::<I>();
    let mut out = vec![[T::ZERO; O]; points.len()];
    fill(points, &mut out, f);
    out.into_flattened()
}

#[cfg(test)]
mod tests;
