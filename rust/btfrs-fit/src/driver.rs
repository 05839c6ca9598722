//! The fit driver: what every fit through the registry runs. It judges the images, optionally
//! masks the bad ones, screens the values ([`crate::robust`]: the screen the models themselves
//! use) and calls the model's fit ([`crate::registry::Entry`]) on the repaired values, returning
//! the model with the robust report. It sits above both the registry and the screen, so neither
//! imports the other.

use crate::model::DynModel;
use crate::options::{Spec, Values};
use crate::registry::Entry;
use crate::robust::{
    moved_images, patch_window, sample_texels, screen_images, screen_values, Flags, Screen, TexelScreen,
};
use btfrs_core::{BtfRef, Error, Monitor, Result};
use serde_json::{json, Value};

/// The robust options every fit takes besides its own (one source: the Python signatures, the
/// CLI and the docs are generated from them).
pub const OPTIONS: &[Spec] = &[
    Spec::bool(
        "robust",
        true,
        "screen the values for outliers (hot pixels, dust, glints) before fitting, replacing those \
         far above both their light and their spatial neighbours; false: fit every value as it is",
    ),
    Spec::bool(
        "exclude_bad_images",
        false,
        "leave out of the fit the whole images found far from their light and view neighbours (a \
         misfired or doubled flash); they are reported either way",
    ),
];

/// [`OPTIONS`] as a struct.
#[derive(Debug, Clone, Copy, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RobustOptions {
    /// Screen and repair outliers.
    pub robust: bool,
    /// Mask the bad images out of the fit.
    pub exclude_bad_images: bool,
}

impl Default for RobustOptions {
    fn default() -> Self {
        crate::options::build(OPTIONS, serde_json::Map::new()).expect("the schema's defaults build")
    }
}

