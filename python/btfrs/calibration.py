"""Light directions from a reflective sphere in the photographs: :func:`calibrate`.

An RTI capture photographed with a glossy black sphere in the frame needs no light file: each
photograph's light is the mirror image of its highlight on the sphere. :func:`calibrate` finds
the sphere (or takes its circle), each photograph's highlight to a fraction of a pixel (the
centre of a clipped highlight too), turns it into a direction in btfrs's frame (x right, y up
the image, z towards the camera) for an orthographic camera or, given the field of view or the
focal length, a perspective one, and flags the photographs it cannot calibrate: no highlight,
two highlights, an overexposed sphere. :meth:`Calibration.save` writes the ``.lp`` file that
relight, RTIBuilder and :func:`btfrs.load` read. The work is done in Rust (``btfrs-calibrate``:
the photographs decoded in parallel, the GIL released, progress shown, Ctrl-C honoured).

>>> cal = btfrs.calibrate("photos/")
>>> cal.save("photos/dirs.lp")
>>> btf = btfrs.load("photos/dirs.lp")
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Tuple, Union

import numpy as np
from numpy.typing import NDArray

from . import _native
from ._checks import PathLike, boolean, integer, real
from ._progress import Progress, callback
from .exceptions import ArgumentTypeError, InvalidArgumentError
from .io import atomic_write

__all__ = ["calibrate", "Calibration", "ImageCalibration", "STATUSES"]

#: What :attr:`ImageCalibration.status` can be: one highlight (``"ok"``), none (``"missing"``),
#: two of similar strength (``"ambiguous"``), or a sphere that is not dark or a highlight that
#: covers much of it (``"overexposed"``).
STATUSES = ("ok", "missing", "ambiguous", "overexposed")


@dataclass(frozen=True)
class ImageCalibration:
    """What calibration found in one photograph."""

    #: The photograph (its path as listed or given).
    file: str
    #: One of :data:`STATUSES`.
    status: str
    #: Why it was not calibrated (None when it was).
    reason: Optional[str]
    #: The highlight's centre in pixels (x right, y down, the image's top-left corner at (0, 0)).
    highlight: Optional[Tuple[float, float]]
    #: The light direction (unit; x right, y up the image, z towards the camera).
    light: Optional[Tuple[float, float, float]]
    #: With a white target: the light's relative intensity (R, G, B; the capture's median = 1).
    intensity: Optional[Tuple[float, float, float]] = None
    #: Something to know about the light (moved onto the horizon from just below it).
    note: Optional[str] = None
    #: The bright spots on the sphere, heaviest first: ``x``, ``y``, ``peak``, ``weight``, ``area``.
    spots: List[Dict[str, float]] = field(default_factory=list)


class Calibration:
    """The lights of a capture found from its sphere (:func:`calibrate`)."""

    def __init__(self, report: Dict[str, Any]) -> None:
        #: Everything found, as :meth:`save_report` writes it.
        self.report = report
        #: ``(height, width)`` of the photographs.
        self.size: Tuple[int, int] = (int(report["height"]), int(report["width"]))
        #: The sphere's outline as a circle ``(cx, cy, r)`` in pixels (found or given).
        cx, cy, r = report["sphere"]["circle"]
        self.sphere: Tuple[float, float, float] = (float(cx), float(cy), float(r))
        #: Every photograph, in order.
        self.images: List[ImageCalibration] = [
            ImageCalibration(file=i["file"], status=i["status"], reason=i["reason"],
                             highlight=None if i["highlight"] is None else tuple(i["highlight"]),
                             light=None if i["light"] is None else tuple(i["light"]),
                             intensity=None if i["intensity"] is None else tuple(i["intensity"]),
                             note=i["note"], spots=i["spots"])
            for i in report["images"]]

    @property
    def calibrated(self) -> List[ImageCalibration]:
        """The photographs whose light was found."""
        return [i for i in self.images if i.light is not None]

    @property
    def files(self) -> List[str]:
        """The calibrated photographs' paths."""
        return [i.file for i in self.calibrated]

    @property
    def lights(self) -> NDArray[np.float64]:
        """``[N, 3]`` light directions of the calibrated photographs (unit vectors)."""
        return np.array([i.light for i in self.calibrated], dtype=np.float64).reshape(-1, 3)

    @property
    def highlights(self) -> NDArray[np.float64]:
        """``[N, 2]`` highlight centres (x, y) in pixels of the calibrated photographs."""
        return np.array([i.highlight for i in self.calibrated], dtype=np.float64).reshape(-1, 2)

    @property
    def intensity(self) -> Optional[NDArray[np.float64]]:
        """``[N, 3]`` relative light intensities (R, G, B) from the white target, or None
        without one."""
        if self.report["white"] is None:
            return None
        return np.array([i.intensity for i in self.calibrated], dtype=np.float64).reshape(-1, 3)

    @property
    def skipped(self) -> Dict[str, str]:
        """The photographs left out, each with why."""
        return {i.file: i.reason or i.status for i in self.images if i.light is None}

    def __repr__(self) -> str:
        cx, cy, r = self.sphere
        return (f"Calibration({len(self.calibrated)} of {len(self.images)} photographs, sphere at ({cx:.1f}, "
                f"{cy:.1f}) radius {r:.1f} px, {self.report['camera']['projection']})")

    def save(self, path: PathLike) -> str:
        """Write the ``.lp`` file (atomically): the count, then ``filename lx ly lz`` per
        calibrated photograph, names relative to the file's folder when the photographs lie in
        it (as relight and RTIBuilder expect), absolute otherwise. Returns the path."""
        p = os.fspath(path)
        if not p.lower().endswith(".lp"):
            raise InvalidArgumentError(f"path: {p}: expected a file name ending in .lp")
        folder = os.path.dirname(os.path.abspath(p))
        names = []
        for f in self.files:
            a = os.path.abspath(f)
            rel = os.path.relpath(a, folder)
            names.append(a if rel.startswith(os.pardir) else rel.replace(os.sep, "/"))
        spaced = [n for n in names if any(c.isspace() for c in n)]
        if spaced:
            warnings.warn(f"{p}: {len(spaced)} file names contain spaces ({spaced[0]!r}, ...): btfrs reads them, "
                          "relight and RTIBuilder read a name only up to its first space", UserWarning, stacklevel=2)
        _native.write_lp(p, names, [(float(x), float(y), float(z)) for x, y, z in self.lights])
        return p

    def save_report(self, path: PathLike) -> str:
        """Write everything found as JSON (atomically): the sphere, the camera, and per
        photograph its status, highlight, spots, light and (with a white target) intensity.
        Returns the path."""
        p = os.fspath(path)
        with atomic_write(p, "w") as f:
            json.dump(self.report, f, indent=1)
        return p

    def figure(self, path: PathLike, image: Union[int, str, None] = None) -> str:
        """A PNG of the sphere as found on one photograph (``image``: an index into
        :attr:`images` or a file; default the first calibrated one), with every calibrated
        highlight, the skipped photographs' spots, and the lights seen from above. Needs
        matplotlib. Returns the path."""
        import matplotlib  # noqa: PLC0415  (optional, heavy)
        matplotlib.use("Agg")
        import matplotlib.image as mpimg  # noqa: PLC0415
        import matplotlib.pyplot as plt  # noqa: PLC0415

        if image is None:
            shown = next(i for i in self.images if i.light is not None)
        elif isinstance(image, str):
            hits = [i for i in self.images if i.file == image or os.path.basename(i.file) == image]
            if not hits:
                raise InvalidArgumentError(f"image: {image!r} is not one of the calibrated photographs")
            shown = hits[0]
        else:
            shown = self.images[integer("image", image, min=0, max=len(self.images) - 1)]
        photo = mpimg.imread(shown.file)
        cx, cy, r = self.sphere
        fig, (ax, bx) = plt.subplots(1, 2, figsize=(10, 5), gridspec_kw={"width_ratios": [1, 1]})
        ax.imshow(photo, extent=(0, photo.shape[1], photo.shape[0], 0), interpolation="nearest")
        t = np.linspace(0, 2 * np.pi, 361)
        ax.plot(cx + r * np.cos(t), cy + r * np.sin(t), color="#00c8ff", lw=1.2, label="sphere outline")
        h = self.highlights
        ax.plot(h[:, 0], h[:, 1], "+", color="#ffd000", ms=6, mew=1, label=f"highlights ({len(h)})")
        bad = [i for i in self.images if i.light is None and i.spots]
        if bad:
            s = np.array([[sp["x"], sp["y"]] for i in bad for sp in i.spots])
            ax.plot(s[:, 0], s[:, 1], "x", color="#ff3030", ms=7, mew=1.5, label=f"spots of skipped ({len(bad)})")
        if shown.highlight is not None:
            ax.plot(*shown.highlight, "o", mfc="none", mec="#ff00ff", ms=12, mew=1.5, label="this photograph's")
        pad = 1.25 * r
        ax.set_xlim(cx - pad, cx + pad)
        ax.set_ylim(cy + pad, cy - pad)
        ax.set_title(f"{os.path.basename(shown.file)}: sphere at ({cx:.1f}, {cy:.1f}), r = {r:.1f} px", fontsize=9)
        ax.legend(loc="lower left", fontsize=7, framealpha=0.8)
        ax.set_xlabel("x (pixels)")
        ax.set_ylabel("y (pixels)")
        l = self.lights
        bx.plot(np.cos(t), np.sin(t), color="0.5", lw=1)
        for e in (30, 60):
            c = np.cos(np.radians(e))
            bx.plot(c * np.cos(t), c * np.sin(t), color="0.8", lw=0.8, ls="--")
            bx.text(c * 0.71, c * 0.71, f"{e}°", fontsize=7, color="0.5")
        sc = bx.scatter(l[:, 0], l[:, 1], c=np.degrees(np.arcsin(np.clip(l[:, 2], -1, 1))), cmap="viridis",
                        vmin=0, vmax=90, s=18)
        fig.colorbar(sc, ax=bx, label="elevation (degrees)", shrink=0.8)
        bx.set_aspect("equal")
        bx.set_xlim(-1.05, 1.05)
        bx.set_ylim(-1.05, 1.05)
        bx.set_xlabel("lx (right)")
        bx.set_ylabel("ly (up the image)")
        bx.set_title(f"{len(l)} lights seen from above ({len(self.skipped)} photographs skipped)", fontsize=9)
        fig.tight_layout()
        p = os.fspath(path)
        with atomic_write(p) as f:
            fig.savefig(f, format="png", dpi=110)
        plt.close(fig)
        return p


