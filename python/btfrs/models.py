"""Fitted reflectance models and what they share.

Every model has the same contract (:class:`Model`, the Python face of the Rust ``Model``
trait): ``evaluate(view, light)`` gives an ``[H, W, 3]`` image at any directions, ``error(btf)``
compares against the present pairs of a sample (use the test half of :meth:`btfrs.Btf.split` for
the held-out figure, the train half for reconstruction), ``nbytes`` is the storage as stored for
rendering, ``arrays``/``from_arrays`` and ``save``/``load`` round-trip. The list of models comes
from the Rust registry (:func:`model_kinds`).
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from typing import Any, Callable, Dict, Iterator, List, Optional, Tuple, Type, TypeVar, Union, cast

import numpy as np
from numpy.typing import ArrayLike, NDArray

from . import _native
from .btf import Btf, read_container
from ._checks import boolean, choice, index, instance, integer
from ._progress import callback
from .exceptions import ArgumentTypeError, FormatError, InternalError, InvalidArgumentError

__all__ = ["ErrorReport", "Model", "Ptm", "Hsh", "Lafortune", "LafortuneView", "Srf", "Sh", "Lpca", "Rbf", "Bilinear", "Neural", "Svbrdf", "load",
           "model_kinds", "class_of", "wrap"]

PathLike = Union[str, "os.PathLike[str]"]

_T = TypeVar("_T")


@dataclass(frozen=True)
class ErrorReport:
    """Accuracy of a model against a BTF (f64 accumulation over every present value).

    ``relative`` is ``||pred - gt|| / ||gt||``; ``psnr`` is in dB against the largest
    ground-truth value (``-inf`` when no ground-truth value is positive); ``samples`` counts
    compared values (texels x pairs x 3).
    """

    rmse: float
    relative: float
    psnr: float
    samples: int

    def __str__(self) -> str:
        return f"rmse {self.rmse:.5f}, relative {100 * self.relative:.2f}%, psnr {self.psnr:.1f} dB"


def _as_dir(name: str, d: ArrayLike) -> List[float]:
    """A query direction as a unit 3-vector: any non-zero vector with z >= 0 is normalised."""
    a = np.asarray(d, dtype=np.float64).reshape(-1)
    if a.shape != (3,):
        raise InvalidArgumentError(f"{name}: expected a direction of three numbers, got shape {np.shape(d)}")
    n = float(np.linalg.norm(a))
    if not np.isfinite(n) or n == 0.0:
        raise InvalidArgumentError(f"{name}: expected a finite, non-zero direction, got {a.tolist()}")
    return [float(x) for x in a / n]


class Model:
    """A fitted model: what every model class shares (the Rust contract, seen from Python).

    ``evaluate(view, light)`` gives an ``[H, W, 3]`` image at any directions, ``error(btf)``
    compares against the present pairs of a sample, ``nbytes`` is the storage as stored for
    rendering (exactly what the default renderer uploads), ``arrays`` / ``from_arrays`` give and
    take the named arrays a file stores, ``save`` / :func:`load` round-trip through one file,
    ``report`` holds the fit's own statistics (empty for a model built from arrays) and
    ``fit_seconds`` the wall time of the fit. Subclasses only document a model and add its own
    accessors; a model registered in Rust without a class here gets this one.
    """

    _kind = ""

    def __init__(self, native: "_native.Model", fit_seconds: Optional[float] = None,
                 report: Optional[Dict[str, Any]] = None) -> None:
        if self._kind and native.kind != self._kind:
            raise ArgumentTypeError(f"native: expected a {self._kind} model, got {native.kind}")
        self._m = native
        self.fit_seconds = fit_seconds
        self.report = dict(native.report() if report is None else report)

    @property
    def kind(self) -> str:
        """The model's registered name (``"ptm"``, ``"lpca"``, ...)."""
        return self._m.kind

    @property
    def height(self) -> int:
        return self._m.dims[0]

    @property
    def width(self) -> int:
        return self._m.dims[1]

    @property
    def nbytes(self) -> int:
        """Bytes as stored for rendering: what the default renderer uploads (quantized where the
        model quantizes, with the GPU's padding and packing)."""
        return self._m.nbytes

    @property
    def renderers(self) -> List[str]:
        """The renderer names (``renderer=`` of :func:`btfrs.render`), the default first."""
        return list(self._m.renderers)

    @property
    def mip(self) -> str:
        """How the coarse levels of its mip pyramid are made (``filter="trilinear"``):
        ``"average"`` (its parameters averaged: exact, the model being linear in them),
        ``"projected"`` (the mean appearance projected on the model) or ``"medoid"``."""
        return self._m.mip

    @property
    def sh_lighting(self) -> bool:
        """Whether it renders under an environment by the SH method
        (``btfrs.render(..., environment=env, lighting="sh")``): a double-SH expansion."""
        return self._m.sh_lighting

    @property
    def exports(self) -> List[str]:
        """The other tools' file formats it can be written as (:meth:`export`)."""
        return list(model_kinds()[self.kind]["exports"])

    def export(self, path: PathLike, *, format: Optional[str] = None, view: ArrayLike = 0,
               force: bool = False, tiled: bool = False, tile_format: str = "jpg", tile_size: int = 256,
               overlap: int = 0, quality: int = 95, progress: Any = None) -> Dict[str, Any]:
        """Write view slot ``view`` (an index or a direction) as another tool's file format
        (:attr:`exports`; by default chosen by the extension of ``path``: ``.ptm``, ``.rti``,
        ``.gltf``, ``.xml`` for Mitsuba). A format written as a folder (relight's, NeuralRTI's,
        glTF's, Mitsuba's) refuses a folder that exists and holds files unless ``force``.
        Returns what the writer chose, e.g. the quantization's ``scale`` and ``bias``, or the
        files written.

        ``tiled=True`` writes relight's or NeuralRTI's folder in its tiled, multi-resolution
        layout, as relight-cli's deepzoom output and OpenLIME's ``deepzoom`` layout have it:
        each plane image a Deep Zoom pyramid (``plane_0.dzi`` + ``plane_0_files/{level}/
        {col}_{row}.{tile_format}``, ``tile_size`` tiles sharing ``overlap`` pixels, level 0 one
        tile), written into a temporary folder that is renamed (``force`` replaces an existing
        folder whole); ``progress(done, total)`` counts the tiles. :func:`btfrs.load` reads it
        back."""
        p = os.fspath(path)
        if format is None and tiled is True:
            # The formats with a tiled layout: relight's, else NeuralRTI's.
            format = next((f for f in ("relight", "neuralrti") if f in self.exports), None)
        if format is None:
            ext = os.path.splitext(p)[1].lstrip(".").lower()
            named = [f.name for f in _native.model_formats() if f.extension == ext and f.name in self.exports]
            format = named[0] if named else ext
        if format not in self.exports:
            can = ", ".join(repr(e) for e in self.exports) or "none"
            raise InvalidArgumentError(f"format: the {self.kind} model cannot be written as {format!r} (its formats: {can})")
        if boolean("tiled", tiled):
            return cast(Dict[str, Any], json.loads(_native.export_tiled(
                p, self._m, format, _slot_index(self, view), boolean("force", force),
                integer("tile_size", tile_size, min=16, max=8192), integer("overlap", overlap, min=0, max=4096),
                choice("tile_format", tile_format, ("jpg", "png")), integer("quality", quality, min=1, max=100),
                callback(progress, "tiles"))))
        return cast(Dict[str, Any], json.loads(_native.export_model(p, self._m, format, _slot_index(self, view),
                                                                    force=boolean("force", force))))

    def evaluate(self, view: ArrayLike, light: ArrayLike) -> NDArray[np.float32]:
        """The ``[H, W, 3]`` float32 image for one view and one light direction (any non-zero
        vectors with z >= 0; they are normalised)."""
        return self._m.evaluate(_as_dir("view", view), _as_dir("light", light))

    def error(self, btf: Btf) -> ErrorReport:
        """RMSE, relative error and PSNR against every present pair of ``btf``."""
        instance("btf", btf, Btf, "a btfrs.Btf")
        d = self._m.error(btf.data, btf.views, btf.lights, btf.mask)
        return ErrorReport(d["rmse"], d["relative"], d["psnr"], int(d["samples"]))

    @property
    def arrays(self) -> Dict[str, NDArray[Any]]:
        """Copies of the model's arrays, by name (what :meth:`save` writes)."""
        return self._m.arrays()

    @classmethod
    def from_arrays(cls, arrays: Dict[str, NDArray[Any]], *, kind: Optional[str] = None) -> "Model":
        """Rebuild a model from :attr:`arrays` (validated: shapes, ranges, finite values).
        ``kind`` is needed only on the base class (``Model.from_arrays(a, kind="lpca")``)."""
        k = kind or cls._kind
        if not k:
            raise InvalidArgumentError("kind: expected the model's name, e.g. kind=\"lpca\"")
        if cls._kind and kind and kind != cls._kind:
            raise InvalidArgumentError(f"kind: {cls.__name__} holds {cls._kind!r} models, got {kind!r}")
        instance("arrays", arrays, dict, "a dict of numpy arrays")
        return wrap(_native.Model.from_arrays(choice("kind", k, tuple(model_kinds())), dict(arrays)))

    def save(self, path: PathLike) -> None:
        """Write the model to one ``.btfrs`` file (atomically)."""
        self._m.save(os.fspath(path), json.dumps({"fit_seconds": self.fit_seconds, "report": _jsonable(self.report)}))

    @classmethod
    def load(cls, path: PathLike) -> "Model":
        """Read a model written by :meth:`save`."""
        return load_as(path, cls)

    def save_web(self, folder: PathLike, **options: Any) -> str:
        """Write the browser viewer with this model to ``folder``: :func:`btfrs.web.save_web`
        (``single_file=True`` for one HTML file, ``force``, ``coords``, ``tiles`` and ``layout``,
        ``uv_scale``). Returns the page's path."""
        if _WEB_WRITER is None:
            raise InternalError("the browser viewer's writer is not registered (import btfrs.web)")
        page: str = _WEB_WRITER(self, folder, **options)
        return page

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.height} x {self.width} texels, {self.nbytes / 2**20:.2f} MiB)"


