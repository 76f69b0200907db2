"""The forms of ``NeuralController``'s node networks give the same numbers bit for bit with XLA's
default CPU emitters: the scan over the nodes, the members written out and the current node's
member alone with its picked weights, alone and inside the rollout engine, and the engine's
rollouts-last layout (``agents_major``) against the per-rollout one."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.extend.core import jaxprs_in_params

from cognet_jax.controllers.neural import (
    AGENTS_MAJOR_MAX_NODES,
    UNROLL_MIN_NODES,
    NeuralController,
)
from cognet_jax.envs.tagging import make_tagging
from cognet_jax.rollout import rollouts

#: XLA's default CPU emitters, which the suite turns off (tests/shared_files.SUITE_XLA_FLAGS;
#: its older emitters round the two forms differently in their last bits)
DEFAULT_EMITTERS = {"xla_cpu_use_fusion_emitters": True}


@pytest.mark.parametrize("nodes,obs_shape", [(4, ()), (6, ()), (5, (3,))])
def test_unrolled_and_scan_node_logits_are_identical(nodes, obs_shape):
    ctrl = NeuralController(2, nodes, 3, obs_shape=obs_shape)
    assert ctrl.unrolled and nodes >= UNROLL_MIN_NODES
    params = ctrl.init(jax.random.key(0)).net_params
    k_obs, k_nodes = jax.random.split(jax.random.key(1))
    obs = 8.0 * jax.random.normal(k_obs, (4096, 2, *obs_shape))
    current = jax.random.randint(k_nodes, (4096, 2), 0, nodes)

    def batched(fn):  # compiled with XLA's default emitters, as a user's process compiles
        lowered = jax.jit(jax.vmap(fn, (None, 0, 0))).lower(params, current, obs)
        return lowered.compile(compiler_options=DEFAULT_EMITTERS)(params, current, obs)

    unrolled = np.asarray(batched(ctrl.unrolled_node_logits))
    scanned = np.asarray(batched(ctrl.scan_node_logits))
    np.testing.assert_array_equal(unrolled.view(np.uint32), scanned.view(np.uint32))
    # and both are the current node's member, as the Flax module computes it
    member = jax.tree.map(lambda p: p[1, 2], params)
    at = np.flatnonzero(np.asarray(current[:, 1]) == 2)[:5]
    direct = jax.vmap(lambda o: ctrl.net.apply(member, o))(obs[at, 1])
    np.testing.assert_allclose(unrolled[at, 1], direct, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("nodes,obs_shape,hidden", [(3, (), 10), (6, (), 10), (3, (3,), 32)])
def test_selected_member_logits_are_the_scan_ones(nodes, obs_shape, hidden):
    """The current node's member alone, its weights picked by ``where``s (``agents_major``
    controllers), gives the logits of every member kept where the agent is in that node."""
    ctrl = NeuralController(2, nodes, 3, obs_shape=obs_shape, hidden=hidden)
    assert ctrl.unrolled
    params = ctrl.init(jax.random.key(0)).net_params
    k_obs, k_nodes = jax.random.split(jax.random.key(1))
    obs = 8.0 * jax.random.normal(k_obs, (4096, 2, *obs_shape))
    current = jax.random.randint(k_nodes, (4096, 2), 0, nodes)

    def batched(fn):  # compiled with XLA's default emitters, as a user's process compiles
        lowered = jax.jit(jax.vmap(jax.vmap(fn), (None, 0, 0))).lower(params, current, obs)
        return lowered.compile(compiler_options=DEFAULT_EMITTERS)(params, current, obs)

    picked = np.stack(batched(ctrl.selected_member_logits), axis=-1)
    scanned = np.asarray(batched(ctrl.scan_agent_logits))
    np.testing.assert_array_equal(picked.view(np.uint32), scanned.view(np.uint32))
    assert len(np.unique(picked)) > nodes * 100


def test_rollouts_do_not_depend_on_the_form(monkeypatch):
    """The per-rollout engine (``agents_major`` off) with the members written out or scanned."""
    env, params = make_tagging("cogdice-paper")  # noisy, respawn
    ctrl = NeuralController(env.num_agents, 6, env.num_actions)
    monkeypatch.setattr(NeuralController, "agents_major", property(lambda self: False))
    policy = ctrl.init(jax.random.key(3))
    key = jax.random.key(4)

    def run():
        out = jax.jit(lambda k, p: rollouts(env, ctrl, k, 512, params, p, record=True))(key, policy)
        return jax.tree.map(np.asarray, out)

    unrolled = run()
    monkeypatch.setattr(NeuralController, "agent_node_logits", NeuralController.scan_agent_logits)
    scanned = run()
    for a, b in zip(jax.tree.leaves(unrolled), jax.tree.leaves(scanned), strict=True):
        np.testing.assert_array_equal(a, b)
    assert jnp.size(jax.tree.leaves(unrolled)[0]) > 0


@pytest.mark.parametrize("nodes,cases", [(3, (0, 1, 2)), (AGENTS_MAJOR_MAX_NODES, (1,))])
def test_agents_major_rollouts_are_the_per_rollout_ones(monkeypatch, nodes, cases):
    """The engine lays the arrays of small-network controllers with at most
    ``AGENTS_MAJOR_MAX_NODES`` nodes out with the rollouts last (``agents_major``: per-agent
    draws, one array per logit, the current member's picked weights): the same returns and
    trajectories bit for bit as the per-rollout ``act`` / ``next_node`` with the ``[nodes]``
    logits, for one policy and for candidates with their own or shared networks, compiled as a
    user's process compiles them (``cases``: which of these three; at 6 nodes the candidates
    with their own networks, the picks themselves are compared at 6 nodes above)."""
    from cognet_jax.controllers.neural import NeuralPolicy
    from cognet_jax.rollout import evaluate_candidates

    env, params = make_tagging("cogdice-paper")  # noisy, respawn
    ctrl = NeuralController(env.num_agents, nodes, env.num_actions)
    assert ctrl.agents_major
    policies = jax.vmap(ctrl.init)(jax.random.split(jax.random.key(5), 4))
    shared = NeuralPolicy(policies.action_probs, jax.tree.map(lambda p: p[0], policies.net_params))
    key = jax.random.key(6)

    def run():
        one = jax.tree.map(lambda p: p[1], policies)
        programs = [
            lambda: rollouts(env, ctrl, key, 256, params, one, record=True),
            lambda: evaluate_candidates(env, ctrl, key, 128, params, policies),
            lambda: evaluate_candidates(
                env, ctrl, key, 128, params, shared, NeuralPolicy(0, None), None, False
            ),
        ]
        chosen = [programs[i] for i in cases]
        compiled = [jax.jit(p).lower().compile(compiler_options=DEFAULT_EMITTERS) for p in chosen]
        return jax.tree.map(np.asarray, [c() for c in compiled])

    agents_major = run()
    monkeypatch.setattr(NeuralController, "agents_major", property(lambda self: False))
    per_rollout = run()
    for a, b in zip(jax.tree.leaves(agents_major), jax.tree.leaves(per_rollout), strict=True):
        np.testing.assert_array_equal(
            a.view(np.uint32) if a.dtype == np.float32 else a,
            b.view(np.uint32) if b.dtype == np.float32 else b,
        )


def test_narrow_nodes_hold_16_bit_integers_up_to_the_measured_limit(monkeypatch):
    """Controllers with few picks ask the engine to hold node and action as a 16-bit integer
    (``narrow_nodes``); the 6-node benchmark's 430 picks keep 32 bits. The numbers are those
    of the per-rollout engine, bit for bit (``test_agents_major_rollouts_are_the_per_rollout_ones``
    at 3 nodes: recorded rollouts, candidates with their own keys)."""
    assert not NeuralController(2, AGENTS_MAJOR_MAX_NODES, 3).narrow_nodes  # 430 picks
    env, params = make_tagging("cogdice-paper")
    ctrl = NeuralController(env.num_agents, 3, env.num_actions)
    assert ctrl.narrow_nodes
    one = ctrl.init(jax.random.key(7))

    def held_in_16_bits():
        fn = lambda: rollouts(env, ctrl, jax.random.key(8), 200, params, one)  # noqa: E731
        return "x200xi16>" in jax.jit(fn).lower().as_text()

    assert held_in_16_bits()
    monkeypatch.setattr(NeuralController, "narrow_nodes", property(lambda self: False))
    assert not held_in_16_bits()


def _jit_calls(jaxpr, name: str) -> list:
    """The ``jit`` equations named ``name`` in ``jaxpr`` and every jaxpr nested in it."""
    found = []
    for eqn in jaxpr.eqns:
        if eqn.primitive.name in ("jit", "pjit") and eqn.params["name"] == name:
            found.append(eqn)
        for sub in jaxprs_in_params(eqn.params):
            found += _jit_calls(sub, name)
    return found


@pytest.mark.parametrize(
    "nodes,network",
    [(3, "_selected_member_outputs"), (AGENTS_MAJOR_MAX_NODES + 1, "_written_out_mlp")],
)
def test_jitted_helpers_are_traced_once_and_change_no_number(monkeypatch, nodes, network):
    """``normal_from_uniform`` and the written-out networks (the current member's, one array
    per logit, for the rollouts-last layout; every member's ``[nodes]`` vector from
    ``UNROLL_MIN_NODES`` nodes in the per-rollout one) are ``jit``s
    so that a rollout traces each once per shape (envs/base.py): every call site of a rollout
    holds the same traced jaxpr, and the rollouts are the numbers of the same code without the
    ``jit``s."""
    import cognet_jax.controllers.neural as neural
    import cognet_jax.envs.base as base

    env, params = make_tagging("cogdice-paper", motion_noise=0.3, obs_noise=0.3)  # normal draws
    ctrl = NeuralController(env.num_agents, nodes, env.num_actions)  # written-out networks
    policy = ctrl.init(jax.random.key(3))
    key = jax.random.key(4)

    def fresh():  # a new function each time: JAX keeps a function's traces
        return lambda k, p: rollouts(env, ctrl, k, 512, params, p, record=True)

    jaxpr = jax.make_jaxpr(fresh())(key, policy).jaxpr
    for name in ("normal_from_uniform", network):
        calls = _jit_calls(jaxpr, name)
        assert len(calls) >= 2, name  # the scan's body and the last step
        assert len({id(c.params["jaxpr"]) for c in calls}) == 1, name
    jitted = jax.tree.map(np.asarray, jax.jit(fresh())(key, policy))
    monkeypatch.setattr(base, "normal_from_uniform", base.normal_from_uniform.__wrapped__)
    monkeypatch.setattr(neural, network, getattr(neural, network).__wrapped__)
    for name in ("normal_from_uniform", network):
        assert not _jit_calls(jax.make_jaxpr(fresh())(key, policy).jaxpr, name)
    plain = jax.tree.map(np.asarray, jax.jit(fresh())(key, policy))
    for a, b in zip(jax.tree.leaves(jitted), jax.tree.leaves(plain), strict=True):
        np.testing.assert_array_equal(a, b)


def test_eager_controller_set_up_is_a_few_programs_and_the_numbers_of_the_plain_code():
    """Building a controller's search distribution, sampling it and initialising node networks
    outside a program (as a user's script or a test does) compiles a few whole programs, not
    every single operation (``uniform_distribution``, ``categorical_from_uniform``,
    ``TabularController.init_distribution`` / ``sample`` and
    ``NeuralController.init_net_params`` are ``jit``s), and gives the numbers of the same code
    run operation by operation."""
    from jax import monitoring

    from cognet_jax.controllers.tabular import TabularController

    # sizes no other test uses, so every program is new to this process
    tabular = TabularController(2, 6, 5, 7, action_counts=(5, 4), layers=3)
    neural = NeuralController(2, 5, 4, obs_shape=(7,), hidden=11)
    key = jax.random.key(9)
    traced = []

    def count(event, duration, **_):
        if event.endswith("jaxpr_trace_duration"):
            traced.append(duration)

    monitoring.register_event_duration_secs_listener(count)
    try:
        dist = tabular.init_distribution()
        sampled = tabular.sample(key, dist)
        nets = neural.init(key)
    finally:
        monitoring.unregister_event_duration_listener(count)
    # 4 programs traced; 74 single operations before these were jits (2026-11-27)
    assert len(traced) <= 12, len(traced)

    with jax.disable_jit():  # every operation on its own, the jits inside included
        plain_dist = tabular.init_distribution()
        plain_sampled = tabular.sample(key, plain_dist)
        plain_nets = neural.init_net_params(key)
    pairs = [(dist, plain_dist), (sampled, plain_sampled), (nets.net_params, plain_nets)]
    for jitted, plain in pairs:
        for a, b in zip(jax.tree.leaves(jitted), jax.tree.leaves(plain), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
