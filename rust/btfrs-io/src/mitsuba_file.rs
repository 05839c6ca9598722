//! Mitsuba 3 scenes of `svbrdf` models: `scene.xml` and four float OpenEXR maps, the model on
//! a square under a camera and a directional light, with the BSDFs whose sum is the model's lobe
//! exactly ([`btfrs_fit::svbrdf::lobe`]):
//!
//! ```text
//! normalmap(normal.exr)
//!   blendbsdf(weight 0.5,
//!     diffuse(reflectance = diffuse.exr = 2 rho_d),
//!     roughconductor(ggx, material "none", alpha = roughness.exr, specular_reflectance = specular.exr = 2 rho_s))
//! ```
//!
//! Mitsuba has no sum of BSDFs; the blend's weight 0.5 halves each lobe and the maps store twice
//! the colours (exact in floating point). `roughconductor` with `material="none"` is GGX with
//! Smith's separable masking and a Fresnel factor of 1, which is the model's specular lobe; its
//! `alpha` is the model's roughness. The normal map holds `(n + 1) / 2` in the square's
//! tangent frame (+X along the texture's columns, +Y up its rows). Values are Mitsuba's
//! radiance; btfrs's units are pi times it (a white Lambertian sample reads cos(theta) in btfrs
//! under a light of irradiance 1).
//!
//! # The scene
//!
//! A `rectangle` (the square [-1, 1]^2 at z = 0, facing +z: btfrs's `Scene.plane(2)`), the maps
//! repeated `uv_scale` times with texture row 0 at +y (the `to_uv` transform flips Mitsuba's
//! texture v), a perspective camera and a `directional` emitter, all as `<default>` parameters
//! a user overrides when loading: `mi.load_file("scene.xml", spp=256, light_direction="0, 0, -1")`.
//! `light_direction` is the direction the light travels (Mitsuba's convention), so the light
//! itself is at minus it. The integrator is `direct`: a flat sample has no interreflection.
//!
//! # Reading
//!
//! [`import`] reads such a scene back as an `svbrdf` model: the bitmaps of the normal map, the
//! blend's two BSDFs and its weight. Files must be plain names in the scene's folder.

use std::fmt::Write as _;
use std::path::Path;

use btfrs_core::{Error, NamedArrays, Result};
use btfrs_fit::svbrdf::lobe::{ALPHA_MAX, ALPHA_MIN};
use btfrs_fit::svbrdf::Svbrdf;
use btfrs_fit::{DynModel, Model};
use serde_json::{json, Value};

use crate::atomic::write_atomic;
use crate::capture::Limits;
use crate::formats::{concrete, decode_normals, plain_name, read_index, Format, Imported};
use crate::image::{read_exr_within, write_exr, write_exr_channels};
use crate::untrusted::{self, Repairs};

/// The format's entry in [`crate::formats::FORMATS`].
pub const FORMAT: Format = Format {
    name: "mitsuba",
    extension: "xml",
    doc: "a Mitsuba 3 scene (XML + EXR maps) whose BSDFs are the model's lobe exactly",
    folder: true,
    index: INDEX,
    export: export_model,
    import: import_model,
};

/// The index file.
pub const INDEX: &str = "scene.xml";
/// The scene's defaults: a camera above and in front of the square, a light from 40 degrees
/// off the normal at azimuth 60 degrees (the direction it travels is minus the light's).
const DEFAULTS: &[(&str, &str)] = &[
    ("spp", "64"),
    ("width", "512"),
    ("height", "512"),
    ("fov", "40"),
    ("origin", "0, -2, 2.4"),
    ("target", "0, 0, 0"),
    ("up", "0, 0, 1"),
    ("light_direction", "-0.321394, -0.556670, -0.766044"),
    ("irradiance", "1"),
    ("uv_scale", "1"),
    ("filter", "bilinear"),
];

fn export_model(model: &dyn DynModel, _view: usize, path: &Path) -> Result<Value> {
    export(concrete::<Svbrdf>(model, "an svbrdf model")?, path)
}

fn import_model(path: &Path, limits: &Limits) -> Result<Imported> {
    let (m, warnings) = import_within(path, limits)?;
    Ok(Imported { model: Box::new(m), warnings })
}