def _slot_index(model: "Model", view: ArrayLike) -> int:
    if isinstance(view, bool):
        raise ArgumentTypeError("view: expected a slot index or a direction, got a bool")
    arrays = model.arrays
    if "views" not in arrays:
        # A model without view slots (one decoder for every view): slot 0, or any direction.
        return index("view", view, 1) if isinstance(view, (int, np.integer)) else 0
    views = arrays["views"]
    n = len(views)
    if isinstance(view, (int, np.integer)):
        return index("view", view, n)
    d = np.asarray(_as_dir("view", view))
    ang = np.degrees(np.arccos(np.clip(views @ d / np.linalg.norm(d), -1, 1)))
    i = int(np.argmin(ang))
    if ang[i] > 0.5:
        raise InvalidArgumentError(f"view: {list(d)} is {ang[i]:.1f} degrees from the nearest view slot; pass a slot index")
    return i


def _decoded(arrays: Dict[str, NDArray[Any]], name: str) -> Optional[NDArray[Any]]:
    """Array ``name``: the floats, or the decoded 8-bit planes ``{name}_q`` with their per-plane
    ``{name}_scale`` and ``{name}_bias`` (``bias + scale * q``, float32 as the model computes)."""
    if name in arrays:
        return arrays[name]
    q = arrays.get(f"{name}_q")
    if q is None:
        return None
    tail = q.shape[2:]
    scale = arrays[f"{name}_scale"].reshape(tail)
    bias = arrays[f"{name}_bias"].reshape(tail)
    return cast(NDArray[Any], bias + scale * q.astype(np.float32))


