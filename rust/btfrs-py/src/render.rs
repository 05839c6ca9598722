//! Bindings of btfrs-render: scenes, cameras, GPU upload and rendering, the CPU reference.

use crate::arrays::{borrow, check_shape, dirs};
use crate::core::BtfArgs;
use crate::errors::{arg, arg_type, IntoPy};
use crate::models::PyModel;
use crate::run::detach;
use btfrs_fit::{RawModel, Renderable};
use btfrs_render::cpu::{render_cpu, render_cpu_env_sh};
use btfrs_render::environment::Environment;
use btfrs_render::filter::{signatures, Filter, MipChain, Source, SIGNATURE_LEN};
use btfrs_render::scene::{Camera, Light, Mesh};
use btfrs_render::sh_env::ShEnvironment;
use btfrs_render::{gpu, Gpu, TileMap, UploadedModel, View};
use numpy::{IntoPyArray, PyArrayDyn, PyArrayMethods, PyUntypedArrayMethods};
use pyo3::prelude::*;
use std::sync::Arc;

/// A triangle mesh with UV-aligned tangent frames.
#[derive(Debug)]
#[pyclass(name = "Scene", module = "btfrs._native", frozen)]
pub struct PyScene {
    mesh: Mesh,
}

#[pymethods]
impl PyScene {
    /// A square of side `size` in the z = 0 plane, normal +z.
    #[staticmethod]
    #[pyo3(signature = (size=2.0))]
    fn plane(size: f32) -> PyResult<Self> {
        if !(size.is_finite() && size > 0.0) {
            return Err(arg("size", format!("expected a positive number, got {size}")));
        }
        Ok(PyScene { mesh: Mesh::plane(size) })
    }

    /// A UV sphere centred at the origin, poles on z.
    #[staticmethod]
    #[pyo3(signature = (radius=1.0, segments=64, rings=32))]
    fn sphere(radius: f32, segments: u32, rings: u32) -> PyResult<Self> {
        Ok(PyScene { mesh: Mesh::sphere(radius, segments, rings).py()? })
    }

    /// An open cylinder around the z axis.
    #[staticmethod]
    #[pyo3(signature = (radius=1.0, height=2.0, segments=64))]
    fn cylinder(radius: f32, height: f32, segments: u32) -> PyResult<Self> {
        Ok(PyScene { mesh: Mesh::cylinder(radius, height, segments).py()? })
    }

    /// An indexed mesh: vertices `[N, 3]`, uvs `[N, 2]`, faces `[F, 3]` (int), normals `[N, 3]`.
    #[staticmethod]
    #[pyo3(signature = (vertices, uvs, faces, normals=None))]
    fn mesh(
        vertices: &Bound<'_, PyAny>,
        uvs: &Bound<'_, PyAny>,
        faces: &Bound<'_, PyAny>,
        normals: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let v = borrow::<f32>("vertices", vertices)?;
        check_shape("vertices", v.shape(), &[None, Some(3)])?;
        let u = borrow::<f32>("uvs", uvs)?;
        check_shape("uvs", u.shape(), &[None, Some(2)])?;
        let f = borrow::<u32>("faces", faces)?;
        check_shape("faces", f.shape(), &[None, Some(3)])?;
        let n = normals.map(|n| borrow::<f32>("normals", n)).transpose()?;
        if let Some(n) = &n {
            check_shape("normals", n.shape(), &[None, Some(3)])?;
        }
        let vs = v.as_slice().map_err(|e| arg("vertices", e))?.as_chunks::<3>().0;
        let us = u.as_slice().map_err(|e| arg("uvs", e))?.as_chunks::<2>().0;
        let fs = f.as_slice().map_err(|e| arg("faces", e))?.as_chunks::<3>().0;
        let ns = match &n {
            Some(n) => Some(n.as_slice().map_err(|e| arg("normals", e))?.as_chunks::<3>().0),
            None => None,
        };
        Ok(PyScene { mesh: Mesh::from_arrays(vs, us, fs, ns).py()? })
    }

    /// Number of triangles.
    #[getter]
    fn triangles(&self) -> usize {
        self.mesh.triangle_count()
    }

    /// Number of vertices.
    #[getter]
    fn vertices(&self) -> usize {
        self.mesh.positions.len()
    }

    /// The mesh as the web viewer's buffers: (interleaved vertex bytes, u32 indices).
    fn web_buffers<'py>(
        &self,
        py: Python<'py>,
    ) -> (Bound<'py, pyo3::types::PyBytes>, Bound<'py, numpy::PyArray1<u32>>) {
        let (v, i) = btfrs_render::web::mesh_buffers(&self.mesh);
        (pyo3::types::PyBytes::new(py, &v), i.into_pyarray(py))
    }
}

