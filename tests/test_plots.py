import math

import numpy as np
import pytest

from cognet_jax import plots

ACTIONS = ("tag", "left", "right")
PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _assert_png(path):
    assert path.exists()
    data = path.read_bytes()
    assert len(data) > 1000
    assert data[:8] == PNG_MAGIC


def _reactive_probs(grid, nodes=3):
    """[nodes, G, 3]: z <= -1 -> node 0 (left), -1 < z <= 1 -> node 1 (tag), z > 1 -> node 2."""
    target = np.where(grid <= -1.0, 0, np.where(grid <= 1.0, 1, 2))
    probs = np.full((nodes, grid.size, 3), 0.05)
    probs[:, np.arange(grid.size), target] = 0.9
    return probs


def test_controller_graph_edges_reactive():
    grid = np.linspace(-10.0, 10.0, 41)  # step 0.5
    edges = plots.controller_graph_edges(grid, _reactive_probs(grid))
    expected_intervals = {0: [(-math.inf, -0.75)], 1: [(-0.75, 1.25)], 2: [(1.25, math.inf)]}
    assert [(s, d) for s, d, _ in edges] == [(s, d) for s in range(3) for d in range(3)]
    for _, dst, intervals in edges:
        assert intervals == expected_intervals[dst]


def test_controller_graph_edges_boundaries_on_midpoints_and_split_regions():
    grid = np.arange(-9.75, 10.0, 0.5)  # midpoints fall on the integers
    target = np.where(np.abs(grid) <= 1.0, 1, 0)  # node 0 on both sides of the tag region
    probs = np.zeros((1, grid.size, 2))
    probs[0, np.arange(grid.size), target] = 1.0
    edges = plots.controller_graph_edges(grid, probs)
    assert edges == [(0, 0, [(-math.inf, -1.0), (1.0, math.inf)]), (0, 1, [(-1.0, 1.0)])]


def test_controller_graph_edges_constant_and_ties():
    grid = np.array([-1.0, 0.0, 1.0])
    probs = np.ones((2, 3, 4))  # all tied -> lowest id
    edges = plots.controller_graph_edges(grid, probs)
    assert edges == [(0, 0, [(-math.inf, math.inf)]), (1, 0, [(-math.inf, math.inf)])]
    with pytest.raises(ValueError):
        plots.controller_graph_edges(grid[::-1], probs)


def test_tabular_graph_edges():
    transitions = np.array([[0, 1, 1], [2, 2, 0], [2, 2, 2]])
    edges = plots.tabular_graph_edges(transitions, ["hear-left", "hear-right", "none"])
    assert edges == [
        (0, 0, ["hear-left"]),
        (0, 1, ["hear-right", "none"]),
        (1, 0, ["none"]),
        (1, 2, ["hear-left", "hear-right"]),
        (2, 2, ["hear-left", "hear-right", "none"]),
    ]
    assert plots.tabular_graph_edges(np.array([[1, 0]]))[0] == (0, 0, ["1"])


def test_format_interval():
    assert plots.format_interval(-math.inf, -1.0) == "(-inf, -1.0]"
    assert plots.format_interval(-0.75, 1.25) == "(-0.75, 1.25]"
    assert plots.format_interval(1.0, math.inf) == "(1.0, inf)"
    assert plots.format_interval(-0.001, 0.123) == "(0.0, 0.12]"


def test_plot_action_distributions(tmp_path):
    probs = np.random.default_rng(0).dirichlet(np.ones(3), size=(2, 4))
    path = tmp_path / "actions.png"
    plots.plot_action_distributions(probs, ACTIONS, path, title="actions")
    _assert_png(path)


def test_plot_node_responses(tmp_path):
    grid = np.linspace(-10.0, 10.0, 41)
    logits = np.random.default_rng(1).normal(size=(2, 3, 1, 3)) * grid[None, None, :, None] / 5
    probs = np.exp(logits) / np.exp(logits).sum(-1, keepdims=True)
    path = tmp_path / "responses.png"
    plots.plot_node_responses(grid, probs, path, title="responses", obs_label="z")
    _assert_png(path)


def test_plot_values(tmp_path):
    values = np.random.default_rng(2).normal(size=30).cumsum()
    path = tmp_path / "sub" / "values.png"
    plots.plot_values(
        values,
        np.maximum.accumulate(values),
        path,
        title="run",
        reference={"reactive controller": 20.76, "random": -23.68},
    )
    _assert_png(path)
    path2 = tmp_path / "values2.png"
    plots.plot_values(values, np.maximum.accumulate(values), path2)
    _assert_png(path2)


def test_plot_value_vs_noise(tmp_path):
    noise = [0.0, 0.5, 1.0]
    results = {"cognet": ([10.0, 8.0, 5.0], [0.5, 0.6, 0.7]), "cogdice": ([9, 6, 2], [1, 1, 1])}
    path = tmp_path / "noise.png"
    plots.plot_value_vs_noise(noise, results, path, title="robustness")
    _assert_png(path)
    with pytest.raises(ValueError):
        plots.plot_value_vs_noise(noise, {"bad": ([1.0], [0.1])}, tmp_path / "bad.png")


def test_plot_controller_graphs_continuous(tmp_path):
    grid = np.linspace(-10.0, 10.0, 41)
    edges = plots.controller_graph_edges(grid, _reactive_probs(grid))
    action_probs = np.tile(
        np.array([[0.02, 0.96, 0.02], [0.9, 0.05, 0.05], [0.1, 0.1, 0.8]]), (2, 1, 1)
    )
    path = tmp_path / "graph.png"
    plots.plot_controller_graphs(action_probs, [edges, edges[:4]], ACTIONS, path, title="reactive")
    _assert_png(path)


def test_plot_controller_graphs_discrete_and_sizes(tmp_path):
    transitions = np.array([[0, 1], [1, 0]])
    edges = plots.tabular_graph_edges(transitions, ["hear-left", "hear-right"])
    actions = np.array([[0, 2]])  # deterministic actions [agents, nodes]
    path = tmp_path / "tabular.png"
    plots.plot_controller_graphs(actions, [edges], ["listen", "open-left", "open-right"], path)
    _assert_png(path)
    for nodes in (1, 8):
        rng = np.random.default_rng(nodes)
        t = rng.integers(0, nodes, size=(nodes, 3))
        path = tmp_path / f"tabular{nodes}.png"
        plots.plot_controller_graphs(
            rng.dirichlet(np.ones(3), size=(1, nodes)),
            [plots.tabular_graph_edges(t)],
            ACTIONS,
            path,
        )
        _assert_png(path)
