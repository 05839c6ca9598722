"""Tileable BTFs: graph-cut Wang BTF tile sets that dress any surface without re-synthesis.

Paper 002 (section 3.2, 4.1, 5.3, Table III). :func:`wang` synthesizes a complete set of
``colors**4`` Wang tiles over any per-texel domain: a fitted model (SH and RGB PTM in their
coefficient domain, every model decoded at probe pairs), a raw :class:`~btfrs.Btf` or a plain
image, in the paper's four steps (corner sampling, edge synthesis, frame construction, interior
synthesis; graph-cut patch filling with Boykov-Kolmogorov max-flow). The set stores the BTFel
table (the referenced texels, once each, as a model of ``1 x N`` texels) plus per-tile index
arrays, arranged canonically in one atlas so any layout of tile ids addresses any material's set.
:meth:`TileSet.tiling` makes a valid stochastic tiling; :func:`btfrs.render` draws it with
``tiles=`` and ``layout=`` on every scene, with every model's shader.

Seam costs are squared feature distances; the feature domain makes them stand for the BTF-space
L2 distance (see ``rust/btfrs-wang/src/features.rs``). The thresholds are relative to the
sample's mean squared distance between random texel pairs (1.0 = a seam between unrelated texels).
"""

from __future__ import annotations

import json
import os
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _native
from ._checks import integer, real
from ._progress import Progress, callback
from .btf import Btf
from .exceptions import ArgumentTypeError, FormatError, InvalidArgumentError
from .models import Model, load_as, register_container, wrap
from .rendering import TileMap

PathLike = Union[str, "os.PathLike[str]"]

#: Probe (view, light) pairs used for a raw Btf's decoded domain (at most this many pairs).
RAW_PROBES = 40


class TileSetReport:
    """Per step: seconds, work, seam costs; and the storage figures of Table III."""

    def __init__(self, data: Dict[str, Any]) -> None:
        self.data = data

    def __getitem__(self, key: str) -> Any:
        return self.data[key]

    @property
    def steps(self) -> List[Dict[str, Any]]:
        steps: List[Dict[str, Any]] = self.data["steps"]
        return steps

    @property
    def seconds(self) -> float:
        """Total synthesis time (seconds)."""
        return float(sum(s["seconds"] for s in self.steps))

    def __repr__(self) -> str:
        return str(self)

    def __str__(self) -> str:
        d = self.data
        lines = [f"Wang tile set: {d['tiles']} tiles of {d['tile']}^2, edge height {d['edge_height']}, "
                 f"{d['colors']} colours per edge direction; domain: {d['domain']}",
                 f"{'step':<20} {'seconds':>8} {'work':>7} {'seam total':>11} {'seam mean':>10} {'seam max':>9}  converged"]
        for s in self.steps:
            mx = "-" if s["seam_max"] is None else f"{s['seam_max']:.4f}"
            lines.append(f"{s['step']:<20} {s['seconds']:8.2f} {s['work']:7d} {s['seam_total']:11.3f} "
                         f"{s['seam_mean']:10.5f} {mx:>9}  {s['converged']}")
        lines.append(f"{'total':<20} {self.seconds:8.2f}")
        lines.append(f"referenced BTFels: {d['btfels']} of {d['sample_texels']} ({100 * d['referenced']:.2f}%); "
                     f"bytes: BTFel table {d['table_bytes']}, atlas indices {d['index_bytes']}, "
                     f"total {d['total_bytes']} ({d['total_bytes'] / 2**20:.2f} MiB)")
        lines.append("seam costs in units of the mean squared distance between random texel pairs "
                     f"({d['pair_scale']:.4g}); matching features keep {100 * d['matching_variance']:.1f}% of the variance")
        return "\n".join(lines)


