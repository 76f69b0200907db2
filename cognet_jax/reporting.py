"""Figures of a finished run, written next to ``results.json``: the value curve of every
search (``write_value_plot``: in-loop value per iteration, running best, known reference
values), then the drawings a search asks for in its ``write_plots`` hook (``engine.Search``;
the built-in searches draw with ``controllers.figures``).
"""

from __future__ import annotations

from pathlib import Path

from cognet_jax import plots
from cognet_jax.hook_results import checked_paths
from cognet_jax.plots import run_title
from cognet_jax.registry import env_entry


def references_for(config) -> dict[str, float]:
    """Known values for the run's simulator and setting (its registry entry's
    ``references``; SPEC section 8 for the built-in ones)."""
    entry = env_entry(config.env.name)
    if not entry.reference_field:
        return {}
    return dict(entry.references.get(getattr(config.env, entry.reference_field), {}))


def write_plots(config, algorithm, policy, results: dict, out_dir) -> list[Path]:
    """Write the run's PNG figures to ``out_dir``: the value curve (``values.png``) of every
    search, then the search's own figures of its best policy (``algorithm.write_plots``);
    returns the paths written."""
    written = [write_value_plot(config, results, out_dir)]
    own = algorithm.write_plots(config, policy, results, out_dir)
    return written + checked_paths(algorithm, "write_plots", own)


def in_loop_best_series(results: dict) -> list:
    """A results.json's in-loop best after each iteration (``in_loop_best_per_iteration``;
    ``best_per_iteration`` in files written before the name)."""
    if "in_loop_best_per_iteration" in results:
        return results["in_loop_best_per_iteration"]
    return results["best_per_iteration"]


def write_value_plot(config, results: dict, out_dir) -> Path:
    """``values.png``: the in-loop value per iteration and the running best, with the known
    values of the run's simulator (``references_for``)."""
    return Path(
        plots.plot_values(
            results["values_per_iteration"],
            in_loop_best_series(results),
            Path(out_dir) / "values.png",
            title=run_title(results),
            reference=references_for(config),
        )
    )
