"""A sweep group's runs in batches that fit the memory budget.

A group's runs share one program, ``vmap``-ed over ``[runs]``: its iteration holds every run's
rollouts at once. Each run's share of ``run.memory_gb`` is ``budget / runs``
(``api.build(lanes=...)``), but a run never goes below one candidate's rollouts in flight,
so thousands of runs side by side can need more than the whole budget. XLA's memory analysis
of the compiled iteration (``memory.check_compiled``) then refuses the program with the bytes
it needs; :func:`run_in_batches` runs the group's runs in batches of the size that fits
instead, one after another (each run's keys and values are its own: a batch gives the numbers
the whole group gives, up to the rounding batching may change, ``sweep``'s docstring).

**[choice]** Every run keeps the memory share it has in the whole group, so a batch needs its share
of the whole group's bytes: the batch size is ``runs x budget / needed`` (times ``BATCH_MARGIN``), a
multiple of the local devices, the batches balanced (the last one pads the fewest runs to the
others' size: one program), found by one compile of the whole group. It is written to
``OUT/sweep-state/{tag}.batch.json`` so that ``--resume`` runs the same batches without that
compile. Each batch has its own checkpoint (``{tag}-b{k}of{size}.checkpoint.msgpack``) and, once
done, its rows (``{tag}-b{k}of{size}.rows.json``, checked to be its runs'), which a resumed sweep
keeps; a resume under a budget the stored batches no longer fit runs smaller ones, all afresh.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax

from cognet_jax.api import Built, build
from cognet_jax.atomic_files import atomic_write_json
from cognet_jax.driver import GroupOptions, run_group
from cognet_jax.errors import CorruptFileError, read_json
from cognet_jax.memory import MemoryOverBudget, gb
from cognet_jax.program import Run

#: a batch's share of what the budget allows (XLA's temporaries do not scale exactly with runs)
BATCH_MARGIN = 0.9
#: the timing fields that add up over batches
SUMMED = ("compile_s", "loop_s", "eval_s", "runs")


def run_in_batches(
    runs: list[Run], tag: str, state: Path | None, opts: GroupOptions
) -> tuple[list[dict], dict]:
    """``(rows, timing)`` of ``run_group`` over ``runs``: all at once, or in batches when the
    whole group's iteration does not fit ``run.memory_gb`` (module docstring). ``state``: the
    sweep's state folder (None: no files); ``opts``: the group's options, whose checkpoint is
    the group's own (``{tag}.checkpoint.msgpack``) while the runs go all at once."""
    devices = jax.local_device_count()
    size_file = None if state is None else state / f"{tag}.batch.json"
    size = _stored_size(size_file, len(runs)) if opts.resume else len(runs)
    while True:
        try:
            if size >= len(runs):
                return run_group(runs, opts)
            return _batches(runs, size, tag, state, opts)
        except MemoryOverBudget as err:
            if size <= devices or not err.before_search:  # one run, or after a search
                raise
            fits = int(size * BATCH_MARGIN * err.budget / err.needed) // devices * devices
            fits = max(devices, min(fits, (size - 1) // devices * devices))
            count = -(-len(runs) // fits)
            per_batch = -(-len(runs) // count)  # balanced: the last batch pads the fewest runs
            opts.log(
                f"{opts.desc or 'group'}: {size} runs side by side need about {gb(err.needed)}, "
                f"over the memory budget of {gb(err.budget)} (run.memory_gb): running them in "
                f"{count} batches of {per_batch}"
            )
            size = -(-per_batch // devices) * devices
            if size_file is not None:
                atomic_write_json(size_file, {"runs": len(runs), "batch": size}, None)


def _stored_size(path: Path | None, runs: int) -> int:
    """The batch size a stopped sweep's group ran with (``runs``: none stored)."""
    if path is None or not path.exists():
        return runs
    stored = read_json(path, ("runs", "batch"))
    batch = stored["batch"]
    if stored["runs"] != runs or not isinstance(batch, int) or not 1 <= batch <= runs:
        raise CorruptFileError(path, f"a batch of {batch!r} of {stored['runs']!r} runs")
    return batch


def _batches(runs: list[Run], size: int, tag: str, state: Path | None, opts: GroupOptions):
    """Every batch of ``size`` runs by ``run_group``, one after another; a finished batch's
    rows are kept in ``state`` and not run again by a resumed sweep."""
    rows, timing = [], {}
    built = _group_built(runs, opts.built)
    count = -(-len(runs) // size)
    for k in range(count):
        batch = runs[k * size : (k + 1) * size]
        name = f"{tag}-b{k}of{size}"  # batches of another size hold other runs
        done = None if state is None else state / f"{name}.rows.json"
        stored = _stored_rows(done, batch) if opts.resume else None
        if stored is not None:
            b_rows, b_timing = stored["rows"], stored["timing"]
        else:
            b_opts = dataclasses.replace(
                opts,
                checkpoint=None if state is None else state / f"{name}.checkpoint.msgpack",
                desc=f"{opts.desc or 'group'} batch {k + 1}/{count}",
                built=built,
                lanes=size,
            )
            b_rows, b_timing = run_group(batch, b_opts)
            if done is not None:
                atomic_write_json(done, {"rows": b_rows, "timing": b_timing}, None)
        rows.extend(b_rows)
        for field in SUMMED:
            timing[field] = timing.get(field, 0) + (b_timing.get(field) or 0)
    timing["batches"] = count
    return rows, timing


def folders_whole(runs: list[Run]) -> bool:
    """Whether every run of ``runs`` with a folder has its results.json and policy there (a
    finished group's or batch's rows are kept only then)."""
    return all(
        (run.folder / name).is_file()
        for run in runs
        if run.folder is not None
        for name in ("results.json", "policy.msgpack")
    )


def _stored_rows(path: Path | None, batch: list[Run]) -> dict | None:
    """A finished batch's ``{"rows", "timing"}``, when ``path`` holds the rows of exactly
    ``batch``'s runs and their folders are whole (else None: the batch runs again, from its
    checkpoint if it has one)."""
    if path is None or not path.exists():
        return None
    if not folders_whole(batch):
        return None
    stored = read_json(path, ("rows", "timing"))
    runs = [(r.get("setting"), r.get("seed")) for r in stored["rows"] if isinstance(r, dict)]
    if runs != [(run.setting, run.seed) for run in batch]:
        raise CorruptFileError(path, "its rows are not the runs of its batch")
    return stored


def _group_built(runs: list[Run], built: Built | None) -> Built:
    """The group's ``api.build`` with every run's memory share as in the whole group
    (``budget / runs``), which each batch keeps: a batch's bytes are then its share of the
    whole group's, and one compile of the group sizes the batches."""
    if built is not None:
        return built
    devices = jax.local_device_count()
    return build(runs[0].config, lanes=-(-len(runs) // devices) * devices)