/// A perspective camera.
#[derive(Debug)]
#[pyclass(name = "Camera", module = "btfrs._native", frozen)]
pub struct PyCamera {
    cam: Camera,
}

#[pymethods]
impl PyCamera {
    /// Look from `eye` at `target` with a vertical field of view of `fov_deg` degrees. `up`
    /// defaults to +z; looking straight up or down it then falls back to +y (the image's up
    /// is world +y). Given, it must not be parallel to the view direction.
    #[staticmethod]
    #[pyo3(signature = (eye, target, fov_deg=40.0, up=None))]
    fn look_at(eye: [f32; 3], target: [f32; 3], fov_deg: f32, up: Option<[f32; 3]>) -> PyResult<Self> {
        let cam = match up {
            Some(u) => Camera::look_at_up(eye, target, fov_deg, u),
            None => Camera::look_at(eye, target, fov_deg),
        };
        Ok(PyCamera { cam: cam.py()? })
    }

    #[getter]
    fn up(&self) -> [f32; 3] {
        self.cam.up
    }

    #[getter]
    fn eye(&self) -> [f32; 3] {
        self.cam.eye
    }

    #[getter]
    fn target(&self) -> [f32; 3] {
        self.cam.target
    }

    #[getter]
    fn fov_deg(&self) -> f32 {
        self.cam.fov_y_deg
    }
}

/// A model uploaded to the GPU.
#[derive(Debug)]
#[pyclass(name = "GpuModel", module = "btfrs._native", frozen)]
pub struct PyGpuModel {
    gpu: Arc<Gpu>,
    up: UploadedModel,
}

#[pymethods]
impl PyGpuModel {
    /// Bytes held on the device.
    #[getter]
    fn device_bytes(&self) -> u64 {
        self.up.device_bytes
    }
}

/// Name, backend and type of the adapter in use.
#[pyfunction]
pub fn gpu_info(py: Python<'_>) -> PyResult<String> {
    detach(py, || Ok(Gpu::shared()?.describe()))
}

/// Upload a raw BTF (every pair present).
#[pyfunction]
pub fn gpu_upload_raw(
    py: Python<'_>,
    data: &Bound<'_, PyAny>,
    views: &Bound<'_, PyAny>,
    lights: &Bound<'_, PyAny>,
) -> PyResult<PyGpuModel> {
    let args = BtfArgs::new(data, views, lights, None)?;
    let b = args.btf()?;
    let raw = RawModel::new(b).py()?;
    detach(py, || {
        let gpu = Gpu::shared()?;
        let up = gpu::upload(&gpu, &raw)?;
        Ok(PyGpuModel { gpu, up })
    })
}

/// Lights from Python tuples (kind, vector, intensity): kind "point" (vector = position) or
/// "directional" (vector = direction towards the light).
fn lights_of(items: Vec<(String, [f32; 3], [f32; 3])>) -> PyResult<Vec<Light>> {
    items
        .into_iter()
        .map(|(k, v, i)| match k.as_str() {
            "point" => Ok(Light::Point { position: v, intensity: i }),
            "directional" => Ok(Light::Directional { direction: v, intensity: i }),
            o => Err(arg("lights", format!("unknown light kind {o:?}"))),
        })
        .collect()
}

/// Pack a `[H, W, 2]` uint16 coordinate map (x, y) into `x | y << 16` entries.
fn coords_of(coords: Option<&Bound<'_, PyAny>>) -> PyResult<Option<(usize, usize, Vec<u32>)>> {
    let Some(c) = coords else { return Ok(None) };
    let a = borrow::<u16>("coords", c)?;
    check_shape("coords", a.shape(), &[None, None, Some(2)])?;
    let (h, w) = (a.shape()[0], a.shape()[1]);
    let s = a.as_slice().map_err(|e| arg("coords", e))?;
    Ok(Some((w, h, s.chunks_exact(2).map(|p| p[0] as u32 | (p[1] as u32) << 16).collect())))
}

type Image<'py> = Bound<'py, PyArrayDyn<f32>>;

/// A tile map from Python: `(atlas [AH, AW] uint32, tile, layout [R, C, 2] uint32 of (atlas
/// tile row, column))`, packed as the renderer's [`TileMap`] parts.
struct TileArgs {
    tile: usize,
    atlas_cols: usize,
    atlas_rows: usize,
    atlas: Vec<u32>,
    layout_cols: usize,
    layout_rows: usize,
    layout: Vec<u32>,
}

