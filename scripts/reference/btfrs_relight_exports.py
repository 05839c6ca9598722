"""The btfrs side of the relight fixtures: fit the fixture capture with btfrs and write every
model relight can read (``.ptm`` RGB and LRGB, ``.rti`` HSH, relight web folders), beside the
fitted models themselves (``models/*.btfrs``), so that relight-cli can relight the exports and
the tests can compare its images with btfrs's own evaluation of the same models.

    python scripts/reference/btfrs_relight_exports.py CAPTURE_FOLDER OUT_FOLDER

``relight_fixtures.sh`` calls it through ``BTFRS_EXPORT_CMD``. The capture is read with
``linear=True``: relight fits the 8-bit values as they are (no sRGB decoding), so the models
are compared with relight in the same units (1.0 = byte 255).
"""
from __future__ import annotations

import os
import sys

import btfrs

#: name -> (model kind, options, format, file or folder name)
EXPORTS = {
    "ptm_rgb": ("ptm", {"kind": "rgb"}, "ptm", "ptm_rgb.ptm"),
    "ptm_lrgb": ("ptm", {"kind": "lrgb"}, "ptm", "ptm_lrgb.ptm"),
    "hsh_4": ("hsh", {"order": 2}, "rti", "hsh_4.rti"),
    "hsh_9": ("hsh", {"order": 3}, "rti", "hsh_9.rti"),
    "web_ptm_rgb": ("ptm", {"kind": "rgb"}, "relight", "web_ptm_rgb"),
    "web_ptm_lrgb": ("ptm", {"kind": "lrgb"}, "relight", "web_ptm_lrgb"),
    "web_hsh_9": ("hsh", {"order": 3}, "relight", "web_hsh_9"),
    "web_rbf": ("rbf", {"components": 9}, "relight", "web_rbf"),
    "web_bilinear_ycc": ("bilinear", {"components": 6, "colour": "ycc", "chroma_components": 3}, "relight",
                         "web_bilinear_ycc"),
}


def main(capture: str, out: str) -> None:
    btf = btfrs.load(capture, linear=True)
    os.makedirs(os.path.join(out, "models"), exist_ok=True)
    for name, (kind, options, fmt, target) in EXPORTS.items():
        model = btfrs.fit.fit(kind, btf, **options)
        model.save(os.path.join(out, "models", f"{name}.btfrs"))
        model.export(os.path.join(out, target), format=fmt)
        print(f"{name}: {kind} {options} -> {target}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
