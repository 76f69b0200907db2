"""Figures for finite-state controllers and training runs (matplotlib's object interface:
``Figure`` objects written to PNG, so importing this module changes no backend or pyplot state).

Every function takes plain numpy arrays (or anything ``np.asarray`` accepts), writes one PNG to
``path``, closes its figure and returns ``path``. There is no JAX in here, so the same functions
serve every controller kind.

* ``plot_action_distributions``: each node's action distribution, one panel per agent.
* ``plot_node_responses``: next-node probabilities as a function of a scalar observation.
* ``plot_values``: in-loop value per iteration, running best, optional reference lines.
* ``controller_graph_edges`` / ``tabular_graph_edges``: the most likely transitions of one agent,
  as ``(src, dst, labels)`` edges (observation intervals, or observation names).
* ``plot_controller_graphs``: each agent's controller drawn as a graph (nodes on a circle).
* ``plot_value_vs_noise``: value against a noise level, one errorbar line per variant.

Next-node probabilities of a neural controller over an observation grid (scalar
observations), to pass to ``plot_node_responses`` / ``controller_graph_edges``::

    logits = jax.vmap(lambda z: controller.all_node_logits(
        policy.net_params, jnp.full((controller.num_agents,), z)))(jnp.asarray(grid))
    probs = np.asarray(jax.nn.softmax(logits, -1)).transpose(1, 2, 0, 3)  # [agents, nodes, G, N]
    edges = [controller_graph_edges(grid, p) for p in probs]
"""

from __future__ import annotations

import functools
import io
import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from types import SimpleNamespace

import numpy as np

from cognet_jax.atomic_files import atomic_write_bytes

__all__ = [
    "controller_graph_edges",
    "format_interval",
    "plot_action_distributions",
    "plot_controller_graphs",
    "plot_node_responses",
    "plot_value_vs_noise",
    "plot_values",
    "tabular_graph_edges",
]

Interval = tuple[float, float]
Edge = tuple[int, int, list]


def run_title(results: dict) -> str:
    """A run's figure title: its experiment and seed (``results.json``'s fields)."""
    return f"{results['experiment']} (seed {results['seed']})"


@functools.cache
def _mpl() -> SimpleNamespace:
    """The matplotlib pieces the figures use, imported at the first figure (0.3 s that a
    command writing no figure does not spend)."""
    import matplotlib
    from matplotlib.figure import Figure
    from matplotlib.patches import Circle, FancyArrowPatch
    from matplotlib.path import Path as MplPath

    return SimpleNamespace(
        colormaps=matplotlib.colormaps,
        Figure=Figure,
        Circle=Circle,
        FancyArrowPatch=FancyArrowPatch,
        Path=MplPath,
    )


def _save(fig, path, dpi: int, title: str | None = None) -> str | Path:
    """Lay out ``fig`` (with ``title`` above its panels, if any), write it to ``path``, close
    it."""
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    image = io.BytesIO()  # written whole, atomically: a failed write keeps the old figure
    fig.savefig(image, dpi=dpi, bbox_inches="tight", format=Path(path).suffix[1:] or "png")
    atomic_write_bytes(path, image.getvalue())
    return path


def _subplots(*grid, figsize=None, **options):
    """``(fig, axes)``: a new ``Figure`` of ``figsize`` with ``Figure.subplots(*grid,
    **options)``."""
    fig = _mpl().Figure(figsize=figsize)
    return fig, fig.subplots(*grid, **options)


def _colors(n: int) -> list:
    cmap = _mpl().colormaps["tab10" if n <= 10 else "tab20"]
    return [cmap(i % cmap.N) for i in range(n)]


# --------------------------------------------------------------------------- distributions