fn tiles_of(tile_map: Option<&Bound<'_, PyAny>>) -> PyResult<Option<TileArgs>> {
    let Some(t) = tile_map else { return Ok(None) };
    let (atlas, tile, layout): (Bound<'_, PyAny>, usize, Bound<'_, PyAny>) =
        t.extract().map_err(|_| arg_type("tile_map", "expected (atlas, tile, layout)"))?;
    let a = borrow::<u32>("tile_map", &atlas)?;
    check_shape("tile_map", a.shape(), &[None, None])?;
    let (ah, aw) = (a.shape()[0], a.shape()[1]);
    if tile == 0 || ah % tile != 0 || aw % tile != 0 {
        return Err(arg("tile_map", format!("the {ah} x {aw} atlas is not made of {tile}^2 tiles")));
    }
    let atlas_v = a.as_slice().map_err(|e| arg("tile_map", e))?.to_vec();
    let l = borrow::<u32>("tile_map", &layout)?;
    check_shape("tile_map", l.shape(), &[None, None, Some(2)])?;
    let (lr, lc) = (l.shape()[0], l.shape()[1]);
    let ls = l.as_slice().map_err(|e| arg("tile_map", e))?;
    if let Some(p) = ls.iter().position(|&v| v > 0xffff) {
        return Err(arg("tile_map", format!("layout entry {} is {}, above 65535", p / 2, ls[p])));
    }
    let layout_v = ls.chunks_exact(2).map(|p| p[0] << 16 | p[1]).collect();
    Ok(Some(TileArgs {
        tile,
        atlas_cols: aw / tile,
        atlas_rows: ah / tile,
        atlas: atlas_v,
        layout_cols: lc,
        layout_rows: lr,
        layout: layout_v,
    }))
}

impl TileArgs {
    fn map(&self) -> TileMap<'_> {
        TileMap {
            tile: self.tile,
            atlas_cols: self.atlas_cols,
            atlas_rows: self.atlas_rows,
            atlas: &self.atlas,
            layout_cols: self.layout_cols,
            layout_rows: self.layout_rows,
            layout: &self.layout,
        }
    }
}

/// The owned parts of a [`View`] converted from Python arguments.
struct ViewArgs {
    lights: Vec<Light>,
    coords: Option<(usize, usize, Vec<u32>)>,
    tiles: Option<TileArgs>,
}

impl ViewArgs {
    fn new(
        lights: Vec<(String, [f32; 3], [f32; 3])>,
        coords: Option<&Bound<'_, PyAny>>,
        tile_map: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        Ok(ViewArgs { lights: lights_of(lights)?, coords: coords_of(coords)?, tiles: tiles_of(tile_map)? })
    }

    fn view<'a>(
        &'a self,
        scene: &'a PyScene,
        camera: &'a PyCamera,
        size: (usize, usize),
        uv_scale: [f32; 2],
    ) -> View<'a> {
        View {
            mesh: &scene.mesh,
            camera: &camera.cam,
            lights: &self.lights,
            width: size.0,
            height: size.1,
            uv_scale,
            coords: self.coords.as_ref().map(|(w, h, m)| (*w, *h, &m[..])),
            tiles: self.tiles.as_ref().map(TileArgs::map),
            filter: None,
        }
    }
}

/// The frame as an array; a frame with a non-finite pixel is a `NumericalError` naming what was
/// drawn (`culprit`: the model, which names its largest stored value), never returned.
fn image<'py>(
    py: Python<'py>,
    v: Vec<f32>,
    w: usize,
    h: usize,
    culprit: Option<&dyn btfrs_fit::DynModel>,
    what: &str,
) -> PyResult<Image<'py>> {
    if let Some(bad) = v.chunks(3).position(|p| !p.iter().all(|x| x.is_finite())) {
        let n = v.chunks(3).filter(|p| !p.iter().all(|x| x.is_finite())).count();
        let e = match culprit {
            Some(m) => btfrs_fit::model::overflow(m, "render"),
            None => btfrs_core::Error::Numerical(format!(
                "render: the {what} gives non-finite values (its stored values overflow when rendered)"
            )),
        };
        let msg = format!("{e}: {n} of {} pixels, the first at row {}, column {}", w * h, bad / w, bad % w);
        return Err(crate::errors::to_py(btfrs_core::Error::Numerical(msg)));
    }
    v.into_pyarray(py).reshape(vec![h, w, 3])
}