class Ptm(Model):
    """A Polynomial Texture Map per view slot (paper 000, section 3.1).

    ``kind="rgb"``: ``coeffs[H, W, V, 3, 6]``, one biquadratic in the light's (x, y) per channel.
    ``kind="lrgb"``: ``coeffs[H, W, V, 6]`` luminance polynomial times ``rgb[H, W, V, 3]``.
    Between view slots, :meth:`evaluate` blends the three nearest slots (inverse angular
    distance); at a slot's own direction it is exactly that slot's fit.

    Fitted with ``bits=8`` (the default) the coefficients are stored as 8-bit planes as a ``.ptm``
    file stores them (per slot and coefficient index one scale and one integer bias shared by the
    channels, colours ``c / 255``): :attr:`nbytes` is what a viewer holds, :meth:`save_ptm`
    writes the model's own bytes, and :attr:`coeffs` / :attr:`rgb` are the decoded values.
    """

    _kind = "ptm"

    @property
    def variant(self) -> str:
        """``"rgb"`` or ``"lrgb"`` (from the shape of the coefficients)."""
        return "rgb" if self.coeffs.ndim == 5 else "lrgb"

    @property
    def coeffs(self) -> np.ndarray:
        """A copy of the coefficients (decoded when 8-bit)."""
        c = _decoded(self.arrays, "coeffs")
        assert c is not None
        return c

    @property
    def rgb(self) -> Optional[np.ndarray]:
        """A copy of the LRGB base colours (largest channel 1; decoded when 8-bit), or None for RGB."""
        return _decoded(self.arrays, "rgb")

    @property
    def bits(self) -> int:
        """8 (8-bit planes) or 32 (floats)."""
        return 8 if "coeffs_q" in self.arrays else 32

    @property
    def views(self) -> np.ndarray:
        """``[V, 3]`` directions of the view slots."""
        return self.arrays["views"]

    def slot(self, view: ArrayLike) -> int:
        """The index of the view slot for ``view``: an int index, or a direction within 0.5
        degrees of a slot's."""
        return _slot_index(self, view)

    def save_ptm(self, path: PathLike, *, view: ArrayLike = 0) -> Tuple[List[float], List[float]]:
        """Write one view slot as an uncompressed ``PTM_1.2`` file (``PTM_FORMAT_RGB`` or
        ``PTM_FORMAT_LRGB``) that RTIViewer and relight open; returns the per-coefficient
        ``(scale, bias)`` of the 8-bit quantisation. Our value 1.0 is the viewer's white (255);
        multiply the data beforehand to choose another exposure. An 8-bit model (``bits=8``, the
        default of :func:`btfrs.fit.ptm`) is written byte for byte from its planes; a float model
        is quantized for the file."""
        r = self.export(path, format="ptm", view=view)
        return r["scale"], r["bias"]

    def __repr__(self) -> str:
        return (f"Ptm({self.variant}, {self.height} x {self.width} texels, {len(self.views)} view slots, "
                f"{self.nbytes / 2**20:.2f} MiB)")


