//! The crate used from outside: generic code over `Real`, and `LengthMismatch` flowing through
//! `?` into a boxed error.

use btfrs_hemimap::{
    hemisphere_to_square, hemisphere_to_square_batch, square_to_hemisphere, square_to_hemisphere_batch, LengthMismatch,
    Real,
};

/// Resamples a square grid of `n x n` cell centres onto directions and back.
fn grid_round_trip<T: Real>(n: usize) -> Result<T, Box<dyn std::error::Error>> {
    let st: Vec<[T; 2]> = (0..n * n)
        .map(|k| {
            let (i, j) = (k / n, k % n);
            [T::from_f64((i as f64 + 0.5) / n as f64), T::from_f64((j as f64 + 0.5) / n as f64)]
        })
        .collect();
    let mut dirs = vec![[T::ZERO; 3]; st.len()];
    square_to_hemisphere_batch(&st, &mut dirs)?;
    let mut back = vec![[T::ZERO; 2]; st.len()];
    hemisphere_to_square_batch(&dirs, &mut back)?;
    let mut worst = T::ZERO;
    for (p, q) in st.iter().zip(&back) {
        for c in 0..2 {
            let e = (p[c] - q[c]).abs();
            if e > worst {
                worst = e;
            }
        }
    }
    Ok(worst)
}

#[test]
fn generic_use_from_another_crate() {
    let e32 = grid_round_trip::<f32>(300).expect("lengths match");
    let e64 = grid_round_trip::<f64>(300).expect("lengths match");
    assert!(e32 < 1e-5, "{e32}");
    assert!(e64 < 1e-12, "{e64}");
    assert_eq!(hemisphere_to_square(square_to_hemisphere(0.5f32, 0.5)), [0.5, 0.5]);
}

#[test]
fn length_mismatch_propagates_through_question_mark() {
    fn f() -> Result<(), Box<dyn std::error::Error + Send + Sync>> {
        let mut out = [[0.0f64; 3]; 2];
        square_to_hemisphere_batch(&[[0.5, 0.5]; 3], &mut out)?;
        Ok(())
    }
    let err = f().expect_err("3 inputs, 2 outputs");
    let lm = err.downcast_ref::<LengthMismatch>().expect("a LengthMismatch");
    assert_eq!((lm.input, lm.output), (3, 2));
}
