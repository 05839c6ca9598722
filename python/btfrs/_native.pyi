"""Type stubs of the PyO3 extension ``btfrs._native`` (checked by ``mypy.stubtest``)."""

from os import PathLike
from typing import Any, Callable, Optional, Union, final

import numpy as np
import numpy.typing as npt

_Path = Union[str, PathLike[str]]
_Progress = Optional[Callable[[int, int], object]]
_F32 = npt.NDArray[np.float32]
_F64 = npt.NDArray[np.float64]
_Bool = npt.NDArray[np.bool_]

__all__ = ['__version__', '_panic_for_test', 'ubo81', 'validate_btf', 'split_pairs', 'material_names', 'make_material', 'Model', 'fit_model', 'load_model', 'model_registry', 'square_to_disk', 'disk_to_square', 'square_to_hemisphere', 'hemisphere_to_square', 'save_container', 'read_container_header', 'write_ptm', 'read_ptm', 'write_rti', 'read_rti', 'write_png', 'read_png', 'write_exr', 'read_exr', 'write_exr_channels', 'load_capture', 'texel_arrays', 'Scene', 'Camera', 'GpuModel', 'gpu_info', 'gpu_upload_raw', 'gpu_render', 'cpu_render_raw', 'gpu_upload_model', 'cpu_render_model', 'env_check', 'env_sky', 'env_sample', 'env_quadrature', 'env_sh', 'render_env_sh', 'MipChain', 'filter_signature', 'filter_build', 'mip_model', 'scene_directions', 'Analysis', 'analyse_btf_native', 'analyse_features_native', 'min_cut_native', 'grid_min_cut_native', 'wang_model_features', 'wang_synthesize', 'wang_tiling', 'wang_check', 'wang_atlas_positions', 'wang_seam_errors', 'wang_random_crops', 'texture_names', 'make_texture']
__version__: str

def _panic_for_test(place: str) -> None: ...
def ubo81() -> _F64: ...
def validate_btf(
    data: _F32, views: _F64, lights: _F64, mask: Optional[_Bool] = None, scan_values: bool = True
) -> None: ...
def split_pairs(
    n_views: int, n_lights: int, holdout: float, seed: int, mask: Optional[_Bool] = None
) -> tuple[_Bool, _Bool]: ...
def material_names() -> list[str]: ...
def make_material(
    name: str,
    size: int,
    views: _F64,
    lights: _F64,
    seed: int,
    relief: float = 1.0,
    subsurface: float = 0.0,
    out: Optional[Union[str, PathLike[str]]] = None,
    progress: _Progress = None,
) -> Optional[_F32]: ...
def square_to_disk(st: npt.NDArray[Any]) -> npt.NDArray[Any]: ...
def disk_to_square(xy: npt.NDArray[Any]) -> npt.NDArray[Any]: ...
def square_to_hemisphere(st: npt.NDArray[Any]) -> npt.NDArray[Any]: ...
def hemisphere_to_square(d: npt.NDArray[Any]) -> npt.NDArray[Any]: ...
def min_cut_native(
    n: int, edges: npt.NDArray[np.int64], capacities: npt.NDArray[Any], terminal_caps: npt.NDArray[Any]
) -> tuple[Union[int, float], _Bool]: ...
def grid_min_cut_native(
    right: npt.NDArray[Any], down: npt.NDArray[Any], terminal_caps: npt.NDArray[Any]
) -> tuple[Union[int, float], _Bool]: ...

@final
class Model:
    @staticmethod
    def from_arrays(kind: str, arrays: dict[str, npt.NDArray[Any]]) -> Model: ...
    @property
    def kind(self) -> str: ...
    @property
    def dims(self) -> tuple[int, int]: ...
    @property
    def nbytes(self) -> int: ...
    @property
    def renderers(self) -> list[str]: ...
    def report(self) -> dict[str, Any]: ...
    def evaluate(self, view: list[float], light: list[float]) -> _F32: ...
    def error(self, data: _F32, views: _F64, lights: _F64, mask: Optional[_Bool] = None) -> dict[str, float]: ...
    def arrays(self) -> dict[str, npt.NDArray[Any]]: ...
    def select_texels(self, texels: list[int]) -> Model: ...
    def save(self, path: _Path, meta_json: str) -> None: ...

