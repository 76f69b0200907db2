"""Figures of each controller kind's best policy, drawn for the searches' ``write_plots``
hooks (``engine.Search``); the run's value curve is ``reporting``'s.

* ``neural_plots``: ``actions.png`` (each node's action distribution) and, on a scalar network
  input, ``node_responses.png`` (next-node probabilities over the observation range) and
  ``controllers.png`` (each agent's controller as a graph: node -> most likely action, edges
  labelled with the observation intervals where that next node is the most likely). For the
  encoded pipeline with a 1-D latent they are drawn over the VAE mean ``mu`` (range: the mu of
  the clean patches at every reachable position, widened by 10 %);
* ``region_plots`` / ``tabular_plots``: ``controllers.png`` of region and tabular controllers;
* ``plot_vae_mu``: the heatmap VAE's mean over the reachable positions (``cognet-jax vae``).
"""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from cognet_jax import plots
from cognet_jax.controllers.regions import region_graph_edges
from cognet_jax.plots import run_title
from cognet_jax.vae import HIGH, LOW, reachable_patches


def action_names(env) -> tuple:
    """Names of the actions (the simulator's ``action_names``, else their indices)."""
    return getattr(env, "action_names", tuple(str(a) for a in range(env.num_actions)))


def neural_node_probs(controller, policy, grid: np.ndarray) -> np.ndarray:
    """Next-node probabilities ``[agents, nodes, G, next_nodes]`` on a scalar observation grid."""
    logits = jax.vmap(
        lambda z: controller.all_node_logits(
            policy.net_params, jnp.full((controller.num_agents,), z, jnp.float32)
        )
    )(jnp.asarray(grid, jnp.float32))
    return np.asarray(jax.nn.softmax(logits, -1)).transpose(1, 2, 0, 3)


def _scalar_feature_grid(algorithm, env, points: int = 401):
    """``(grid [points], label)`` of a scalar network input, or ``(None, None)`` when the
    networks read a vector (e.g. raw heatmap patches)."""
    pipeline = getattr(algorithm, "pipeline", None)
    if pipeline is not None and pipeline.kind == "encoded" and pipeline.feature_shape == (1,):
        mu = np.asarray(pipeline.features(jnp.asarray(reachable_patches())))[:, 0]
        pad = 0.1 * (mu.max() - mu.min())
        return np.linspace(mu.min() - pad, mu.max() + pad, points), "VAE mean mu"
    if env.obs_shape == () and env.obs_range is not None:
        lo, hi = env.obs_range
        return np.linspace(lo, hi, points), "observation"
    return None, None


def region_plots(env, policy, results: dict, out_dir) -> list[Path]:
    """``controllers.png`` of a deterministic region controller: each agent's
    graph, edges labelled with the observation intervals of its regions."""
    edges = [
        region_graph_edges(np.asarray(policy.points[i]), np.asarray(policy.transitions[i]))
        for i in range(env.num_agents)
    ]
    path = Path(out_dir) / "controllers.png"
    actions = np.asarray(policy.actions)
    title = run_title(results)
    return [Path(plots.plot_controller_graphs(actions, edges, action_names(env), path, title))]


def tabular_plots(env, policy, results: dict, out_dir, names, observation_names) -> list[Path]:
    """``controllers.png`` of a deterministic tabular controller: each agent's
    graph, edges labelled with ``observation_names [agents][obs]``; ``names``: the actions'."""
    edges = [
        plots.tabular_graph_edges(np.asarray(policy.transitions[i]), observation_names[i])
        for i in range(env.num_agents)
    ]
    path = Path(out_dir) / "controllers.png"
    actions = np.asarray(policy.actions)
    return [Path(plots.plot_controller_graphs(actions, edges, names, path, run_title(results)))]


def neural_plots(algorithm, policy, results: dict, out_dir) -> list[Path]:
    """Figures of a neural (COGNet-DICE) policy: ``actions.png`` always; on a scalar network
    input (module docstring) also ``node_responses.png`` and ``controllers.png``."""
    env, out_dir, title = algorithm.env, Path(out_dir), run_title(results)
    names = action_names(env)
    action_probs = np.asarray(policy.action_probs)
    written = [
        plots.plot_action_distributions(
            action_probs, names, out_dir / "actions.png", title=f"{title}: action distributions"
        )
    ]
    grid, obs_label = _scalar_feature_grid(algorithm, env)
    if grid is not None:
        probs = neural_node_probs(algorithm.controller, policy, grid)
        written.append(
            plots.plot_node_responses(
                grid,
                probs,
                out_dir / "node_responses.png",
                title=f"{title}: next-node probabilities",
                obs_label=obs_label,
            )
        )
        edges = [plots.controller_graph_edges(grid, p) for p in probs]
        written.append(
            plots.plot_controller_graphs(
                action_probs, edges, names, out_dir / "controllers.png", title=title
            )
        )
    return [Path(p) for p in written]


def plot_vae_mu(vae, path) -> Path:
    """Thesis Fig. 5.10: the VAE mean mu of the clean patch seen from every reachable
    position (x, y)."""
    mu = np.asarray(vae.encode(jnp.asarray(reachable_patches()))[0])[:, 0]
    grid = mu.reshape(HIGH - LOW + 1, HIGH - LOW + 1)
    title = "VAE mean mu over reachable positions"
    return Path(plots.plot_position_map(grid, LOW, HIGH, path, title, "mu"))
