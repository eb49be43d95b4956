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