/// Render an uploaded model on the GPU: (image, draw ms, read-back ms).
#[pyfunction]
#[pyo3(signature = (model, scene, camera, lights, width, height, uv_scale, coords=None, tile_map=None, filter=None))]
#[allow(clippy::too_many_arguments)]
pub fn gpu_render<'py>(
    py: Python<'py>,
    model: &PyGpuModel,
    scene: &PyScene,
    camera: &PyCamera,
    lights: Vec<(String, [f32; 3], [f32; 3])>,
    width: usize,
    height: usize,
    uv_scale: [f32; 2],
    coords: Option<&Bound<'py, PyAny>>,
    tile_map: Option<&Bound<'py, PyAny>>,
    filter: Option<(String, PyRef<'py, PyMipChain>)>,
) -> PyResult<(Image<'py>, f64, f64)> {
    let args = ViewArgs::new(lights, coords, tile_map)?;
    let f = filter_of(filter)?;
    let view =
        View { filter: f.as_ref().map(|(m, c)| (*m, &c.chain)), ..args.view(scene, camera, (width, height), uv_scale) };
    let (img, t) = detach(py, || gpu::render(&model.gpu, &model.up, &view))?;
    let what = format!("{} model", model.up.shader_name());
    Ok((image(py, img, width, height, None, &what)?, t.draw_ms, t.readback_ms))
}

/// Render a raw BTF with the CPU reference renderer.
#[pyfunction]
#[pyo3(signature = (data, views, btf_lights, scene, camera, lights, width, height, uv_scale, coords=None, tile_map=None, filter=None))]
#[allow(clippy::too_many_arguments)]
pub fn cpu_render_raw<'py>(
    py: Python<'py>,
    data: &Bound<'py, PyAny>,
    views: &Bound<'py, PyAny>,
    btf_lights: &Bound<'py, PyAny>,
    scene: &PyScene,
    camera: &PyCamera,
    lights: Vec<(String, [f32; 3], [f32; 3])>,
    width: usize,
    height: usize,
    uv_scale: [f32; 2],
    coords: Option<&Bound<'py, PyAny>>,
    tile_map: Option<&Bound<'py, PyAny>>,
    filter: Option<(String, PyRef<'py, PyMipChain>)>,
) -> PyResult<Image<'py>> {
    let args = BtfArgs::new(data, views, btf_lights, None)?;
    let b = args.btf()?;
    let _ = dirs("views", &args.views)?;
    let raw = RawModel::new(b).py()?;
    let args = ViewArgs::new(lights, coords, tile_map)?;
    let f = filter_of(filter)?;
    let view =
        View { filter: f.as_ref().map(|(m, c)| (*m, &c.chain)), ..args.view(scene, camera, (width, height), uv_scale) };
    check_size(width, height)?;
    let img = detach(py, || render_cpu(&raw, &view))?;
    image(py, img, width, height, None, "raw BTF")
}

fn check_size(width: usize, height: usize) -> PyResult<()> {
    if width == 0 || height == 0 || width > 16384 || height > 16384 {
        return Err(arg("size", format!("expected 1 to 16384 pixels per side, got {width} x {height}")));
    }
    Ok(())
}

/// The 3D texture limit of the device the renderers use (WebGPU's default when there is none:
/// the CPU reference then still builds what the GPU would).
fn max_3d() -> usize {
    Gpu::shared().map(|g| g.limits.max_texture_dimension_3d as usize).unwrap_or(2048)
}

/// Upload any fitted model; `method` picks the renderer where a model has several ("9tap" or
/// "3d" for LPCA; "default" is the first).
#[pyfunction]
#[pyo3(signature = (model, method="default"))]
pub fn gpu_upload_model(py: Python<'_>, model: &PyModel, method: &str) -> PyResult<PyGpuModel> {
    detach(py, || {
        let gpu = Gpu::shared()?;
        let r = model.inner.renderer(method, gpu.limits.max_texture_dimension_3d as usize)?;
        let up = gpu::upload(&gpu, r.as_ref())?;
        Ok(PyGpuModel { gpu, up })
    })
}

/// A model's GPU data for the web viewer (see `btfrs_render::web`): a dict of `shader` (str),
/// `params`, `store`, `tables` (u32 arrays), `dirs` (f32 `[n, 4]`), `volume` (None or
/// `((width, height, depth), u8 bytes)`) and `chunk_len`. `method` picks the renderer as for
/// the upload.
#[pyfunction]
#[pyo3(signature = (model, method="default"))]
pub fn web_model<'py>(py: Python<'py>, model: &PyModel, method: &str) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let w = detach(py, || {
        // WebGPU's guaranteed 3D texture side (browsers' default limit).
        let r = model.inner.renderer(method, 2048)?;
        btfrs_render::web::web_model(r.as_ref())
    })?;
    let d = pyo3::types::PyDict::new(py);
    d.set_item("shader", w.shader)?;
    d.set_item("params", w.params.into_pyarray(py))?;
    d.set_item("store", w.store.into_pyarray(py))?;
    let n = w.dirs.len();
    let flat: Vec<f32> = w.dirs.into_iter().flatten().collect();
    d.set_item("dirs", flat.into_pyarray(py).reshape([n, 4])?)?;
    d.set_item("tables", w.tables.into_pyarray(py))?;
    match w.volume {
        Some((size, bytes)) => d.set_item("volume", (size, pyo3::types::PyBytes::new(py, &bytes)))?,
        None => d.set_item("volume", py.None())?,
    }
    d.set_item("chunk_len", w.chunk_len)?;
    Ok(d)
}