def fit_model(
    kind: str,
    data: _F32,
    views: _F64,
    lights: _F64,
    mask: Optional[_Bool] = None,
    options_json: str = "{}",
    progress: _Progress = None,
) -> Model: ...
def load_model(path: _Path) -> tuple[Model, str]: ...
def model_registry() -> list[tuple[str, str, list[str], list[tuple[str, str]]]]: ...
def save_container(path: _Path, kind: str, meta_json: str, arrays: list[tuple[str, npt.NDArray[Any]]]) -> None: ...
def read_container_header(path: _Path) -> tuple[str, str, list[tuple[str, str, list[int], int, Optional[bool]]]]: ...
def write_ptm(path: _Path, model: Model, view: int) -> tuple[list[float], list[int]]: ...
def read_ptm(path: _Path) -> Model: ...
def write_rti(path: _Path, model: Model, view: int) -> tuple[list[float], list[float]]: ...
def read_rti(path: _Path) -> Model: ...
def write_png(path: _Path, image: _F32, exposure: float = 1.0) -> None: ...
def read_png(path: _Path) -> _F32: ...
def write_exr(path: _Path, image: _F32) -> None: ...
def read_exr(path: _Path) -> _F32: ...
def write_exr_channels(path: _Path, names: list[str], planes: _F32) -> None: ...
def load_capture(
    kind: str,
    path: _Path,
    table: Optional[_Path] = None,
    crop: Optional[tuple[int, int, int, int]] = None,
    views: Optional[list[int]] = None,
    lights: Optional[list[int]] = None,
    linear: bool = False,
    mmap_to: Optional[_Path] = None,
    progress: Optional[Callable[[int, int], object]] = None,
) -> tuple[Optional[_F32], npt.NDArray[np.float64], npt.NDArray[np.float64], Optional[npt.NDArray[np.bool_]], str]: ...
def texel_arrays(kind: str) -> list[str]: ...

@final
class Scene:
    @staticmethod
    def plane(size: float = 2.0) -> Scene: ...
    @staticmethod
    def sphere(radius: float = 1.0, segments: int = 64, rings: int = 32) -> Scene: ...
    @staticmethod
    def cylinder(radius: float = 1.0, height: float = 2.0, segments: int = 64) -> Scene: ...
    @staticmethod
    def mesh(
        vertices: npt.NDArray[np.float32],
        uvs: npt.NDArray[np.float32],
        faces: npt.NDArray[np.uint32],
        normals: Optional[npt.NDArray[np.float32]] = None,
    ) -> Scene: ...
    @property
    def triangles(self) -> int: ...
    @property
    def vertices(self) -> int: ...

@final
class Camera:
    @staticmethod
    def look_at(eye: Any, target: Any, fov_deg: float = 40.0, up: Optional[Any] = None) -> Camera: ...
    @property
    def up(self) -> list[float]: ...
    @property
    def eye(self) -> list[float]: ...
    @property
    def target(self) -> list[float]: ...
    @property
    def fov_deg(self) -> float: ...

@final
class GpuModel:
    @property
    def device_bytes(self) -> int: ...

_Lights = list[tuple[str, list[float], list[float]]]

def gpu_info() -> str: ...
def gpu_upload_raw(data: _F32, views: _F64, lights: _F64) -> GpuModel: ...
def gpu_render(
    model: GpuModel,
    scene: Scene,
    camera: Camera,
    lights: _Lights,
    width: int,
    height: int,
    uv_scale: list[float],
    coords: Optional[npt.NDArray[np.uint16]] = None,
    tile_map: Optional[tuple[npt.NDArray[np.uint32], int, npt.NDArray[np.uint32]]] = None,
    filter: _Filter = None,
) -> tuple[_F32, float, float]: ...
def cpu_render_raw(
    data: _F32,
    views: _F64,
    btf_lights: _F64,
    scene: Scene,
    camera: Camera,
    lights: _Lights,
    width: int,
    height: int,
    uv_scale: list[float],
    coords: Optional[npt.NDArray[np.uint16]] = None,
    tile_map: Optional[tuple[npt.NDArray[np.uint32], int, npt.NDArray[np.uint32]]] = None,
    filter: _Filter = None,
) -> _F32: ...
def gpu_upload_model(model: Model, method: str = "default") -> GpuModel: ...
def cpu_render_model(
    model: Model,
    scene: Scene,
    camera: Camera,
    lights: _Lights,
    width: int,
    height: int,
    uv_scale: list[float],
    coords: Optional[npt.NDArray[np.uint16]] = None,
    method: str = "default",
    tile_map: Optional[tuple[npt.NDArray[np.uint32], int, npt.NDArray[np.uint32]]] = None,
    filter: _Filter = None,
) -> _F32: ...
def env_check(rgb: _F32) -> None: ...
def env_sky(sun: list[float], turbidity: float, height: int, ground: float) -> _F32: ...
def env_sample(rgb: _F32, samples: int, seed: int) -> tuple[_F32, _F32]: ...
def env_quadrature(rgb: _F32) -> tuple[_F32, _F32]: ...
def env_sh(rgb: _F32, n: int) -> npt.NDArray[np.float64]: ...
def render_env_sh(
    model: Model,
    uploaded: Optional[GpuModel],
    scene: Scene,
    camera: Camera,
    environment: _F32,
    width: int,
    height: int,
    uv_scale: list[float],
    coords: Optional[npt.NDArray[np.uint16]] = None,
    tile_map: Optional[tuple[npt.NDArray[np.uint32], int, npt.NDArray[np.uint32]]] = None,
    filter: _Filter = None,
) -> tuple[_F32, float, float]: ...
@final
class MipChain:
    @property
    def levels(self) -> int: ...

