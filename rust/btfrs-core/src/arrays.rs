//! Named, typed n-dimensional arrays: how a model or an analysis describes itself for saving.
//!
//! A model lists its arrays by name ([`NamedArrays`]) and rebuilds itself from them; the
//! `.btfrs` container (btfrs-io) stores exactly these arrays, and the Python bindings hand them
//! to numpy one for one. Keeping the names, dtypes and shapes in the model's own crate means a
//! Rust user can save and load a model without the bindings, and that a new model defines its
//! file layout in one place.
//!
//! Every accessor checks the shape it expects (`None` = any extent) and reports a mismatch as an
//! [`Error::InvalidArgument`] naming the array, so a bad file or a bad user array gets the same
//! clear message.

use crate::{Error, Result};

/// The element types an array may hold (the container's dtypes).
#[derive(Debug, Clone, PartialEq)]
pub enum ArrayData {
    /// `u8`
    U8(Vec<u8>),
    /// `u16`
    U16(Vec<u16>),
    /// `i32`
    I32(Vec<i32>),
    /// `f32`
    F32(Vec<f32>),
    /// `f64`
    F64(Vec<f64>),
}

impl ArrayData {
    /// Number of elements.
    pub fn len(&self) -> usize {
        match self {
            ArrayData::U8(v) => v.len(),
            ArrayData::U16(v) => v.len(),
            ArrayData::I32(v) => v.len(),
            ArrayData::F32(v) => v.len(),
            ArrayData::F64(v) => v.len(),
        }
    }

    /// True when there are no elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The dtype's name as the container and numpy spell it: "u8", "u16", "i32", "f32", "f64".
    pub fn dtype(&self) -> &'static str {
        match self {
            ArrayData::U8(_) => "u8",
            ArrayData::U16(_) => "u16",
            ArrayData::I32(_) => "i32",
            ArrayData::F32(_) => "f32",
            ArrayData::F64(_) => "f64",
        }
    }
}

/// One array: its shape (row-major) and its elements.
#[derive(Debug, Clone, PartialEq)]
pub struct Array {
    /// Extent per axis; the product equals the element count.
    pub shape: Vec<usize>,
    /// The elements, row-major.
    pub data: ArrayData,
}

/// Element types that can be read out of an [`ArrayData`].
pub trait Element: Copy + 'static {
    /// The dtype's name.
    const DTYPE: &'static str;
    /// The elements when `d` holds this type.
    fn slice(d: &ArrayData) -> Option<&[Self]>;
    /// Wrap a vector.
    fn wrap(v: Vec<Self>) -> ArrayData;
}

macro_rules! element {
    ($t:ty, $v:ident, $name:literal) => {
        impl Element for $t {
            const DTYPE: &'static str = $name;
            fn slice(d: &ArrayData) -> Option<&[Self]> {
                match d {
                    ArrayData::$v(x) => Some(x),
                    _ => None,
                }
            }
            fn wrap(v: Vec<Self>) -> ArrayData {
                ArrayData::$v(v)
            }
        }
    };
}
element!(u8, U8, "u8");
element!(u16, U16, "u16");
element!(i32, I32, "i32");
element!(f32, F32, "f32");
element!(f64, F64, "f64");

/// An ordered set of named arrays.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct NamedArrays {
    entries: Vec<(String, Array)>,
}

impl NamedArrays {
    /// An empty set.
    pub fn new() -> Self {
        NamedArrays::default()
    }

    /// Add (or replace) an array. Panics in debug builds when the shape does not match the
    /// element count: that is a bug of the model writing it, never of user data.
    pub fn put<T: Element>(&mut self, name: &str, shape: &[usize], data: Vec<T>) {
        debug_assert_eq!(shape.iter().product::<usize>(), data.len(), "array {name}: shape {shape:?}");
        self.insert(name, Array { shape: shape.to_vec(), data: T::wrap(data) });
    }

    /// Add (or replace) an array, checking its shape against its length.
    pub fn insert(&mut self, name: &str, a: Array) {
        self.entries.retain(|(n, _)| n != name);
        self.entries.push((name.to_string(), a));
    }

    /// Add an array given as parts, checking that the shape matches the data (for readers of
    /// untrusted files and user arrays).
    pub fn insert_checked(&mut self, name: &str, shape: Vec<usize>, data: ArrayData) -> Result<()> {
        let n = shape.iter().try_fold(1usize, |a, &b| a.checked_mul(b));
        if n != Some(data.len()) {
            return Err(Error::arg(name, format!("shape {shape:?} does not match its {} elements", data.len())));
        }
        self.insert(name, Array { shape, data });
        Ok(())
    }

