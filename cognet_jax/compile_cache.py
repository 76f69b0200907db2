"""JAX's persistent compilation cache for the ``cognet-jax`` commands: where it lives, its size
bound, a folder made usable again, and its warnings as one line (docs/reference.md, "Compiled
programs are kept")."""

from __future__ import annotations

import hashlib
import importlib
import importlib.util
import logging
import os
import re
import shutil
import sys
from collections import deque
from collections.abc import Callable
from pathlib import Path
from typing import TypeVar

T = TypeVar("T")

#: the environment variable naming the compilation cache folder ("off" turns it off)
CACHE_VARIABLE = "COGNET_JAX_CACHE"


#: the cache may hold this many bytes; JAX evicts the least recently used programs above it
#: (with the ``filelock`` package, which torch brings; without it the folder is not bounded)
CACHE_MAX_BYTES = 2 * 10**9
#: an entry of either cache larger than this is removed unread (a cache reads an entry whole,
#: several copies at once): the programs this library keeps are far smaller, since arrays
#: larger than ``compiled.CONSTANT_BYTES`` are arguments, never constants of a program
ENTRY_MAX_BYTES = CACHE_MAX_BYTES // 4


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
    try:  # a link to nothing, a path under a file, a folder it may not write: said here
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        reason = "a link to nothing" if folder.is_symlink() else err.strerror or type(err).__name__
        cache_note(f"{CACHE_VARIABLE}={folder}: cannot be made ({reason}); programs are not kept")
        return
    foreign = foreign_files(folder)
    if foreign:  # JAX's eviction and the repair below would remove or rewrite them
        cache_note(
            f"{CACHE_VARIABLE}={folder}: holds files that are not compiled programs "
            f"({', '.join(foreign[:3])}); compiled programs are not kept there"
        )
        return
    if not _seal_entries(folder):
        return
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    _watch_lookups()
    _one_cache_warning(folder)
    if importlib.util.find_spec("filelock") is not None:  # JAX's eviction needs it
        repair_cache_folder(folder)
        jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)


#: the name of an entry of JAX's compilation cache: ``<program name>-<sha256 hex>-cache`` and
#: its access time ``...-atime``
ENTRY_NAME = re.compile(r"^.+-[0-9a-f]{64}-(cache|atime)$")
#: other names JAX keeps in the folder (its eviction's lock)
JAX_FILES = (".lockfile",)


def foreign_files(folder: Path) -> list[str]:
    """The names in ``folder`` that JAX's compilation cache did not write: other names, and
    folders under an entry's name (a run folder, say); sorted, ``[]`` for a folder that does
    not exist or cannot be read."""
    try:
        paths = list(folder.iterdir())
    except OSError:
        return []
    return sorted(
        p.name
        for p in paths
        if p.name not in JAX_FILES and (not ENTRY_NAME.match(p.name) or p.is_dir())
    )


#: the end of every entry this package writes: a tag and the SHA-256 of the entry's key and
#: bytes (``_SealedCache``)
SEAL_TAG = b"cognet-jax-seal-1"
SEAL_BYTES = len(SEAL_TAG) + 32


def _seal(key: str, body: bytes) -> bytes:
    return SEAL_TAG + hashlib.sha256(key.encode() + b"\0" + body).digest()


class _SealedCache:
    """JAX's compilation cache with every entry sealed to its key: ``put`` appends
    ``_seal(key, bytes)``, ``get`` returns an entry only when its seal matches, and removes it
    otherwise (damaged, swapped with another program's, or written without a seal), so JAX
    compiles afresh: an entry that loads under the wrong key would run another program (XLA
    aborts the process on a sharding mismatch, past any error handling)."""

    def __init__(self, base, folder: Path):
        self._base, self._folder = base, folder

    def __getattr__(self, name):
        return getattr(self._base, name)

    def get(self, key: str):
        value = self._base.get(key)
        if value is None:
            return None
        body, seal = value[:-SEAL_BYTES], value[-SEAL_BYTES:]
        if len(value) >= SEAL_BYTES and seal == _seal(key, body):
            return body
        _remove_entry(self._folder, key)
        cache_note(
            f"compilation cache {self._folder}: an entry that does not match its program "
            "(damaged, swapped or written by another version) is removed and compiled afresh"
        )
        return None

    def put(self, key: str, value: bytes) -> None:
        self._base.put(key, value + _seal(key, value))


def _seal_entries(folder: Path) -> bool:
    """Make JAX's compilation cache of ``folder`` a ``_SealedCache`` (when it is built, at the
    first compile); ``False`` (with one note: programs are then not kept) when this JAX has no
    hook for it."""
    try:
        from jax._src import compilation_cache as jax_cache

        make = jax_cache.get_file_cache
    except (ImportError, AttributeError):
        cache_note(f"compilation cache {folder}: this JAX cannot seal its entries; not kept")
        return False
    if getattr(make, "sealed", False):
        return True

    def sealed(path: str):
        made = make(path)
        return None if made is None else (_SealedCache(made[0], Path(path)), made[1])

    sealed.sealed = True
    jax_cache.get_file_cache = sealed
    return True