/// A `bitmap` texture element named `name` reading `file`.
fn bitmap(name: &str, file: &str, raw: bool, indent: &str) -> String {
    format!(
        "{indent}<texture type=\"bitmap\" name=\"{name}\">\n\
         {indent}    <string name=\"filename\" value=\"{file}\"/>\n\
         {indent}    <boolean name=\"raw\" value=\"{raw}\"/>\n\
         {indent}    <string name=\"filter_type\" value=\"$filter\"/>\n\
         {indent}    <string name=\"wrap_mode\" value=\"repeat\"/>\n\
         {indent}    <transform name=\"to_uv\">\n\
         {indent}        <scale x=\"1\" y=\"-1\"/>\n\
         {indent}        <translate x=\"0\" y=\"1\"/>\n\
         {indent}        <scale value=\"$uv_scale\"/>\n\
         {indent}    </transform>\n\
         {indent}</texture>\n"
    )
}

/// The scene's XML.
fn scene_xml(m: &Svbrdf) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "<?xml version=\"1.0\" encoding=\"utf-8\"?>");
    let _ = writeln!(
        s,
        "<!-- A btfrs svbrdf model ({} x {} texels) on the square [-1, 1]^2 at z = 0. Render with Mitsuba 3:\n     \
         mitsuba scene.xml, or mi.render(mi.load_file(\"scene.xml\", spp=256)). Every <default> can be\n     \
         overridden at load time. Values are radiance; btfrs's images are pi times them. -->",
        m.height, m.width
    );
    let _ = writeln!(s, "<scene version=\"3.0.0\">");
    for (k, v) in DEFAULTS {
        let _ = writeln!(s, "    <default name=\"{k}\" value=\"{v}\"/>");
    }
    s.push_str(
        "    <integrator type=\"direct\"/>\n\
         \x20   <sensor type=\"perspective\">\n\
         \x20       <string name=\"fov_axis\" value=\"y\"/>\n\
         \x20       <float name=\"fov\" value=\"$fov\"/>\n\
         \x20       <float name=\"near_clip\" value=\"0.01\"/>\n\
         \x20       <transform name=\"to_world\">\n\
         \x20           <lookat origin=\"$origin\" target=\"$target\" up=\"$up\"/>\n\
         \x20       </transform>\n\
         \x20       <sampler type=\"independent\">\n\
         \x20           <integer name=\"sample_count\" value=\"$spp\"/>\n\
         \x20       </sampler>\n\
         \x20       <film type=\"hdrfilm\">\n\
         \x20           <integer name=\"width\" value=\"$width\"/>\n\
         \x20           <integer name=\"height\" value=\"$height\"/>\n\
         \x20           <string name=\"pixel_format\" value=\"rgb\"/>\n\
         \x20           <rfilter type=\"box\"/>\n\
         \x20       </film>\n\
         \x20   </sensor>\n\
         \x20   <emitter type=\"directional\">\n\
         \x20       <vector name=\"direction\" value=\"$light_direction\"/>\n\
         \x20       <rgb name=\"irradiance\" value=\"$irradiance\"/>\n\
         \x20   </emitter>\n\
         \x20   <shape type=\"rectangle\">\n\
         \x20       <bsdf type=\"normalmap\">\n",
    );
    s.push_str(&bitmap("normalmap", "normal.exr", true, "            "));
    s.push_str(
        "            <bsdf type=\"blendbsdf\">\n\
         \x20               <float name=\"weight\" value=\"0.5\"/>\n\
         \x20               <bsdf type=\"diffuse\">\n",
    );
    s.push_str(&bitmap("reflectance", "diffuse.exr", false, "                    "));
    s.push_str(
        "                </bsdf>\n\
         \x20               <bsdf type=\"roughconductor\">\n\
         \x20                   <string name=\"distribution\" value=\"ggx\"/>\n\
         \x20                   <string name=\"material\" value=\"none\"/>\n",
    );
    s.push_str(&bitmap("alpha", "roughness.exr", true, "                    "));
    s.push_str(&bitmap("specular_reflectance", "specular.exr", false, "                    "));
    s.push_str(
        "                </bsdf>\n\
         \x20           </bsdf>\n\
         \x20       </bsdf>\n\
         \x20   </shape>\n\
         </scene>\n",
    );
    s
}

