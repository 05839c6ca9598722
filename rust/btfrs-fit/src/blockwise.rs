//! Fitting a BTF in blocks of texels fitted apart: the contract `btfrs.dask` drives, where each
//! block is one chunk of a chunked (zarr) BTF, fitted on whichever machine holds it.
//!
//! A model says, through [`crate::Model::BLOCKWISE`], which of three cases it is:
//!
//! * [`Blockwise::Texels`]: every texel's parameters depend on its own values and the
//!   directions only (PTM, HSH: the per-slot pseudo-inverses depend on the lights and the mask;
//!   Lafortune; double SH). Each block is fitted by the ordinary fit with `overrides` merged into
//!   the options (the float variant of an 8-bit model), the per-texel arrays
//!   ([`crate::Model::TEXEL_ARRAYS`]) are stitched, every other array must come out identical
//!   from every block (the driver checks it: a generic test of the claim), and
//!   [`crate::Model::finish_blocks`] does what the fit does over all texels at once
//!   (quantization). The result equals the fit of the whole BTF bit for bit.
//! * [`Blockwise::Staged`]: a global step sits between per-block passes, so the model exposes
//!   its stages and the driver runs them as reductions: SRF (the mean BRDF is a sum over texels,
//!   paper 003 section 4: [`crate::srf::mean_sums`], [`crate::srf::phong_of_mean`],
//!   [`crate::srf::residual`]), LPCA (principal coordinates from a seeded sample, k-means and
//!   refinement on the client, one task per cluster: [`crate::lpca::staged`]) and the light
//!   bases RBF and bilinear (per-slot moments of the resampled light functions merged in
//!   pairs, eigenvectors on the client, projection per block: [`crate::light_pca::staged`]).
//! * [`Blockwise::Unsupported`]: the reason, which the driver puts in its error.

