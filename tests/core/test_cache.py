"""The content-addressed array cache: keys follow content, entries round-trip, damage misses."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from realitygap.core.cache import CACHE_DIR_ENV, CACHE_ENV, ArrayCache, content_key, default_cache


def test_content_key_is_equal_for_equal_content_and_differs_for_any_change() -> None:
    a = np.arange(6.0).reshape(2, 3)
    base = content_key(a, {"r": 0.035, "b": 0.23}, "cmd")
    assert base == content_key(a.copy(), {"b": 0.23, "r": 0.035}, "cmd")  # key order irrelevant
    changed = a.copy()
    changed[1, 2] += 1e-12
    others = {
        content_key(changed, {"r": 0.035, "b": 0.23}, "cmd"),
        content_key(a, {"r": 0.0350001, "b": 0.23}, "cmd"),
        content_key(a, {"r": 0.035, "b": 0.23}, "ticks"),
        content_key(a.reshape(3, 2), {"r": 0.035, "b": 0.23}, "cmd"),  # same bytes, other shape
        content_key(a.astype(np.float32), {"r": 0.035, "b": 0.23}, "cmd"),
    }
    assert base not in others and len(others) == 5


def test_content_key_refuses_objects_it_cannot_hash_stably() -> None:
    with pytest.raises(TypeError, match="cannot hash"):
        content_key({"x": object()})


def test_put_then_get_round_trips_the_arrays(tmp_path) -> None:
    cache = ArrayCache(tmp_path)
    key = content_key("k")
    arrays = {"poses": np.random.default_rng(0).normal(size=(5, 3)), "ids": np.arange(4)}
    assert cache.get("replay", key) is None
    cache.put("replay", key, arrays)
    got = cache.get("replay", key)
    assert got is not None and set(got) == set(arrays)
    for name in arrays:
        np.testing.assert_array_equal(got[name], arrays[name])
        assert got[name].dtype == arrays[name].dtype
    assert not list(tmp_path.rglob("*.tmp"))  # written atomically, nothing left behind


def test_a_damaged_entry_is_a_miss_not_an_error(tmp_path) -> None:
    cache = ArrayCache(tmp_path)
    key = content_key("damaged")
    cache.put("replay", key, {"a": np.ones(3)})
    path = tmp_path / "replay" / f"{key}.npz"
    path.write_bytes(path.read_bytes()[:20])
    assert cache.get("replay", key) is None


def test_object_arrays_and_bad_names_are_refused(tmp_path) -> None:
    cache = ArrayCache(tmp_path)
    with pytest.raises(TypeError, match="dtype object"):
        cache.put("replay", content_key(1), {"a": np.array([object()])})
    with pytest.raises(ValueError, match="hex key"):
        cache.get("replay", "../../etc/passwd")
    with pytest.raises(ValueError, match="limit_bytes"):
        ArrayCache(tmp_path, limit_bytes=0)


def test_prune_removes_the_entries_used_longest_ago(tmp_path) -> None:
    one = np.zeros(1000)  # ~8 kB each
    cache = ArrayCache(tmp_path, limit_bytes=10**9)
    keys = [content_key(i) for i in range(4)]
    for i, k in enumerate(keys):
        cache.put("replay", k, {"a": one})
        old = time.time() - 100 + i  # the first written is the oldest
        os.utime(tmp_path / "replay" / f"{k}.npz", (old, old))
    cache.get("replay", keys[0])  # used now: kept
    size = (tmp_path / "replay" / f"{keys[0]}.npz").stat().st_size
    cache.limit_bytes = int(2.5 * size)
    cache.prune()
    left = {p.stem for p in (tmp_path / "replay").glob("*.npz")}
    assert left == {keys[0], keys[3]}


def test_default_cache_follows_the_environment(monkeypatch, tmp_path) -> None:
    monkeypatch.setenv(CACHE_DIR_ENV, str(tmp_path))
    monkeypatch.delenv(CACHE_ENV, raising=False)
    cache = default_cache()
    assert cache is not None and cache.directory == tmp_path
    monkeypatch.setenv(CACHE_ENV, "0")
    assert default_cache() is None
