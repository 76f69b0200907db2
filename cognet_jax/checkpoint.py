"""Checkpoints of a running search: the full algorithm state pytree (search distributions,
network parameters and optimiser states, thresholds, best policy, progress counters), the PRNG
keys of the run, the iteration reached and the metrics recorded so far.

Format: one msgpack file written with ``flax.serialization`` (no pickle)::

    {"format": 1, "meta": JSON text, "iteration": int,
     "keys": {name: uint32 key data}, "state": state dict of the algorithm state,
     "history": state dict of the stacked metrics [iterations, ...] (absent at iteration 0)}

For a sweep the leaves of ``state`` and ``history`` carry a leading ``[runs]`` axis (history is
then ``[iterations, runs]``). Writes are atomic: the bytes go to a temporary file in the same
folder, which is flushed, fsync'ed and renamed over the old checkpoint with ``os.replace``
(and the folder is fsync'ed), so a crash or SIGKILL at any moment leaves either the previous or
the new checkpoint, never a torn one.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any

import jax
import numpy as np
from flax import serialization

from cognet_jax.atomic_files import atomic_write_bytes
from cognet_jax.errors import CorruptFileError, InputError, MismatchError
from cognet_jax.prng import impl_of

CHECKPOINT_NAME = "checkpoint.msgpack"
FORMAT = 1


def stack_history(history: list) -> Any:
    """List of per-iteration metrics pytrees -> one pytree with a leading ``[iterations]`` axis
    (numpy, on the host); ``None`` for an empty list."""
    if not history:
        return None
    host = jax.device_get(history)
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *host)


def save_checkpoint(
    path: str | Path,
    *,
    state: Any,
    keys: dict[str, jax.Array],
    iteration: int,
    history: Any,
    meta: dict,
) -> None:
    """Atomically write a checkpoint (see module docstring). ``history`` is the stacked metrics
    (``stack_history``) or ``None``; ``keys`` typed PRNG keys (stored as their key data)."""
    payload = {
        "format": FORMAT,
        "meta": json.dumps(meta),
        "iteration": int(iteration),
        "keys": {k: np.asarray(jax.random.key_data(v)) for k, v in keys.items()},
        "state": serialization.to_state_dict(jax.device_get(state)),
    }
    if history is not None:
        payload["history"] = serialization.to_state_dict(history)
    atomic_write_bytes(path, serialization.msgpack_serialize(payload))


def read_checkpoint(path: str | Path) -> dict:
    """The raw checkpoint dict with ``meta`` decoded; FileNotFoundError if missing."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    try:
        raw = serialization.msgpack_restore(path.read_bytes())
    except Exception as err:  # msgpack's errors for truncated or foreign bytes
        raise CorruptFileError(path, f"{type(err).__name__}: {err}".rstrip(": ")) from None
    if not isinstance(raw, dict) or raw.get("format") != FORMAT:
        found = raw.get("format") if isinstance(raw, dict) else type(raw).__name__
        raise CorruptFileError(path, f"unknown checkpoint format {found!r}")
    missing = [k for k in ("meta", "iteration", "keys", "state") if k not in raw]
    if missing:
        raise CorruptFileError(path, f"missing {', '.join(missing)}")
    try:
        raw["meta"] = json.loads(raw["meta"])
    except (TypeError, ValueError) as err:
        raise CorruptFileError(path, f"meta is not valid JSON: {err}") from None
    raw["path"] = str(path)
    return raw


def restore_state(template: Any, raw: dict) -> Any:
    """The algorithm state stored in ``raw`` with the structure (and types) of ``template``;
    ``CorruptFileError`` when it does not fit."""
    try:
        state = _with_absent_fields(serialization.to_state_dict(template), raw["state"])
        return serialization.from_state_dict(template, state)
    except (ValueError, KeyError, TypeError, AttributeError) as err:
        raise CorruptFileError(
            raw.get("path", "checkpoint"), f"state does not fit: {err}"
        ) from None


#: fields renamed since checkpoints were written: old name -> name of now
RENAMED_FIELDS = {"best_value": "in_loop_best"}


def _renamed(stored: dict) -> dict:
    """``stored`` (one level of a state dict) under the names of now (``RENAMED_FIELDS``)."""
    return {RENAMED_FIELDS.get(k, k): v for k, v in stored.items()}