class Hsh(Model):
    """Hemispherical harmonics per view slot (Gautron et al. 2004): the light basis of ``.rti``
    HSH files (RTIViewer, relight), of order 1 to 4 (``order**2`` coefficients per channel).

    ``coeffs[H, W, V, 3, order**2]`` (decoded when 8-bit); the basis, with the viewers' signs and
    ``phi = atan2(l_y, l_x)``, is written out in ``rust/btfrs-fit/src/hsh.rs`` and
    :func:`btfrs.fit.hsh`. Between view slots, :meth:`evaluate` blends the three nearest slots.
    With ``bits=8`` (the default) the coefficients are 8-bit planes whose three channels share
    one scale and bias per slot and term, as a ``.rti`` file stores them; :meth:`save_rti`
    writes one slot byte for byte.
    """

    _kind = "hsh"

    @property
    def order(self) -> int:
        """The order n (``n**2`` terms per channel)."""
        return int(round(np.sqrt(self.coeffs.shape[-1])))

    @property
    def coeffs(self) -> np.ndarray:
        """A copy of the coefficients ``[H, W, V, 3, order**2]`` (decoded when 8-bit)."""
        c = _decoded(self.arrays, "coeffs")
        assert c is not None
        return c

    @property
    def bits(self) -> int:
        """8 (8-bit planes) or 32 (floats)."""
        return 8 if "coeffs_q" in self.arrays else 32

    @property
    def views(self) -> np.ndarray:
        """``[V, 3]`` directions of the view slots."""
        return self.arrays["views"]

    def slot(self, view: ArrayLike) -> int:
        """The index of the view slot for ``view``: an int index, or a direction within 0.5
        degrees of a slot's."""
        return _slot_index(self, view)

    def save_rti(self, path: PathLike, *, view: ArrayLike = 0) -> Tuple[List[float], List[float]]:
        """Write one view slot as a ``.rti`` HSH file (``#HSH1.2``, type 3) and return the file's
        two float arrays ``(scale, bias)``: byte ``c`` of term ``j`` decodes to
        ``bias[j] + scale[j] * c / 255`` (relight's reading; RTIViewer's ``.rti`` loader reads the
        two arrays as a minimum and a maximum instead). Our value 1.0 is the viewer's white."""
        r = self.export(path, format="rti", view=view)
        return r["scale"], r["bias"]

    def __repr__(self) -> str:
        return (f"Hsh(order {self.order}, {self.height} x {self.width} texels, {len(self.views)} view slots, "
                f"{self.nbytes / 2**20:.2f} MiB)")