class TileSet:
    """A complete Wang tile set (see the module docs). Tile ids are canonical:
    ``((north * C + east) * C + south) * C + west``."""

    def __init__(self, *, tile: int, edge_height: int, colors: int, codes: ArrayLike, texels: ArrayLike,
                 btfels: ArrayLike, indices: ArrayLike, atlas: ArrayLike, report: Dict[str, Any],
                 source: Dict[str, Any], model: Optional[Model] = None, table_values: Optional[ArrayLike] = None,
                 origin: Union[None, Model, Btf, ArrayLike] = None) -> None:
        self.tile = int(tile)
        self.edge_height = int(edge_height)
        self.colors = int(colors)
        #: ``[n, 4]`` (north, east, south, west) colours per tile id.
        self.codes = np.asarray(codes, dtype=np.uint8)
        #: ``[n, tile, tile]`` sample texel (row-major index) per tile pixel.
        self.texels = np.asarray(texels, dtype=np.uint32)
        #: ``[N]`` the BTFel table: referenced sample texels, ascending.
        self.btfels = np.asarray(btfels, dtype=np.uint32)
        #: ``[n, tile, tile]`` indices into the BTFel table.
        self.indices = np.asarray(indices, dtype=np.uint32)
        #: ``[C^2 tile, C^2 tile]`` the canonical atlas of BTFel indices.
        self.atlas = np.asarray(atlas, dtype=np.uint32)
        self.report = TileSetReport(report)
        #: What the set was made from: ``{"kind": "model"|"btf"|"image", "model": kind, "dims": [H, W]}``.
        self.source = dict(source)
        #: The BTFel table as a model of ``1 x N`` texels (None for images and raw BTFs).
        self.model = model
        #: For images: ``[N, C]`` values of the BTFel table.
        self.table_values = None if table_values is None else np.asarray(table_values, dtype=np.float32)
        self._origin = origin  # the object synthesized from (not saved)

    @property
    def n_tiles(self) -> int:
        return int(self.codes.shape[0])

    def __repr__(self) -> str:
        return (f"TileSet({self.n_tiles} tiles of {self.tile}^2, {self.colors} colours, "
                f"{len(self.btfels)} BTFels from a {self.source.get('model') or self.source['kind']} "
                f"{self.source['dims'][0]} x {self.source['dims'][1]})")

    # --- tiling -------------------------------------------------------------------------
    def tiling(self, rows: int, cols: int, *, seed: int = 0, wrap: Union[bool, Sequence[bool]] = False,
               tiles: Optional[Sequence[int]] = None) -> NDArray[np.uint32]:
        """A valid stochastic Wang tiling: ``[rows, cols]`` uint32 tile ids, row 0 at the top.

        ``wrap``: True (or ``(columns, rows)``) makes the last column match the first (a
        cylinder's seam) and/or the last row the first. ``tiles``: restrict to these tile ids
        (a request no arrangement satisfies raises :class:`InvalidArgumentError`)."""
        wc, wr = _wrap(wrap)
        allowed = None if tiles is None else [integer("tiles", t, min=0) for t in tiles]
        return _native.wang_tiling(self.colors, integer("rows", rows, min=1), integer("cols", cols, min=1),
                                   integer("seed", seed, min=0), wc, wr, allowed)

    def check(self, layout: ArrayLike, *, wrap: Union[bool, Sequence[bool]] = False) -> None:
        """Raise :class:`InvalidArgumentError` naming the first cell whose edge colours do not match."""
        wc, wr = _wrap(wrap)
        _native.wang_check(self.colors, _layout(layout), wc, wr)

    def atlas_positions(self) -> np.ndarray:
        """``[n, 2]`` (row, column) in tiles of each tile id in :attr:`atlas`."""
        return _native.wang_atlas_positions(self.colors)

    def tile_map(self, model: Union[Model, Btf], layout: ArrayLike) -> TileMap:
        """The :class:`btfrs.rendering.TileMap` that draws ``layout`` with ``model``: the set's own
        BTFel model (:attr:`model`), or the model / Btf it was synthesized from (same size)."""
        lay = _layout(layout)
        if lay.size and int(lay.max()) >= self.n_tiles:
            raise InvalidArgumentError(f"layout: tile {int(lay.max())} does not exist (the set has {self.n_tiles})")
        dims = _dims_of(model)
        n = len(self.btfels)
        if self.model is not None and model is self.model or (dims == (1, n) and _kind_of(model) == self.source.get("model")):
            atlas = self.atlas
        elif dims == tuple(self.source["dims"]):
            atlas = self.btfels[self.atlas]
        else:
            raise InvalidArgumentError(
                f"model: the tile set was synthesized from a {self.source['dims'][0]} x {self.source['dims'][1]} "
                f"sample (its BTFel model is 1 x {n}); got a {dims[0]} x {dims[1]} one")
        pos = self.atlas_positions()[lay]
        return TileMap(np.ascontiguousarray(atlas, dtype=np.uint32), self.tile, np.ascontiguousarray(pos, dtype=np.uint32))

    def layout_texels(self, layout: ArrayLike) -> NDArray[Any]:
        """The sample texels of a layout: ``[rows tile, cols tile]`` row-major sample indices."""
        lay = _layout(layout)
        r, c = lay.shape
        t = self.texels[lay]  # [r, c, w, w]
        return np.ascontiguousarray(t.transpose(0, 2, 1, 3).reshape(r * self.tile, c * self.tile))

    # --- pictures -------------------------------------------------------------------------
    def table_colors(self, view: Sequence[float] = (0.0, 0.0, 1.0), light: Sequence[float] = (0.4, 0.3, 0.866)) -> NDArray[np.float32]:
        """``[N, 3]`` the BTFel table's RGB at one (view, light) pair (images: their values)."""
        if self.table_values is not None:
            v = self.table_values
            return v[:, :3] if v.shape[1] >= 3 else np.repeat(v[:, :1], 3, axis=1)
        if self.model is not None:
            img = self.model._m.evaluate(_unit(view), _unit(light))
            return np.asarray(img, dtype=np.float32).reshape(-1, 3)
        src = self._origin
        if src is None:
            raise InvalidArgumentError("tiles: a set made from a raw Btf keeps no BTFel values once saved; "
                                       "render it with the Btf (btfrs.render(btf, ..., tiles=, layout=))")
        if isinstance(src, Btf):
            vi = int(np.argmax(src.views @ np.asarray(_unit(view))))
            li = int(np.argmax(src.lights @ np.asarray(_unit(light))))
            return np.asarray(src.data[:, :, vi, li, :], dtype=np.float32).reshape(-1, 3)[self.btfels]
        raise InvalidArgumentError("tiles: no BTFel values to show")

    def image(self, layout: Optional[ArrayLike] = None, *, view: Sequence[float] = (0.0, 0.0, 1.0),
              light: Sequence[float] = (0.4, 0.3, 0.866)) -> NDArray[np.float32]:
        """RGB image ``[H, W, 3]`` of a layout (default: the atlas) at one (view, light) pair."""
        colors = self.table_colors(view, light)
        if layout is None:
            atlas_image: NDArray[np.float32] = colors[self.atlas]
            return atlas_image
        lay = _layout(layout)
        r, c = lay.shape
        t = self.indices[lay].transpose(0, 2, 1, 3).reshape(r * self.tile, c * self.tile)
        layout_image: NDArray[np.float32] = colors[t]
        return layout_image

    def picture(self, *, view: Sequence[float] = (0.0, 0.0, 1.0), light: Sequence[float] = (0.4, 0.3, 0.866),
                gap: int = 6) -> NDArray[np.float32]:
        """The tiles in their atlas arrangement, apart, each edge marked with its colour (a bar
        outside the tile), as an RGB image in [0, 1] (exposure normalised)."""
        img = self.image(view=view, light=light)
        img = img / max(float(np.percentile(img, 99.5)), 1e-6)
        a = self.colors * self.colors
        w, g = self.tile, gap
        side = a * (w + 2 * g)
        out = np.full((side, side, 3), 0.12, dtype=np.float32)
        palette = np.array([[0.9, 0.15, 0.1], [0.1, 0.75, 0.2], [0.15, 0.35, 0.95], [0.95, 0.8, 0.1],
                            [0.8, 0.2, 0.9], [0.1, 0.85, 0.85], [1.0, 0.55, 0.1], [0.6, 0.6, 0.6]], dtype=np.float32)
        hpal, vpal = palette[: self.colors], palette[::-1][: self.colors]
        pos = self.atlas_positions()
        for tid in range(self.n_tiles):
            r, c = pos[tid]
            y0, x0 = r * (w + 2 * g) + g, c * (w + 2 * g) + g
            out[y0:y0 + w, x0:x0 + w] = np.clip(img[r * w:(r + 1) * w, c * w:(c + 1) * w], 0, 1)
            n_, e_, s_, w_ = self.codes[tid]
            b = max(g - 2, 1)
            out[y0 - b:y0, x0:x0 + w] = hpal[n_]
            out[y0 + w:y0 + w + b, x0:x0 + w] = hpal[s_]
            out[y0:y0 + w, x0 - b:x0] = vpal[w_]
            out[y0:y0 + w, x0 + w:x0 + w + b] = vpal[e_]
        return out

    # --- seams ------------------------------------------------------------------------------
    def seam_errors(self, layout: ArrayLike, *, window: int = 5, windows: int = 600, seed: int = 0) -> Dict[str, float]:
        """Neighbourhood error of a tiled layout across tile edges and inside tiles (windows
        against their best match in the sample, relative units), beside plain tiling of random
        crops of the sample on the same grid."""
        feats = self._features()
        lay = _layout(layout)
        out = self.layout_texels(lay)
        edge, inner = _native.wang_seam_errors(feats, out, self.tile, window, windows, seed)
        h, w = self.source["dims"]
        crops = _native.wang_random_crops(h, w, self.tile, lay.shape[0], lay.shape[1], seed)
        cedge, cinner = _native.wang_seam_errors(feats, crops, self.tile, window, windows, seed)
        return {"edge": edge, "interior": inner, "crops_edge": cedge, "crops_interior": cinner}

    def _features(self) -> NDArray[np.float32]:
        if self._origin is None:
            raise InvalidArgumentError("tiles: seam errors need the sample the set was synthesized from "
                                       "(a loaded set does not keep it)")
        return _features_of(self._origin, self.source.get("domain_arg", "auto"))[0]

    # --- files ------------------------------------------------------------------------------
    def save(self, path: PathLike) -> None:
        """Write the set to one ``.btfrs`` container (atomically); :func:`btfrs.load` reads it."""
        meta = {"tile": self.tile, "edge_height": self.edge_height, "colors": self.colors,
                "report": self.report.data, "source": self.source}
        # The container stores signed 32-bit integers; texel ids are far below 2^31.
        def i32(a: NDArray[Any]) -> NDArray[np.int32]:
            return np.ascontiguousarray(a, dtype=np.int32)

        arrays: List[Tuple[str, NDArray[Any]]] = [("codes", self.codes), ("texels", i32(self.texels)), ("btfels", i32(self.btfels)),
                  ("indices", i32(self.indices)), ("atlas", i32(self.atlas))]
        if self.model is not None:
            meta["model_kind"] = self.model.kind
            arrays += [(f"model.{k}", v) for k, v in self.model._m.arrays().items()]
        if self.table_values is not None:
            arrays.append(("table_values", self.table_values))
        _native.save_container(os.fspath(path), "tiles", json.dumps(meta), arrays)

    @classmethod
    def load(cls, path: PathLike) -> "TileSet":
        """Read a set written by :meth:`save`."""
        tile_set: TileSet = load_as(path, cls)
        return tile_set

    @classmethod
    def _from_container(cls, path: PathLike, meta: Dict[str, Any], arrays: Dict[str, NDArray[Any]]) -> "TileSet":
        try:
            model = None
            if "model_kind" in meta:
                ma = {k[len("model."):]: v for k, v in arrays.items() if k.startswith("model.")}
                model = wrap(_native.Model.from_arrays(meta["model_kind"], ma))
            ts = cls(tile=meta["tile"], edge_height=meta["edge_height"], colors=meta["colors"],
                     codes=arrays["codes"], texels=arrays["texels"], btfels=arrays["btfels"],
                     indices=arrays["indices"], atlas=arrays["atlas"], report=meta["report"],
                     source=meta["source"], model=model, table_values=arrays.get("table_values"))
        except KeyError as e:
            raise FormatError(f"{os.fspath(path)}: tile set without {e}") from None
        n = ts.colors ** 4
        w = ts.tile
        a = ts.colors ** 2 * w
        if ts.codes.shape != (n, 4) or ts.texels.shape != (n, w, w) or ts.indices.shape != (n, w, w) \
                or ts.atlas.shape != (a, a):
            raise FormatError(f"{os.fspath(path)}: tile set arrays do not match {n} tiles of {w}^2")
        if len(ts.btfels) == 0 or int(ts.indices.max()) >= len(ts.btfels) or int(ts.atlas.max()) >= len(ts.btfels):
            raise FormatError(f"{os.fspath(path)}: tile indices point outside the BTFel table")
        if not np.array_equal(ts.btfels[ts.indices], ts.texels):
            raise FormatError(f"{os.fspath(path)}: the per-tile indices do not reproduce the tiles' texels")
        return ts


