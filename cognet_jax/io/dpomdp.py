"""Parser for MADP ``.dpomdp`` files (SPEC section 7.3) into a dense :class:`TabularModel`.

Format summary
--------------
Header, in this order and each exactly once::

    agents: 2                      (a count or a list of names)
    discount: 1
    values: reward                 (or cost: every reward is negated)
    states: tiger-left tiger-right (a count or a list of names)
    start: ...                     (see below)
    actions:                       (then one line per agent: a count or names)
    observations:                  (likewise)

``start`` forms: ``start: uniform``; ``start: s`` (one state, name or index); ``start: p1 .. pS``;
``start include: s ...`` (uniform over the listed states); ``start exclude: s ...`` (uniform over
the others). A ``start:`` (or ``agents:``, ``states:``, ``start include:`` ...) line with nothing
after the colon takes its value from the next line, as in the MADP example files.

Then ``T``, ``O`` and ``R`` lines in any order::

    T: ja : s : s' : p        T: ja : s :  + a row of |S| numbers or 'uniform'
                              T: ja :      + 'uniform', 'identity' or |S| rows of |S| numbers
    O: ja : s' : jo : p       O: ja : s' : + a row of |JO| numbers or 'uniform'
                              O: ja :      + 'uniform' or |S| rows of |JO| numbers
    R: ja : s : s' : jo : r   R: ja : s : s' : + a row of |JO| numbers
                              R: ja : s :      + |S| rows of |JO| numbers

A state is ``*``, a name, or an index. A joint action / observation is ``*``, a single integer
(the *joint index*, last agent fastest: ``ja = sum_i a_i prod_{j>i} |A_j|``), or one token per
agent (name, index or ``*``). Names match ``[A-Za-z][A-Za-z0-9_-]*``; a number in an index
position is always an index. ``#`` starts a comment. Later lines overwrite earlier ones. A
trailing ``:`` on the row / matrix header lines may be left out (``T: ja`` + ``identity``, as
the MADP example file documents it).

Rewards reduce to ``R(s, ja)`` exactly as MADP does it: a line whose ``s'`` and ``jo`` are both
the single token ``*`` *sets* ``R(s, ja)``; a line naming ``s'`` (with ``jo`` = ``*``) *adds*
``T(s, ja, s') * r``; a line naming ``jo`` (or using the row / matrix forms) adds
``T(s, ja, s') * O(ja, s', jo) * r`` for every matching ``s'`` and ``jo`` (a ``*`` ``s'`` then
means "every s'", and a per-agent ``* *`` joint observation counts as naming every ``jo``).

Choices made here (where the format or MADP leaves room)
--------------------------------------------------------
* **Unspecified rows.** ``T`` and ``O`` start as all zeros (as in MADP) and every row
  ``T(.|s, ja)`` and ``O(.|ja, s')`` must sum to 1 within ``1e-9`` once the whole file is read;
  this is MADP's own ``SanityCheck``, which rejects a never-written row (it sums to 0). A row
  never written gives ``"T(.|s=..., ja=...) never specified"`` (no line to point to); a row
  that sums to something else names the last line that wrote into it. Single entries outside
  ``[0, 1]`` are rejected on their line.
* **Rewards computed from T and O** use the values of T and O *at that line*, as MADP does. To
  make that safe, the rows involved must already be complete (sum to 1) at that line, and may
  not be changed by a later line; both are reported as errors on the offending line.
* ``start: k`` with a single integer ``k`` is the state with index ``k`` (never a probability
  vector, even when |S| = 1: write ``start: 1.0`` for that). A start vector must be
  non-negative and sum to 1 within ``1e-6``; it is then renormalised exactly.
* ``discount`` must lie in ``[0, 1]``; the ``discount`` argument of :func:`parse_dpomdp`
  overrides the file's value.
* Counts given as numbers name the items ``"0"``, ``"1"``, ...
* Models whose ``T`` or ``O`` array would exceed :data:`MAX_ENTRIES` entries, or with more than
  :data:`MAX_COUNT` agents, states, actions or observations, are rejected (a parse error
  rather than an out-of-memory crash on a corrupted count).
* **Errors where MADP's rules would silently decide** (a model nobody meant): a file with no
  ``R`` line (every reward 0, so every controller is worth 0), and a file whose last line has no
  newline and leaves some rewards unwritten (a reward section cut short). Rewards a complete
  file leaves unwritten are 0, as in MADP: many files write only the non-zero ones.
* ``.pgmx`` (factored) and ``.toi-dpomdp`` (transition-observation independent) models are
  other formats: they are refused with a message saying so.
* A missing file raises the usual ``FileNotFoundError``; everything wrong *inside* the text
  raises :class:`DpomdpParseError` (a ``ValueError``) naming the file and line.

Performance: the text is tokenised once; every line becomes a few dictionary look-ups (cached
per distinct joint action / state token) and one vectorised numpy assignment, so files of
hundreds of states and several hundred KB parse in well under a second or two.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
import re
import time
import zlib
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from cognet_jax import status
from cognet_jax.errors import InputError

__all__ = [
    "MAX_COUNT",
    "MAX_ENTRIES",
    "PROB_TOL",
    "DpomdpParseError",
    "TabularModel",
    "load_dpomdp",
    "parse_dpomdp",
]

#: Rows of T and O must sum to 1 within this tolerance.
PROB_TOL = 1e-9
#: Tolerance on the sum of a start vector (renormalised afterwards).
START_TOL = 1e-6
#: Largest accepted number of entries of T (|S| |JA| |S|) or O (|JA| |S| |JO|).
MAX_ENTRIES = 2**27
#: A ``T`` with more entries than this is stored in float32 (half the memory: a 2025-state,
#: 16-joint-action model takes 262 MB instead of 525 MB). Its rows are still summed in float64;
#: the tolerance grows by float32's rounding, at most ``2**-24`` summed over a row of
#: probabilities that add up to 1.
FLOAT64_T_ENTRIES = 2**25
#: Largest accepted count of agents, states, actions or observations.
MAX_COUNT = 2**16

_HEADER = ("agents", "discount", "values", "states", "start", "actions", "observations")
_NUM_RE = re.compile(r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?")
_ROW_RE = re.compile(
    r"[+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?(?: [+-]?(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)*"
)
_INT_RE = re.compile(r"\d+")
_ID_RE = re.compile(r"[A-Za-z][A-Za-z0-9_\-]*")


class DpomdpParseError(InputError):
    """A ``.dpomdp`` text is malformed. ``str()`` reads ``"file:line: what is wrong"``.

    Attributes: ``path`` (the file name, or ``"<string>"``), ``line`` (1-based, or ``None`` when
    the problem concerns the whole file) and ``message``.
    """

    def __init__(self, path: str, line: int | None, message: str):
        self.path = path
        self.line = line
        self.message = message
        where = f"{path}:{line}" if line is not None else f"{path}"
        super().__init__(f"{where}: {message}")


#: Model formats of the MADP toolbox this parser does not read (suffix -> what it is).
UNSUPPORTED_FORMATS = {
    ".pgmx": "a factored model (.pgmx)",
    ".toi-dpomdp": "a transition-observation independent model (.toi-dpomdp)",
}


@dataclasses.dataclass(frozen=True, eq=False)
class TabularModel:
    """A finite Dec-POMDP as dense arrays (compared and hashed by identity).

    ``transition[s, ja, s']`` = T(s'|s, ja); ``observation[ja, s', jo]`` = O(jo|ja, s');
    ``reward[s, ja]`` = R(s, ja) (already negated for ``values: cost``); ``initial_belief[s]``.
    Joint indices put the last agent fastest (SPEC 7.3). Arrays are float64 and read-only,
    except ``transition`` of a model with more than ``FLOAT64_T_ENTRIES`` entries (float32).
    """

    agent_names: tuple[str, ...]
    state_names: tuple[str, ...]
    action_names: tuple[tuple[str, ...], ...]
    observation_names: tuple[tuple[str, ...], ...]
    discount: float
    transition: np.ndarray
    observation: np.ndarray
    reward: np.ndarray
    initial_belief: np.ndarray
    source: str = "<string>"

    @property
    def num_agents(self) -> int:
        return len(self.agent_names)

    @property
    def num_states(self) -> int:
        return len(self.state_names)

    @property
    def action_counts(self) -> tuple[int, ...]:
        return tuple(len(a) for a in self.action_names)

    @property
    def obs_counts(self) -> tuple[int, ...]:
        return tuple(len(o) for o in self.observation_names)

    @property
    def num_joint_actions(self) -> int:
        return int(np.prod(self.action_counts))

    @property
    def num_joint_obs(self) -> int:
        return int(np.prod(self.obs_counts))

    def joint_action_index(self, actions_per_agent: Sequence[int | str]):
        """Joint action index of one action per agent (indices or names; last agent fastest).
        Integer arrays of shape ``[agents, ...]`` give an array of joint indices."""
        idx = [
            self.action_names[i].index(a) if isinstance(a, str) else a
            for i, a in enumerate(actions_per_agent)
        ]
        out = np.ravel_multi_index(tuple(np.asarray(a) for a in idx), self.action_counts)
        return int(out) if np.ndim(out) == 0 else out

    def joint_obs_index(self, obs_per_agent: Sequence[int | str]):
        """Joint observation index of one observation per agent (last agent fastest)."""
        idx = [
            self.observation_names[i].index(o) if isinstance(o, str) else o
            for i, o in enumerate(obs_per_agent)
        ]
        out = np.ravel_multi_index(tuple(np.asarray(o) for o in idx), self.obs_counts)
        return int(out) if np.ndim(out) == 0 else out

    def split_joint_action(self, ja) -> tuple:
        """Per-agent action indices of joint action ``ja`` (int or integer array)."""
        parts = np.unravel_index(ja, self.action_counts)
        return tuple(int(p) if np.ndim(p) == 0 else p for p in parts)

    def split_joint_obs(self, jo) -> tuple:
        """Per-agent observation indices of joint observation ``jo`` (int or integer array)."""
        parts = np.unravel_index(jo, self.obs_counts)
        return tuple(int(p) if np.ndim(p) == 0 else p for p in parts)

    def joint_action_name(self, ja: int) -> str:
        parts = self.split_joint_action(ja)
        return " ".join(self.action_names[i][a] for i, a in enumerate(parts))

    def joint_obs_name(self, jo: int) -> str:
        parts = self.split_joint_obs(jo)
        return " ".join(self.observation_names[i][o] for i, o in enumerate(parts))

    def with_discount(self, discount: float) -> TabularModel:
        """The same model with another discount."""
        return dataclasses.replace(self, discount=_check_discount(discount))


def _check_discount(discount: float) -> float:
    d = float(discount)
    if not (0.0 <= d <= 1.0):
        raise ValueError(f"discount must lie in [0, 1], got {discount!r}")
    return d


# --------------------------------------------------------------------------------------------
# Reading and tokenising


def _read_source(path_or_text, name: str | None) -> tuple[str, str]:
    """Return ``(text, label)`` for a path (``.gz`` allowed), a text, or raw bytes."""
    if isinstance(path_or_text, bytes | bytearray):
        label = name or "<bytes>"
        return _decode(bytes(path_or_text), label), label
    if isinstance(path_or_text, str) and ("\n" in path_or_text or "\r" in path_or_text):
        return path_or_text, name or "<string>"
    if not isinstance(path_or_text, str | os.PathLike):
        raise TypeError(f"expected a path, a text or bytes, got {type(path_or_text).__name__}")
    path = Path(path_or_text)
    label = name or str(path_or_text)
    for suffix, what in UNSUPPORTED_FORMATS.items():
        if suffix in path.name:
            raise DpomdpParseError(
                label, None, f"{what} is not supported: only .dpomdp files (or .dpomdp.gz) are"
            )
    if path.exists() and not path.is_file():  # a folder, a FIFO, a device: never read
        raise DpomdpParseError(label, None, "not a regular file")
    _check_size_and_head(path, label)
    data = path.read_bytes()
    return _decode(data, label), label


#: the largest model file read: its tokens take about 20 bytes of memory per byte of text
MAX_FILE_BYTES = 2**30


def _check_size_and_head(path: Path, label: str) -> None:
    """Refuse, before reading it whole, a file over ``MAX_FILE_BYTES`` or one whose first
    64 KiB hold NUL bytes (binary data, e.g. a sparse or corrupt file; a gzip file is read)."""
    try:
        size = path.stat().st_size
        with path.open("rb") as f:
            head = f.read(65536)
    except OSError:
        return  # missing or unreadable: ``read_bytes`` says so
    if head[:2] != b"\x1f\x8b" and b"\x00" in head:
        line = head[: head.index(b"\x00")].count(b"\n") + 1
        raise DpomdpParseError(label, line, "a NUL byte: binary data, not a .dpomdp text")
    if size > MAX_FILE_BYTES:
        raise DpomdpParseError(
            label,
            None,
            f"{size / 2**30:.1f} GiB, over the {MAX_FILE_BYTES / 2**30:.0f} GiB a model file may "
            "have (its tokens take about 20 bytes of memory per byte of text)",
        )


def _decode(data: bytes, label: str) -> str:
    if data[:2] == b"\x1f\x8b":
        try:
            data = _gunzip(data, label)
        except (OSError, EOFError, zlib.error) as exc:
            raise DpomdpParseError(label, None, f"cannot decompress gzip data: {exc}") from exc
    # A byte-order mark (Notepad) is no token; undecodable bytes become U+FFFD: harmless in
    # comments, an invalid token elsewhere.
    return data.decode("utf-8-sig", errors="replace")


def _gunzip(data: bytes, label: str) -> bytes:
    """The gzip ``data`` decompressed (every member), refused once the text passes
    ``MAX_FILE_BYTES``: a few megabytes of gzip can hold gigabytes of text, which would be
    read whole before any check."""
    parts, total = [], 0
    while data:
        member = zlib.decompressobj(wbits=31)
        chunk = data
        while chunk and not member.eof:
            piece = member.decompress(chunk, 2**24)
            total += len(piece)
            if total > MAX_FILE_BYTES:
                raise DpomdpParseError(
                    label,
                    None,
                    f"its gzip data holds over {MAX_FILE_BYTES / 2**30:.0f} GiB of text, more "
                    "than a model file may have (its tokens take about 20 bytes of memory per "
                    "byte of text)",
                )
            parts.append(piece)
            chunk = member.unconsumed_tail
        if not member.eof:
            raise EOFError("the gzip data ends before its end-of-stream marker")
        data = member.unused_data.lstrip(b"\x00")  # the next member (gzip pads with NULs)
    return b"".join(parts)


def model_digest(path: Path) -> str:
    """SHA-256 of the model text ``path`` holds: gzip data decompressed first, so a ``.gz``
    copy of a model is the same model (the bytes of a plain file otherwise)."""
    data = Path(path).read_bytes()
    if data[:2] == b"\x1f\x8b":
        data = _gunzip(data, str(path))
    return hashlib.sha256(data).hexdigest()


#: the line breaks of a .dpomdp file
_LINE_BREAK = re.compile(r"\r\n|\r|\n")


#: a parse longer than this says how far it is (``status.say``), once every
#: ``PROGRESS_EVERY_S``
PROGRESS_AFTER_S, PROGRESS_EVERY_S = 2.0, 1.0
#: lines between two looks at the clock
PROGRESS_LINES = 8192


class _Progress:
    """Status lines of a long parse: ``tick(line, lines, phase)`` says ``"reading FILE:
    phase, line N of M (P%)"`` once ``PROGRESS_AFTER_S`` have passed, at most once every
    ``PROGRESS_EVERY_S``."""

    def __init__(self, label: str):
        self.label = label
        self.start, self.last = time.monotonic(), float("-inf")

    def tick(self, line: int, lines: int, phase: str) -> None:
        now = time.monotonic()
        if now - self.start >= PROGRESS_AFTER_S and now - self.last >= PROGRESS_EVERY_S:
            self.last = now
            share = 100 * line // max(lines, 1)
            status.say(f"reading {self.label}: {phase}, line {line} of {lines} ({share}%)")


def _tokenise(text: str, progress: _Progress | None = None) -> list[tuple[int, list[str]]]:
    """Non-empty logical lines as ``(line number, tokens)``; ``:`` is always its own token.
    Lines end at ``\n``, ``\r\n`` or ``\r`` only (``str.splitlines`` also breaks at
    Unicode separators such as U+2028, which would turn the rest of a comment into a line)."""
    out = []
    raw_lines = _LINE_BREAK.split(text)
    for lineno, raw in enumerate(raw_lines, start=1):
        if progress is not None and lineno % PROGRESS_LINES == 0:
            progress.tick(lineno, len(raw_lines), "splitting")
        cut = raw.find("#")
        if cut >= 0:
            raw = raw[:cut]
        if ":" in raw:
            raw = raw.replace(":", " : ")
        toks = raw.split()
        if toks:
            out.append((lineno, toks))
    return out


def _ix(*sets: np.ndarray) -> tuple:
    """``np.ix_(*sets)``: the block of an array at these index sets (one per leading axis), to
    read or assign. A set ``0, 1, ..., k-1`` (what ``*`` gives) becomes the slice ``0:k``, and
    with at most one set left as indices this is plain numpy indexing that keeps every axis in
    place: the same block, without gathering it through index arrays, so a wildcard line
    over a large model costs little (benchmarks/NOTES.md, "Measurements behind code
    choices")."""
    ranges = [len(x) > 0 and x[0] == 0 and np.array_equal(x, np.arange(len(x))) for x in sets]
    if len(sets) - sum(ranges) > 1:
        return np.ix_(*sets)
    return tuple(slice(0, len(x)) if r else x for x, r in zip(sets, ranges))


def _count(n: int, one: str, many: str) -> str:
    return f"{n} {one if n == 1 else many}"


def _fmt(tok: str) -> str:
    return repr(tok) if len(tok) <= 40 else repr(tok[:37] + "...")


# --------------------------------------------------------------------------------------------
# The parser


class _Parser:
    def __init__(self, text: str, label: str):
        self.label = label
        self.progress = _Progress(label)
        self.lines = _tokenise(text, self.progress)
        self.pos = 0
        self.last_line = text.count("\n") + 1 if text else 1

    # -- errors and line access ---------------------------------------------------------------

    def error(self, line: int | None, msg: str) -> DpomdpParseError:
        return DpomdpParseError(self.label, line, msg)

    def next_line(self, after: int, what: str) -> tuple[int, list[str]]:
        """Consume the next logical line; at end of file, blame line ``after``."""
        if self.pos >= len(self.lines):
            raise self.error(after, f"file ends here; expected {what} on the next line")
        item = self.lines[self.pos]
        self.pos += 1
        self.tick(item[0])
        return item

    def tick(self, line: int) -> None:
        """Every ``PROGRESS_LINES`` consumed lines, the progress of a long parse."""
        if self.pos % PROGRESS_LINES == 0:
            self.progress.tick(line, self.last_line, "reading the entries")

    def rest_or_next(self, lineno: int, rest: list[str], what: str) -> tuple[int, list[str]]:
        if rest:
            return lineno, rest
        return self.next_line(lineno, what)

    # -- scalar tokens ------------------------------------------------------------------------

    def number(self, tok: str, line: int, what: str) -> float:
        if not _NUM_RE.fullmatch(tok):
            raise self.error(line, f"{what}: expected a number, found {_fmt(tok)}")
        val = float(tok)
        if not np.isfinite(val):
            raise self.error(line, f"{what}: number {_fmt(tok)} is out of range")
        return val

    def numbers(self, toks: list[str], line: int, n: int, what: str) -> np.ndarray:
        if len(toks) != n:
            raise self.error(
                line, f"{what}: expected {n} numbers, found {_count(len(toks), 'entry', 'entries')}"
            )
        if not _ROW_RE.fullmatch(" ".join(toks)):
            bad = next(t for t in toks if not _NUM_RE.fullmatch(t))
            raise self.error(line, f"{what}: expected a number, found {_fmt(bad)}")
        row = np.array(toks, dtype=np.float64)
        if not np.all(np.isfinite(row)):
            raise self.error(line, f"{what}: a number is out of range")
        return row

    def probs(self, toks: list[str], line: int, n: int, what: str) -> np.ndarray:
        row = self.numbers(toks, line, n, what)
        if np.any(row < 0.0) or np.any(row > 1.0):
            bad = row[(row < 0.0) | (row > 1.0)][0]
            raise self.error(line, f"{what}: probability {bad:g} is not in [0, 1]")
        return row

    def count_or_names(self, toks: list[str], line: int, what: str) -> tuple[str, ...]:
        if len(toks) > MAX_COUNT:
            raise self.error(line, f"{what}: more than {MAX_COUNT} names")
        if len(toks) == 1 and _INT_RE.fullmatch(toks[0]):
            n = int(toks[0])
            if n < 1:
                raise self.error(line, f"{what}: the count must be at least 1, got {n}")
            if n > MAX_COUNT:
                raise self.error(line, f"{what}: count {n} is too large (limit {MAX_COUNT})")
            return tuple(str(i) for i in range(n))
        seen = set()
        for t in toks:
            if not _ID_RE.fullmatch(t):
                raise self.error(
                    line,
                    f"{what}: expected a count or names matching [A-Za-z][A-Za-z0-9_-]*, "
                    f"found {_fmt(t)}",
                )
            if t in seen:
                raise self.error(line, f"{what}: name {_fmt(t)} appears twice")
            seen.add(t)
        return tuple(toks)

    # -- header -------------------------------------------------------------------------------

    def header_key(self, toks: list[str]) -> str | None:
        if len(toks) >= 2 and toks[1] == ":":
            return toks[0]
        if len(toks) >= 3 and toks[0] == "start" and toks[2] == ":":
            return "start"
        return None

    def expect_header(self, key: str) -> tuple[int, list[str]]:
        idx = _HEADER.index(key)
        if self.pos >= len(self.lines):
            raise self.error(
                self.last_line,
                f"file ends before '{key}:' (the header is {', '.join(_HEADER)}, in this order)",
            )
        lineno, toks = self.lines[self.pos]
        found = self.header_key(toks)
        if found == key:
            self.pos += 1
            return lineno, toks
        if found in _HEADER:
            if _HEADER.index(found) < idx:
                raise self.error(lineno, f"'{found}:' given twice (or out of order)")
            raise self.error(
                lineno,
                f"missing '{key}:' before '{found}:' (the header is {', '.join(_HEADER)}, "
                "in this order)",
            )
        if found in ("T", "O", "R"):
            raise self.error(lineno, f"missing '{key}:': the header must come before {found} lines")
        raise self.error(lineno, f"expected '{key}:', found {_fmt(toks[0])}")

    def parse_header(self) -> None:
        lineno, toks = self.expect_header("agents")
        line, vals = self.rest_or_next(lineno, toks[2:], "the number of agents or their names")
        self.agent_names = self.count_or_names(vals, line, "agents")
        n = len(self.agent_names)

        lineno, toks = self.expect_header("discount")
        if len(toks) != 3:
            raise self.error(lineno, f"discount: expected one number, found {len(toks) - 2}")
        self.discount = self.number(toks[2], lineno, "discount")
        if not 0.0 <= self.discount <= 1.0:
            raise self.error(lineno, f"discount {self.discount:g} is not in [0, 1]")

        lineno, toks = self.expect_header("values")
        # MADP's own box-pushing file writes the word in double quotes: values: "reward"
        if len(toks) != 3 or toks[2].strip('"') not in ("reward", "cost"):
            raise self.error(lineno, "values: expected 'reward' or 'cost'")
        self.cost = toks[2].strip('"') == "cost"

        lineno, toks = self.expect_header("states")
        line, vals = self.rest_or_next(lineno, toks[2:], "the number of states or their names")
        self.state_names = self.count_or_names(vals, line, "states")
        self.nS = len(self.state_names)
        self.state_index = {name: i for i, name in enumerate(self.state_names)}

        lineno, toks = self.expect_header("start")
        self.initial_belief = self.parse_start(lineno, toks)

        self.action_names = self.per_agent_lists("actions", n)
        self.observation_names = self.per_agent_lists("observations", n)
        self.action_counts = tuple(len(a) for a in self.action_names)
        self.obs_counts = tuple(len(o) for o in self.observation_names)
        self.nJA = int(np.prod(self.action_counts, dtype=object))
        self.nJO = int(np.prod(self.obs_counts, dtype=object))
        t_size = self.nS * self.nJA * self.nS
        o_size = self.nJA * self.nS * self.nJO
        if max(t_size, o_size) > MAX_ENTRIES:
            raise self.error(
                self.obs_header_line,
                f"model too large: T has {t_size} and O {o_size} entries (limit {MAX_ENTRIES})",
            )
        self.action_index = [{nm: i for i, nm in enumerate(a)} for a in self.action_names]
        self.obs_index = [{nm: i for i, nm in enumerate(o)} for o in self.observation_names]

    def per_agent_lists(self, key: str, n: int) -> tuple[tuple[str, ...], ...]:
        lineno, toks = self.expect_header(key)
        self.obs_header_line = lineno
        out = []
        rest = toks[2:]
        if rest:  # first agent's list on the keyword line
            out.append(self.count_or_names(rest, lineno, f"{key} of agent 0"))
        line = lineno
        while len(out) < n:
            i = len(out)
            line, vals = self.next_line(line, f"the {key} of agent {i} (one line per agent)")
            if self.header_key(vals) is not None:
                raise self.error(line, f"{key}: expected one line per agent ({n}), found only {i}")
            out.append(self.count_or_names(vals, line, f"{key} of agent {i}"))
        return tuple(out)

    def state_token(self, tok: str, line: int, what: str) -> int:
        if _INT_RE.fullmatch(tok):
            k = int(tok)
            if k >= self.nS:
                raise self.error(
                    line, f"{what}: state index {k} out of range (there are {self.nS} states)"
                )
            return k
        k = self.state_index.get(tok)
        if k is None:
            raise self.error(line, f"{what}: unknown state name {_fmt(tok)}")
        return k

    def parse_start(self, lineno: int, toks: list[str]) -> np.ndarray:
        nS = self.nS
        mode = toks[1] if toks[1] != ":" else None
        if mode not in (None, "include", "exclude"):
            raise self.error(
                lineno,
                f"start: expected 'start:', 'start include:' or "
                f"'start exclude:', found 'start {toks[1]}'",
            )
        rest = toks[2:] if mode is None else toks[3:]
        line, vals = self.rest_or_next(lineno, rest, "the start distribution")
        if mode is not None:
            listed = {self.state_token(t, line, f"start {mode}") for t in vals}
            b0 = np.zeros(nS)
            if mode == "include":
                b0[sorted(listed)] = 1.0
            else:
                b0[:] = 1.0
                b0[sorted(listed)] = 0.0
                if b0.sum() == 0:
                    raise self.error(line, "start exclude: every state is excluded")
            return b0 / b0.sum()
        if vals == ["uniform"]:
            return np.full(nS, 1.0 / nS)
        if len(vals) == 1 and (_INT_RE.fullmatch(vals[0]) or _ID_RE.fullmatch(vals[0])):
            b0 = np.zeros(nS)
            b0[self.state_token(vals[0], line, "start")] = 1.0
            return b0
        if len(vals) != nS:
            raise self.error(
                line,
                f"start: expected 'uniform', one state or {nS} probabilities, "
                f"found {_count(len(vals), 'entry', 'entries')}",
            )
        b0 = self.probs(vals, line, nS, "start")
        total = b0.sum()
        if abs(total - 1.0) > START_TOL:
            raise self.error(line, f"start: probabilities sum to {total:.12g}, not 1")
        return b0 / total

    # -- index sets -------------------------------------------------------------------------

    def joint_set(self, field: list[str], line: int, kind: str) -> np.ndarray:
        """Indices matched by a joint action (``kind='a'``) or observation (``'o'``) field."""
        key = tuple(field)
        cache = self.ja_cache if kind == "a" else self.jo_cache
        hit = cache.get(key)
        if hit is not None:
            return hit
        counts = self.action_counts if kind == "a" else self.obs_counts
        names = self.action_index if kind == "a" else self.obs_index
        what = "joint action" if kind == "a" else "joint observation"
        single = "action" if kind == "a" else "observation"
        total = self.nJA if kind == "a" else self.nJO
        n = len(counts)
        if not field:
            raise self.error(line, f"missing {what} (empty field between ':')")
        if len(field) == 1 and field[0] == "*":
            out = np.arange(total)
        elif len(field) == 1 and n > 1 and _INT_RE.fullmatch(field[0]):
            k = int(field[0])
            if k >= total:
                raise self.error(line, f"joint {single} index {k} out of range (there are {total})")
            out = np.array([k])
        elif len(field) == n:
            per_agent = []
            for i, tok in enumerate(field):
                if tok == "*":
                    per_agent.append(np.arange(counts[i]))
                elif _INT_RE.fullmatch(tok):
                    k = int(tok)
                    if k >= counts[i]:
                        raise self.error(
                            line,
                            f"{single} index {k} of agent {i} out of range "
                            f"(agent {i} has {counts[i]})",
                        )
                    per_agent.append(np.array([k]))
                else:
                    k = names[i].get(tok)
                    if k is None:
                        raise self.error(line, f"unknown {single} name {_fmt(tok)} for agent {i}")
                    per_agent.append(np.array([k]))
            grids = np.meshgrid(*per_agent, indexing="ij")
            out = np.ravel_multi_index(tuple(g.ravel() for g in grids), counts)
        else:
            raise self.error(
                line,
                f"{what} {_fmt(' '.join(field))}: expected '*', one joint index or {n} "
                f"per-agent tokens, found {_count(len(field), 'token', 'tokens')}",
            )
        out = np.asarray(out, dtype=np.intp)
        cache[key] = out
        return out

    def state_set(self, field: list[str], line: int, what: str) -> np.ndarray:
        if len(field) != 1:
            if not field:
                raise self.error(line, f"missing {what} (empty field between ':')")
            raise self.error(
                line,
                f"{what}: expected one state, found {_count(len(field), 'token', 'tokens')} "
                f"({_fmt(' '.join(field))})",
            )
        tok = field[0]
        hit = self.s_cache.get(tok)
        if hit is not None:
            return hit
        if tok == "*":
            out = np.arange(self.nS)
        else:
            out = np.array([self.state_token(tok, line, what)])
        out = out.astype(np.intp)
        self.s_cache[tok] = out
        return out

    # -- body -------------------------------------------------------------------------------

    def parse_body(self) -> None:
        nS, nJA, nJO = self.nS, self.nJA, self.nJO
        large = nS * nJA * nS > FLOAT64_T_ENTRIES
        self.T = np.zeros((nS, nJA, nS), np.float32 if large else np.float64)
        self.t_tol = PROB_TOL + (2.0**-24 if large else 0.0)
        self.O = np.zeros((nJA, nS, nJO))
        self.R = np.zeros((nS, nJA))
        self.t_line = np.zeros((nS, nJA), dtype=np.int64)  # last line writing row T(.|s,ja)
        self.o_line = np.zeros((nJA, nS), dtype=np.int64)  # last line writing row O(.|ja,s')
        self.r_written = np.zeros((nS, nJA), dtype=bool)  # an R line wrote R(s, ja)
        self.r_lines = 0
        self.t_used = np.zeros((nS, nJA), dtype=np.int64)  # R line that read row T(.|s,ja)
        self.o_used = np.zeros((nJA, nS), dtype=np.int64)
        self.any_used = False
        # which rows of T [S, JA] / O [JA, S] are given and sum to 1: computed when a reward
        # line first needs them after a T / O line, so R lines cost O(their own size)
        self.t_complete: np.ndarray | None = None
        self.o_complete: np.ndarray | None = None
        self.ja_cache: dict = {}
        self.jo_cache: dict = {}
        self.s_cache: dict = {}
        while self.pos < len(self.lines):
            lineno, toks = self.lines[self.pos]
            self.pos += 1
            self.tick(lineno)
            kind = toks[0]
            if len(toks) < 2 or toks[1] != ":" or kind not in ("T", "O", "R"):
                found = self.header_key(toks)
                if found in _HEADER:
                    raise self.error(
                        lineno, f"'{found}:' out of place: the header must come first, once"
                    )
                raise self.error(lineno, f"expected a T:, O: or R: line, found {_fmt(toks[0])}")
            fields: list[list[str]] = [[]]
            for t in toks[2:]:
                if t == ":":
                    fields.append([])
                else:
                    fields[-1].append(t)
            trailing = not fields[-1]
            if trailing:
                fields.pop()
            if kind == "T":
                self.t_line_(lineno, fields, trailing)
                self.t_complete = None  # rows may have changed
            elif kind == "O":
                self.o_line_(lineno, fields, trailing)
                self.o_complete = None
            else:
                self.r_line_(lineno, fields, trailing)
                self.r_lines += 1

    def single_value(self, field: list[str], line: int, what: str) -> float:
        if len(field) != 1:
            raise self.error(
                line, f"{what}: expected one number, found {_count(len(field), 'token', 'tokens')}"
            )
        return self.number(field[0], line, what)

    def check_prob(self, p: float, line: int, what: str) -> None:
        if not 0.0 <= p <= 1.0:
            raise self.error(line, f"{what}: probability {p:g} is not in [0, 1]")

    def check_t_unused(self, s, ja, line: int) -> None:
        if self.any_used:
            used = self.t_used[_ix(s, ja)]
            if used.any():
                raise self.error(
                    line,
                    f"T changes a row that the reward on line {int(used.max())} already used "
                    "(put T lines before R lines that name s' or jo)",
                )

    def check_o_unused(self, ja, sp, line: int) -> None:
        if self.any_used:
            used = self.o_used[_ix(ja, sp)]
            if used.any():
                raise self.error(
                    line,
                    f"O changes a row that the reward on line {int(used.max())} already used "
                    "(put O lines before R lines that name jo)",
                )

    def keyword_or_matrix(self, line: int, what: str, keywords: tuple[str, ...]):
        """Next line: a keyword (returned as str) or the first row of a matrix (list)."""
        alts = ", ".join(f"'{k}'" for k in keywords)
        expect = f"{alts} or a matrix" if keywords else "a matrix"
        ln, toks = self.next_line(line, f"{expect} for {what}")
        if len(toks) == 1 and toks[0] in keywords:
            return ln, toks[0]
        return ln, toks

    def matrix(self, first: tuple[int, list[str]], rows: int, cols: int, what: str, probs: bool):
        ln, toks = first
        out = np.empty((rows, cols))
        lines = np.empty(rows, dtype=np.int64)
        reader = self.probs if probs else self.numbers
        for r in range(rows):
            if r > 0:
                ln, toks = self.next_line(ln, f"row {r + 1} of {rows} of the matrix for {what}")
            if self.header_key(toks) is not None:
                raise self.error(ln, f"matrix for {what} has {r} rows, expected {rows}")
            out[r] = reader(toks, ln, cols, f"row {r + 1} of the matrix for {what}")
            lines[r] = ln
        return out, lines

    def t_line_(self, line: int, fields: list[list[str]], trailing: bool) -> None:
        nS = self.nS
        nf = len(fields)
        if nf == 4 and not trailing:  # T: ja : s : s' : p
            ja = self.joint_set(fields[0], line, "a")
            s = self.state_set(fields[1], line, "start state")
            sp = self.state_set(fields[2], line, "end state")
            p = self.single_value(fields[3], line, "T probability")
            self.check_prob(p, line, "T")
            self.check_t_unused(s, ja, line)
            if len(s) == 1 and len(ja) == 1 and len(sp) == 1:
                self.T[s[0], ja[0], sp[0]] = p
                self.t_line[s[0], ja[0]] = line
            else:
                self.T[_ix(s, ja, sp)] = p
                self.t_line[_ix(s, ja)] = line
        elif nf == 2:  # T: ja : s : + row
            ja = self.joint_set(fields[0], line, "a")
            s = self.state_set(fields[1], line, "start state")
            ln, toks = self.next_line(line, f"'uniform' or a row of {nS} probabilities")
            if toks == ["uniform"]:
                row = np.full(nS, 1.0 / nS)
            else:
                row = self.probs(toks, ln, nS, "T row ('uniform' or |S| probabilities)")
            self.check_t_unused(s, ja, ln)
            self.T[_ix(s, ja)] = row
            self.t_line[_ix(s, ja)] = ln
        elif nf == 1:  # T: ja : + uniform | identity | matrix
            ja = self.joint_set(fields[0], line, "a")
            ln, got = self.keyword_or_matrix(line, "T", ("uniform", "identity"))
            self.check_t_unused(np.arange(nS), ja, ln)
            if got == "uniform":
                self.T[:, ja, :] = 1.0 / nS
                self.t_line[:, ja] = ln
            elif got == "identity":
                self.T[:, ja, :] = np.eye(nS)[:, None, :]
                self.t_line[:, ja] = ln
            else:
                mat, lines = self.matrix((ln, got), nS, nS, "T", probs=True)
                self.T[:, ja, :] = mat[:, None, :]
                self.t_line[:, ja] = lines[:, None]
        else:
            raise self.error(
                line,
                "malformed T line: expected 'T: ja : s : s' : p', 'T: ja : s :' + a row, "
                "or 'T: ja :' + 'uniform' / 'identity' / a matrix",
            )

    def o_line_(self, line: int, fields: list[list[str]], trailing: bool) -> None:
        nS, nJO = self.nS, self.nJO
        nf = len(fields)
        if nf == 4 and not trailing:  # O: ja : s' : jo : p
            ja = self.joint_set(fields[0], line, "a")
            sp = self.state_set(fields[1], line, "end state")
            jo = self.joint_set(fields[2], line, "o")
            p = self.single_value(fields[3], line, "O probability")
            self.check_prob(p, line, "O")
            self.check_o_unused(ja, sp, line)
            if len(ja) == 1 and len(sp) == 1 and len(jo) == 1:
                self.O[ja[0], sp[0], jo[0]] = p
                self.o_line[ja[0], sp[0]] = line
            else:
                self.O[_ix(ja, sp, jo)] = p
                self.o_line[_ix(ja, sp)] = line
        elif nf == 2:  # O: ja : s' : + row
            ja = self.joint_set(fields[0], line, "a")
            sp = self.state_set(fields[1], line, "end state")
            ln, toks = self.next_line(line, f"'uniform' or a row of {nJO} probabilities")
            if toks == ["uniform"]:
                row = np.full(nJO, 1.0 / nJO)
            else:
                row = self.probs(toks, ln, nJO, "O row ('uniform' or |JO| probabilities)")
            self.check_o_unused(ja, sp, ln)
            self.O[_ix(ja, sp)] = row
            self.o_line[_ix(ja, sp)] = ln
        elif nf == 1:  # O: ja : + uniform | matrix
            ja = self.joint_set(fields[0], line, "a")
            ln, got = self.keyword_or_matrix(line, "O", ("uniform",))
            self.check_o_unused(ja, np.arange(nS), ln)
            if got == "uniform":
                self.O[ja] = 1.0 / nJO
                self.o_line[ja] = ln
            else:
                mat, lines = self.matrix((ln, got), nS, nJO, "O", probs=True)
                self.O[ja] = mat[None]
                self.o_line[ja] = lines[None, :]
        else:
            raise self.error(
                line,
                "malformed O line: expected 'O: ja : s' : jo : p', 'O: ja : s' :' + a row, "
                "or 'O: ja :' + 'uniform' / a matrix",
            )

    def require_complete(self, s, ja, sp, need_o: bool, line: int) -> None:
        """Rewards naming s' / jo read T (and O): those rows must be complete already."""
        if self.t_complete is None:
            sums = self.T.sum(-1, dtype=np.float64)
            self.t_complete = (self.t_line > 0) & (np.abs(sums - 1.0) <= self.t_tol)
        bad = ~self.t_complete[_ix(s, ja)]
        if bad.any():
            i, j = np.argwhere(bad)[0]
            raise self.error(
                line,
                f"this reward depends on T(.|s={self.state_names[s[i]]}, "
                f"ja={self.ja_name(ja[j])}), which is not complete yet (T must be fully "
                "given before R lines that name s' or jo)",
            )
        self.t_used[_ix(s, ja)] = line
        if need_o:
            if self.o_complete is None:
                self.o_complete = (self.o_line > 0) & (np.abs(self.O.sum(-1) - 1.0) <= PROB_TOL)
            bad = ~self.o_complete[_ix(ja, sp)]
            if bad.any():
                i, j = np.argwhere(bad)[0]
                raise self.error(
                    line,
                    f"this reward depends on O(.|ja={self.ja_name(ja[i])}, "
                    f"s'={self.state_names[sp[j]]}), which is not complete yet (O must be "
                    "fully given before R lines that name jo)",
                )
            self.o_used[_ix(ja, sp)] = line
        self.any_used = True

    def r_line_(self, line: int, fields: list[list[str]], trailing: bool) -> None:
        nS, nJO = self.nS, self.nJO
        nf = len(fields)
        if nf == 5 and not trailing:  # R: ja : s : s' : jo : r
            ja = self.joint_set(fields[0], line, "a")
            s = self.state_set(fields[1], line, "start state")
            sp_any = fields[2] == ["*"]
            jo_any = fields[3] == ["*"]
            sp = self.state_set(fields[2], line, "end state")
            jo = None if jo_any else self.joint_set(fields[3], line, "o")
            r = self.single_value(fields[4], line, "reward")
            self.r_written[_ix(s, ja)] = True
            if sp_any and jo_any:
                if len(s) == 1 and len(ja) == 1:
                    self.R[s[0], ja[0]] = r
                else:
                    self.R[_ix(s, ja)] = r
                return
            self.require_complete(s, ja, sp, not jo_any, line)
            t_sub = self.T[_ix(s, ja, sp)]  # [s, ja, s']
            if jo_any:
                self.R[_ix(s, ja)] += r * t_sub.sum(-1)
            else:
                o_sub = self.O[_ix(ja, sp, jo)].sum(-1)  # [ja, s']
                self.R[_ix(s, ja)] += r * (t_sub * o_sub[None]).sum(-1)
        elif nf == 3:  # R: ja : s : s' : + row over jo
            ja = self.joint_set(fields[0], line, "a")
            s = self.state_set(fields[1], line, "start state")
            sp = self.state_set(fields[2], line, "end state")
            ln, toks = self.next_line(line, f"a row of {nJO} rewards")
            row = self.numbers(toks, ln, nJO, "R row (|JO| rewards)")
            self.require_complete(s, ja, sp, True, line)
            self.r_written[_ix(s, ja)] = True
            t_sub = self.T[_ix(s, ja, sp)]
            o_r = self.O[_ix(ja, sp)] @ row  # [ja, s']
            self.R[_ix(s, ja)] += (t_sub * o_r[None]).sum(-1)
        elif nf == 2:  # R: ja : s : + |S| x |JO| matrix
            ja = self.joint_set(fields[0], line, "a")
            s = self.state_set(fields[1], line, "start state")
            first = self.next_line(line, f"a {nS} x {nJO} reward matrix")
            mat, _ = self.matrix(first, nS, nJO, "R", probs=False)
            self.require_complete(s, ja, np.arange(nS), True, line)
            self.r_written[_ix(s, ja)] = True
            o_r = (self.O[ja] * mat[None]).sum(-1)  # [ja, s']
            self.R[_ix(s, ja)] += np.einsum("sat,at->sa", self.T[_ix(s, ja)], o_r)
        else:
            raise self.error(
                line,
                "malformed R line: expected 'R: ja : s : s' : jo : r', 'R: ja : s : s' :' + a "
                "row, or 'R: ja : s :' + a matrix",
            )

    def ja_name(self, ja: int) -> str:
        parts = np.unravel_index(int(ja), self.action_counts)
        return ",".join(self.action_names[i][int(a)] for i, a in enumerate(parts))

    # -- final checks -----------------------------------------------------------------------

    def finish(self) -> None:
        """Every row of T and O was given and sums to one (else the error names the line)."""
        self.check_rows(
            self.T.sum(-1, dtype=np.float64),
            self.t_line,
            self.t_tol,
            lambda s, ja: f"T(.|s={self.state_names[s]}, ja={self.ja_name(ja)})",
            "T",
        )
        self.check_rows(
            self.O.sum(-1),
            self.o_line,
            PROB_TOL,
            lambda ja, sp: f"O(.|ja={self.ja_name(ja)}, s'={self.state_names[sp]})",
            "O",
        )

    def check_rows(self, sums, lines, tol: float, row_name, table: str) -> None:
        """``sums [a, b]`` of the rows of a table written last on ``lines [a, b]`` (0: never):
        the first row written whose sum is off by more than ``tol``, else the first row never
        written, is an error; ``row_name(a, b)`` names a row."""
        bad = (lines > 0) & (np.abs(sums - 1.0) > tol)
        if bad.any():
            a, b = min(np.argwhere(bad), key=lambda ij: lines[ij[0], ij[1]])
            raise self.error(
                int(lines[a, b]),
                f"{row_name(a, b)} sums to {sums[a, b]:.12g}, not 1 (tolerance {tol:g}); last "
                "written here",
            )
        missing = lines == 0
        if missing.any():
            a, b = np.argwhere(missing)[0]
            more = int(missing.sum()) - 1
            extra = f" (and {more} more rows of {table})" if more else ""
            raise self.error(None, f"{row_name(a, b)} never specified{extra}")

    def check_rewards(self, text: str) -> None:
        """Where MADP's defaults would silently decide, an error (see the module docstring)."""
        if self.r_lines == 0:
            raise self.error(None, "no R: lines: every reward would be 0 (write the rewards)")
        if not text.endswith(("\n", "\r")) and not self.r_written.all():
            missing = int((~self.r_written).sum())
            raise self.error(
                self.lines[-1][0],
                f"the file ends without a newline and {missing} of {self.r_written.size} "
                "rewards R(s, ja) were never written: was the file cut short?",
            )

    def current_line(self) -> int | None:
        if 0 < self.pos <= len(self.lines):
            return self.lines[self.pos - 1][0]
        return None

    def run(self, discount: float | None, text: str = "") -> TabularModel:
        self.parse_header()
        self.parse_body()
        self.finish()
        self.check_rewards(text)
        R = -self.R if self.cost else self.R
        arrays = [self.T, self.O, R + 0.0, self.initial_belief]
        for a in arrays:
            a.setflags(write=False)
        return TabularModel(
            agent_names=self.agent_names,
            state_names=self.state_names,
            action_names=self.action_names,
            observation_names=self.observation_names,
            discount=self.discount if discount is None else discount,
            transition=arrays[0],
            observation=arrays[1],
            reward=arrays[2],
            initial_belief=arrays[3],
            source=self.label,
        )


def parse_dpomdp(
    path_or_text: str | os.PathLike | bytes, discount: float | None = None, *, name=None
) -> TabularModel:
    """Parse a ``.dpomdp`` model.

    ``path_or_text``: a path (``.gz`` files, or any gzip data, are decompressed), a ``str``
    holding the file text itself (recognised by containing a newline), or raw ``bytes``.
    ``discount`` overrides the file's discount. ``name`` labels the source in error messages
    and in ``TabularModel.source`` (default: the path, or ``"<string>"``).

    Raises :class:`DpomdpParseError` (a ``ValueError``) naming the file and line for any
    malformed content; see the module docstring for the accepted grammar and the choices made.
    """
    if discount is not None:
        discount = _check_discount(discount)
    text, label = _read_source(path_or_text, name)
    parser = _Parser(text, label)
    try:
        return parser.run(discount, text)
    except DpomdpParseError:
        raise
    except (IndexError, KeyError, ValueError, TypeError, OverflowError, MemoryError) as exc:
        # Safety net: a malformed input must never escape as a bare internal exception.
        raise DpomdpParseError(
            label, parser.current_line(), f"cannot parse this line ({type(exc).__name__}: {exc})"
        ) from exc


def load_dpomdp(path: str | os.PathLike, discount: float | None = None) -> TabularModel:
    """Alias of :func:`parse_dpomdp` for a file path."""
    return parse_dpomdp(path, discount)
