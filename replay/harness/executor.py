"""Executor interface for Monte Carlo sweeps: a local process pool by default, Dask distributed optionally.

Every task is a top-level function of picklable arguments that seeds its own numpy Generator, so results do
not depend on where or in which order tasks run: `run_tasks(fn, args, executor)` returns results in the
order of `args` for every executor.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from concurrent.futures import ProcessPoolExecutor
from typing import Any, Callable, Iterable, Sequence


class Executor(ABC):
    """Maps a function over argument tuples; results in input order."""

    name = "executor"

    @abstractmethod
    def map(self, fn: Callable[..., Any], args: Sequence[tuple], progress: str | None = None) -> list: ...

    def close(self) -> None:
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def _progress(it: Iterable, total: int, desc: str | None):
    if desc is None:
        return it
    from tqdm import tqdm

    return tqdm(it, total=total, desc=desc, leave=False)


class LocalExecutor(Executor):
    """Process pool of `workers` processes; workers <= 1 runs in this process (no pickling, easiest to debug)."""

    name = "local"

    def __init__(self, workers: int = 1):
        self.workers = int(workers)
        self._pool = ProcessPoolExecutor(self.workers) if self.workers > 1 else None

    def map(self, fn, args, progress=None):
        args = list(args)
        if self._pool is None:
            return [fn(*a) for a in _progress(args, len(args), progress)]
        futs = [self._pool.submit(fn, *a) for a in args]
        return [f.result() for f in _progress(futs, len(futs), progress)]

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None


class DaskExecutor(Executor):
    """Dask distributed: connect to `address` (a running scheduler) or start a LocalCluster.

    Needs the optional extra `dask` (pip install "dask[distributed]").
    """

    name = "dask"

    def __init__(self, address: str | None = None, n_workers: int = 1, threads_per_worker: int = 1, processes: bool = True):
        try:
            from dask.distributed import Client, LocalCluster
        except ImportError as exc:  # pragma: no cover - exercised only without the extra
            raise ImportError('Dask executor needs the optional extra: pip install "dask[distributed]"') from exc
        self._cluster = None
        if address is None:
            self._cluster = LocalCluster(n_workers=n_workers, threads_per_worker=threads_per_worker, processes=processes,
                                         dashboard_address=None)
            self.client = Client(self._cluster)
        else:
            self.client = Client(address)

    def map(self, fn, args, progress=None):
        args = list(args)
        futs = [self.client.submit(fn, *a, pure=False) for a in args]
        return [f.result() for f in _progress(futs, len(futs), progress)]

    def close(self):
        self.client.close()
        if self._cluster is not None:
            self._cluster.close()


def make_executor(kind: str = "local", workers: int = 1, address: str | None = None) -> Executor:
    """'local' (process pool; 1 worker = in-process) or 'dask' (LocalCluster, or `address` of a scheduler)."""
    if kind == "local":
        return LocalExecutor(workers)
    if kind == "dask":
        return DaskExecutor(address, n_workers=workers)
    raise ValueError(f"unknown executor {kind!r} (use 'local' or 'dask')")


def run_tasks(fn: Callable[..., Any], args: Sequence[tuple], executor: Executor | None = None, progress: str | None = None) -> list:
    if executor is None:
        with LocalExecutor(1) as ex:
            return ex.map(fn, args, progress)
    return executor.map(fn, args, progress)
