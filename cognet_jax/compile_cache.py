"""JAX's persistent compilation cache for the ``cognet-jax`` commands: where it lives, its size
bound, a folder made usable again, and its warnings as one line (docs/reference.md, "Compiled
programs are kept")."""

from __future__ import annotations

import importlib
import importlib.util
import os
import shutil
import sys
from pathlib import Path

#: the environment variable naming the compilation cache folder ("off" turns it off)
CACHE_VARIABLE = "COGNET_JAX_CACHE"


#: the cache may hold this many bytes; JAX evicts the least recently used programs above it
#: (with the ``filelock`` package, which torch brings; without it the folder is not bounded)
CACHE_MAX_BYTES = 2 * 10**9


def compile_cache_dir() -> Path | None:
    """Where the command line keeps compiled programs (JAX's persistent compilation cache):
    ``$COGNET_JAX_CACHE``, else ``$XDG_CACHE_HOME/cognet-jax/xla``, else
    ``~/.cache/cognet-jax/xla``; ``None`` when ``COGNET_JAX_CACHE=off``."""
    chosen = os.environ.get(CACHE_VARIABLE, "")
    if chosen.lower() in ("off", "0", "false", "none"):
        return None
    if chosen:
        return Path(chosen).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache"
    return Path(base) / "cognet-jax" / "xla"


def use_compile_cache(args) -> None:
    """Keep every compiled program in ``compile_cache_dir()`` (unless ``--no-compile-cache``,
    or a cache folder was already chosen, e.g. by ``JAX_COMPILATION_CACHE_DIR``): a repeated run
    loads its programs instead of compiling them. The cache key holds JAX's and XLA's versions
    and the machine's devices, so another version or machine compiles afresh (and adds its own
    entries)."""
    import jax

    folder = None if args.no_compile_cache else compile_cache_dir()
    if folder is None or jax.config.jax_compilation_cache_dir:
        return
    if folder.exists() and not folder.is_dir():
        cache_note(f"{CACHE_VARIABLE}={folder}: not a folder; compiled programs are not kept")
        return
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    _one_cache_warning(folder)
    if importlib.util.find_spec("filelock") is not None:  # JAX's eviction needs it
        repair_cache_folder(folder)
        jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)


def repair_cache_folder(folder: Path) -> None:
    """Make ``folder`` one JAX's size-bounded cache can use: every ``NAME-cache`` entry gets the
    ``NAME-atime`` file JAX's eviction reads (time 0: evicted first), and access-time files
    without an entry are removed, as are entries that are not regular files. A folder filled by
    runs without the bound lacks them, and JAX then warns at every write and never stores a
    new entry."""
    try:
        names = {p.name for p in folder.iterdir()}
    except OSError:  # not there yet, or unreadable: JAX reports what it cannot do
        return
    for name in sorted(names):  # an entry that is not a regular file is unusable: removed
        path = folder / name
        if name.endswith(("-cache", "-atime")) and not path.is_file():
            if path.is_dir():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
            names.discard(name)
    for name in names:
        try:
            if name.endswith("-cache") and name[: -len("-cache")] + "-atime" not in names:
                (folder / (name[: -len("-cache")] + "-atime")).write_bytes(bytes(8))
            elif name.endswith("-atime") and name[: -len("-atime")] + "-cache" not in names:
                (folder / name).unlink()
        except OSError:
            pass


def _one_cache_warning(folder: Path) -> None:
    """JAX's warnings about its compilation cache (an entry it cannot read or write) become
    one line per process: the first, shortened; the program is compiled all the same."""
    import warnings

    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        if "compilation cache" not in text:
            return shown(message, category, filename, lineno, file, line)
        cache_note(f"compilation cache {folder}: {text[:160]}")

    warnings.showwarning = show


#: the first note about a cache of this process (``cache_note``)
_CACHE_TOLD: list[str] = []


def cache_note(text: str) -> None:
    """One ``note:`` line on stderr per process about the caches (JAX's compilation cache
    warning, or an unusable kept program removed by ``traced``): the first; later ones are
    dropped, so a run says at most one line about its caches."""
    if not _CACHE_TOLD:
        _CACHE_TOLD.append(text)
        print(f"note: {text}", file=sys.stderr)
