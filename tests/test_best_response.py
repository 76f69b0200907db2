"""Exact best response of one agent in a layered controller (``algorithms.best_response``)."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from shared_files import dpomdp_file as _file

from cognet_jax.algorithms.best_response import best_response
from cognet_jax.controllers.tabular import DeterministicTabularPolicy, TabularController
from cognet_jax.envs.tabular import make_tabular
from cognet_jax.exact import exact_value as exact_numpy
from cognet_jax.exact import exact_values, policy_tree_transitions, tree_num_nodes
from cognet_jax.io.dpomdp import parse_dpomdp


def _reachable_part(actions, transitions, num_obs):
    """The nodes of one agent's controller (``actions [nodes]``, ``transitions [nodes, obs]``)
    that node 0 reaches through its ``num_obs`` observations, renumbered in the order found:
    the same policy on fewer nodes."""
    order, seen = [0], {0}
    for q in order:
        for nxt in transitions[q, :num_obs]:
            if int(nxt) not in seen:
                seen.add(int(nxt))
                order.append(int(nxt))
    new_id = np.zeros(len(actions), np.int64)
    new_id[order] = np.arange(len(order))
    return actions[order], new_id[transitions[order]]


def _tree_values(model, other_actions, other_trans, agent, horizon):
    """Exact value of every deterministic policy tree of ``agent`` against the other agent's
    fixed controller (brute force, numpy, one batch; the other controller cut to the nodes it
    reaches, so joint nodes are fewer)."""
    other_actions, other_trans = _reachable_part(
        other_actions, other_trans, model.obs_counts[1 - agent]
    )
    z, a = model.obs_counts[agent], model.action_counts[agent]
    nodes = tree_num_nodes(z, horizon)
    trees = np.array(list(itertools.product(range(a), repeat=nodes)), np.int64)
    width = max(nodes, other_actions.shape[0])
    acts = np.zeros((len(trees), 2, width), np.int64)
    tr = np.zeros((len(trees), 2, width, max(model.obs_counts)), np.int64)
    acts[:, agent, :nodes], tr[:, agent, :nodes, :z] = trees, policy_tree_transitions(z, horizon)
    other = 1 - agent
    acts[:, other, : len(other_actions)] = other_actions
    tr[:, other, : len(other_actions)] = other_trans
    return np.asarray(exact_values(model, acts, tr, horizon, 1.0))


def _layered_controller(env, width, horizon):
    """A 2-agent controller of ``horizon`` layers of ``width`` nodes for ``env``."""
    return TabularController(
        2,
        width * horizon,
        env.num_actions,
        env.num_obs,
        action_counts=env.action_counts,
        obs_counts=env.obs_counts,
        layers=horizon,
    )


def _responders(env, params, width) -> dict:
    """Agent -> its best response, compiled (one program per agent, whatever the policy)."""
    return {a: jax.jit(lambda p, a=a: best_response(env, params, p, width, a)) for a in (0, 1)}


def _check_response(model, respond, policy, agent, horizon):
    """The agent's response (``respond[agent]``) is worth the best of its enumerated trees, its
    layers play that value exactly, and the other agent's rows are untouched; returns the new
    policy."""
    new, value, fits = respond[agent](policy)
    other = 1 - agent
    trees = _tree_values(
        model,
        np.asarray(policy.actions[other]),
        np.asarray(policy.transitions[other]),
        agent,
        horizon,
    )
    assert bool(fits)  # the tests' widths hold every history of a layer
    # the best tree of this agent, found by enumerating every one of them
    assert float(value) == pytest.approx(trees.max(), abs=1e-3)
    got = exact_numpy(model, np.asarray(new.actions), np.asarray(new.transitions), horizon, 1.0)
    assert got == pytest.approx(trees.max(), abs=1e-3)
    assert np.array_equal(np.asarray(new.actions[other]), np.asarray(policy.actions[other]))
    assert np.array_equal(np.asarray(new.transitions[other]), np.asarray(policy.transitions[other]))
    return new


@pytest.mark.parametrize("name, horizon, width", [("dectiger", 3, 4), ("recycling", 3, 4)])
def test_best_response_is_the_best_tree_and_its_layers_play_it(name, horizon, width):
    model = parse_dpomdp(_file(name), discount=1.0)
    env, params = make_tabular(model, horizon)
    ctrl = _layered_controller(env, width, horizon)
    respond = _responders(env, params, width)
    for seed in range(3):
        policy = ctrl.sample(jax.random.key(seed), ctrl.init_distribution())
        for agent in (0, 1):  # 2 observations: at most 4 histories in the last layer
            _check_response(model, respond, policy, agent, horizon)


def test_a_response_that_needs_more_nodes_than_a_layer_has_is_refused():
    model = parse_dpomdp(_file("dectiger"), discount=1.0)
    env, params = make_tabular(model, 3)
    ctrl = TabularController(2, 3, env.num_actions, env.num_obs, layers=3)  # width 1
    # the other agent listens twice: the best response opens the door the growls point away
    # from, which needs different actions after different observations at step 3
    policy = DeterministicTabularPolicy(
        actions=jnp.zeros((2, 3), jnp.int32),
        transitions=jnp.asarray([[[1, 1], [2, 2], [2, 2]]] * 2, jnp.int32),
    )
    assert ctrl.layer_width == 1
    listen = int(np.argmax([a == "listen" for a in model.action_names[0]]))
    policy = policy.replace(actions=jnp.full((2, 3), listen, jnp.int32))
    new, value, fits = jax.jit(lambda p: best_response(env, params, p, 1, 0))(policy)
    assert not bool(fits)
    assert np.array_equal(np.asarray(new.actions), np.asarray(policy.actions))
    before = exact_numpy(model, np.asarray(policy.actions), np.asarray(policy.transitions), 3, 1.0)
    assert float(value) > before  # the tree exists, it only does not fit


def _random_model_text(seed: int, states: int, actions, observations) -> str:
    """A random 2-agent MADP model whose agents differ (two-decimal probabilities, so the
    rows sum to 1 exactly in the text)."""
    rng = np.random.default_rng(seed)

    def row(n):
        shares = 1 + rng.multinomial(100 - n, np.ones(n) / n)
        return " ".join(f"{k / 100:.2f}" for k in shares)

    lines = ["agents: 2", "discount: 1", "values: reward", f"states: {states}", "start:"]
    lines += ["uniform", "actions:", *map(str, actions), "observations:", *map(str, observations)]
    for a0, a1 in itertools.product(range(actions[0]), range(actions[1])):
        for s in range(states):
            lines += [f"T: {a0} {a1} : {s} :", row(states)]
            lines += [f"O: {a0} {a1} : {s} :", row(observations[0] * observations[1])]
            lines.append(f"R: {a0} {a1} : {s} : * : * : {rng.normal():.2f}")
    return "\n".join(lines) + "\n"


def test_best_response_of_agents_with_different_action_and_observation_counts():
    """Agent 0 has 3 actions and 2 observations, agent 1 has 2 actions and 3 observations:
    each agent's response is the best of its enumerated trees (2,187 and 8,192 of them)."""
    horizon, width = 3, 9
    model = parse_dpomdp(_random_model_text(4, 3, (3, 2), (2, 3)).encode(), discount=1.0)
    env, params = make_tabular(model, horizon)
    ctrl = _layered_controller(env, width, horizon)
    policy = ctrl.sample(jax.random.key(0), ctrl.init_distribution())
    respond = _responders(env, params, width)
    for agent in (0, 1):  # at most 9 histories in a layer
        new = _check_response(model, respond, policy, agent, horizon)
        # the agent's actions stay within its own action count
        assert int(np.asarray(new.actions[agent]).max()) < model.action_counts[agent]