def plot_action_distributions(
    action_probs,
    action_names: Sequence[str],
    path,
    title: str | None = None,
    dpi: int = 120,
):
    """Grouped bars of every node's action distribution, one panel per agent.

    ``action_probs [agents, nodes, actions]``; ``action_names`` has one name per action.
    """
    probs = np.asarray(action_probs, dtype=float)
    if probs.ndim != 3:
        raise ValueError(f"action_probs must be [agents, nodes, actions], got {probs.shape}")
    agents, nodes, actions = probs.shape
    names = _action_names(action_names, actions)
    fig, axes = _subplots(
        1,
        agents,
        figsize=(max(3.5, 0.9 * nodes + 1.5) * agents, 3.4),
        squeeze=False,
        sharey=True,
    )
    width = 0.8 / actions
    x = np.arange(nodes)
    colors = _colors(actions)
    for i, ax in enumerate(axes[0]):
        for a in range(actions):
            ax.bar(
                x - 0.4 + (a + 0.5) * width, probs[i, :, a], width, color=colors[a], label=names[a]
            )
        ax.set_xticks(x, [f"q{q}" for q in range(nodes)])
        ax.set_ylim(0.0, 1.05)
        ax.set_xlabel("node")
        ax.set_title(f"agent {i}")
        ax.grid(axis="y", alpha=0.3)
    axes[0, 0].set_ylabel("probability")
    axes[0, -1].legend(title="action", fontsize=8, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    return _save(fig, path, dpi, title)


def plot_node_responses(
    obs_grid,
    probs,
    path,
    title: str | None = None,
    obs_label: str = "observation",
    dpi: int = 120,
):
    """Stacked next-node probabilities against a scalar observation, one subplot per
    (agent, node): rows are agents, columns nodes.

    ``obs_grid [G]`` ascending; ``probs [agents, nodes, G, next_nodes]``.
    """
    grid = np.asarray(obs_grid, dtype=float)
    p = np.asarray(probs, dtype=float)
    if p.ndim != 4 or grid.ndim != 1 or p.shape[2] != grid.shape[0]:
        raise ValueError(
            f"need obs_grid [G] and probs [agents, nodes, G, next_nodes]; got {grid.shape}, "
            f"{p.shape}"
        )
    agents, nodes, _, nxt = p.shape
    fig, axes = _subplots(
        agents,
        nodes,
        figsize=(2.8 * nodes + 1.2, 2.3 * agents + 0.6),
        squeeze=False,
        sharex=True,
        sharey=True,
    )
    colors = _colors(nxt)
    labels = [f"\u2192 q{j}" for j in range(nxt)]
    for i in range(agents):
        for q in range(nodes):
            ax = axes[i, q]
            ax.stackplot(grid, p[i, q].T, colors=colors, labels=labels, alpha=0.85)
            ax.set_xlim(grid[0], grid[-1])
            ax.set_ylim(0.0, 1.0)
            ax.set_title(f"agent {i}, node q{q}", fontsize=9)
            if q == 0:
                ax.set_ylabel("P(next node)")
            if i == agents - 1:
                ax.set_xlabel(obs_label)
    handles, lab = axes[0, 0].get_legend_handles_labels()
    fig.legend(
        handles, lab, title="next node", loc="center left", bbox_to_anchor=(1.0, 0.5), fontsize=8
    )
    return _save(fig, path, dpi, title)


# --------------------------------------------------------------------------- training curves


def plot_values(
    values_per_iteration,
    in_loop_best_per_iteration,
    path,
    title: str | None = None,
    reference: Mapping[str, float] | None = None,
    ylabel: str = "value",
    dpi: int = 120,
):
    """The value of each iteration (``values_per_iteration``, as the search reports it) and
    the in-loop best; ``reference`` maps a label to a value drawn as a dashed horizontal line
    (e.g. ``{"reactive controller": 20.76}``)."""
    values = np.asarray(values_per_iteration, dtype=float).reshape(-1)
    best = np.asarray(in_loop_best_per_iteration, dtype=float).reshape(-1)
    fig, ax = _subplots(figsize=(6.4, 3.8))
    ax.plot(
        np.arange(values.size),
        values,
        lw=1.0,
        alpha=0.7,
        color="tab:blue",
        label="value per iteration",
    )
    ax.plot(np.arange(best.size), best, lw=1.8, color="tab:orange", label="best so far")
    styles = ["--", ":", "-.", (0, (5, 1, 1, 1))]
    for k, (name, v) in enumerate((reference or {}).items()):
        ax.axhline(
            float(v),
            color=_colors(10)[(k + 2) % 10],
            ls=styles[k % len(styles)],
            lw=1.2,
            label=f"{name} ({float(v):g})",
        )
    ax.set_xlabel("iteration")
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")
    if title:
        ax.set_title(title)
    return _save(fig, path, dpi)


def plot_value_vs_noise(
    noise_levels,
    results: Mapping[str, tuple],
    path,
    title: str | None = None,
    xlabel: str = "noise level",
    ylabel: str = "value",
    dpi: int = 120,
):
    """Value against noise level with standard-error bars; ``results`` maps a variant name to
    ``(means [L], stderrs [L])`` over the ``noise_levels [L]``."""
    x = np.asarray(noise_levels, dtype=float).reshape(-1)
    fig, ax = _subplots(figsize=(6.0, 3.8))
    for name, (means, stderrs) in results.items():
        m = np.asarray(means, dtype=float).reshape(-1)
        s = np.asarray(stderrs, dtype=float).reshape(-1)
        if m.shape != x.shape or s.shape != x.shape:
            raise ValueError(f"variant {name!r}: means/stderrs must have shape {x.shape}")
        ax.errorbar(x, m, yerr=s, marker="o", ms=4, capsize=3, lw=1.4, label=str(name))
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    if results:
        ax.legend(fontsize=8, loc="best")
    if title:
        ax.set_title(title)
    return _save(fig, path, dpi)


# --------------------------------------------------------------------------- controller graphs


def controller_graph_edges(obs_grid, probs) -> list[tuple[int, int, list[Interval]]]:
    """Most likely transitions of one agent with a scalar observation.

    ``obs_grid [G]`` strictly ascending; ``probs [nodes, G, next_nodes]`` (probabilities or
    logits: only the argmax matters). For every source node the argmax next node is taken at each
    grid point; consecutive grid points with the same argmax form one interval whose bounds are the
    midpoints between neighbouring grid points, or ``-inf`` / ``+inf`` where the run reaches the
    ends of the grid. Returns ``(src, dst, [(lo, hi), ...])`` sorted by ``(src, dst)``, intervals
    ascending; intervals read ``(lo, hi]`` (ties in the argmax go to the lower node id).
    """
    grid = np.asarray(obs_grid, dtype=float)
    p = np.asarray(probs, dtype=float)
    if grid.ndim != 1 or grid.size == 0:
        raise ValueError(f"obs_grid must be a non-empty 1-D array, got shape {grid.shape}")
    if p.ndim != 3 or p.shape[1] != grid.size:
        raise ValueError(f"probs must be [nodes, G={grid.size}, next_nodes], got {p.shape}")
    if np.any(np.diff(grid) <= 0):
        raise ValueError("obs_grid must be strictly ascending")
    mids = (grid[:-1] + grid[1:]) / 2.0
    best = np.argmax(p, axis=-1)  # [nodes, G]
    edges = []
    for src in range(p.shape[0]):
        row = best[src]
        cuts = np.flatnonzero(row[1:] != row[:-1])  # last index of every run but the final one
        starts = np.concatenate([[0], cuts + 1])
        ends = np.concatenate([cuts, [grid.size - 1]])
        by_dst: dict[int, list[Interval]] = {}
        for s, e in zip(starts, ends, strict=True):
            lo = -math.inf if s == 0 else float(mids[s - 1])
            hi = math.inf if e == grid.size - 1 else float(mids[e])
            by_dst.setdefault(int(row[s]), []).append((lo, hi))
        edges.extend((src, dst, by_dst[dst]) for dst in sorted(by_dst))
    return edges


def tabular_graph_edges(
    transitions, obs_names: Sequence[str] | None = None
) -> list[tuple[int, int, list[str]]]:
    """Transitions of one deterministic tabular agent as edges.

    ``transitions [nodes, obs]`` int (next node per node and observation); ``obs_names`` one label
    per observation (default: the indices). Returns ``(src, dst, [observation labels])`` sorted by
    ``(src, dst)``, labels in observation order.
    """
    t = np.asarray(transitions)
    if t.ndim != 2:
        raise ValueError(f"transitions must be [nodes, obs], got {t.shape}")
    names = [str(k) for k in range(t.shape[1])] if obs_names is None else list(obs_names)
    if len(names) != t.shape[1]:
        raise ValueError(f"{len(names)} obs_names for {t.shape[1]} observations")
    edges = []
    for src in range(t.shape[0]):
        for dst in np.unique(t[src]):
            edges.append((src, int(dst), [str(names[z]) for z in np.flatnonzero(t[src] == dst)]))
    return edges


def _fmt_num(v: float) -> str:
    if math.isinf(v):
        return "inf" if v > 0 else "-inf"
    s = f"{round(float(v), 2) + 0.0:.2f}"  # + 0.0 turns -0.0 into 0.0
    return s[:-1] if s.endswith("0") else s


def format_interval(lo: float, hi: float) -> str:
    """``(lo, hi]`` with 1-2 decimals, ``)`` for an infinite upper bound: ``(-inf, -1.0]``."""
    return f"({_fmt_num(lo)}, {_fmt_num(hi)}{')' if math.isinf(hi) else ']'}"


#: the most observation labels an edge shows (a model of thousands of observations would
#: otherwise draw a label of thousands of names: minutes of text layout for an unreadable figure)
MAX_EDGE_LABELS = 12


def _edge_text(labels: Sequence) -> str:
    if len(labels) > MAX_EDGE_LABELS:
        shown = _edge_text(labels[: MAX_EDGE_LABELS - 1])
        return f"{shown}\n... ({len(labels)} in all)"
    parts = [
        lab if isinstance(lab, str) else format_interval(float(lab[0]), float(lab[1]))
        for lab in labels
    ]
    if all(not isinstance(lab, str) for lab in labels):
        return "\n".join(parts)
    per_line = 3
    return "\n".join(", ".join(parts[k : k + per_line]) for k in range(0, len(parts), per_line))


def _action_names(action_names, num_actions: int) -> list[str]:
    names = list(action_names) if action_names is not None else []
    return [names[a] if a < len(names) else f"a{a}" for a in range(num_actions)]


def _unit(deg: float) -> np.ndarray:
    r = math.radians(deg)
    return np.array([math.cos(r), math.sin(r)])


def _align(direction: np.ndarray) -> dict:
    dx, dy = direction
    ha = "left" if dx > 0.35 else ("right" if dx < -0.35 else "center")
    va = "bottom" if dy > 0.35 else ("top" if dy < -0.35 else "center")
    return dict(ha=ha, va=va)


_NODE_R, _LOOP, _RAD, _SCALE = 0.42, 0.75, 0.25, 0.75  # data units; _SCALE inches per unit
# where along an edge (Bezier parameter from the source) its label may go, in order of preference
_LABEL_TS = (0.4, 0.5, 0.3, 0.6, 0.25, 0.7, 0.2)


def _layout(nodes: int) -> tuple[list[float], list[np.ndarray], tuple[float, ...]]:
    """Node angles and centres on a circle (node 0 on top, clockwise) and the axes limits."""
    angles = [90.0 - 360.0 * q / nodes for q in range(nodes)]
    if nodes == 1:
        centers = [np.zeros(2)]
    else:
        ring = max(1.7, 1.45 / math.sin(math.pi / nodes))  # adjacent centres >= 2.9 apart
        centers = [ring * _unit(a) for a in angles]
    xy = np.array(centers)
    mx, my = _NODE_R + _LOOP + 1.1, _NODE_R + _LOOP + 0.4  # room for loops and their labels
    return (
        angles,
        centers,
        (xy[:, 0].min() - mx, xy[:, 0].max() + mx, xy[:, 1].min() - my, xy[:, 1].max() + my),
    )


def _text_box(pos, text: str, fontsize: float, ha: str = "center", va: str = "center"):
    """Approximate extent ``(x0, x1, y0, y1)`` in data units of a text drawn at ``pos``."""
    lines = text.split("\n")
    w = (0.6 * fontsize / 72 * max(len(line) for line in lines) + 0.06) / _SCALE
    h = (1.25 * fontsize / 72 * len(lines) + 0.04) / _SCALE
    x0 = {"left": pos[0], "right": pos[0] - w}.get(ha, pos[0] - w / 2)
    y0 = {"bottom": pos[1], "top": pos[1] - h}.get(va, pos[1] - h / 2)
    return (x0, x0 + w, y0, y0 + h)


def _overlap(a, b) -> float:
    return max(0.0, min(a[1], b[1]) - max(a[0], b[0])) * max(0.0, min(a[3], b[3]) - max(a[2], b[2]))


_NODE_FS, _EDGE_FS = 9, 8
_LABEL_BOX = dict(boxstyle="round,pad=0.15", facecolor="white", edgecolor="none", alpha=0.95)


def _draw_nodes(ax, probs: np.ndarray, names: list[str], centers, taken: list) -> list:
    """One circle per node with its most likely action and that action's probability; the
    start node has a thicker rim. Returns the circles (edges end at them)."""
    radius, circles = _NODE_R, []
    for q in range(probs.shape[0]):
        a = int(np.argmax(probs[q]))
        longest = max(len(names[a]), 4)
        circle = _mpl().Circle(
            centers[q],
            radius,
            facecolor="#f4f4f4",
            edgecolor="black",
            lw=2.2 if q == 0 else 1.3,
            zorder=6,
        )
        ax.add_patch(circle)
        circles.append(circle)
        ax.text(
            *centers[q],
            f"q{q}\n{names[a]}\n{probs[q, a]:.2f}",
            ha="center",
            va="center",
            fontsize=min(_NODE_FS, _NODE_FS * 7.0 / longest),
            zorder=7,
            linespacing=1.1,
        )
        x, y = centers[q]
        taken.append((x - radius, x + radius, y - radius, y + radius))
    return circles


def _draw_start(ax, c0, taken: list) -> None:
    """The start marker: an incoming arrow to node 0, from its upper left."""
    direction = _unit(160.0)
    tail = c0 + (_NODE_R + 0.65) * direction
    style = dict(arrowstyle="-|>", mutation_scale=14, lw=1.6, shrinkA=0, shrinkB=1, zorder=2)
    ax.add_patch(_mpl().FancyArrowPatch(tail, c0 + _NODE_R * direction, color="black", **style))
    start = tail + 0.05 * direction
    ax.text(*start, "start", fontsize=_NODE_FS, ha="right", va="center")
    taken.append(_text_box(start, "start", _NODE_FS, ha="right"))


def _draw_self_loop(ax, c, out, text: str, color, taken: list) -> None:
    """A loop on the node at ``c``, bulging in the direction ``out``, labelled ``text``."""
    radius, loop = _NODE_R, _LOOP
    theta = math.degrees(math.atan2(out[1], out[0]))
    verts = [
        c + radius * _unit(theta + 32),
        c + (radius + loop) * _unit(theta + 42),
        c + (radius + loop) * _unit(theta - 42),
        c + radius * _unit(theta - 32),
    ]
    mpl_path = _mpl().Path
    path = mpl_path(verts, [mpl_path.MOVETO, *[mpl_path.CURVE4] * 3])
    ax.add_patch(
        _mpl().FancyArrowPatch(
            path=path, arrowstyle="-|>", mutation_scale=12, color=color, lw=1.4, zorder=2
        )
    )
    pos = c + (radius + 0.62 * loop) * out
    ax.text(*pos, text, fontsize=_EDGE_FS, color=color, bbox=_LABEL_BOX, zorder=5, **_align(out))
    taken.append(_text_box(pos, text, _EDGE_FS, **_align(out)))


def _draw_arc(ax, c, end, patches, text: str, color, taken: list) -> None:
    """An arc from the node at ``c`` to the node at ``end`` (``patches``: their circles)."""
    style = dict(arrowstyle="-|>", mutation_scale=14, lw=1.4, shrinkA=1, shrinkB=1, zorder=2)
    style.update(connectionstyle=f"arc3,rad={_RAD}", patchA=patches[0], patchB=patches[1])
    ax.add_patch(_mpl().FancyArrowPatch(c, end, color=color, **style))
    # arc3 is a quadratic Bezier with this control point (in display space, which equals data
    # space up to scale since the aspect is equal); the label goes to the point along it that
    # overlaps least with what is already placed, preferring t = 0.4 (nearer the source)
    d = end - c
    ctrl = c + d / 2 + _RAD * np.array([d[1], -d[0]])
    best = None
    for t in _LABEL_TS:
        pos = (1 - t) ** 2 * c + 2 * t * (1 - t) * ctrl + t**2 * end
        tb = _text_box(pos, text, _EDGE_FS)
        score = sum(_overlap(tb, other) for other in taken)
        if best is None or score < best[0] - 1e-9:
            best = (score, pos, tb)
        if score == 0.0:
            break
    _, pos, tb = best
    taken.append(tb)
    label = dict(fontsize=_EDGE_FS, bbox=_LABEL_BOX, ha="center", va="center", zorder=5)
    ax.text(*pos, text, color=color, **label)


def _draw_graph(ax, probs: np.ndarray, edges: Sequence[Edge], names: list[str]) -> None:
    nodes = probs.shape[0]
    angles, centers, limits = _layout(nodes)
    colors = _colors(nodes)
    taken = []  # approximate boxes of what is drawn, to place edge labels where it is free
    circles = _draw_nodes(ax, probs, names, centers, taken)
    _draw_start(ax, centers[0], taken)
    # self-loops first (their labels have a fixed place), then the other edges
    for src, dst, labels in sorted(edges, key=lambda e: int(e[0]) != int(e[1])):
        src, dst = int(src), int(dst)
        text = _edge_text(labels)
        if src == dst:
            out = _unit(angles[src]) if nodes > 1 else _unit(90.0)
            _draw_self_loop(ax, centers[src], out, text, colors[src], taken)
        else:
            pair = (circles[src], circles[dst])
            _draw_arc(ax, centers[src], centers[dst], pair, text, colors[src], taken)
    ax.set_xlim(limits[0], limits[1])
    ax.set_ylim(limits[2], limits[3])
    ax.set_aspect("equal")
    ax.axis("off")


def plot_controller_graphs(
    action_probs,
    edges_per_agent: Sequence[Sequence[Edge]],
    action_names: Sequence[str],
    path,
    title: str | None = None,
    dpi: int = 130,
):
    """Draw every agent's controller as a graph, one panel per agent.

    ``action_probs [agents, nodes, actions]`` (or ``[agents, nodes]`` int actions of a
    deterministic controller); ``edges_per_agent[i]`` is a list of ``(src, dst, labels)`` as
    returned by ``controller_graph_edges`` (labels ``(lo, hi)`` intervals) or
    ``tabular_graph_edges`` (labels strings). Nodes sit on a circle, each showing its id, most
    likely action and that action's probability; an edge is an arrow coloured by its source node
    and labelled with the observations that lead there; self-loops point outwards; node 0 has an
    incoming "start" arrow.
    """
    probs = np.asarray(action_probs)
    names_in = list(action_names) if action_names is not None else []
    if probs.ndim == 2:  # deterministic actions -> one-hot
        k = max(len(names_in), int(probs.max()) + 1)
        probs = np.eye(k)[probs.astype(int)]
    probs = probs.astype(float)
    if probs.ndim != 3:
        raise ValueError(f"action_probs must be [agents, nodes, actions], got {probs.shape}")
    agents = probs.shape[0]
    if len(edges_per_agent) != agents:
        raise ValueError(f"{len(edges_per_agent)} edge lists for {agents} agents")
    names = _action_names(names_in, probs.shape[2])
    x0, x1, y0, y1 = _layout(probs.shape[1])[2]
    scale = _SCALE  # fonts stay fixed, so the figure grows with the node count
    fig, axes = _subplots(
        1, agents, figsize=(scale * (x1 - x0) * agents, scale * (y1 - y0) + 0.6), squeeze=False
    )
    for i, ax in enumerate(axes[0]):
        _draw_graph(ax, probs[i], edges_per_agent[i], names)
        ax.set_title(f"agent {i}")
    return _save(fig, path, dpi, title)


def plot_sweep_values(result: dict, path, label) -> str | Path:
    """A sweep's value of each iteration (``values_per_iteration``), mean over seeds +- s.e.
    per setting (``label`` names a setting's grid values)."""
    fig, ax = _subplots(figsize=(7, 4))
    for index, values in enumerate(result["settings"]):
        v = np.array([r["values_per_iteration"] for r in result["rows"] if r["setting"] == index])
        mean = v.mean(0)
        se = v.std(0, ddof=1) / np.sqrt(v.shape[0]) if v.shape[0] > 1 else np.zeros_like(mean)
        x = np.arange(1, mean.size + 1)
        (line,) = ax.plot(x, mean, label=label(values))
        ax.fill_between(x, mean - se, mean + se, color=line.get_color(), alpha=0.2)
    ax.set_xlabel("iteration")
    ax.set_ylabel("value of the iteration (mean over seeds +- s.e.)")
    ax.set_title(f"{result['experiment']}: {len(result['seeds'])} seeds per setting")
    ax.legend(fontsize=8)
    return _save(fig, path, 120)


def plot_position_map(grid, low: int, high: int, path, title: str, label: str, dpi: int = 110):
    """``grid [x, y]`` over the positions ``low..high`` in both coordinates, as an image."""
    fig, ax = _subplots(figsize=(4.6, 3.8))
    im = ax.imshow(grid, origin="lower", extent=(low - 0.5, high + 0.5, low - 0.5, high + 0.5))
    ax.set_xlabel("y")
    ax.set_ylabel("x")
    ax.set_title(title)
    fig.colorbar(im, ax=ax, label=label)
    return _save(fig, path, dpi)