/// How a model's fit splits over blocks of texels (see the module doc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Blockwise {
    /// Fit blocks apart with these options overridden (a JSON object), stitch, finish.
    Texels {
        /// Merged into the user's options for the per-block fits, e.g. `{"bits": 32}`.
        overrides: &'static str,
        /// The report's entries that count over texels, summed when the blocks' reports merge
        /// (the others: equal in every block and kept, or means weighted by the texels).
        counts: &'static [&'static str],
    },
    /// A global step between per-block passes; the driver runs the model's stages by the
    /// protocol named here (`"mean_brdf"`: SRF's; `"clustered_pca"`: LPCA's; `"light_pca"`: the
    /// light bases'), so a second model with the same stages needs no new driver code.
    Staged(&'static str),
    /// Cannot be fitted blockwise (yet): why.
    Unsupported(&'static str),
}

impl Blockwise {
    /// `(strategy, detail, counts)` as the bindings report it: `("texels", overrides,
    /// counts)`, `("staged", protocol, [])` or `("unsupported", reason, [])`.
    pub fn describe(&self) -> (&'static str, &'static str, &'static [&'static str]) {
        match *self {
            Blockwise::Texels { overrides, counts } => ("texels", overrides, counts),
            Blockwise::Staged(protocol) => ("staged", protocol, &[]),
            Blockwise::Unsupported(why) => ("unsupported", why, &[]),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::registry::{lookup, MODELS};
    use btfrs_core::arrays::{ArrayData, NamedArrays};
    use btfrs_core::materials::{generate, MaterialSpec, Preset};
    use btfrs_core::{BtfRef, Monitor};

    /// `a` then `b` along the first axis (the rows of two blocks of texel rows).
    fn concat(a: &btfrs_core::arrays::Array, b: &btfrs_core::arrays::Array) -> (Vec<usize>, ArrayData) {
        let mut shape = a.shape.clone();
        shape[0] += b.shape[0];
        let data = match (&a.data, &b.data) {
            (ArrayData::U8(x), ArrayData::U8(y)) => ArrayData::U8([x.as_slice(), y].concat()),
            (ArrayData::U16(x), ArrayData::U16(y)) => ArrayData::U16([x.as_slice(), y].concat()),
            (ArrayData::I32(x), ArrayData::I32(y)) => ArrayData::I32([x.as_slice(), y].concat()),
            (ArrayData::F32(x), ArrayData::F32(y)) => ArrayData::F32([x.as_slice(), y].concat()),
            (ArrayData::F64(x), ArrayData::F64(y)) => ArrayData::F64([x.as_slice(), y].concat()),
            _ => panic!("dtypes differ"),
        };
        (shape, data)
    }

    #[test]
    fn texel_models_fitted_in_two_blocks_equal_the_whole_fit() {
        // Every model that claims `Texels`, with every example's options and a mask: the top
        // and bottom rows fitted apart with the overrides, stitched, finished, must give the
        // whole fit's arrays exactly, and every shared array must agree between the blocks.
        let btf = generate(&MaterialSpec::new(Preset::Bumps, 8, 3), &Monitor::new()).unwrap();
        let b = btf.as_ref();
        let (nv, nl) = (b.views.len(), b.lights.len());
        let mask: Vec<bool> = (0..nv * nl).map(|i| i % 5 != 2).collect();
        let mut checked = 0;
        for masked in [false, true] {
            let whole = BtfRef { mask: masked.then_some(&mask[..]), ..b };
            let half = whole.height / 2;
            let per = whole.abrdf_len() * whole.width;
            let top = BtfRef { height: half, data: &whole.data[..half * per], ..whole };
            let bottom = BtfRef { height: whole.height - half, data: &whole.data[half * per..], ..whole };
            for e in MODELS {
                let Blockwise::Texels { overrides, .. } = e.blockwise else { continue };
                for (label, options) in e.examples {
                    let options = crate::options::parse_json(options).unwrap();
                    let mut block = options.clone();
                    block.extend(crate::options::parse_json(overrides).unwrap());
                    let parts: Vec<NamedArrays> = [&top, &bottom]
                        .iter()
                        .map(|x| (e.fit)(x, &block, &Monitor::new()).unwrap().to_arrays())
                        .collect();
                    let mut stitched = NamedArrays::new();
                    for (name, a) in parts[0].iter() {
                        let other = parts[1].array(name).unwrap();
                        if e.texel_arrays.contains(&name) {
                            let (shape, data) = concat(a, other);
                            stitched.insert_checked(name, shape, data).unwrap();
                        } else {
                            assert_eq!(a, other, "{label}: shared array {name} differs between blocks");
                            stitched.insert(name, a.clone());
                        }
                    }
                    let finished = (lookup(e.kind).unwrap().finish_blocks)(&stitched, &options).unwrap();
                    let local = (e.fit)(&whole, &options, &Monitor::new()).unwrap();
                    assert_eq!(finished.to_arrays(), local.to_arrays(), "{label} masked={masked}");
                    checked += 1;
                }
            }
        }
        assert!(checked >= 16, "only {checked} option sets were checked");
    }

    #[test]
    fn srf_and_lpca_in_stages_equal_the_whole_fit() {
        use crate::lpca::{self, staged, LpcaOptions};
        use crate::srf;
        let btf = generate(&MaterialSpec::new(Preset::Bumps, 12, 3), &Monitor::new()).unwrap();
        let b = btf.as_ref();
        let half = b.height / 2;
        let per = b.abrdf_len() * b.width;
        let blocks = [
            BtfRef { height: half, data: &b.data[..half * per], ..b },
            BtfRef { height: b.height - half, data: &b.data[half * per..], ..b },
        ];
        // SRF: the mean's sums reduced over the blocks, then the residual per block.
        let geo = srf::PairGeometry::new(b.views, b.lights, b.mask).unwrap();
        let parts: Vec<Vec<[f64; 3]>> = blocks.iter().map(|x| srf::mean_sums(x).unwrap()).collect();
        let sums: Vec<[f64; 3]> =
            parts[0].iter().zip(&parts[1]).map(|(x, y)| std::array::from_fn(|c| x[c] + y[c])).collect();
        let (phong, _) = srf::phong_of_mean(&geo, &sums, b.texels()).unwrap();
        let s: Vec<f32> =
            blocks.iter().flat_map(|x| srf::residual(x, &geo, &phong, &Monitor::new()).unwrap().0).collect();
        let (local, _) = srf::fit_srf(&b, &Monitor::new()).unwrap();
        // The sums add in another order: equal to rounding, not bit for bit.
        assert!((phong.n - local.phong.n).abs() <= 1e-9 * local.phong.n, "{phong:?} vs {:?}", local.phong);
        let worst = s.iter().zip(&local.s).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst <= 1e-5, "s differs by {worst}");

        // LPCA on every texel, and on a sample of 48 of the 144 (the others assigned to the
        // clusters found on it and projected): the stages are the fit's own functions, so
        // equality shows they are wired as the fit wires them.
        let d = b.abrdf_len();
        let t = b.texels();
        let every = LpcaOptions { clusters: 6, components: 3, reduced_dims: 16, ..LpcaOptions::default() };
        for opts in [every, LpcaOptions { sample: 48, ..every }] {
            let pick = staged::sample(b.height, b.width, &opts).unwrap();
            let sample: Vec<f32> = match &pick {
                Some(p) => p.iter().flat_map(|&i| b.texel(i as usize).to_vec()).collect(),
                None => b.data.to_vec(),
            };
            let (mu, q) = staged::subspace(&sample, d, b.height, b.width, &opts, &Monitor::new()).unwrap();
            let zs: Vec<_> = blocks.iter().map(|x| staged::project(x.data, d, &mu, &q).unwrap()).collect();
            let z = nalgebra::DMatrix::from_fn(t, q.ncols(), |i, j| {
                if i < zs[0].nrows() {
                    zs[0][(i, j)]
                } else {
                    zs[1][(i - zs[0].nrows(), j)]
                }
            });
            let (ids, members) = staged::cluster(&z, b.height, b.width, &opts, &Monitor::new()).unwrap();
            let fits: Vec<_> = members
                .iter()
                .enumerate()
                .map(|(k, m)| {
                    let x: Vec<f32> = m.iter().flat_map(|&i| b.texel(i as usize).to_vec()).collect();
                    staged::fit_cluster_sampled(&x, m, d, b.height, b.width, k, &opts).unwrap()
                })
                .collect();
            let m = staged::assemble(b.height, b.width, b.views, b.lights, None, ids, &members, &fits, &opts).unwrap();
            let local = lpca::fit_lpca(&b, &opts, &Monitor::new()).unwrap();
            assert_eq!(local.sampled.map(|f| f.sample), (opts.sample < t).then_some(48));
            use crate::Model;
            assert_eq!(m.to_arrays(), local.to_arrays(), "sample {}", opts.sample);
        }
        let opts = every;
        // Full-space clustering cannot be staged: a clear error naming the option.
        let bad = LpcaOptions { reduced_dims: 0, ..opts };
        assert!(staged::sample(b.height, b.width, &bad).unwrap_err().to_string().starts_with("reduced_dims:"));
    }
}