def _jsonable(d: Dict[str, Any]) -> Dict[str, Any]:
    out: Dict[str, Any] = {}
    for k, v in d.items():
        if isinstance(v, (np.integer,)):
            v = int(v)
        elif isinstance(v, (np.floating,)):
            v = float(v)
        elif isinstance(v, dict):
            v = _jsonable(v)
        out[k] = v
    return out


class Srf(Model):
    """Phong + spatially-varying residual function (paper 003, sections 4 and 5).

    ``value = kd * l_z + ks * max(h_z, 0)^n + s(P) . h`` per colour channel, with one Blinn-Phong
    (``phong`` = kd rgb, ks rgb, n) for the material and ``s[H, W, 3, 3]`` per texel.
    ``report`` has ``phong_relative`` and ``srf_relative``: the relative error of Phong alone
    and of Phong + SRF over the fitted pairs.
    """

    _kind = "srf"

    @property
    def phong(self) -> np.ndarray:
        """``[kd_r, kd_g, kd_b, ks_r, ks_g, ks_b, n]``."""
        return self.arrays["phong"]

    @property
    def s(self) -> np.ndarray:
        """``[H, W, 3, 3]``: s(P) per texel and channel."""
        return self.arrays["s"]


class Lafortune(Model):
    """Per-texel Lafortune lobes (paper 000, section 3.2), fitted over all views at once.

    ``value = l_z * (kd + sum_i max(Cx lx vx + Cy ly vy + Cz lz vz, 0)^n_i)``; ``kind="lum"``
    fits the luminance and multiplies by a per-texel base colour, ``kind="rgb"`` fits each
    channel. ``params`` is ``[H, W, P]`` (lum) or ``[H, W, 3, P]`` (rgb) with
    ``P = 1 + 4 * lobes`` ordered ``kd, (Cx, Cy, Cz, n) per lobe``; ``status`` is 0 (converged),
    1 (fell back: damped restart or fewer lobes) or 2 (failed: diffuse only) per fit;
    ``report`` counts them.
    """

    _kind = "lafortune"


class LafortuneView(Model):
    """Per-view Lafortune lobes (paper 000, section 3.2, fitted "like the PTM"): one lobe set
    per texel and measured view slot, a function of the light, blended between the three
    nearest view slots at render time as the PTM is.

    Within slot ``v``: ``value = l_z * (kd + sum_i max(D_i . l, 0)^n_i)`` with
    ``D = (Cx vx, Cy vy, Cz vz)``, the Lafortune lobe at the slot's view ``v`` written as an axis
    in light space (at a fixed view only these products are determined). ``params`` is
    ``[H, W, V, P]`` (lum, with ``rgb`` ``[H, W, V, 3]`` base colours) or ``[H, W, V, 3, P]``
    (rgb), ``P = 1 + 4 * lobes`` ordered ``kd, (Dx, Dy, Dz, n) per lobe``; ``views`` are the
    slots' directions; ``status`` is 0/1/2 per fit as for :class:`Lafortune`; ``source[v]`` is
    the slot whose lobes slot ``v`` uses: itself, or for a slot with too few present lights the
    nearest fitted one (``report["borrowed_slots"]`` lists those).
    """

    _kind = "lafortune_view"

    @property
    def views(self) -> np.ndarray:
        """``[V, 3]`` float64: the view direction of each slot."""
        return self.arrays["views"]