/// Fit the model of `entry` with its options robustly: judge the images, optionally
/// mask the bad ones, screen the values and fit to the repaired values. Returns the model and
/// the robust report (`Null` with `robust = false`).
///
/// A model whose texels are fitted apart ([`crate::Model::SCREENS_TEXELS`]) screens each texel
/// in its own pass ([`TexelScreen`]); the others are screened first and fitted to a repaired
/// copy of the values. Both give the same model.
pub fn fit(
    entry: &Entry,
    btf: &BtfRef<'_>,
    options: &Values,
    robust: RobustOptions,
    monitor: &Monitor,
) -> Result<(Box<dyn DynModel>, Value)> {
    if !robust.robust && !robust.exclude_bad_images {
        return Ok(((entry.fit)(btf, options, monitor)?, Value::Null));
    }
    let (h, w) = (btf.height, btf.width);
    let im = screen_images(btf.views, btf.lights, btf.mask, btf.data, &sample_texels(h, w))?;
    let moved = moved_images(btf.views, btf.lights, btf.mask, btf.data, w, patch_window(h, w))?;
    monitor.check()?;
    let mut sc = Screen::new(Flags::new(), im, moved);
    let mut mask_owned: Option<Vec<bool>> = None;
    if robust.exclude_bad_images && !sc.bad_images.is_empty() {
        let nl = btf.lights.len();
        let mut m = btf.mask.map_or_else(|| vec![true; btf.views.len() * nl], <[bool]>::to_vec);
        for &(v, l) in &sc.bad_images {
            m[v * nl + l] = false;
        }
        if !m.iter().any(|&x| x) {
            return Err(Error::arg("exclude_bad_images", "every image was found bad; nothing is left to fit"));
        }
        mask_owned = Some(m);
    }
    let mask = mask_owned.as_deref().or(btf.mask);
    if let (true, Some(fit_screened)) = (robust.robust, entry.fit_screened) {
        let ts = TexelScreen::new(btf, sc.floor);
        let b = BtfRef::new(h, w, btf.views, btf.lights, btf.data, mask)?;
        let model = fit_screened(&b, options, &ts, monitor)?;
        sc.values = ts.into_flags();
        let mut report = sc.report(btf, true, robust.exclude_bad_images);
        report["robust"] = json!(true);
        return Ok((model, report));
    }
    sc.values = screen_values(btf, sc.floor, 0..h, 0..w, monitor)?;
    // Out of core: a repaired copy that does not fit the memory limit is not made; the values
    // found are reported (`repaired: false`, with the reason) and the fit sees them as measured.
    let too_big =
        robust.robust && monitor.memory_limit().is_some_and(|limit| std::mem::size_of_val(btf.data) as u64 > limit);
    let repaired = |sc: &Screen| -> Option<Vec<f32>> {
        if !robust.robust || too_big || sc.values.is_empty() {
            return None;
        }
        let mut d = btf.data.to_vec();
        for &(i, x) in &sc.values {
            d[i] = x;
        }
        Some(d)
    };
    let fit_on = |data: Option<&[f32]>| -> Result<Box<dyn DynModel>> {
        let b = BtfRef::new(btf.height, btf.width, btf.views, btf.lights, data.unwrap_or(btf.data), mask)?;
        (entry.fit)(&b, options, monitor)
    };
    let data = repaired(&sc);
    let model = fit_on(data.as_deref())?;
    let replace = data.is_some();
    let mut report = sc.report(btf, replace, robust.exclude_bad_images);
    report["robust"] = json!(robust.robust);
    if too_big && !sc.values.is_empty() {
        report["not_repaired"] = json!(format!(
            "a repaired copy of the values ({:.1} MB) would exceed memory_limit; pass robust=False to skip the screen \
             or raise the limit",
            std::mem::size_of_val(btf.data) as f64 / 1e6
        ));
    }
    Ok((model, report))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::robust::screen;
    use crate::robust::tests::lambert;

    /// The fits that screen each texel in their own pass (PTM, HSH, neural) give the model that a fit to
    /// a repaired copy of the whole data gives (the separate screen's flags applied), bit for
    /// bit, and flag the same values; with and without held-out pairs, every path of the pass
    /// (PTM-RGB's texels 8 at a time and the rest of a row, PTM-LRGB's one at a time).
    #[test]
    fn a_screen_inside_the_pass_fits_what_a_repaired_copy_fits() {
        let (h, w, nv, nl) = (8, 11, 3, 40);
        let (views, lights, mut data) = lambert(h, w, nv, nl);
        let abrdf = nv * nl * 3;
        // Texels 0, 9 (in a group of 8), 10 (the rest of row 1), 45 and the last.
        for &i in &[5usize, 9 * abrdf + 200, 10 * abrdf + 3, 45 * abrdf + 301, data.len() - 1] {
            data[i] *= 1000.0;
        }
        let mut mask = vec![true; nv * nl];
        mask[7] = false;
        mask[nl + 3] = false;
        let robust = RobustOptions { robust: true, exclude_bad_images: false };
        for m in [None, Some(&mask[..])] {
            let b = BtfRef::new(h, w, &views, &lights, &data, m).unwrap();
            let sc = screen(&b, &Monitor::new()).unwrap();
            assert_eq!(sc.values.len(), 5);
            let mut fixed = data.clone();
            for &(i, x) in &sc.values {
                fixed[i] = x;
            }
            let repaired = BtfRef::new(h, w, &views, &lights, &fixed, m).unwrap();
            for (kind, json) in [
                ("ptm", r#"{"kind": "rgb"}"#),
                ("ptm", r#"{"kind": "lrgb"}"#),
                ("hsh", "{}"),
                ("hsh", r#"{"order": 3, "bits": 32}"#),
                ("neural", r#"{"latents": 2, "hidden": 8, "steps": 30, "horizon": 0}"#),
                // On a sample of 64 texels: the sample and every texel encoded are repaired.
                ("neural", r#"{"latents": 2, "hidden": 8, "steps": 30, "horizon": 0, "train_texels": 64}"#),
            ] {
                let e = crate::registry::lookup(kind).unwrap();
                let opts = &crate::options::parse_json(json).unwrap();
                assert!(e.fit_screened.is_some(), "{kind}");
                let (model, report) = fit(e, &b, opts, robust, &Monitor::new()).unwrap();
                let reference = (e.fit)(&repaired, opts, &Monitor::new()).unwrap();
                assert!(model.to_arrays() == reference.to_arrays(), "{kind} {json} mask {}", m.is_some());
                assert_eq!(report["values_flagged"], sc.values.len(), "{kind} {json}");
                assert_eq!(report["values_replaced"], sc.values.len(), "{kind} {json}");
            }
            let ts = TexelScreen::new(&b, sc.floor);
            crate::ptm::fit_ptm_screened(&b, &Default::default(), Some(&ts), &Monitor::new()).unwrap();
            assert_eq!(ts.into_flags(), sc.values);
        }
    }
}