def repair_cache_folder(folder: Path) -> None:
    """Make ``folder`` one JAX's size-bounded cache can use: every ``NAME-cache`` entry gets the
    ``NAME-atime`` file JAX's eviction reads (time 0: evicted first), and access-time files
    without an entry are removed, as are entries that are not regular files or are larger than
    ``ENTRY_MAX_BYTES``. A folder filled by runs without the bound lacks them, and JAX then
    warns at every write and never stores a new entry."""
    try:
        names = {p.name for p in folder.iterdir()}
    except OSError:  # not there yet, or unreadable: JAX reports what it cannot do
        return
    names = {n for n in names if ENTRY_NAME.match(n)}  # never a file of anyone else
    for name in sorted(names):  # an entry that is not a regular file is unusable: removed
        path = folder / name
        if path.is_file() and not path.is_symlink() and _size(path) > ENTRY_MAX_BYTES:
            path.unlink(missing_ok=True)
            cache_note(f"compilation cache {folder}: {name[:24]}... is removed unread (too large)")
        if not path.is_file():
            if not path.is_dir():  # a folder is someone's (the cache is then not used)
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


def _size(path: Path) -> int:
    try:
        return path.stat().st_size
    except OSError:
        return 0


def _one_cache_warning(folder: Path) -> None:
    """JAX's warnings about its compilation cache (an entry it cannot read or write) become
    one line per process: the first, shortened; the program is compiled all the same."""
    import warnings

    shown = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        text = " ".join(str(message).split())
        if "compilation cache" not in text:
            return shown(message, category, filename, lineno, file, line)
        if "Error reading" in text and _LOOKED_UP:  # the entry just read: compiled afresh,
            _remove_entry(folder, _LOOKED_UP[-1])  # and JAX writes the new one in its place
            text += " (the entry is removed)"
        cache_note(f"compilation cache {folder}: {text[:160]}")

    warnings.showwarning = show
    # every unreadable entry reaches ``show`` (and is removed), not only a line's first
    warnings.filterwarnings("always", message="Error reading persistent compilation cache")


#: the first note about a cache of this process (``cache_note``)
_CACHE_TOLD: list[str] = []


def cache_note(text: str) -> None:
    """One ``note:`` line on stderr per process about the caches (JAX's compilation cache
    warning, or an unusable kept program removed by ``traced``): the first; later ones are
    dropped, so a run says at most one line about its caches."""
    if not _CACHE_TOLD:
        _CACHE_TOLD.append(text)
        print(f"note: {text}", file=sys.stderr)


#: the compilation cache's keys JAX looked up last in this process, in order, and how many it
#: looked up in all (``_watch_lookups``)
_LOOKED_UP: deque[str] = deque(maxlen=256)
_LOOKUPS = [0]
_LOOKUP = re.compile(r"Cache hit for key: '([^']+)'")


def _watch_lookups() -> None:
    """Record every key JAX's compilation cache finds an entry for (its ``lru_cache`` logger's
    debug lines, which go no further than they went before), so an entry that fails is known."""
    logger = logging.getLogger("jax._src.lru_cache")
    shown = logger.getEffectiveLevel()

    def record_key(record: logging.LogRecord) -> bool:
        found = _LOOKUP.match(record.getMessage())
        if found:
            _LOOKED_UP.append(found.group(1))
            _LOOKUPS[0] += 1
        return record.levelno >= shown

    logger.addFilter(record_key)
    logger.setLevel(logging.DEBUG)


def _remove_entry(folder: Path, key: str) -> None:
    """Remove the compilation cache's entry ``key`` (and its access time) from ``folder``."""
    for suffix in ("-cache", "-atime"):
        path = Path(folder) / f"{key}{suffix}"
        try:
            if path.is_dir() and not path.is_symlink():
                shutil.rmtree(path, ignore_errors=True)
            else:
                path.unlink(missing_ok=True)
        except OSError:
            pass


def compiled_despite_cache(compile: Callable[[], T]) -> T:
    """``compile()``; when it fails after JAX looked up entries of its compilation cache (an
    entry swapped with another program's or damaged loads, then fails), those entries are
    removed with one note and it compiles once more: the cache never blocks a program."""
    import jax

    start = _LOOKUPS[0]
    try:
        return compile()
    except Exception as err:
        folder = jax.config.jax_compilation_cache_dir
        count = min(_LOOKUPS[0] - start, len(_LOOKED_UP))
        looked_up = list(_LOOKED_UP)[len(_LOOKED_UP) - count :]
        if not folder or not looked_up:
            raise
        for key in looked_up:
            _remove_entry(Path(folder), key)
        reason = " ".join(str(err).split())[:80] or type(err).__name__
        cache_note(
            f"compilation cache {folder}: an entry that would not run is removed and the "
            f"program compiled afresh ({type(err).__name__}: {reason})"
        )
        return compile()