class Sh(Model):
    """Double spherical harmonics with constrained least squares (paper 002, section 3.1 and
    appendix), 8-bit quantized with a scale and bias per colour channel.

    ``f_c(v, l) = sum_ij C[c, i, j] y_i(v) y_j(l)`` with real orthonormal SH; ``q`` is
    ``[H, W, 3, view_coeffs, light_coeffs]`` uint8 and ``C = bias[c] + scale[c] * q``.
    """

    _kind = "sh"


class Lpca(Model):
    """Local PCA: clustered Eigen-BRDFs (paper 004, section 3), 8-bit quantized per
    Eigen-BRDF with the scales folded into the per-texel weights (section 6.3).

    Rendered by the original 9-tap interpolation (section 5, ``renderer="9tap"``) or by the
    Eigen-BRDFs resampled on the elevated concentric map and stored in one 3D texture
    (section 6, ``renderer="3d"``).
    """

    _kind = "lpca"

    @property
    def compression(self) -> float:
        """Raw size at one byte per value (as the measured data is stored) over :attr:`nbytes`."""
        a = self.arrays
        k, c1, v, l, _ = a["basis"].shape
        return cast(float, self.height * self.width * v * l * 3 / self.nbytes)


class _LightPca(Model):
    """What the RBF and bilinear light bases share (rust/btfrs-fit/src/light_pca.rs): per view
    slot a float32 ``table`` ``[V, n, n, R]`` of principal light functions on an ``n x n`` grid
    of the concentric square (row: 3 mean values, then each component's values), and per texel
    8-bit coefficients ``coeffs_q`` ``[H, W, V, K]`` decoded as ``coeffs_bias + coeffs_scale * q``
    (one scale and bias per slot and plane)."""

    _kind = ""

    @property
    def views(self) -> np.ndarray:
        """``[V, 3]`` float64: the view direction of each slot."""
        return self.arrays["views"]

    @property
    def planes(self) -> int:
        """Coefficient planes per view slot (luminance and chroma together for ``"ycc"``)."""
        return int(self.arrays["coeffs_q"].shape[3])

    @property
    def resolution(self) -> int:
        """Light grid nodes per side."""
        return int(self.arrays["table"].shape[1])

    @property
    def colour(self) -> str:
        """``"rgb"`` or ``"ycc"``."""
        return "rgb" if int(self.arrays["layout"][0]) == 0 else "ycc"

    @property
    def coeffs(self) -> NDArray[np.float32]:
        """``[H, W, V, K]`` float32: the decoded coefficients."""
        a = self.arrays
        v, k = a["coeffs_q"].shape[2:]
        return cast(NDArray[np.float32],
                    (a["coeffs_bias"].reshape(v, k) + a["coeffs_scale"].reshape(v, k) * a["coeffs_q"]).astype(np.float32))


class Rbf(_LightPca):
    """relight's RBF light basis per view slot: Gaussian RBF interpolation of each texel's light
    samples, resampled on a light grid and compressed by PCA into 8-bit planes (see
    :func:`btfrs.fit.rbf`)."""

    _kind = "rbf"


class Bilinear(_LightPca):
    """relight's bilinear light basis per view slot: a light grid fitted by regularised least
    squares with bilinear weights, compressed by PCA into 8-bit planes (see
    :func:`btfrs.fit.bilinear`)."""

    _kind = "bilinear"