/// The window layout of a model family drawn from image tiles (see
/// `btfrs_render::web::web_window`): `probes` are `(model, planes uint8 [h, w, nplanes])`, two
/// of one size and one of another. Returns `{"shader", "params", "constants": [(offset,
/// words)], "texels": [(offset, bytes, from)], "store_words", "capacity", "dirs", "tables"}`.
#[pyfunction]
pub fn web_window<'py>(
    py: Python<'py>,
    probes: Vec<(PyRef<'py, PyModel>, Bound<'py, PyAny>)>,
    capacity: usize,
) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let mut held = Vec::with_capacity(probes.len());
    let mut nplanes = 0;
    for (_, planes) in &probes {
        let a = crate::arrays::borrow::<u8>("planes", planes)?;
        crate::arrays::check_shape("planes", a.shape(), &[None, None, None])?;
        nplanes = a.shape()[2];
        held.push(a);
    }
    let slices =
        held.iter().map(|a| a.as_slice().map_err(|e| crate::errors::arg("planes", e))).collect::<PyResult<Vec<_>>>()?;
    let models: Vec<&dyn btfrs_fit::DynModel> = probes.iter().map(|(m, _)| m.inner.as_ref()).collect();
    let w = detach(py, || {
        let renderers = models.iter().map(|m| m.renderer("default", 2048)).collect::<btfrs_core::Result<Vec<_>>>()?;
        let list: Vec<btfrs_render::web::Probe<'_>> = renderers
            .iter()
            .zip(&slices)
            .map(|(r, q)| btfrs_render::web::Probe {
                model: r.as_ref(),
                planes: q,
                texels: q.len().checked_div(nplanes).unwrap_or(0),
            })
            .collect();
        btfrs_render::web::web_window(&list, nplanes, capacity)
    })?;
    let d = pyo3::types::PyDict::new(py);
    d.set_item("shader", w.shader)?;
    d.set_item("params", w.params.into_pyarray(py))?;
    let constants: Vec<(u32, Bound<'py, numpy::PyArray1<u32>>)> =
        w.constants.into_iter().map(|(o, words)| (o, words.into_pyarray(py))).collect();
    d.set_item("constants", constants)?;
    let texels: Vec<(u32, u32, Vec<u32>)> = w.texels.into_iter().map(|t| (t.offset, t.bytes, t.from)).collect();
    d.set_item("texels", texels)?;
    d.set_item("store_words", w.store_words)?;
    d.set_item("capacity", w.capacity)?;
    let n = w.dirs.len();
    let flat: Vec<f32> = w.dirs.into_iter().flatten().collect();
    d.set_item("dirs", flat.into_pyarray(py).reshape([n, 4])?)?;
    d.set_item("tables", w.tables.into_pyarray(py))?;
    Ok(d)
}

/// A coordinate map or a tile map laid out for the web viewer, checked against `model`:
/// `{"words": uint32 map buffer, "map_size": [w, h], "tiles": [4], "tile_atlas": [4]}`.
#[pyfunction]
#[pyo3(signature = (model, coords=None, tile_map=None))]
pub fn web_map<'py>(
    py: Python<'py>,
    model: &PyModel,
    coords: Option<&Bound<'py, PyAny>>,
    tile_map: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let args = ViewArgs::new(Vec::new(), coords, tile_map)?;
    let dims = model.inner.dims();
    let w = detach(py, || {
        let tiles = args.tiles.as_ref().map(TileArgs::map);
        btfrs_render::web::web_map(args.coords.as_ref().map(|(w, h, m)| (*w, *h, &m[..])), tiles, dims)
    })?;
    let d = pyo3::types::PyDict::new(py);
    d.set_item("words", w.words.into_pyarray(py))?;
    d.set_item("map_size", w.fields.map_size)?;
    d.set_item("tiles", w.fields.tiles)?;
    d.set_item("tile_atlas", w.fields.tile_atlas)?;
    Ok(d)
}

/// The layouts the web viewer agrees on with the shaders, as JSON (see `btfrs_render::web`).
#[pyfunction]
pub fn web_layout() -> String {
    btfrs_render::web::layout().to_string()
}

