"""Training pairs: indexing from split lists, augmentation, the Dataset and the resized-image cache."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from msdepth.data import kitti
from msdepth.data.pairs import (
    StereoPairs,
    _read_resized_pair,
    augment,
    build_pair_cache,
    index_pairs,
    load_pair_cache,
)
from msdepth.errors import DataError
from msdepth.io import write_png


def _rgb(h: int, w: int, seed: int) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


@pytest.fixture()
def tree(tmp_path: Path) -> tuple[Path, list[tuple[Path, Path]]]:
    """Four pairs in KITTI raw layout, 30 x 50 px."""
    pairs = []
    for i in range(4):
        left = tmp_path / "drive" / "image_02" / "data" / f"{i:010d}.png"
        right = tmp_path / "drive" / "image_03" / "data" / f"{i:010d}.png"
        write_png(left, _rgb(30, 50, 2 * i))
        write_png(right, _rgb(30, 50, 2 * i + 1))
        pairs.append((left, right))
    return tmp_path, pairs


def test_index_pairs_resolves_jpg_names_and_reports_missing(tree, tmp_path: Path) -> None:
    root, pairs = tree
    rel = [
        (str(left.relative_to(root)).replace(".png", ".jpg"), str(r.relative_to(root))) for left, r in pairs
    ]
    rel.append(("drive/image_02/data/9999999999.jpg", "drive/image_03/data/9999999999.jpg"))
    split = tmp_path / "split.txt"
    kitti.write_split(split, rel)
    index = index_pairs(split, root)
    assert index.pairs == pairs  # the .jpg names resolved to the .png files on disk
    assert index.missing == [rel[-1]]


def test_index_pairs_with_nothing_usable_names_the_split(tmp_path: Path) -> None:
    split = tmp_path / "split.txt"
    kitti.write_split(split, [("a/0.jpg", "b/0.jpg")])
    with pytest.raises(DataError, match="split.txt: none of its 1 pairs exist"):
        index_pairs(split, tmp_path)


def _draws(seed: int) -> tuple[bool, bool]:
    """(flip, colour) as :func:`augment` draws them from a generator seeded with ``seed``."""
    u = torch.rand(2, generator=torch.Generator().manual_seed(seed))
    return bool(u[0] < 0.5), bool(u[1] < 0.5)


def test_augment_flip_swaps_the_views() -> None:
    left, right = torch.rand(3, 8, 12), torch.rand(3, 8, 12)
    seed = next(s for s in range(100) if _draws(s) == (True, False))
    new_left, new_right = augment(left, right, torch.Generator().manual_seed(seed))
    # The mirrored right view is a valid left view of the mirrored scene, and vice versa.
    assert torch.equal(new_left, right.flip(-1)) and torch.equal(new_right, left.flip(-1))
    seed = next(s for s in range(100) if _draws(s) == (False, False))
    new_left, new_right = augment(left, right, torch.Generator().manual_seed(seed))
    assert torch.equal(new_left, left) and torch.equal(new_right, right)


def test_augment_colour_is_the_same_for_both_views_and_in_range() -> None:
    seeds = [s for s in range(200) if _draws(s) == (False, True)][:10]
    image = torch.rand(3, 8, 12)
    for seed in seeds:
        new_left, new_right = augment(image, image.clone(), torch.Generator().manual_seed(seed))
        assert torch.equal(new_left, new_right)  # one gamma/brightness/colour draw for the pair
        assert not torch.equal(new_left, image)
        assert new_left.min() >= 0 and new_left.max() <= 1


def test_dataset_samples_are_deterministic_per_seed_epoch_index(tree) -> None:
    _, pairs = tree
    a = StereoPairs(pairs, 16, 24, augment=True, seed=5)
    b = StereoPairs(pairs, 16, 24, augment=True, seed=5)
    sample = a[2]
    assert sample["left"].shape == (3, 16, 24) and sample["left"].dtype == torch.float32
    assert torch.equal(sample["left"], b[2]["left"]) and torch.equal(sample["right"], b[2]["right"])
    changed = 0
    for epoch in range(1, 6):
        b.set_epoch(epoch)
        changed += not torch.equal(sample["left"], b[2]["left"])
    assert changed > 0  # other epochs draw other augmentations


def test_cache_gives_exactly_the_decoded_samples(tree, tmp_path: Path) -> None:
    _, pairs = tree
    path = tmp_path / "cache" / "pairs.npy"
    build_pair_cache(pairs, 16, 24, path, progress=False)
    cache = load_pair_cache(path, len(pairs), 16, 24)
    assert cache.shape == (4, 2, 16, 24, 3) and cache.dtype == np.uint8
    plain = StereoPairs(pairs, 16, 24, augment=True, seed=1)
    cached = StereoPairs(pairs, 16, 24, augment=True, seed=1, cache=cache)
    for i in range(len(pairs)):
        for key in ("left", "right"):
            assert torch.equal(plain[i][key], cached[i][key])
    left, right = _read_resized_pair(*pairs[3], 16, 24)
    assert np.array_equal(cache[3, 0], left) and np.array_equal(cache[3, 1], right)


def test_cache_leaves_out_unreadable_pairs_and_reports_them(tree, tmp_path: Path) -> None:
    _, pairs = tree
    pairs[1][1].write_bytes(b"")  # a zero-byte right image
    data = pairs[2][0].read_bytes()
    pairs[2][0].write_bytes(data[: len(data) // 2])  # a truncated left image
    path = tmp_path / "cache" / "pairs.npy"
    report = build_pair_cache(pairs, 16, 24, path, progress=False)
    assert report.pairs == [pairs[0], pairs[3]]
    assert [(left, right) for left, right, _ in report.unreadable] == [pairs[1], pairs[2]]
    assert str(pairs[1][1]) in report.unreadable[0][2] and str(pairs[2][0]) in report.unreadable[1][2]
    cache = load_pair_cache(path, 2, 16, 24)
    assert np.array_equal(cache[1, 0], _read_resized_pair(*pairs[3], 16, 24)[0])
    assert [p.name for p in path.parent.iterdir()] == ["pairs.npy"]  # no temp file left behind


@pytest.mark.parametrize("fault", ["all_unreadable", "size_mismatch"])
def test_cache_errors_never_leave_a_partial_file(tree, tmp_path: Path, fault: str) -> None:
    _, pairs = tree
    if fault == "all_unreadable":
        for left, _ in pairs:
            left.write_bytes(b"")
        match = "none of the 4 pairs is readable"
    else:
        write_png(pairs[2][1], _rgb(31, 50, 0))
        match = r"0000000002.png is \(30, 50\) but its right image .*0000000002.png is \(31, 50\)"
    path = tmp_path / "cache" / "pairs.npy"
    with pytest.raises(DataError, match=match):
        build_pair_cache(pairs, 16, 24, path, progress=False)
    assert list(path.parent.iterdir()) == []


def test_load_cache_rejects_a_stale_or_foreign_file(tree, tmp_path: Path) -> None:
    _, pairs = tree
    path = tmp_path / "pairs.npy"
    build_pair_cache(pairs, 16, 24, path, progress=False)
    with pytest.raises(
        DataError, match="pairs.npy: pair cache is uint8 .* expected uint8 \\(4, 2, 32, 24, 3\\)"
    ):
        load_pair_cache(path, 4, 32, 24)
    with pytest.raises(DataError, match="pairs.npy: pair cache"):
        load_pair_cache(path, 5, 16, 24)
    junk = tmp_path / "junk.npy"
    junk.write_bytes(b"not numpy")
    with pytest.raises(DataError, match=r"junk.npy: not a readable .npy array .*; re-run the cache stage"):
        load_pair_cache(junk, 4, 16, 24)


def test_views_of_different_sizes_name_both_files(tree) -> None:
    _, pairs = tree
    write_png(pairs[1][1], _rgb(31, 50, 0))
    with pytest.raises(
        DataError, match=r"0000000001.png is \(30, 50\) but its right image .*0000000001.png is \(31, 50\)"
    ):
        StereoPairs(pairs, 16, 24)[1]


def test_crops_are_one_window_of_both_views_at_the_source_scale(tree, tmp_path: Path) -> None:
    """train.crop_scale 2: the cache holds the pairs at twice the size, a sample is a 16 x 24
    window of it at the same place in both views, drawn per (seed, epoch, index), and the
    augmentation's own draws are those of the uncropped sample."""
    from msdepth.data.pairs import crop_origin, sample_generator, to_tensor

    _, pairs = tree
    path = tmp_path / "cache" / "pairs2.npy"
    build_pair_cache(pairs, 32, 48, path, progress=False)
    cache = load_pair_cache(path, len(pairs), 32, 48)
    plain = StereoPairs(pairs, 16, 24, seed=3, crop_scale=2)
    cached = StereoPairs(pairs, 16, 24, seed=3, cache=cache, crop_scale=2)
    origins = set()
    for i in range(len(pairs)):
        top, left = crop_origin((32, 48), (16, 24), 3, 0, i)
        origins.add((top, left))
        window = np.s_[top : top + 16, left : left + 24]
        for view, key in enumerate(("left", "right")):
            expected = to_tensor(cache[i, view][window])
            assert torch.equal(cached[i][key], expected) and torch.equal(plain[i][key], expected)
    assert len(origins) > 1  # not one fixed window
    assert 0 <= min(o[0] for o in origins) and max(o[0] for o in origins) <= 16
    cached.set_epoch(1)
    assert any(
        crop_origin((32, 48), (16, 24), 3, 1, i) != crop_origin((32, 48), (16, 24), 3, 0, i) for i in range(4)
    )
    jittered = StereoPairs(pairs, 16, 24, augment=True, seed=3, cache=cache, crop_scale=2)
    top, left = crop_origin((32, 48), (16, 24), 3, 0, 2)
    crop = [to_tensor(cache[2, v][top : top + 16, left : left + 24]) for v in (0, 1)]
    expected = augment(*crop, sample_generator(3, 0, 2))
    assert torch.equal(jittered[2]["left"], expected[0]) and torch.equal(jittered[2]["right"], expected[1])


def test_a_crop_cache_of_the_wrong_size_is_refused(tree, tmp_path: Path) -> None:
    _, pairs = tree
    cache = np.zeros((len(pairs), 2, 16, 24, 3), dtype=np.uint8)  # the crop's size, not 2x it
    with pytest.raises(DataError, match="at 32x48"):
        StereoPairs(pairs, 16, 24, cache=cache, crop_scale=2)