_Filter = Optional[tuple[str, MipChain]]

def filter_signature(model: Model) -> _F32: ...
def filter_build(
    kind: str,
    dims: tuple[int, int],
    coords: Optional[npt.NDArray[np.uint16]] = None,
    tile_map: Optional[tuple[npt.NDArray[np.uint32], int, npt.NDArray[np.uint32]]] = None,
    signature: Optional[_F32] = None,
) -> tuple[MipChain, npt.NDArray[np.int64], _F32]: ...
def mip_model(model: Model, idx: npt.NDArray[np.int64], weights: _F32) -> Model: ...
def scene_directions(
    scene: Scene,
    camera: Camera,
    lights: _Lights,
    width: int,
    height: int,
    uv_scale: list[float],
    dims: tuple[int, int],
) -> dict[str, npt.NDArray[Any]]: ...

@final
class Analysis:
    @property
    def height(self) -> int: ...
    @property
    def width(self) -> int: ...
    @property
    def levels(self) -> int: ...
    @property
    def textons(self) -> list[int]: ...
    @property
    def dim(self) -> int: ...
    @property
    def m(self) -> int: ...
    @property
    def neighbourhoods(self) -> list[tuple[int, int]]: ...
    def options(self) -> dict[str, int]: ...
    def texton_map(self, level: int) -> npt.NDArray[np.uint16]: ...
    def dots(self, level: int) -> _F64: ...
    def distances(self, level: int) -> _F32: ...
    def similar(self, neighbourhood: int, level: int) -> tuple[npt.NDArray[np.int32], _F32]: ...
    def ensure_neighbourhood(
        self, neighbourhood: int, levels: int, progress: _Progress = None, first: int = 0
    ) -> None: ...
    def kcoherence(
        self,
        height: int,
        width: int,
        k: int,
        neighbourhood: int,
        coarse_neighbourhood: int,
        levels: int,
        toroidal: bool,
        seed: int,
        progress: _Progress = None,
    ) -> npt.NDArray[np.uint16]: ...
    def jump_map(
        self, height: int, width: int, neighbourhood: int, jump: float, seed: int, progress: _Progress = None
    ) -> npt.NDArray[np.uint16]: ...
    def quality(
        self,
        coords: npt.NDArray[np.uint16],
        neighbourhood: int,
        samples: int,
        seed: int,
        window: int = 3,
        scales: int = 3,
        windows: int = 1024,
        progress: _Progress = None,
    ) -> dict[str, Any]: ...
    def arrays(self) -> dict[str, npt.NDArray[Any]]: ...
    @staticmethod
    def from_arrays(arrays: dict[str, npt.NDArray[Any]], options: dict[str, Any]) -> Analysis: ...

def analyse_btf_native(
    data: _F32,
    views: _F64,
    lights: _F64,
    mask: Optional[_Bool] = None,
    textons: int = 1024,
    features: str = "pca",
    dims: int = 48,
    images: int = 150,
    levels: int = 3,
    m: int = 10,
    neighbourhoods: list[int] = ...,
    iterations: int = 20,
    seed: int = 0,
    memory_limit: Optional[int] = None,
    progress: _Progress = None,
) -> Analysis: ...
def analyse_features_native(
    sample: _F32,
    textons: int = 1024,
    levels: int = 3,
    m: int = 10,
    neighbourhoods: list[int] = ...,
    iterations: int = 20,
    seed: int = 0,
    progress: _Progress = None,
) -> Analysis: ...

_U32 = npt.NDArray[np.uint32]

def wang_model_features(model: Model, domain: str) -> tuple[_F32, str]: ...
def wang_synthesize(
    sample: _F32, options_json: str, progress: _Progress = None
) -> tuple[_U32, npt.NDArray[np.uint8], _U32, _U32, _U32, str]: ...
def wang_tiling(
    colors: int, rows: int, cols: int, seed: int, wrap_cols: bool = False, wrap_rows: bool = False,
    allowed: Optional[list[int]] = None,
) -> _U32: ...
def wang_check(colors: int, layout: _U32, wrap_cols: bool = False, wrap_rows: bool = False) -> None: ...
def wang_atlas_positions(colors: int) -> _U32: ...
def wang_seam_errors(
    sample: _F32, output: _U32, tile: int, window: int = 5, windows: int = 600, seed: int = 0
) -> tuple[float, float]: ...
def wang_random_crops(height: int, width: int, tile: int, rows: int, cols: int, seed: int) -> _U32: ...
def texture_names() -> list[str]: ...
def make_texture(
    name: str, height: int, width: int, seed: int, period: tuple[int, int]
) -> npt.NDArray[np.float32]: ...