/// Render any fitted model with the CPU reference renderer (`method` as for the upload): the
/// same object the GPU draws, evaluated by its own Rust code.
#[pyfunction]
#[pyo3(signature = (model, scene, camera, lights, width, height, uv_scale, coords=None, method="default", tile_map=None, filter=None))]
#[allow(clippy::too_many_arguments)]
pub fn cpu_render_model<'py>(
    py: Python<'py>,
    model: &PyModel,
    scene: &PyScene,
    camera: &PyCamera,
    lights: Vec<(String, [f32; 3], [f32; 3])>,
    width: usize,
    height: usize,
    uv_scale: [f32; 2],
    coords: Option<&Bound<'py, PyAny>>,
    method: &str,
    tile_map: Option<&Bound<'py, PyAny>>,
    filter: Option<(String, PyRef<'py, PyMipChain>)>,
) -> PyResult<Image<'py>> {
    let args = ViewArgs::new(lights, coords, tile_map)?;
    let f = filter_of(filter)?;
    let view =
        View { filter: f.as_ref().map(|(m, c)| (*m, &c.chain)), ..args.view(scene, camera, (width, height), uv_scale) };
    check_size(width, height)?;
    let img = detach(py, || {
        let r: Box<dyn Renderable + '_> = model.inner.renderer(method, max_3d())?;
        render_cpu(r.as_ref(), &view)
    })?;
    image(py, img, width, height, Some(model.inner.as_ref()), "model")
}

/// What a scene asks of a sample of `dims` = (height, width) texels, per covered pixel
/// (btfrs_render::usage::scene_directions): a dict of arrays `pixels [N]` (row-major index),
/// `views [N, 3]`, `lights [N, L, 3]`, `irradiance [N, L]`, `uv [N, 2]`, `footprint [N]`
/// (texels per pixel, NaN where unknown).
#[pyfunction]
#[pyo3(signature = (scene, camera, lights, width, height, uv_scale, dims))]
#[allow(clippy::too_many_arguments)]
pub fn scene_directions<'py>(
    py: Python<'py>,
    scene: &PyScene,
    camera: &PyCamera,
    lights: Vec<(String, [f32; 3], [f32; 3])>,
    width: usize,
    height: usize,
    uv_scale: [f32; 2],
    dims: (usize, usize),
) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let args = ViewArgs::new(lights, None, None)?;
    let view = args.view(scene, camera, (width, height), uv_scale);
    check_size(width, height)?;
    let s = detach(py, || btfrs_render::usage::scene_directions(&view, dims))?;
    let (n, nl) = (s.pixels.len(), s.n_lights);
    let flat3 = |v: Vec<[f32; 3]>| v.into_iter().flatten().collect::<Vec<f32>>();
    let d = pyo3::types::PyDict::new(py);
    d.set_item("pixels", s.pixels.into_pyarray(py))?;
    d.set_item("views", flat3(s.views).into_pyarray(py).reshape(vec![n, 3])?)?;
    d.set_item("lights", flat3(s.lights).into_pyarray(py).reshape(vec![n, nl, 3])?)?;
    d.set_item("irradiance", s.irradiance.into_pyarray(py).reshape(vec![n, nl])?)?;
    d.set_item("uv", s.uv.into_iter().flatten().collect::<Vec<f32>>().into_pyarray(py).reshape(vec![n, 2])?)?;
    d.set_item("footprint", s.footprint.into_pyarray(py))?;
    Ok(d)
}

/// A lat-long environment from a `[H, 2H, 3]` float32 array, validated by the renderer.
fn environment_of(rgb: &Bound<'_, PyAny>) -> PyResult<Environment> {
    let a = borrow::<f32>("environment", rgb)?;
    check_shape("environment", a.shape(), &[None, None, Some(3)])?;
    let (h, w) = (a.shape()[0], a.shape()[1]);
    let s = a.as_slice().map_err(|e| arg("environment", e))?;
    Environment::new(w, h, s.to_vec()).py()
}

type Lights<'py> = (Bound<'py, PyArrayDyn<f32>>, Bound<'py, PyArrayDyn<f32>>);

