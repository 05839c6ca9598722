#!/usr/bin/env python3
"""Check the written description of relight's web format against relight's own renders.

This is an independent numpy evaluator of the relight web format (info.json +
plane_N.jpg), written from the description in tests/fixtures/relight/README.md.
It renders every entry of manifest.json whose source is a web folder and prints
how far it lands from the image relight-cli wrote.  It needs numpy and Pillow
only (no btfrs, no relight).

    python scripts/reference/relight_check.py tests/fixtures/relight

Exit status 1 when any render differs from relight's by more than --tolerance
(default 1 grey level, to allow for float32 vs float64 rounding at the
truncation boundaries).
"""

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np
from PIL import Image


def load_web(folder):
    folder = Path(folder)
    info = json.loads((folder / "info.json").read_text())
    w, h = info["width"], info["height"]
    nplanes = sum(info["yccplanes"]) if info["colorspace"] == "mycc" else info["nplanes"]
    planes = np.zeros((nplanes, h, w), dtype=np.float64)
    for j in range((nplanes - 1) // 3 + 1):
        with Image.open(folder / f"plane_{j}.jpg") as im:
            rgb = np.asarray(im.convert("RGB"), dtype=np.float64)
        for c in range(3):
            if 3 * j + c < nplanes:
                planes[3 * j + c] = rgb[..., c]
    mat = info["materials"][0]
    scale = np.asarray(mat["scale"], dtype=np.float64)
    bias = np.asarray(mat["bias"], dtype=np.float64)
    # coefficient in [0, 255] units: 255 * (byte/255 - bias) * scale
    coeff = 255.0 * (planes / 255.0 - bias[:, None, None]) * scale[:, None, None]
    return info, planes, coeff


def ptm_weights(lx, ly, n):
    out = []
    degree = 0
    while True:
        for k in range(degree + 1):
            out.append(ly**k * lx ** (degree - k))
            if len(out) == n:
                return np.asarray(out)
        degree += 1


def hsh_weights(lx, ly):
    lz = math.sqrt(max(0.0, 1.0 - lx * lx - ly * ly))
    phi = math.atan2(ly, lx)
    if phi < 0:
        phi += 2 * math.pi
    theta = min(math.acos(lz), math.pi / 2 - 0.01)
    ct = math.cos(theta)
    ct2 = ct * ct
    s = math.sqrt(ct - ct2)
    return np.asarray([
        1 / math.sqrt(2 * math.pi),
        math.sqrt(6 / math.pi) * math.cos(phi) * s,
        math.sqrt(3 / (2 * math.pi)) * (-1 + 2 * ct),
        math.sqrt(6 / math.pi) * s * math.sin(phi),
        math.sqrt(30 / math.pi) * math.cos(2 * phi) * (-ct + ct2),
        math.sqrt(30 / math.pi) * math.cos(phi) * (-1 + 2 * ct) * s,
        math.sqrt(5 / (2 * math.pi)) * (1 - 6 * ct + 6 * ct2),
        math.sqrt(30 / math.pi) * (-1 + 2 * ct) * s * math.sin(phi),
        math.sqrt(30 / math.pi) * (-ct + ct2) * math.sin(2 * phi),
    ])


def mrgb_basis(info, nplanes, ndim):
    raw = np.asarray(info["basis"], dtype=np.float64).reshape(nplanes + 1, ndim, 3)
    rng = np.asarray(info["materials"][0]["range"], dtype=np.float64)
    basis = raw.copy()
    basis[1:] = (raw[1:] - 127.0) / rng[:, None, None]
    return basis


def rbf_weights(info, basis, lx, ly):
    lights = np.asarray(info["lights"], dtype=np.float64).reshape(-1, 3)
    lz = math.sqrt(max(0.0, 1 - lx * lx - ly * ly))
    d2 = ((lights - np.array([lx, ly, lz])) ** 2).sum(1)
    w = np.exp(-d2 / info["sigma"] ** 2)
    w /= w.sum()
    w = np.where(w > 0.001, w, 0.0)
    w /= w.sum()
    return np.einsum("i,pik->pk", w, basis)  # (nplanes+1, 3)


def bilinear_weights(info, basis, lx, ly):
    res = info["resolution"]
    lz = math.sqrt(max(0.0, 1 - lx * lx - ly * ly))
    s = abs(lx) + abs(ly) + abs(lz)
    x = ((lx + ly) / s + 1) / 2 * (res - 1)
    y = ((ly - lx) / s + 1) / 2 * (res - 1)
    sx = min(res - 2, max(0, math.floor(x)))
    sy = min(res - 2, max(0, math.floor(y)))
    dx, dy = x - sx, y - sy
    b = basis.reshape(basis.shape[0], res, res, 3)  # [p, y, x, k]
    return ((1 - dx) * (1 - dy) * b[:, sy, sx] + dx * (1 - dy) * b[:, sy, sx + 1]
            + (1 - dx) * dy * b[:, sy + 1, sx] + dx * dy * b[:, sy + 1, sx + 1])


def render(folder, light):
    info, planes, coeff = load_web(folder)
    light = np.asarray(light, dtype=np.float64)
    light /= np.linalg.norm(light)
    lx, ly = light[0], light[1]
    typ, cs = info["type"], info["colorspace"]
    nplanes = coeff.shape[0]
    h, w = coeff.shape[1:]
    if cs == "rgb":
        if typ == "ptm":
            lw = ptm_weights(lx, ly, nplanes // 3)
        elif typ == "hsh":
            lw = hsh_weights(lx, ly)[: nplanes // 3]
        else:
            raise SystemExit(f"unsupported type {typ}")
        out = np.einsum("j,jchw->hwc", lw, coeff.reshape(nplanes // 3, 3, h, w))
    elif cs == "lrgb":
        lw = ptm_weights(lx, ly, nplanes - 3)
        lum = np.einsum("p,phw->hw", lw, coeff[3:]) / 255.0
        out = lum[..., None] * np.moveaxis(planes[:3], 0, -1)
    elif cs == "mrgb":
        ndim = info["resolution"] ** 2 if typ == "bilinear" else len(info["lights"]) // 3
        basis = mrgb_basis(info, nplanes, ndim)
        lw = rbf_weights(info, basis, lx, ly) if typ == "rbf" else bilinear_weights(info, basis, lx, ly)
        out = lw[0][None, None, :] + np.einsum("pk,phw->hwk", lw[1:], coeff)
    else:
        raise SystemExit(f"unsupported colorspace {cs}")
    return np.clip(np.trunc(out), 0, 255).astype(np.uint8)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("fixtures", type=Path)
    ap.add_argument("--tolerance", type=int, default=1)
    args = ap.parse_args()
    manifest = json.loads((args.fixtures / "manifest.json").read_text())
    worst = 0
    for entry in manifest["relit"]:
        src = args.fixtures / entry["web_folder"]
        mine = render(src, entry["light"]).astype(int)
        with Image.open(args.fixtures / entry["output"]) as im:
            theirs = np.asarray(im.convert("RGB")).astype(int)
        d = np.abs(mine - theirs)
        worst = max(worst, int(d.max()))
        print(f"{entry['output']:60s} max|diff|={d.max():3d}  pixels off={np.count_nonzero(d)}/{d.size}")
    print(f"worst difference: {worst}")
    return 1 if worst > args.tolerance else 0


if __name__ == "__main__":
    sys.exit(main())