/// Write `m` as a Mitsuba scene folder at `path` (the folder, or its `scene.xml`). Returns the
/// files written.
pub fn export(m: &Svbrdf, path: &Path) -> Result<Value> {
    m.validate()?;
    let dir = FORMAT.folder_of(path);
    std::fs::create_dir_all(&dir).map_err(|e| Error::io(dir.display().to_string(), e))?;
    let (w, h) = (m.width, m.height);
    let twice = |v: &[f32]| v.iter().map(|&x| 2.0 * x).collect::<Vec<f32>>();
    write_exr(&dir.join("diffuse.exr"), &twice(&m.diffuse), w, h)?;
    write_exr(&dir.join("specular.exr"), &twice(&m.specular), w, h)?;
    write_exr_channels(&dir.join("roughness.exr"), w, h, &[("Y".to_string(), m.roughness.clone())])?;
    let normal: Vec<f32> = m.normal.iter().map(|&x| 0.5 * x + 0.5).collect();
    write_exr(&dir.join("normal.exr"), &normal, w, h)?;
    let xml = scene_xml(m);
    // The scene last: a reader that finds it finds every map it names.
    write_atomic(&dir.join(INDEX), |f| f.write_all(xml.as_bytes()))?;
    Ok(json!({
        "folder": dir.display().to_string(),
        "files": ["diffuse.exr", "specular.exr", "roughness.exr", "normal.exr", INDEX],
        "defaults": DEFAULTS.iter().map(|(k, v)| (k.to_string(), json!(v))).collect::<serde_json::Map<_, _>>(),
    }))
}

fn bad(shown: &str, what: &str, msg: impl std::fmt::Display) -> Error {
    Error::format(shown, format!("{what}: {msg}"))
}

/// The one child element of `node` with tag `tag` and attribute `name` (if given).
fn child<'a, 'i>(
    node: roxmltree::Node<'a, 'i>,
    tag: &str,
    name: Option<&str>,
    shown: &str,
) -> Result<roxmltree::Node<'a, 'i>> {
    let mut it = node.children().filter(|c| {
        c.is_element() && c.tag_name().name() == tag && name.is_none_or(|n| c.attribute("name") == Some(n))
    });
    let found = it.next();
    let what = match name {
        Some(n) => format!("<{tag} name=\"{n}\">"),
        None => format!("<{tag}>"),
    };
    match (found, it.next()) {
        (Some(c), None) => Ok(c),
        (Some(_), Some(other)) => Err(bad(shown, &format!("line {}", line(other)), format!("a second {what}"))),
        (None, _) => Err(bad(
            shown,
            &format!("line {}", line(node)),
            format!("<{}> has no {what}; expected the scene btfrs writes", node.tag_name().name()),
        )),
    }
}

/// The `value` of a child `<tag name="name">`, with `$default` parameters substituted.
fn value(
    node: roxmltree::Node<'_, '_>,
    tag: &str,
    name: &str,
    defaults: &[(String, String)],
    shown: &str,
) -> Result<String> {
    let c = child(node, tag, Some(name), shown)?;
    let v = c.attribute("value").ok_or_else(|| bad(shown, name, "no value attribute"))?;
    Ok(match v.strip_prefix('$') {
        Some(k) => defaults
            .iter()
            .find(|(d, _)| d == k)
            .map(|(_, v)| v.clone())
            .ok_or_else(|| bad(shown, name, format!("${k} has no <default>")))?,
        None => v.to_string(),
    })
}

/// The `<bsdf type="kind">` child of `node`.
fn bsdf<'a, 'i>(node: roxmltree::Node<'a, 'i>, kind: &str, shown: &str) -> Result<roxmltree::Node<'a, 'i>> {
    let b = child(node, "bsdf", None, shown)?;
    if b.attribute("type") != Some(kind) {
        return Err(bad(
            shown,
            &format!("line {}", line(b)),
            format!("expected a {kind} BSDF, got {:?}", b.attribute("type").unwrap_or("")),
        ));
    }
    Ok(b)
}

/// The line of `node` in its document.
fn line(node: roxmltree::Node<'_, '_>) -> u32 {
    node.document().text_pos_at(node.range().start).row
}

/// The EXR file of bitmap texture `name` under `node`: its path in `dir`.
fn map_file(
    node: roxmltree::Node<'_, '_>,
    name: &str,
    dir: &Path,
    defaults: &[(String, String)],
    shown: &str,
) -> Result<std::path::PathBuf> {
    let tex = child(node, "texture", Some(name), shown)?;
    let file = value(tex, "string", "filename", defaults, shown)?;
    if !plain_name(&file) || !file.to_ascii_lowercase().ends_with(".exr") {
        return Err(bad(shown, name, format!("{file:?}: expected an .exr file name in the scene's folder")));
    }
    let file = dir.join(&file);
    if !untrusted::present(&file) {
        return Err(bad(shown, name, format!("{file:?} does not exist beside the scene")));
    }
    Ok(file)
}