fn light_arrays(py: Python<'_>, lights: Vec<Light>) -> PyResult<Lights<'_>> {
    let n = lights.len();
    let (mut d, mut i) = (Vec::with_capacity(3 * n), Vec::with_capacity(3 * n));
    for l in lights {
        if let Light::Directional { direction, intensity } = l {
            d.extend(direction);
            i.extend(intensity);
        }
    }
    Ok((d.into_pyarray(py).reshape(vec![n, 3])?, i.into_pyarray(py).reshape(vec![n, 3])?))
}

/// Check a lat-long environment (finite, non-negative, 2:1, not black).
#[pyfunction]
pub fn env_check(rgb: &Bound<'_, PyAny>) -> PyResult<()> {
    environment_of(rgb).map(|_| ())
}

/// Preetham's analytic sky as a `[height, 2 height, 3]` lat-long array (zenith luminance 1).
#[pyfunction]
#[pyo3(signature = (sun, turbidity, height, ground))]
pub fn env_sky<'py>(
    py: Python<'py>,
    sun: [f64; 3],
    turbidity: f64,
    height: usize,
    ground: f64,
) -> PyResult<Image<'py>> {
    let e = detach(py, || Environment::sky(sun, turbidity, height, ground))?;
    e.rgb.into_pyarray(py).reshape(vec![e.height, e.width, 3])
}

/// `samples` importance-sampled directional lights: (directions [N, 3], intensities [N, 3]).
#[pyfunction]
pub fn env_sample<'py>(py: Python<'py>, rgb: &Bound<'py, PyAny>, samples: usize, seed: u64) -> PyResult<Lights<'py>> {
    let e = environment_of(rgb)?;
    let l = detach(py, || e.sample_lights(samples, seed))?;
    light_arrays(py, l)
}

/// Every lit pixel as a light (the brute-force quadrature): (directions, intensities).
#[pyfunction]
pub fn env_quadrature<'py>(py: Python<'py>, rgb: &Bound<'py, PyAny>) -> PyResult<Lights<'py>> {
    let e = environment_of(rgb)?;
    light_arrays(py, e.quadrature_lights())
}

/// The environment's projection on the first `n` real SH: `[n, 3]` float64.
#[pyfunction]
pub fn env_sh<'py>(py: Python<'py>, rgb: &Bound<'py, PyAny>, n: usize) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let e = environment_of(rgb)?;
    let c = detach(py, || Ok(e.sh_project(n)))?;
    let k = c.len();
    c.into_iter().flatten().collect::<Vec<f64>>().into_pyarray(py).reshape(vec![k, 3])
}

/// Render a double-SH model under an environment by the SH method, on the GPU (`gpu` given:
/// the uploaded model) or the CPU: (image, draw ms, read-back ms; 0 on the CPU).
#[pyfunction]
#[pyo3(signature = (model, uploaded, scene, camera, environment, width, height, uv_scale, coords=None, tile_map=None, filter=None))]
#[allow(clippy::too_many_arguments)]
pub fn render_env_sh<'py>(
    py: Python<'py>,
    model: &PyModel,
    uploaded: Option<&PyGpuModel>,
    scene: &PyScene,
    camera: &PyCamera,
    environment: &Bound<'py, PyAny>,
    width: usize,
    height: usize,
    uv_scale: [f32; 2],
    coords: Option<&Bound<'py, PyAny>>,
    tile_map: Option<&Bound<'py, PyAny>>,
    filter: Option<(String, PyRef<'py, PyMipChain>)>,
) -> PyResult<(Image<'py>, f64, f64)> {
    let kl = btfrs_render::cpu::sh_expansion_of(model.inner.as_ref()).py()?.light_coeffs;
    let env = environment_of(environment)?;
    let args = ViewArgs::new(Vec::new(), coords, tile_map)?;
    let f = filter_of(filter)?;
    let view =
        View { filter: f.as_ref().map(|(m, c)| (*m, &c.chain)), ..args.view(scene, camera, (width, height), uv_scale) };
    check_size(width, height)?;
    let (img, t) = detach(py, || {
        let she = ShEnvironment::new(&env, kl)?;
        match uploaded {
            Some(u) => gpu::render_env_sh(&u.gpu, &u.up, &view, &she),
            None => Ok((render_cpu_env_sh(model.inner.as_ref(), &view, &she)?, Default::default())),
        }
    })?;
    Ok((image(py, img, width, height, Some(model.inner.as_ref()), "model")?, t.draw_ms, t.readback_ms))
}

/// A mip chain for filtered lookups (btfrs_render::filter), built once per model and map.
#[derive(Debug)]
#[pyclass(name = "MipChain", module = "btfrs._native", frozen)]
pub struct PyMipChain {
    chain: MipChain,
}

#[pymethods]
impl PyMipChain {
    /// Number of levels.
    #[getter]
    fn levels(&self) -> usize {
        self.chain.levels.len()
    }
}