class Neural(Model):
    """A neural BTF (see :func:`btfrs.fit.neural`): per texel a code of ``latents`` values
    stored as 8-bit planes, and one decoder MLP, ``(code, direction encoding) -> hidden ->
    hidden -> RGB``.

    ``latents`` is the decoded ``[H, W, latents]`` codes; ``layers`` the decoder's
    ``(weight [out, in], bias [out])`` pairs, the inputs ordered as the codes then the
    encoding (``directions``: ``"light"`` = the light's x, y; ``"xy"`` = view x, y, light x, y;
    ``"half"`` = those and the half vector's x, y); ``activation`` is ``"elu"`` or ``"relu"``.
    A single-view model (``directions == "light"``) with at most 9 latents is written in
    NeuralRTI's web format by ``model.export(folder, format="neuralrti")``.
    """

    _kind = "neural"
    _DIRECTIONS = ("light", "xy", "half")
    _ACTIVATIONS = ("elu", "relu")

    @property
    def latents(self) -> np.ndarray:
        """``[H, W, latents]`` float32: the decoded codes (``bias + scale * q``)."""
        out = _decoded(self.arrays, "latents")
        assert out is not None
        return out

    @property
    def directions(self) -> str:
        """The direction encoding: ``"light"``, ``"xy"`` or ``"half"``."""
        return self._DIRECTIONS[int(self.arrays["architecture"][2])]

    @property
    def activation(self) -> str:
        """The hidden layers' activation: ``"elu"`` or ``"relu"``."""
        return self._ACTIVATIONS[int(self.arrays["architecture"][3])]

    @property
    def layers(self) -> List[Tuple[np.ndarray, np.ndarray]]:
        """The decoder's three ``(weight [out, in], bias [out])`` float32 pairs, on the data's
        scale. Layer 1's inputs are the code, then the encoding: the coordinates of
        :attr:`directions`; with a horizon map, the clearances (the light's, and for the BTF
        encodings the view's first: ``asin(d_z)`` minus the texel's :attr:`horizon` at the
        direction's azimuth, interpolated between bins); then, for each table of :attr:`tables`,
        its features at the direction (view, light, half vector, as many as the encoding has),
        looked up bilinearly."""
        u = self._m.unpacked()
        return [(u[f"layer{i}_weight"], u[f"layer{i}_bias"]) for i in (1, 2, 3)]

    @property
    def tables(self) -> np.ndarray:
        """``[tables, grid, grid, features]`` float32: the learned direction tables (view, light,
        half vector; none for NeuralRTI's form), node ``[j, i]`` at point ``(i, j) / (grid -
        1)`` of the elevated concentric square (:func:`btfrs.hemimap.hemisphere_to_square`)."""
        return self._m.unpacked()["tables"]

    @property
    def horizon(self) -> Optional[np.ndarray]:
        """``[H, W, bins]`` float32: each texel's horizon, the elevation angle (radians) above
        which the relief around it does not hide a direction, at ``bins`` azimuths ``2 pi k /
        bins`` from x towards y, rebuilt from the stored map (``mean + coords @ basis``, the
        coordinates 8-bit planes); ``None`` for a decoder without one (NeuralRTI's form)."""
        a = self.arrays
        if "horizon_q" not in a:
            return None
        c = a["horizon_bias"] + a["horizon_scale"] * a["horizon_q"].astype(np.float32)
        return np.ascontiguousarray(a["horizon_mean"] + c @ a["horizon_basis"], dtype=np.float32)


class Svbrdf(Model):
    """A per-texel microfacet SVBRDF: per texel a diffuse colour, a specular colour, a GGX
    roughness and a shading normal (tangent space: x right, y up the image, z out of the
    surface). ``value = diffuse (n.l) + specular pi D(n.h) G1(n.l) G1(n.v) / (4 n.v)``, GGX's
    ``D`` and Smith's ``G1``: Mitsuba's ``diffuse`` plus its ``roughconductor`` (GGX, no
    Fresnel) times the specular colour."""

    _kind = "svbrdf"

    @property
    def diffuse(self) -> np.ndarray:
        """``[H, W, 3]`` diffuse colour (``value = diffuse (n.l)`` for a matte texel)."""
        return self.arrays["diffuse"]

    @property
    def specular(self) -> np.ndarray:
        """``[H, W, 3]`` specular colour."""
        return self.arrays["specular"]

    @property
    def roughness(self) -> np.ndarray:
        """``[H, W]`` GGX alpha (glTF's roughness is its square root)."""
        return self.arrays["roughness"]

    @property
    def normals(self) -> np.ndarray:
        """``[H, W, 3]`` unit shading normals."""
        return self.arrays["normal"]