def wang(source: Union[Model, Btf, ArrayLike], *, tile: int = 64, edge_height: int = 16, colors: int = 2, seed: int = 0,
         domain: str = "auto", progress: Progress = True, **options: Any) -> TileSet:
    """Synthesize a complete Wang tile set (``colors**4`` tiles) over ``source``: a fitted
    :class:`~btfrs.Model`, a :class:`~btfrs.Btf` or an image ``[H, W, C]`` (float or uint8).

    ``domain`` (models): ``"auto"`` (coefficients for SH and RGB PTM, decoded otherwise),
    ``"coefficients"`` or ``"decoded"``. Further options: ``patch`` (fill patch side; 0 = auto
    ``min(5 h / 2, 5 tile / 8)``), ``candidates`` (offsets matched per patch, 1024), ``best_of`` (3),
    ``pixel_threshold`` (0.3) and ``total_threshold`` (0.02) in units of the sample's mean squared
    distance between random texel pairs, ``refine`` (refinement patches per fill, 24),
    ``corner_candidates`` (48), ``matching_dims`` (8)."""
    tile = integer("tile", tile, min=4)
    edge_height = integer("edge_height", edge_height, min=2)
    colors = integer("colors", colors, min=2, max=8)
    seed = integer("seed", seed, min=0)
    for k in ("pixel_threshold", "total_threshold"):
        if k in options:
            options[k] = real(k, options[k], min=0.0)
    feats, dom, kind = _features_of(source, domain)
    h, w = feats.shape[:2]
    opts = {"tile": tile, "edge_height": edge_height, "colors": colors, "seed": seed, **options}
    texels, codes, btfels, indices, atlas, rep = _native.wang_synthesize(
        feats, opts, callback(progress, "wang tiles"))
    report = json.loads(rep)
    model = None
    table_values = None
    src = {"kind": kind, "dims": [int(h), int(w)], "domain": dom, "domain_arg": domain}
    if isinstance(source, Model):  # kind "model"
        src["model"] = source.kind
        model = wrap(source._m.select_texels(btfels.tolist()))
        table_bytes = int(model.nbytes)
    elif isinstance(source, Btf):  # kind "btf"
        table_bytes = int(len(btfels) * source.data.shape[2] * source.data.shape[3] * 3 * 4)
    else:  # kind "image"
        table_values = feats.reshape(h * w, -1)[btfels]
        table_bytes = int(table_values.shape[0] * table_values.shape[1])  # 8-bit per channel
    index_bytes = int(atlas.size * 4)
    report.update({"tiles": int(codes.shape[0]), "tile": tile, "edge_height": edge_height, "colors": colors,
                   "domain": dom, "btfels": int(len(btfels)), "sample_texels": int(h * w),
                   "referenced": float(len(btfels) / (h * w)), "table_bytes": table_bytes,
                   "index_bytes": index_bytes, "total_bytes": table_bytes + index_bytes})
    return TileSet(tile=tile, edge_height=edge_height, colors=colors, codes=codes, texels=texels, btfels=btfels,
                   indices=indices, atlas=atlas, report=report, source=src, model=model,
                   table_values=table_values, origin=source)