def _with_absent_fields(template: Any, stored: Any) -> Any:
    """``stored`` (a state dict) with the fields that ``template``'s state dict holds as
    ``None`` and ``stored`` lacks added as ``None``: optional parts of a state added to the
    library since the checkpoint was written, off in the search it resumes; fields stored
    under an old name (``RENAMED_FIELDS``) read under the new one."""
    if not (isinstance(template, dict) and isinstance(stored, dict)):
        return stored
    stored = _renamed(stored)
    filled = {k: _with_absent_fields(template.get(k), v) for k, v in stored.items()}
    filled.update({k: None for k, v in template.items() if v is None and k not in stored})
    return filled


def restore_history(template: Any, raw: dict) -> list:
    """Per-iteration metrics as a list of pytrees shaped like ``template`` (one iteration)."""
    if "history" not in raw:
        return []
    stored = _with_absent_fields(serialization.to_state_dict(template), raw["history"])
    stacked = serialization.from_state_dict(template, stored)
    n = int(raw["iteration"])
    return [jax.tree.map(lambda x, i=i: np.asarray(x)[i], stacked) for i in range(n)]


def restore_key(raw: dict, name: str, impl: str) -> jax.Array:
    """The typed key ``name`` stored in ``raw`` (generator ``impl``, ``run.prng_impl``)."""
    return jax.random.wrap_key_data(np.asarray(raw["keys"][name]), impl=impl_of(impl))


#: Policy files: ``{"format": POLICY_FORMAT, "version": 1, "kind": class name, "sha256": hex,
#: "policy": flax msgpack bytes of the policy pytree}``. Files written before the header
#: existed (the bare msgpack bytes of the policy) are still read.
POLICY_FORMAT = "cognet-jax policy"
POLICY_VERSION = 1


def policy_bytes(policy, fingerprint: dict | None = None) -> bytes:
    """The bytes of a policy file for ``policy`` (a policy pytree); ``fingerprint``: what the
    policy was trained with (``records.fingerprint``: hashes of the shaping config and of the
    model file), checked when it is read back."""
    body = serialization.to_bytes(jax.device_get(policy))
    header = {
        "format": POLICY_FORMAT,
        "version": POLICY_VERSION,
        "kind": type(policy).__name__,
        "sha256": hashlib.sha256(body).hexdigest(),
        "policy": body,
    }
    if fingerprint is not None:
        header["fingerprint"] = json.dumps(fingerprint, sort_keys=True)
    return serialization.msgpack_serialize(header)


def read_policy(path: str | Path, template, fingerprint: dict | None = None):
    """The policy saved in ``path``, restored into the structure of ``template``. A damaged
    file (truncated, checksum, foreign bytes, newer version) is a ``CorruptFileError``; a
    policy of another kind or other shapes, or whose stored fingerprint differs from
    ``fingerprint`` in any key both have, is a ``MismatchError``."""
    path = Path(path)
    if not path.is_file():  # deleted or moved: not a damaged file
        raise InputError(
            f"{path}: no policy file there (the run folder lost it: train the run again, or "
            "evaluate the folder it was copied from)"
        )
    try:
        raw = serialization.msgpack_restore(path.read_bytes())
    except Exception as err:  # truncated or foreign bytes
        raise CorruptFileError(path, f"{type(err).__name__}: {err}".rstrip(": ")) from None
    if not (isinstance(raw, dict) and raw.get("format") == POLICY_FORMAT):
        return restore_msgpack(path, template)  # a file without the header
    if not isinstance(raw.get("version"), int) or raw["version"] > POLICY_VERSION:
        raise CorruptFileError(
            path, f"policy file version {raw.get('version')!r}; this cognet-jax reads <= 1"
        )
    body = raw.get("policy")
    if not isinstance(body, bytes) or hashlib.sha256(body).hexdigest() != raw.get("sha256"):
        raise CorruptFileError(path, "checksum mismatch: the policy bytes are damaged")
    kind = type(template).__name__
    if raw.get("kind") != kind:
        raise MismatchError(
            f"{path}: holds a {raw.get('kind')} where this configuration needs a {kind}"
        )
    _check_fingerprint(path, raw.get("fingerprint"), fingerprint)
    return restore_msgpack(path, template, data=body)


