"""Threaded kernels: the same numbers whatever the number of threads and slices."""

import numpy as np

from mapfilter.maps.floorplan import FloorPlan
from mapfilter.maps.walls import crosses_wall
from mapfilter.runtime.threads import for_slices


def _office_like_map():
    wall = np.zeros((200, 300), dtype=bool)
    wall[[0, -1], :] = True
    wall[:, [0, -1]] = True
    wall[100, :] = True
    wall[100, 140:160] = False
    for c in range(50, 300, 50):
        wall[:100, c] = True
    return FloorPlan(wall, 0.1)


def _run_all(n):
    rng = np.random.default_rng(3)
    fp = _office_like_map()
    a = fp.sample_free(n, rng)
    b = a + rng.normal(0, 1.5, a.shape)
    return (crosses_wall(fp, a, b),)


def test_results_do_not_depend_on_the_thread_count(monkeypatch):
    n = 70_001  # odd, several slices per thread, a partial last block
    monkeypatch.setenv("MAPFILTER_THREADS", "1")
    one = _run_all(n)
    monkeypatch.setenv("MAPFILTER_THREADS", "3")
    three = _run_all(n)
    for x, y in zip(one, three):
        np.testing.assert_array_equal(x, y)
    assert one[0].any() and not one[0].all()


def test_for_slices_covers_every_element_once_and_raises_kernel_errors(monkeypatch):
    monkeypatch.setenv("MAPFILTER_THREADS", "4")
    seen = np.zeros(100_003, dtype=np.int64)

    def kernel(lo, hi, out):
        out[lo:hi] += 1

    for_slices(kernel, seen.size, seen, min_per_thread=1000)
    assert (seen == 1).all()

    def failing(lo, hi):
        raise ValueError("boom")

    try:
        for_slices(failing, 10_000, min_per_thread=10)
    except ValueError as exc:
        assert "boom" in str(exc)
    else:
        raise AssertionError("the kernel's error was swallowed")


def test_a_forked_child_gets_its_own_threads(monkeypatch):
    import multiprocessing

    monkeypatch.setenv("MAPFILTER_THREADS", "2")
    _run_all(70_001)  # the parent's pool exists now
    ctx = multiprocessing.get_context("fork")
    with ctx.Pool(1) as pool:
        crossed = pool.apply_async(_run_all, (70_001,)).get(timeout=120)[0]
    np.testing.assert_array_equal(crossed, _run_all(70_001)[0])
