"""render/view_threads.py: views two at a time in threads give the bits of one after another."""

import threading
import time

import numpy as np
import pytest
import torch

from lghcc.common.scene import GaussianScene
from lghcc.encoder.gaussians.gaussian_views import fit_cameras
from lghcc.encoder.gaussians.rdoq import sensitivities
from lghcc.render import view_threads
from lghcc.render.gaussians3dgs import gaussians_from_scene
from lghcc.render.importance import gaussian_contributions
from lghcc.render.view_threads import map_views


def _scene(n, seed=0):
    rng = np.random.default_rng(seed)
    f = np.float32
    return GaussianScene(rng.uniform(-1, 1, (n, 3)).astype(f), (0.3 * rng.normal(size=(n, 4, 3))).astype(f),
                         rng.normal(1, 1, n).astype(f), np.log(rng.uniform(0.01, 0.08, (n, 3))).astype(f),
                         rng.normal(size=(n, 4)).astype(f))


def test_results_come_in_the_items_order_and_two_run_at_once():
    running, most = [0], [0]
    lock = threading.Lock()

    def fn(x):
        with lock:
            running[0] += 1
            most[0] = max(most[0], running[0])
        time.sleep(0.02 * (5 - x))  # the first items finish last
        with lock:
            running[0] -= 1
        return x * x

    assert list(map_views(fn, range(5), threads=2)) == [0, 1, 4, 9, 16]
    assert most[0] == 2
    assert list(map_views(fn, range(5), threads=1)) == [0, 1, 4, 9, 16]
    assert list(map_views(fn, [], threads=2)) == []


def test_the_threads_run_in_the_callers_grad_mode_and_intra_op_threads():
    before = torch.get_num_threads()
    seen = lambda _: (torch.is_grad_enabled(), torch.get_num_threads(), threading.current_thread().name)  # noqa: E731
    try:
        torch.set_num_threads(1)
        with torch.no_grad():
            got = list(map_views(seen, range(3), threads=2))
        assert [g[:2] for g in got] == [(False, 1)] * 3
        assert all(g[2].startswith("lghcc-view") for g in got)
        torch.set_num_threads(2)
        assert [g[:2] for g in map_views(seen, range(3), threads=2)] == [(True, 2)] * 3
    finally:
        torch.set_num_threads(before)
    assert torch.get_num_threads() == before


def test_views_over_the_memory_budget_go_one_at_a_time():
    name = lambda _: threading.current_thread().name  # noqa: E731
    over = view_threads.VIEW_MEMORY_BUDGET + 1
    assert set(map_views(name, range(3), threads=2, view_bytes=over)) == {threading.current_thread().name}
    assert all(n.startswith("lghcc-view") for n in map_views(name, range(3), threads=2, view_bytes=over - 2))


def test_an_error_in_a_view_reaches_the_caller():
    def fn(x):
        if x == 2:
            raise ValueError("view 2")
        return x

    with pytest.raises(ValueError, match="view 2"):
        list(map_views(fn, range(4), threads=2))


def test_contributions_and_sensitivities_have_the_bits_of_one_view_after_another(monkeypatch):
    """Large enough (40k Gaussians) that torch splits the operations between its threads."""
    scene = _scene(40_000)
    g = gaussians_from_scene(scene)
    cams = fit_cameras(scene, 3, 96)
    small = _scene(300, seed=1)
    small_cams = fit_cameras(small, 3, 24)
    got = {}
    for threads in (1, 2):
        monkeypatch.setattr(view_threads, "VIEW_THREADS", threads)
        got[threads] = (gaussian_contributions(g.means, g.quats, g.scales, g.opacities, cams),
                        sensitivities(small, small_cams, probes=2))
    assert got[1][0].sum() > 0 and got[1][1].sum() > 0
    assert np.array_equal(got[1][0], got[2][0])
    assert np.array_equal(got[1][1], got[2][1])
