"""Files written whole or not at all: a failed write (full disk, file size limit, a folder in
the way) leaves the previous file in place and names the path. No JAX import, so light modules
(plots) use it too."""

from __future__ import annotations

import contextlib
import json
import math
import os
from pathlib import Path


def atomic_write_bytes(path: str | Path, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically (temp file, fsync, ``os.replace``, fsync dir). A
    failed write (full disk, file size limit, a folder in the way) leaves ``path`` as it was,
    removes the temporary file and raises ``OSError`` naming ``path``."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except OSError as err:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise OSError(err.errno, f"cannot write {path}: {err.strerror or err}") from None
    try:
        fd = os.open(path.parent, os.O_RDONLY)
    except OSError:  # pragma: no cover - platforms without directory fds
        return
    try:
        os.fsync(fd)
    except OSError:  # pragma: no cover
        pass
    finally:
        os.close(fd)


def atomic_write_text(path: str | Path, text: str) -> None:
    atomic_write_bytes(path, text.encode())


def plain(value):
    """``value`` as strict JSON can write it: NumPy / JAX scalars and arrays as Python numbers
    and lists (a plug-in simulator's ``numpy.int64`` horizon lands in results.json), tuples as
    lists, and NaN / infinities as ``null`` (``NaN`` is no JSON: jq and browsers refuse the
    file). Other objects are left for ``json.dumps`` to refuse."""
    if isinstance(value, dict):
        return {k: plain(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [plain(v) for v in value]
    if isinstance(value, bool | int | str) or value is None:
        return value
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if callable(getattr(value, "tolist", None)):  # numpy / jax scalars and arrays
        return plain(value.tolist())
    return value


def json_text(value, indent: int | None = None) -> str:
    """Strict JSON of ``plain(value)``: what every results file of a run is written with."""
    return json.dumps(plain(value), indent=indent, allow_nan=False)


def atomic_write_json(path: str | Path, value, indent: int | None = 1) -> None:
    atomic_write_text(path, json_text(value, indent))