def _tuple(name: str, value: object, n: int, what: str) -> Tuple[object, ...]:
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) and not isinstance(value, np.ndarray):
        raise ArgumentTypeError(f"{name}: expected {what}, got {value!r}")
    items = tuple(value)
    if len(items) != n:
        raise ArgumentTypeError(f"{name}: expected {what}, got {value!r}")
    return items


def calibrate(images: Union[PathLike, Sequence[PathLike]], sphere: Optional[Sequence[float]] = None, *,
              fov: Optional[float] = None, focal: Optional[float] = None, white: Optional[Sequence[int]] = None,
              linear: bool = False, progress: Progress = None) -> Calibration:
    """Find the light of each photograph from its highlight on a reflective sphere.

    Parameters:
        images: a folder (every JPEG, PNG, TIFF and EXR in it, sorted by name) or a list of
            photographs, all of one size, all showing the sphere.
        sphere: the sphere's outline as a circle ``(cx, cy, r)`` in pixels (x right, y down,
            the image's top-left corner at (0, 0): the centre of the top-left pixel is
            (0.5, 0.5)), used as given. Default: found, as the darkest round region of the
            photographs, its outline traced to a fraction of a pixel (which needs the sphere
            darker than what surrounds it).
        fov: the camera's horizontal field of view in degrees (across the image's width), for a
            perspective correction; or
        focal: its 35 mm-equivalent focal length in millimetres (EXIF ``FocalLengthIn35mmFilm``).
            Neither: an orthographic camera (a long lens far from a small sphere).
        white: a white, matte target in the frame facing the camera, ``(row, col, rows, cols)``
            in pixels as ``btfrs.load``'s ``crop``: each light's relative intensity is the
            target's mean colour over the light's cosine (:attr:`Calibration.intensity`).
        linear: 8- and 16-bit values are linear already (TIFFs converted from RAW), not sRGB.
        progress: ``True`` for a progress bar, or a ``(done, total)`` callable.

    Photographs that cannot be calibrated (no highlight, two highlights, an overexposed
    sphere) are left out with a ``UserWarning`` naming each and why (:attr:`Calibration.skipped`);
    when none can, a :class:`~btfrs.exceptions.DegenerateDataError` names them all. Photographs of
    different sizes raise :class:`~btfrs.exceptions.FormatError` naming the file; a sphere that
    cannot be found, :class:`~btfrs.exceptions.DegenerateDataError`.
    """
    folder: Optional[str] = None
    files: Optional[List[str]] = None
    if isinstance(images, (str, os.PathLike)):
        p = os.fspath(images)
        if not os.path.isdir(p):
            if os.path.exists(p):
                raise InvalidArgumentError(f"images: {p} is a file; expected a folder of photographs or a list of them")
            raise FileNotFoundError(f"images: {p}: no such folder")
        folder = p
    elif isinstance(images, (list, tuple)):
        files = []
        for k, f in enumerate(images):
            if not isinstance(f, (str, os.PathLike)):
                raise ArgumentTypeError(f"images[{k}]: expected a path, got {type(f).__name__}")
            files.append(os.fspath(f))
    else:
        raise ArgumentTypeError(f"images: expected a folder or a list of photographs, got {type(images).__name__}")
    circle = None
    if sphere is not None:
        c = _tuple("sphere", sphere, 3, "a circle (cx, cy, r) in pixels")
        circle = (real("sphere[0] (cx)", c[0]), real("sphere[1] (cy)", c[1]),
                  real("sphere[2] (r)", c[2], min=3.0))
    if fov is not None and focal is not None:
        raise InvalidArgumentError("fov: give the field of view or the focal length, not both")
    fov_v = None if fov is None else real("fov", fov, min=0.0, max=170.0, min_open=True, max_open=True)
    focal_v = None if focal is None else real("focal", focal, min=0.0, min_open=True)
    rect = None
    if white is not None:
        w = _tuple("white", white, 4, "a rectangle (row, col, rows, cols) in pixels")
        rect = (integer("white[0] (row)", w[0], min=0), integer("white[1] (col)", w[1], min=0),
                integer("white[2] (rows)", w[2], min=1), integer("white[3] (cols)", w[3], min=1))
    text = _native.calibrate_sphere(folder, files, circle, fov_v, focal_v, rect, boolean("linear", linear),
                                    callback(progress, "calibrating"))
    cal = Calibration(json.loads(text))
    skipped = cal.skipped
    if skipped:
        listed = "; ".join(f"{os.path.basename(f)}: {why}" for f, why in list(skipped.items())[:10])
        more = f"; and {len(skipped) - 10} more" if len(skipped) > 10 else ""
        warnings.warn(f"{len(skipped)} of {len(cal.images)} photographs not calibrated (left out of the lights): "
                      f"{listed}{more}", UserWarning, stacklevel=2)
    notes = [f"{os.path.basename(i.file)}: {i.note}" for i in cal.images if i.note]
    for w_text in cal.report["warnings"] + (["; ".join(notes)] if notes else []):
        warnings.warn(w_text, UserWarning, stacklevel=2)
    return cal