/// The map of texture `name` (its file `file`): `(rgb, width, height)`, every value finite
/// and not negative (an [`Error::Format`] naming the texture, its file and the pixel).
fn read_map(file: &Path, name: &str, shown: &str, max_bytes: u64) -> Result<(Vec<f32>, usize, usize)> {
    let (v, w, h) = read_exr_within(file, max_bytes)?;
    if let Some(i) = v.iter().position(|x| !(x.is_finite() && *x >= 0.0)) {
        return Err(bad(
            shown,
            name,
            format!(
                "{}: value {} at pixel {} (channel {}); expected finite values >= 0",
                file.display(),
                v[i],
                i / 3,
                i % 3
            ),
        ));
    }
    Ok((v, w, h))
}

/// Read a Mitsuba scene written by btfrs (its folder or `scene.xml`) as an `svbrdf` model.
/// A roughness (`alpha`) outside the model's range is clamped to it with a warning
/// ([`import_within`] returns it); infinities, NaN and negative values are refused.
pub fn import(path: &Path) -> Result<Svbrdf> {
    Ok(import_within(path, &Limits::default())?.0)
}

/// [`import`] within `limits` (see [`crate::untrusted`]), with the warnings about values it
/// changed.
pub fn import_within(path: &Path, limits: &Limits) -> Result<(Svbrdf, Vec<String>)> {
    let (dir, shown, text) = read_index(path, INDEX, untrusted::XML_INDEX, limits.max_bytes)?;
    let shown = shown.as_str();
    let doc = untrusted::parse_xml(&text, shown)?;
    let scene = doc.root_element();
    if scene.tag_name().name() != "scene" {
        return Err(bad(shown, "XML", "the root element is not <scene>"));
    }
    let mut defaults: Vec<(String, String)> = Vec::new();
    for c in scene.children().filter(|c| c.is_element() && c.tag_name().name() == "default") {
        let (Some(name), Some(v)) = (c.attribute("name"), c.attribute("value")) else {
            return Err(bad(shown, &format!("line {}", line(c)), "a <default> without a name and a value"));
        };
        if defaults.iter().any(|(d, _)| d == name) {
            return Err(bad(
                shown,
                &format!("line {}", line(c)),
                format!("a second <default name=\"{name}\">; each parameter has one default"),
            ));
        }
        defaults.push((name.to_string(), v.to_string()));
    }
    let shape = child(scene, "shape", None, shown)?;
    let nm = bsdf(shape, "normalmap", shown)?;
    let blend = bsdf(nm, "blendbsdf", shown)?;
    let weight: f64 =
        value(blend, "float", "weight", &defaults, shown)?.trim().parse().map_err(|e| bad(shown, "weight", e))?;
    if !(weight > 0.0 && weight < 1.0) {
        return Err(bad(shown, "weight", format!("{weight}: expected a blend weight in (0, 1)")));
    }
    let mut parts = blend.children().filter(|c| c.is_element() && c.tag_name().name() == "bsdf");
    let (diffuse_node, conductor) = match (parts.next(), parts.next(), parts.next()) {
        (Some(a), Some(b), None)
            if a.attribute("type") == Some("diffuse") && b.attribute("type") == Some("roughconductor") =>
        {
            (a, b)
        }
        _ => return Err(bad(shown, "blendbsdf", "expected a diffuse and a roughconductor BSDF, in that order")),
    };
    for (key, want) in [("distribution", "ggx"), ("material", "none")] {
        let v = value(conductor, "string", key, &defaults, shown)?;
        if v != want {
            return Err(bad(shown, key, format!("{v:?}: the svbrdf lobe is roughconductor with {key} {want:?}")));
        }
    }
    let names = ["normalmap", "reflectance", "specular_reflectance", "alpha"];
    let files = [
        map_file(nm, names[0], &dir, &defaults, shown)?,
        map_file(diffuse_node, names[1], &dir, &defaults, shown)?,
        map_file(conductor, names[2], &dir, &defaults, shown)?,
        map_file(conductor, names[3], &dir, &defaults, shown)?,
    ];
    let max_bytes = limits.max_bytes;
    let (nrm, w, h) = read_map(&files[0], names[0], shown, max_bytes)?;
    // The model's floats (and the three maps still to read) within max_bytes before reading them.
    untrusted::check_declared(
        shown,
        &format!("a {w} x {h} svbrdf model (4 maps of 3 floats per texel and their model, 96 bytes per texel)"),
        (w as u64).checked_mul(h as u64).and_then(|t| t.checked_mul(96)),
        max_bytes,
    )?;
    let same = |i: usize| -> Result<Vec<f32>> {
        let (v, mw, mh) = read_map(&files[i], names[i], shown, max_bytes)?;
        if (mw, mh) != (w, h) {
            return Err(bad(shown, names[i], format!("{mw} x {mh} pixels; the normal map has {w} x {h}")));
        }
        Ok(v)
    };
    let d = same(1)?;
    let s = same(2)?;
    let r = same(3)?;
    let t = w * h;
    let normal = decode_normals(&nrm, 1.0, shown, "normalmap")?;
    // A roughness outside the model's range is clamped to it, and said so.
    let mut low = Repairs::new(
        shown,
        format!("alpha value(s) below the svbrdf's smallest roughness ({ALPHA_MIN}) raised to it"),
        "value(s)",
        "pixel(s)",
    );
    let mut high = Repairs::new(
        shown,
        format!("alpha value(s) above the svbrdf's largest roughness ({ALPHA_MAX}) lowered to it"),
        "value(s)",
        "pixel(s)",
    );
    let roughness: Vec<f32> = (0..t)
        .map(|i| {
            // Compared as the f32 the model stores: the export writes ALPHA_MIN as f32.
            let (a, lo, hi) = (r[3 * i], ALPHA_MIN as f32, ALPHA_MAX as f32);
            if a < lo {
                low.add(i, f64::from(a));
            } else if a > hi {
                high.add(i, f64::from(a));
            }
            a.clamp(lo, hi)
        })
        .collect();
    let mut a = NamedArrays::new();
    a.put("diffuse", &[h, w, 3], d.iter().map(|&x| (x as f64 * (1.0 - weight)) as f32).collect());
    a.put("specular", &[h, w, 3], s.iter().map(|&x| (x as f64 * weight) as f32).collect());
    a.put("roughness", &[h, w], roughness);
    a.put("normal", &[h, w, 3], normal);
    let m = <Svbrdf as Model>::from_arrays(&a).map_err(|e| bad(shown, "maps", e))?;
    let mut warnings = Vec::new();
    low.report(&mut warnings);
    high.report(&mut warnings);
    Ok((m, warnings))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn model() -> Svbrdf {
        let (h, w) = (3usize, 4usize);
        let t = h * w;
        let mut a = NamedArrays::new();
        let f = |i: usize, s: f32| ((i * 7 + 3) % 11) as f32 / 11.0 * s;
        a.put("diffuse", &[h, w, 3], (0..3 * t).map(|i| f(i, 0.9)).collect());
        a.put("specular", &[h, w, 3], (0..3 * t).map(|i| f(i, 0.4)).collect());
        a.put("roughness", &[h, w], (0..t).map(|i| 0.05 + f(i, 0.9)).collect());
        let normal: Vec<f32> = (0..t)
            .flat_map(|i| {
                let (p, q) = (f(i, 0.6) - 0.3, 0.2 - f(i + 1, 0.4));
                let l = (p * p + q * q + 1.0).sqrt();
                [-p / l, -q / l, 1.0 / l]
            })
            .collect();
        a.put("normal", &[h, w, 3], normal);
        <Svbrdf as Model>::from_arrays(&a).unwrap()
    }

    #[test]
    fn a_scene_reads_back_as_the_model_it_was_written_from() {
        let dir = tempfile::tempdir().unwrap();
        let m = model();
        export(&m, &dir.path().join("s")).unwrap();
        let back = import(&dir.path().join("s").join(INDEX)).unwrap();
        // Doubling and halving are exact; the normal goes through (n + 1) / 2 and back.
        assert_eq!(back.diffuse, m.diffuse);
        assert_eq!(back.specular, m.specular);
        assert_eq!(back.roughness, m.roughness);
        for (a, b) in back.normal.iter().zip(&m.normal) {
            assert!((a - b).abs() < 2e-7, "{a} {b}");
        }
    }

    #[test]
    fn roughness_at_the_ends_of_its_range_reads_back_without_a_warning() {
        let dir = tempfile::tempdir().unwrap();
        let mut m = model();
        m.roughness[0] = ALPHA_MIN as f32;
        m.roughness[1] = ALPHA_MAX as f32;
        export(&m, dir.path()).unwrap();
        let (back, warnings) = import_within(dir.path(), &Limits::default()).unwrap();
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!(back.roughness, m.roughness);
    }

    #[test]
    fn maps_outside_the_scene_folder_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        export(&model(), dir.path()).unwrap();
        let p = dir.path().join(INDEX);
        let xml = std::fs::read_to_string(&p).unwrap().replace("\"diffuse.exr\"", "\"/etc/diffuse.exr\"");
        std::fs::write(&p, xml).unwrap();
        let e = import(&p).unwrap_err().to_string();
        assert!(e.contains("expected an .exr file name in the scene's folder"), "{e}");
    }
}
