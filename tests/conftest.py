import os

import numpy as np
import pytest

import btfrs


def in_ci() -> bool:
    """Whether the suite runs in CI (``.ci/run`` sets ``CI=true``, as CI services do; any value
    but empty, ``0``, ``false`` or ``no`` counts). There a missing optional tool (Mitsuba,
    Chromium, playwright) fails the tests that need it instead of skipping them. The one place
    the suite reads the switch."""
    return os.environ.get("CI", "").strip().lower() not in ("", "0", "false", "no")


@pytest.fixture(scope="session")
def knit():
    """The built-in knit at 32^2 (UBO 81 x 81), shared by the tests that only read it."""
    return btfrs.materials.make("knit", size=32, seed=1)


def biquadratic_data(h, w, views, lights, seed=0):
    """Data that is exactly a biquadratic PTM per texel, view and channel, and its coefficients."""
    rng = np.random.default_rng(seed)
    coef = rng.uniform(-0.3, 0.7, size=(h, w, len(views), 3, 6))
    lx, ly = lights[:, 0], lights[:, 1]
    basis = np.stack([lx * lx, ly * ly, lx * ly, lx, ly, np.ones_like(lx)], axis=-1)  # [L, 6]
    data = np.einsum("hwvck,lk->hwvlc", coef, basis)
    return data.astype(np.float32), coef


# The files whose tests take longest (a fresh-clone CI run's figures: 38-233 s each on one of two
# workers), longest first. scripts/test.sh gives pytest-xdist whole files in collection order
# (`--dist loadfile --no-loadscope-reorder`), each worker taking the next file as it finishes
# one, so these start first and the short files fill the end: otherwise a long file handed out
# last left one worker running alone for a minute. Any file not listed keeps its place after them.
LONGEST_FILES = ("test_stability.py", "test_viewer.py", "test_docs.py", "test_out_of_core.py",
                 "test_cli_readme.py", "test_ground_truth.py", "test_viewer_rti.py", "test_synth.py",
                 "test_dask.py", "test_environment.py", "test_evaluate.py", "test_tiles.py")


def pytest_collection_modifyitems(items):
    rank = {name: i for i, name in enumerate(LONGEST_FILES)}
    items.sort(key=lambda item: rank.get(item.path.name, len(LONGEST_FILES)))  # stable: file order kept