    /// The names and arrays, in insertion order.
    pub fn iter(&self) -> impl Iterator<Item = (&str, &Array)> {
        self.entries.iter().map(|(n, a)| (n.as_str(), a))
    }

    /// Number of arrays.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// True when there are no arrays.
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The array called `name`, if present.
    pub fn array(&self, name: &str) -> Option<&Array> {
        self.entries.iter().find(|(n, _)| n == name).map(|(_, a)| a)
    }

    /// True when an array called `name` is present.
    pub fn contains(&self, name: &str) -> bool {
        self.array(name).is_some()
    }

    /// The elements and shape of `name`, which must hold `T` and match `shape` (`None` = any
    /// extent on that axis).
    pub fn get<T: Element>(&self, name: &str, shape: &[Option<usize>]) -> Result<(&[T], &[usize])> {
        let a = self.array(name).ok_or_else(|| Error::arg(name, "missing array"))?;
        let s = T::slice(&a.data)
            .ok_or_else(|| Error::arg(name, format!("expected dtype {}, got {}", T::DTYPE, a.data.dtype())))?;
        check_shape(name, &a.shape, shape)?;
        Ok((s, &a.shape))
    }

    /// [`NamedArrays::get`] when the array may be absent.
    pub fn get_opt<T: Element>(&self, name: &str, shape: &[Option<usize>]) -> Result<Option<(&[T], &[usize])>> {
        if self.contains(name) {
            self.get(name, shape).map(Some)
        } else {
            Ok(None)
        }
    }

    /// A `[n, 3]` f64 array as directions (checked: finite, unit length within 1e-4, z >= 0).
    pub fn directions(&self, name: &str, n: Option<usize>) -> Result<Vec<[f64; 3]>> {
        let (d, _) = self.get::<f64>(name, &[n, Some(3)])?;
        let v: Vec<[f64; 3]> = d.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        crate::directions::validate(name, &v)?;
        Ok(v)
    }

    /// Store directions as a `[n, 3]` f64 array.
    pub fn put_directions(&mut self, name: &str, d: &[[f64; 3]]) {
        self.put(name, &[d.len(), 3], d.iter().flatten().copied().collect::<Vec<f64>>());
    }
}

/// Check `shape` against `expected` (`None` = any extent).
pub fn check_shape(name: &str, shape: &[usize], expected: &[Option<usize>]) -> Result<()> {
    let ok = shape.len() == expected.len() && shape.iter().zip(expected).all(|(&s, e)| e.is_none_or(|e| e == s));
    if ok {
        return Ok(());
    }
    let want: Vec<String> = expected.iter().map(|e| e.map_or("any".to_string(), |e| e.to_string())).collect();
    Err(Error::arg(name, format!("expected shape [{}], got {shape:?}", want.join(", "))))
}

/// Check that every value is finite, naming the first that is not.
pub fn check_finite<T: Copy + Into<f64>>(name: &str, x: &[T]) -> Result<()> {
    match x.iter().position(|&v| !v.into().is_finite()) {
        Some(i) => Err(Error::arg(name, format!("value at flat index {i} is not finite"))),
        None => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn get_checks_dtype_shape_and_presence() {
        let mut a = NamedArrays::new();
        a.put("x", &[2, 3], vec![0.0f32; 6]);
        assert_eq!(a.get::<f32>("x", &[Some(2), None]).unwrap().1, &[2, 3]);
        let e = a.get::<f32>("x", &[Some(3), None]).unwrap_err().to_string();
        assert!(e.starts_with("x: expected shape [3, any]"), "{e}");
        assert!(a.get::<u8>("x", &[None, None]).unwrap_err().to_string().contains("expected dtype u8, got f32"));
        assert!(a.get::<f32>("y", &[None]).unwrap_err().to_string().starts_with("y: missing"));
        assert!(a.get_opt::<f32>("y", &[None]).unwrap().is_none());
        // Replacing keeps one entry.
        a.put("x", &[1], vec![1.0f32]);
        assert_eq!(a.len(), 1);
    }

    #[test]
    fn checked_insert_rejects_overflowing_and_mismatched_shapes() {
        let mut a = NamedArrays::new();
        assert!(a.insert_checked("z", vec![usize::MAX, 2], ArrayData::U8(vec![])).is_err());
        assert!(a.insert_checked("z", vec![2, 2], ArrayData::U8(vec![0; 3])).is_err());
        assert!(a.insert_checked("z", vec![0, 5], ArrayData::U8(vec![])).is_ok());
    }

    #[test]
    fn finite_check_names_the_first_bad_value() {
        let e = check_finite("w", &[1.0f32, f32::NAN, f32::INFINITY]).unwrap_err().to_string();
        assert_eq!(e, "w: value at flat index 1 is not finite");
    }
}