#: what each fingerprint key stands for, in the refusal
FINGERPRINT_KEYS = {
    "config": (
        "the config it was trained with (results.json's config was edited, or the policy "
        "file comes from another run)",
        "--set evaluates it under another setting on purpose",
    ),
    "model": (
        "the model file it was trained on (the file changed since)",
        "restore the file, or train on the new one",
    ),
    "numerics": (
        "these numeric settings",
        "evaluate with the settings and --import modules it was trained with",
    ),
    "generator": (
        "the seed and generator of the run in this folder (results.json's seed or "
        "run.prng_impl was edited, or the policy file comes from another run)",
        "restore the run's files; --seed N or --set run.prng_impl=... evaluates a policy with "
        "others on purpose",
    ),
}

#: what evaluating under a differing key would give, where it is not another policy's number
OUTCOMES = {"generator": "a number its run never had, silently"}


def _check_fingerprint(path: Path, stored, expected: dict | None) -> None:
    if stored is None or expected is None:  # a file written before fingerprints, or no check
        return
    try:
        stored = json.loads(stored)
    except (TypeError, ValueError):
        raise CorruptFileError(path, "the fingerprint is not valid JSON") from None
    if not isinstance(stored, dict):
        raise CorruptFileError(path, "the fingerprint is not a record")
    for key, (what, remedy) in FINGERPRINT_KEYS.items():
        differ = fingerprint_difference(stored, expected, (key,))
        if differ:
            outcome = OUTCOMES.get(key, "a number of another policy")
            raise MismatchError(
                f"{path}: this policy does not belong to {what}{differ[len(key) :]}; "
                f"evaluating it would give {outcome} ({remedy})"
            )


def fingerprint_difference(stored: dict, expected: dict, keys=tuple(FINGERPRINT_KEYS)) -> str:
    """The first of ``keys`` in which fingerprint ``stored`` (as written) and ``expected``
    (now) differ, as words: ``"numerics (prng: trained 'rbg', now 'threefry2x32')"``; "" when
    they agree. A name recorded only now is no difference (``_known``)."""
    for key in keys:
        if key not in stored or key not in expected:
            continue
        old, now = stored[key], expected[key]
        if isinstance(old, dict):  # a setting recorded since the file was written
            now = _known(old, now)
        if old == now or (key == "model" and old == expected.get("model_file")):
            continue  # (a gzip model's policy written before the text's digest: its bytes')
        if isinstance(old, dict) and isinstance(now, dict):
            names = sorted(set(old) | set(now))
            parts = "; ".join(
                f"{n}: trained {old.get(n)!r}, now {now.get(n)!r}"
                for n in names
                if old.get(n) != now.get(n)
            )
            return f"{key} ({parts})"
        return f"{key} ({'model file digest' if key == 'model' else key} differs)"
    return ""


def _known(stored: dict, expected) -> dict:
    """``expected`` (a dict) without the names ``stored`` lacks, except ``imported`` (modules
    imported now and not at training are a difference); ``imported_late`` keeps the modules
    loaded at both times, with the stored digests of those not loaded now (they never ran)."""
    if not isinstance(expected, dict):
        return expected
    known = {k: v for k, v in expected.items() if k in stored or k == "imported"}
    late, now = stored.get("imported_late"), known.get("imported_late")
    if isinstance(late, dict) and isinstance(now, dict):
        known["imported_late"] = {n: now.get(n, d) for n, d in late.items()}
    return known


def _shape(x) -> tuple:
    """The shape of an array, a ``jax.ShapeDtypeStruct`` or a scalar."""
    return tuple(x.shape) if hasattr(x, "shape") else np.shape(x)


def restore_msgpack(path: str | Path, template, data: bytes | None = None):
    """``flax.serialization.from_bytes(template, bytes of path)`` with every way a damaged file
    fails (truncated, trailing bytes, wrong structure, wrong shapes) turned into one
    ``CorruptFileError``; the restored leaves must have the template's shapes. ``data``: the
    bytes to restore when they are not the whole file (named ``path`` in errors). The
    template's leaves may be shapes (``jax.eval_shape``)."""
    path = Path(path)
    data = path.read_bytes() if data is None else data
    try:
        restored = serialization.from_bytes(template, data)
    except Exception as err:  # msgpack and flax raise ValueError, TypeError, AttributeError, ...
        raise CorruptFileError(path, f"{type(err).__name__}: {err}".rstrip(": ")) from None
    want = [_shape(x) for x in jax.tree.leaves(template)]
    got = [_shape(x) for x in jax.tree.leaves(restored)]
    if want != got:
        raise MismatchError(
            f"{path}: holds arrays of shapes {got[:3]}... where this model needs {want[:3]}...: "
            "it was saved for other settings (nodes, problem, network size)"
        )
    return restored