def _features_of(source: Union[None, Model, Btf, ArrayLike], domain: str) -> Tuple[NDArray[np.float32], str, str]:
    """Features ``[H, W, D]`` float32, the domain's name, and the source kind."""
    if isinstance(source, Model):
        f, name = _native.wang_model_features(source._m, domain)
        return f, name, "model"
    if isinstance(source, Btf):
        nv, nl = source.data.shape[2], source.data.shape[3]
        pairs = [(v, l) for v in range(nv) for l in range(nl)]
        step = max(1, len(pairs) // RAW_PROBES)
        pick = pairs[::step][:RAW_PROBES]
        f = np.stack([source.data[:, :, v, l, :] for v, l in pick], axis=2).reshape(
            source.data.shape[0], source.data.shape[1], -1)
        f = np.ascontiguousarray(f / np.sqrt(len(pick)), dtype=np.float32)
        return f, f"raw BTF at {len(pick)} measured pairs", "btf"
    if isinstance(source, np.ndarray) or hasattr(source, "__array__"):
        a = np.asarray(source)
        if a.ndim == 2:
            a = a[:, :, None]
        if a.ndim != 3:
            raise InvalidArgumentError(f"source: expected an image [H, W, C], got shape {a.shape}")
        if a.dtype == np.uint8:
            a = a.astype(np.float32) / 255.0
        elif not np.issubdtype(a.dtype, np.floating):
            raise ArgumentTypeError(f"source: expected a float or uint8 image, got dtype {a.dtype}")
        return np.ascontiguousarray(a, dtype=np.float32), "rgb", "image"
    raise ArgumentTypeError(f"source: expected a btfrs Model, a Btf or an image array, got {type(source).__name__}")


def _wrap(wrap: Union[bool, Sequence[bool]]) -> Tuple[bool, bool]:
    if isinstance(wrap, (bool, np.bool_)):
        return bool(wrap), bool(wrap)
    try:
        wc, wr = wrap
    except (TypeError, ValueError):
        raise ArgumentTypeError(f"wrap: expected a bool or (columns, rows), got {wrap!r}") from None
    return bool(wc), bool(wr)


def _layout(layout: ArrayLike) -> NDArray[np.uint32]:
    a = np.asarray(layout)
    if a.ndim != 2 or a.size == 0:
        raise InvalidArgumentError(f"layout: expected a non-empty [rows, cols] array of tile ids, got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.integer):
        raise ArgumentTypeError(f"layout: expected integer tile ids, got dtype {a.dtype}")
    if a.min() < 0:
        raise InvalidArgumentError(f"layout: tile ids must be >= 0, got {int(a.min())}")
    return np.ascontiguousarray(a, dtype=np.uint32)


def _dims_of(model: Union[Model, Btf]) -> Tuple[int, ...]:
    if isinstance(model, Btf):
        return tuple(model.data.shape[:2])
    return (int(model.height), int(model.width))


def _kind_of(model: object) -> Optional[str]:
    kind: Optional[str] = getattr(model, "kind", None)
    return kind


def _unit(v: ArrayLike) -> List[float]:
    a = np.asarray(v, dtype=np.float64)
    return [float(x) for x in a / np.linalg.norm(a)]


register_container("tiles", TileSet._from_container)
