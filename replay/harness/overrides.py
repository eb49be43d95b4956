"""``--set FIELD=VALUE`` for the benchmarks: a frozen settings dataclass with some fields replaced."""

from __future__ import annotations

import dataclasses


def apply_overrides(cfg, overrides: list[str]):
    """``FIELD=VALUE`` strings -> ``cfg`` with those fields replaced (typed like the current value); a nested settings
    field as ``GROUP.FIELD=VALUE`` (e.g. ``motion.select=true``). An unknown field exits naming the known ones."""
    types = {f.name: type(getattr(cfg, f.name)) for f in dataclasses.fields(cfg)}
    kw = {}
    nested: dict[str, list[str]] = {}
    for item in overrides:
        name, sep, val = item.partition("=")
        group, dot, sub = name.partition(".")
        if dot and group in types and dataclasses.is_dataclass(getattr(cfg, group)):
            nested.setdefault(group, []).append(f"{sub}={val}")
            continue
        if not sep or name not in types:
            raise SystemExit(f"--set {item!r}: expected FIELD=VALUE with FIELD one of {sorted(types)}")
        ty = types[name]
        try:
            if ty is bool:
                kw[name] = val.strip().lower() in ("1", "true", "yes", "on")
            elif getattr(cfg, name) is None:  # an optional number left at None
                kw[name] = None if val.strip().lower() == "none" else float(val)
            else:
                kw[name] = ty(val)
        except ValueError:
            raise SystemExit(f"--set {item!r}: {val!r} is not a {ty.__name__ if ty is not type(None) else 'number'}") from None
    for group, items in nested.items():
        kw[group] = apply_overrides(getattr(cfg, group), items)
    return dataclasses.replace(cfg, **kw)