/// The view's filter from Python: (mode, chain) or None.
fn filter_of(filter: Option<(String, PyRef<'_, PyMipChain>)>) -> PyResult<Option<(Filter, PyRef<'_, PyMipChain>)>> {
    filter.map(|(f, c)| Ok((Filter::parse(&f).py()?, c))).transpose()
}

/// Appearance signatures of a model's texels, `[texels, 18]` (btfrs_render::filter::signatures).
#[pyfunction]
pub fn filter_signature<'py>(py: Python<'py>, model: &PyModel) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
    let (h, w) = model.inner.dims();
    let sig = detach(py, || Ok(signatures(model.inner.as_ref())))?;
    sig.into_pyarray(py).reshape(vec![h * w, SIGNATURE_LEN])
}

/// Build the mip chain of the texture a render shows: `kind` "average" (coarse levels are new
/// texels: returns also the groups, `[G, 4]` texel indices (-1 unused) and weights) or
/// "medoid" (levels of existing texels chosen by `signature` `[texels, K]`; zeros when None).
#[pyfunction]
#[pyo3(signature = (kind, dims, coords=None, tile_map=None, signature=None))]
#[allow(clippy::type_complexity)]
pub fn filter_build<'py>(
    py: Python<'py>,
    kind: &str,
    dims: (usize, usize),
    coords: Option<&Bound<'py, PyAny>>,
    tile_map: Option<&Bound<'py, PyAny>>,
    signature: Option<&Bound<'py, PyAny>>,
) -> PyResult<(PyMipChain, Bound<'py, PyArrayDyn<i64>>, Bound<'py, PyArrayDyn<f32>>)> {
    let args = ViewArgs::new(Vec::new(), coords, tile_map)?;
    let (h, w) = dims;
    let texels = h * w;
    let tm = args.tiles.as_ref().map(|t| TileMap {
        tile: t.tile,
        atlas_cols: t.atlas_cols,
        atlas_rows: t.atlas_rows,
        atlas: &t.atlas,
        layout_cols: t.layout_cols,
        layout_rows: t.layout_rows,
        layout: &t.layout,
    });
    if let Some(t) = &tm {
        t.validate(texels).py()?;
    }
    let source = || match (&tm, &args.coords) {
        (Some(t), _) => Source::Tiles(t),
        (None, Some((mw, mh, m))) => Source::Coords(*mw, *mh, m, w),
        (None, None) => Source::Sample(h, w),
    };
    let (chain, groups) = match kind {
        "average" => MipChain::build_average(source(), texels).py()?,
        "medoid" => {
            let (sig, k) = match signature {
                Some(s) => {
                    let a = borrow::<f32>("signature", s)?;
                    check_shape("signature", a.shape(), &[Some(texels), None])?;
                    let k = a.shape()[1];
                    (a.as_slice().map_err(|e| arg("signature", e))?.to_vec(), k)
                }
                None => (vec![0.0f32; texels], 1),
            };
            (MipChain::build(source(), &sig, k, texels).py()?, Vec::new())
        }
        o => return Err(arg("kind", format!("expected \"average\" or \"medoid\", got {o:?}"))),
    };
    let g = groups.len();
    let mut idx = vec![-1i64; g * 4];
    let mut wts = vec![0.0f32; g * 4];
    for (i, grp) in groups.iter().enumerate() {
        for (j, &(t, wt)) in grp.iter().enumerate() {
            idx[i * 4 + j] = t as i64;
            wts[i * 4 + j] = wt;
        }
    }
    Ok((PyMipChain { chain }, idx.into_pyarray(py).reshape(vec![g, 4])?, wts.into_pyarray(py).reshape(vec![g, 4])?))
}

/// The model extended by averaged texels (btfrs_fit::registry::mip_texels): groups as returned
/// by `filter_build("average", ...)`.
#[pyfunction]
pub fn mip_model(
    py: Python<'_>,
    model: &PyModel,
    idx: &Bound<'_, PyAny>,
    weights: &Bound<'_, PyAny>,
) -> PyResult<PyModel> {
    let i = borrow::<i64>("idx", idx)?;
    let w = borrow::<f32>("weights", weights)?;
    let (i, w) = (i.as_slice().map_err(|e| arg("idx", e))?, w.as_slice().map_err(|e| arg("weights", e))?);
    if i.len() != w.len() || i.len() % 4 != 0 {
        return Err(arg("weights", "expected [G, 4] indices and weights of the same shape"));
    }
    let groups: Vec<Vec<(u32, f32)>> = i
        .chunks(4)
        .zip(w.chunks(4))
        .map(|(a, b)| a.iter().zip(b).filter(|(t, _)| **t >= 0).map(|(&t, &x)| (t as u32, x)).collect())
        .collect();
    let inner = detach(py, || btfrs_fit::registry::mip_texels(model.inner.as_ref(), &groups))?;
    Ok(PyModel { inner, robust: serde_json::Value::Null })
}