def model_kinds() -> Dict[str, Dict[str, Any]]:
    """Every registered model and its facts, from the Rust registry: ``{kind: facts}`` with
    ``doc`` (one line), ``about`` (a few paragraphs), ``options`` (the schema: ``name``,
    ``type``, ``default``, ``allowed``, ``doc``, and ``min``/``max``/``choices``), ``renderers``
    (the default first), ``examples`` (``(label, options)`` pairs, what the demo and the bench
    fit), ``sweep`` (``(label, options, quick, note)`` of :func:`btfrs.evaluate`), ``sampling``,
    ``exports`` (other tools' formats), ``mip``, ``blockwise``, ``scans_values``,
    ``stochastic`` (trained by stochastic gradient descent: another seed gives another model) and
    ``export_options`` (the options a fit needs for its model to go into every format of
    ``exports``)."""
    global _REGISTRY
    if _REGISTRY is None:
        _REGISTRY = {}
        for f in _native.model_facts():
            f["examples"] = [(lab, o) for lab, o in f["examples"]]
            f["sweep"] = [(s["label"], s["options"], bool(s["quick"]), s["note"]) for s in f["sweep"]]
            _REGISTRY[f.pop("kind")] = f
    return _REGISTRY


def class_of(kind: str) -> Type[Model]:
    """The Python class of model ``kind``: its own class where one adds accessors, else
    :class:`Model`."""
    return next((c for c in _all_subclasses(Model) if c._kind == kind), Model)


_REGISTRY: Optional[Dict[str, Dict[str, Any]]] = None


def wrap(native: "_native.Model", fit_seconds: Optional[float] = None, report: Optional[Dict[str, Any]] = None) -> Model:
    """The Python object of a native model: the class documented for its kind, else
    :class:`Model` itself (a model registered in Rust needs no Python code)."""
    return class_of(native.kind)(native, fit_seconds=fit_seconds, report=report)


def _all_subclasses(c: Type[_T]) -> Iterator[Type[_T]]:
    for s in c.__subclasses__():
        yield s
        yield from _all_subclasses(s)


def load_as(path: PathLike, cls: Type[_T]) -> _T:
    """:func:`load`, checking that the file holds a ``cls`` (else :class:`FormatError`)."""
    obj = load(path)
    if not isinstance(obj, cls):
        raise FormatError(f"{os.fspath(path)}: holds a {type(obj).__name__}, not a {cls.__name__}")
    return obj


def load(path: PathLike) -> Any:
    """Load any ``.btfrs`` file: a :class:`~btfrs.Btf`, a fitted model, a synthesis analysis or a
    Wang tile set (:class:`btfrs.tiles.TileSet`)."""
    meta: Any
    p = os.fspath(path)
    kind, _, _ = _native.read_container_header(p)
    if kind in model_kinds():
        m, meta = _native.load_model(p)
        meta = json.loads(meta)
        return wrap(m, fit_seconds=meta.get("fit_seconds"), report=meta.get("report") or {})
    kind, meta, arrays = read_container(path)
    if kind == "btf":
        return Btf.from_arrays(path, arrays)
    loader = _CONTAINERS.get(kind)
    if loader is not None:
        return loader(path, meta, arrays)
    raise FormatError(f"{p}: unknown content {kind!r}")


#: Readers of the other kinds a ``.btfrs`` container holds: ``kind -> reader(path, meta, arrays)``,
#: filled in by the modules that define them (synthesis analyses, tile sets), so this layer needs
#: not import them.
_CONTAINERS: Dict[str, Callable[[PathLike, Dict[str, Any], Dict[str, NDArray[Any]]], Any]] = {}


#: What :meth:`Model.save_web` calls: :func:`btfrs.web.save_web`, registered by that module
#: (a higher layer, which this one cannot import).
_WEB_WRITER: Optional[Callable[..., str]] = None


def register_web_writer(writer: Callable[..., str]) -> None:
    """Make :meth:`Model.save_web` write with ``writer(model, folder, **options)``."""
    global _WEB_WRITER
    _WEB_WRITER = writer


def register_container(kind: str, reader: Any) -> None:
    """Make :func:`load` read ``.btfrs`` files of content ``kind`` with ``reader(path, meta, arrays)``."""
    _CONTAINERS[kind] = reader
