"""Small helpers shared by tests (fixtures and shared-data paths are in tests/conftest.py)."""

from __future__ import annotations


class Collect:
    """A pipeline sink keeping everything written, in order."""

    def __init__(self) -> None:
        self.items: list = []

    def write(self, item, topic=None) -> None:
        self.items.append(item)

    def write_location(self, *a, **k) -> None:
        pass


def subclasses(cls) -> set[type]:
    """Every subclass of a class, at any depth."""
    out: set[type] = set()
    for sub in cls.__subclasses__():
        out |= {sub} | subclasses(sub)
    return out


def bumpy_map(seed: int, half_m: float, cell_m: float, n_bumps: int, width_m: tuple[float, float]):
    """A local metric gravity map (north/east axes -half..half) of Gaussian bumps of 20 mGal (1-sigma amplitude)."""
    import numpy as np

    from companion.gravity import GravityMap, LocalGravityMap

    rng = np.random.default_rng(seed)
    ax = np.arange(-half_m, half_m + 1, cell_m)
    N, E = np.meshgrid(ax, ax, indexing="ij")
    g = np.zeros_like(N)
    for _ in range(n_bumps):
        c = rng.uniform(-half_m, half_m, 2)
        w = rng.uniform(*width_m)
        g += rng.normal(0, 20) * np.exp(-((N - c[0]) ** 2 + (E - c[1]) ** 2) / (2 * w * w))
    return LocalGravityMap(GravityMap(g, ax, ax, "local_m"))
