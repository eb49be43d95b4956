"""Monte Carlo executor: in-process, local process pool and Dask LocalCluster give identical results."""

import numpy as np
import pytest

from companion.gravity import MatchWindow
from companion.gravity.matchers.li_viterbi import CellMap, ViterbiConfig, ViterbiMatcher
from replay.harness.executor import LocalExecutor, make_executor, run_tasks


def mc_task(seed: int, sigma_z: float) -> np.ndarray:
    """One seeded Monte Carlo draw: a Viterbi match of a noisy window on a random map."""
    rng = np.random.default_rng(seed)
    cmap = CellMap.from_array(np.random.default_rng(0).normal(0, 20, (40, 40)), 500.0)
    T = 5
    true = cmap.centre(np.array([20.0, 20.0])) + np.outer(np.arange(T) * 10.0, [70.0, 40.0])
    z = cmap.value(cmap.cell_of(true)) + rng.normal(0, sigma_z, T)
    ins = true + rng.normal(0, 600.0, 2)
    win = MatchWindow.of(np.arange(T) * 10.0, ins, np.tile([70.0, 40.0], (T, 1)), z)
    res = ViterbiMatcher(None, ViterbiConfig(n=7, o=3, T=T, sigma_z_mgal=max(sigma_z, 0.5), representation_error=False),
                         cell_map=cmap).match(win)
    return res.track_ne_m


ARGS = [(s, sz) for s in range(6) for sz in (0.5, 2.0)]


def test_local_pool_equals_in_process():
    ref = run_tasks(mc_task, ARGS)
    with LocalExecutor(workers=2) as ex:
        pooled = ex.map(mc_task, ARGS)
    assert len(ref) == len(pooled) == len(ARGS)
    for a, b in zip(ref, pooled):
        np.testing.assert_array_equal(a, b)
    assert not all(np.array_equal(ref[0], r) for r in ref[1:])  # the draws differ


def test_dask_local_cluster_equals_local():
    pytest.importorskip("dask.distributed")
    ref = run_tasks(mc_task, ARGS)
    from replay.harness.executor import DaskExecutor

    with DaskExecutor(n_workers=1, processes=False) as ex:
        out = ex.map(mc_task, ARGS)
    for a, b in zip(ref, out):
        np.testing.assert_array_equal(a, b)


def test_unknown_executor_kind():
    with pytest.raises(ValueError):
        make_executor("spark")
