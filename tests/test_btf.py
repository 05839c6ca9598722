import os

import numpy as np
import pytest

import btfrs
from btfrs.exceptions import FormatError, InvalidArgumentError

D = btfrs.directions.ubo81()


def small(h=3, w=2, v=D[:4], l=D[:5]):
    rng = np.random.default_rng(0)
    return btfrs.Btf(rng.random((h, w, len(v), len(l), 3), dtype=np.float32), v, l)


def test_layout_and_views_without_copies():
    b = small()
    assert b.shape == (3, 2, 4, 5, 3) and (b.height, b.width, b.n_views, b.n_lights) == (3, 2, 4, 5)
    assert b.nbytes == 3 * 2 * 4 * 5 * 3 * 4
    img = b.image(2, 3)
    assert img.shape == (3, 2, 3) and np.shares_memory(img, b.data)
    np.testing.assert_array_equal(img, b.data[:, :, 2, 3])
    im = b.images()
    assert im.shape == (4, 5, 3, 2, 3) and np.shares_memory(im, b.data)
    np.testing.assert_array_equal(im[1, 4, 2, 1], b.data[2, 1, 1, 4])
    ab = b.abrdf(1, 1)
    assert ab.flags.c_contiguous and np.shares_memory(ab, b.data)
    with pytest.raises(IndexError, match="view"):
        b.image(4, 0)


def test_float64_is_converted_and_ints_rejected():
    d = np.zeros((1, 1, 4, 5, 3))
    assert small().data.dtype == np.float32
    assert btfrs.Btf(d, D[:4], D[:5]).data.dtype == np.float32
    with pytest.raises(TypeError, match="data: expected a float array"):
        btfrs.Btf(d.astype(np.uint8), D[:4], D[:5])


@pytest.mark.parametrize(
    "views, match",
    [
        (np.array([[0, 0, 2.0]]), "views: direction 0 .* has length 2"),
        (np.array([[0, 0, -1.0]]), "views: .*z < 0"),
        (np.array([[np.nan, 0, 1.0]]), "views: direction 0 is not finite"),
    ],
)
def test_bad_directions_name_the_argument(views, match):
    with pytest.raises(InvalidArgumentError, match=match):
        btfrs.Btf(np.zeros((1, 1, 1, 5, 3), np.float32), views, D[:5])


def test_bad_shapes_and_values():
    with pytest.raises(ValueError, match=r"data: expected shape \(H, W, V, L, 3\)"):
        btfrs.Btf(np.zeros((2, 2, 3), np.float32), D[:1], D[:1])
    with pytest.raises(ValueError, match=r"data: expected shape \(\*, \*, 3, 5, 3\), got \[1, 1, 2, 5, 3\]"):
        btfrs.Btf(np.zeros((1, 1, 2, 5, 3), np.float32), D[:3], D[:5])
    bad = np.zeros((2, 2, 4, 5, 3), np.float32)
    bad[1, 0, 2, 3, 1] = np.inf
    with pytest.raises(InvalidArgumentError, match="data: value inf at flat index"):
        btfrs.Btf(bad, D[:4], D[:5])
    with pytest.raises(ValueError, match="mask"):
        btfrs.Btf(np.zeros((1, 1, 4, 5, 3), np.float32), D[:4], D[:5], mask=np.zeros((4, 5), bool))


def test_split_is_a_partition_sharing_the_data():
    b = small(v=D, l=D)
    train, test = b.split(holdout=0.1, seed=3)
    assert test.pairs == round(0.1 * 81 * 81) and train.pairs + test.pairs == 81 * 81
    assert not np.any(train.mask & test.mask)
    assert np.shares_memory(train.data, b.data) and np.shares_memory(test.data, b.data)
    t2 = b.split(holdout=0.1, seed=3)[1]
    np.testing.assert_array_equal(t2.mask, test.mask)
    assert not np.array_equal(b.split(holdout=0.1, seed=4)[1].mask, test.mask)
    # A second split of the train half stays inside it.
    a, c = train.split(holdout=0.5, seed=0)
    assert not np.any((a.mask | c.mask) & test.mask)
    with pytest.raises(InvalidArgumentError, match="holdout"):
        b.split(holdout=1.5)


def test_select():
    b = small(v=D[:6], l=D[:7])
    s = b.select(views=slice(1, 3), lights=[0, 2, 4])
    assert s.shape == (3, 2, 2, 3, 3)
    np.testing.assert_array_equal(s.data[:, :, 1, 2], b.data[:, :, 2, 4])
    np.testing.assert_array_equal(s.views, D[1:3])
    assert s.data.flags.c_contiguous and not np.shares_memory(s.data, b.data)


@pytest.mark.parametrize("mmap", [False, True])
def test_save_load_round_trip(tmp_path, mmap):
    b, _ = small(v=D[:9], l=D[:8]).split(holdout=0.25, seed=1)
    p = tmp_path / "s.btfrs"
    b.save(p)
    c = btfrs.Btf.load(p, mmap=mmap)
    np.testing.assert_array_equal(c.data, b.data)
    np.testing.assert_array_equal(c.views, b.views)
    np.testing.assert_array_equal(c.mask, b.mask)
    assert isinstance(btfrs.load(p), btfrs.Btf)
    assert os.listdir(tmp_path) == ["s.btfrs"]


def test_files_fail_cleanly(tmp_path):
    with pytest.raises(FileNotFoundError):
        btfrs.Btf.load(tmp_path / "missing.btfrs")
    with pytest.raises(FileNotFoundError):
        small().save(tmp_path / "no" / "dir.btfrs")
    junk = tmp_path / "junk.btfrs"
    junk.write_bytes(b"not a btfrs file at all")
    with pytest.raises(FormatError, match="bad magic"):
        btfrs.Btf.load(junk)
    # A failed write leaves nothing behind: a directory in the way of the rename.
    (tmp_path / "taken.btfrs").mkdir()
    with pytest.raises(OSError):
        small().save(tmp_path / "taken.btfrs")
    assert sorted(os.listdir(tmp_path)) == ["junk.btfrs", "taken.btfrs"]
