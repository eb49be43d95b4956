"""The files a command reads and writes, checked at start, before anything is opened or created.

An input is a regular file of a sane size: a device (``/dev/zero``, ``/dev/urandom``) would be read until memory runs
out, a FIFO without a writer blocks the process forever, a directory is no file. No output may be any input of the
run (the same path, or the same file by another name): the signing key, the config, the log or the map would be
overwritten. A path with a NUL byte names no file. Each check returns the one-line reason, or "".
"""

from __future__ import annotations

import os
import stat
from collections.abc import Iterable
from pathlib import Path

#: a settings file or a signing key larger than this is not one (the annotated example config is 6 KB, a key 64 B)
MAX_CONFIG_BYTES = 1 << 20
MAX_KEY_BYTES = 4096


def input_problem(path: str | os.PathLike, what: str, max_bytes: int | None = None) -> str:
    """Why ``path`` cannot be read as ``what`` ("" when it can, or is missing: its reader says so): not a regular
    file, too large, a NUL byte in its name."""
    text = os.fspath(path)
    if "\0" in text:
        return f"{what} {text!r} contains a NUL byte"
    try:
        st = os.stat(text)
    except FileNotFoundError:
        return ""  # (the reader says so in its own words)
    except OSError as err:
        return f"{what} {text}: {err.strerror or err}"
    if not stat.S_ISREG(st.st_mode):
        kind = ("a directory" if stat.S_ISDIR(st.st_mode) else "a FIFO" if stat.S_ISFIFO(st.st_mode)
                else "a device" if stat.S_ISCHR(st.st_mode) or stat.S_ISBLK(st.st_mode) else "not a file")
        return f"{what} {text} is {kind}, not a regular file"
    if max_bytes is not None and st.st_size > max_bytes:
        return f"{what} {text} is {st.st_size} bytes: more than a {what} can be ({max_bytes} at most)"
    return ""


def output_problem(out: str | os.PathLike, inputs: Iterable[tuple[str, str | os.PathLike | None]]) -> str:
    """Why ``out`` cannot be written ("" when it can): a NUL byte, or it is one of ``inputs`` ((what, path), ...)."""
    text = os.fspath(out)
    if "\0" in text:
        return f"output {text!r} contains a NUL byte"
    o = Path(text)
    for what, src in inputs:
        if not src or "\0" in os.fspath(src):
            continue
        s = Path(src)
        same = o.resolve() == s.resolve()
        if not same and o.exists() and s.exists():
            same = os.path.samefile(o, s)
        if same:
            return f"the output {o} is the {what} {s}: refusing to overwrite it"
    return ""
