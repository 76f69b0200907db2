"""Batched rollouts: ``lax.scan`` over time, vectorised over rollouts (and, for the candidates
of an iteration, over candidate policies inside the same scan: ``evaluate_candidates``). Works
with any environment of ``cognet_jax.envs.base`` and any controller kind of
``cognet_jax.controllers``.

Per time step t (SPEC section 1): every agent draws ``a_t`` from its node, the environment
returns ``r_t = R(s_t, a_t)``, ``s_{t+1}`` and ``z_{t+1}``, every agent moves to
``q_{t+1} ~ g(. | q_t, z_{t+1})``. The return is ``sum_t gamma^t r_t`` with ``gamma`` read from
``env_params.discount``. All agents start in node 0.

Random numbers: one key drives a whole batch of rollouts. Each time step draws one block of
uniforms ``[rollouts, 2 agents + env.step_noise]`` (the controller's action and transition draws,
then the simulator's noise), so there is one generator call per step for all rollouts instead of
one per rollout. Common random numbers across candidate policies = the same key for every
candidate: ``evaluate_candidates`` draws the block once per step, outside the step functions'
``vmap`` over the candidates, and every candidate reads it.

Speed without changing a number: each uniform is drawn once, in a kernel XLA cannot fuse it
into several times, and the loop state XLA must copy at every step is kept small.

- Rollouts last (``agents_major`` controllers) and one key per batch of rollouts
  (``rollouts``; candidates with keys of their own): the kernel that draws the next nodes of
  step t also draws their uniforms from step t's block, then the actions of step t + 1 from
  the next block, and holds node and action as one integer (``node x actions + action``,
  16-bit for controllers with ``narrow_nodes``). The simulator's uniforms, read by several
  kernels, are drawn one step ahead and carried through the scan. The loop state is then the
  simulator's state, that integer, the returns and the simulator's uniforms: no block of the
  controller's uniforms is stored, nor copied twice per step as XLA copies loop state that
  several kernels read (benchmarks/NOTES.md, "Eleventh pass").
- Otherwise the whole block is drawn one step ahead, carried through the scan and read by
  every kernel and candidate: candidates sharing each step's block (common random numbers in
  ``evaluate_candidates``) would compute draws made in the kernels again for each candidate,
  and the rollouts-first layout ran 0.7-0.99x as fast with them.

Drawn inside each step, XLA fused the generator into every kernel that reads the block (the
action draw, the env step's outputs, the node draw) and computed it again in each. Threefry
keys are drawn through ``prng.fast_key`` (the same stream, written out without JAX's CPU loop).
tests/test_rollout.py checks the engine against the plain scan that draws inside each step.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

from cognet_jax.memory import candidate_chunk, traced_bytes
from cognet_jax.prng import fast_key


@struct.dataclass
class Trajectory:
    """What a batch of R rollouts did (leading axis R).

    ``nodes [R, H, agents]`` q_t, ``actions [R, H, agents]`` a_t, ``obs [R, H, agents, *obs_shape]``
    z_{t+1}, ``next_nodes [R, H, agents]`` q_{t+1}, ``rewards [R, H]`` r_t, ``ret [R]`` discounted
    return.
    """

    nodes: jax.Array
    actions: jax.Array
    obs: jax.Array
    next_nodes: jax.Array
    rewards: jax.Array
    ret: jax.Array


def shard_rollouts(tree):
    """Lay the leading ``[rollouts]`` axis of every leaf over the ``"rollouts"`` axis of the
    active mesh (``jax.set_mesh``); without such a mesh the arrays are returned unchanged."""
    mesh = jax.sharding.get_abstract_mesh()
    if mesh.empty or "rollouts" not in mesh.axis_names:
        return tree
    spec = jax.sharding.PartitionSpec("rollouts")
    return jax.tree.map(lambda x: jax.lax.with_sharding_constraint(x, spec), tree)


def rollouts(
    env, controller, key: jax.Array, num: int, env_params: Any, policy: Any, record: bool = False
):
    """``num`` rollouts of one (stochastic or deterministic) joint ``policy``.

    Returns the discounted returns ``[num]``, or a ``Trajectory`` when ``record`` is true.
    Several policies on the same ``key``: ``evaluate_candidates`` draws each step's uniforms
    once for all of them; ``vmap`` of this function over the policies gives the same numbers
    but may draw the controller's uniforms again for each policy (module docstring, "Speed").
    """
    return _simulate(env, controller, key, num, env_params, policy, record=record)


def _simulate(
    env, controller, key, num, env_params, policy, record=False, lanes=None, shared_key=False
):
    """The rollout engine. ``lanes``: None (one policy, one key), or ``(policy_axes,
    key_axis)`` for C candidate policies at once (``policy_axes`` the vmap ``in_axes`` prefix
    of ``policy``; ``key_axis`` 0 when ``key`` holds one key per candidate, None for one key
    shared by all): the scan over time then advances every candidate's rollouts, its step
    functions ``vmap``-ed over the candidates, and returns ``[C, num]``.

    The same computation as ``vmap`` over the candidates of the one-policy engine, bit for bit
    (tests/test_rollout.py), traced in less time: JAX batches a ``vmap``-ed ``lax.scan`` by
    tracing its body again, twice when the carry becomes batched (and the memory probe is
    spared too).

    ``shared_key``: the caller ``vmap``s this over policies that share ``key`` (one
    candidate's engine under ``evaluate_candidates``' chunks): the block is then drawn one
    step ahead and carried, as for candidates sharing a key in ``lanes``.

    Layout (``_Steps``): the step functions are ``vmap``-ed over the rollouts, which are the
    leading axis of every array, or, for controllers with ``agents_major`` (small written-out
    node networks), the last."""
    if record and lanes is not None:
        raise ValueError("rollouts of several candidates are not recorded")
    n, h = env.num_agents, env.horizon
    policy_axes, key_axis = lanes if lanes is not None else (None, None)

    def lane(fn, *axes):
        """``fn`` over the candidates (``vmap`` with ``axes``), or ``fn`` with one policy."""
        return fn if lanes is None else jax.vmap(fn, in_axes=axes)

    def per_key(fn):
        """``fn`` of a key, over the candidates' keys when each has its own."""
        return fn if key_axis is None else jax.vmap(fn)

    def uniforms(k, width):
        return shard_rollouts(jax.random.uniform(fast_key(k), (num, width)))

    steps = _Steps(env, controller, lane, key_axis, policy_axes)
    k_reset, k_steps = per_key(lambda k: tuple(jax.random.split(k)))(key)
    states = per_key(lambda k: steps.reset(uniforms(k, env.reset_noise), env_params))(k_reset)
    nodes = steps.initial_nodes(num, n)
    ret = jnp.zeros(num, jnp.float32)
    if lanes is not None:
        count = _count(policy, policy_axes)
        lead = lambda x: jnp.broadcast_to(x, (count, *x.shape))  # noqa: E731
        nodes, ret = lead(nodes), lead(ret)
        if key_axis is None:  # every candidate starts from the same states
            states = jax.tree.map(lead, states)

    step_keys = per_key(lambda k: jax.random.split(k, h))(k_steps)
    if key_axis is not None:
        step_keys = jnp.swapaxes(step_keys, 0, 1)  # [h, C]

    def block(k):
        """A step's uniforms ``[*C, R, width]`` in the steps' layout."""
        return steps.uniform_layout(per_key(lambda k: uniforms(k, 2 * n + env.step_noise))(k))

    # draws in the kernels that read them: rollouts last (the faster layout on CPU), and no
    # other policy reads this batch's block (a key per candidate, or one policy that no caller
    # vmaps over a shared key)
    unshared = key_axis is not None or (lanes is None and not shared_key)
    in_kernel = steps.rollouts_last and unshared
    loop = _TimeLoop(env, controller, steps, policy, env_params, block, in_kernel, record)
    ret, out = loop.run(step_keys, states, nodes, ret)
    if not record:
        return ret
    return Trajectory(*(steps.trajectory_layout(x) for x in out), ret)


# Horizons past this many steps sum the returns with compensation (``_TimeLoop.add``): a plain
# float32 sum of h rewards can be off by up to about h x 6e-8 of their total, which at a million
# steps is a wrong leading digit; up to it, the plain sum (off by at most about 1e-3 of the
# total), which keeps every shorter run's numbers as they were.
COMPENSATED_AFTER = 2**14


class _TimeLoop:
    """The scan over time of ``_simulate`` (see the module docstring, "Speed").

    Step t reads the simulator's states, what is held of the nodes and the uniforms carried
    from step t - 1, and the keys of steps t and t + 1. ``in_kernel``: the step holds ``node x
    actions + action`` (16-bit for controllers with ``narrow_nodes``) and the simulator's
    uniforms, and draws the next nodes' uniforms from step t's key in the kernel that reads
    them; otherwise it holds the nodes and step t's whole block, drawn one step ahead."""

    def __init__(self, env, controller, steps, policy, env_params, block, in_kernel, record):
        self.env, self.steps, self.policy, self.env_params = env, steps, policy, env_params
        self.block, self.in_kernel, self.record = block, in_kernel, record
        self.base = env.num_actions
        narrow = getattr(controller, "narrow_nodes", False)
        narrow = narrow and controller.num_nodes * self.base < 2**15  # node x actions fit
        self.held_dtype = jnp.int16 if narrow else jnp.int32
        self.gamma = jnp.asarray(env_params.discount, jnp.float32)

    def draw(self, k):
        """A step's uniforms: the actions', the next nodes' and the simulator's."""
        n, steps = self.env.num_agents, self.steps
        u_ctrl, u_env = steps.split_uniforms(self.block(k), 2 * n)
        return (*steps.split_uniforms(u_ctrl, n), u_env)

    def held(self, nodes, u):
        """What the next step starts from besides the states: nodes and uniforms."""
        if not self.in_kernel:
            return nodes, u
        u_act, _, u_env = u
        actions = self.steps.act(u_act, self.policy, nodes)
        return (nodes * self.base + actions).astype(self.held_dtype), u_env

    def step(self, carry, k, k_next):
        """Time step t from ``carry`` and the keys of steps t and t + 1 (None at the last):
        the next carry, or the returns at the last step, and what ``record`` keeps."""
        steps, policy = self.steps, self.policy
        states, held_nodes, u, ret, disc = carry
        if self.in_kernel:  # node * base + action, and the simulator's uniforms
            nodes, actions = jnp.divmod(held_nodes.astype(jnp.int32), self.base)
            u_move, u_env = self.draw(k)[1], u
        else:  # the nodes, and the step's block
            nodes, (u_act, u_move, u_env) = held_nodes, u
            actions = steps.act(u_act, policy, nodes)
        states, obs, reward = steps.env_step(u_env, states, actions, self.env_params)
        next_nodes = steps.move(u_move, policy, nodes, obs)
        ret = self.add(ret, disc * reward.astype(jnp.float32))  # also from float64 rewards
        out = (nodes, actions, obs, next_nodes, reward) if self.record else None
        if k_next is None:
            return (ret[0] if self.compensated else ret), out
        return (states, *self.held(next_nodes, self.draw(k_next)), ret, disc * self.gamma), out

    def add(self, ret, term):
        """``ret + term`` in float32; past ``COMPENSATED_AFTER`` steps a compensated (Kahan)
        sum, ``ret`` the pair (sum, the low-order part it lost)."""
        if not self.compensated:
            return ret + term
        total, lost = ret
        term = term - lost
        new_total = total + term
        return new_total, (new_total - total) - term

    def run(self, step_keys, states, nodes, ret):
        """The returns after every step of ``step_keys [h, ...]``, and the steps' records
        stacked over time (None without ``record``)."""
        self.compensated = step_keys.shape[0] > COMPENSATED_AFTER
        if self.compensated:
            ret = (ret, jnp.zeros_like(ret))
        init = (states, *self.held(nodes, self.draw(step_keys[0])), ret, jnp.float32(1.0))
        carry, out = jax.lax.scan(
            lambda c, ks: self.step(c, *ks), init, (step_keys[:-1], step_keys[1:])
        )
        ret, out_last = self.step(carry, step_keys[-1], None)
        if self.record:
            out = jax.tree.map(lambda a, b: jnp.concatenate([a, b[None]]), out, out_last)
        return ret, out


class _Steps:
    """The batched step functions of ``_simulate`` and the layout of their arrays.

    Rollouts first (every controller but those below): ``vmap`` over the rollouts of the
    per-rollout functions (``controller.act``, ``env.step``, ``controller.next_node``), so
    every array is ``[*C, R, ...]`` (``C`` the candidates when there are several).

    Rollouts last (controllers with ``agents_major``: small written-out node networks that
    read the observations themselves): the rollouts are the minor axis of every array,
    ``[*C, ..., R]``. The controller's per-agent
    functions (``agent_act``, ``agent_next_node``) are ``vmap``-ed over the rollouts, then
    the agents, so the networks' arrays are ``[*C, agents, R]``; ``env.step`` is ``vmap``-ed
    with the rollouts' axis last (``in_axes``/``out_axes`` -1); each step's uniform block is
    transposed once, to ``[*C, width, R]``. The same operations on every element, so the same
    numbers (tests/test_neural.py); with the agents (2 for tagging) or a network's logits as
    the minor axis XLA's CPU loops ran the networks at half the speed (benchmarks/NOTES.md,
    "Eighth pass"). The trajectories of ``record`` are transposed back at the end."""

    def __init__(self, env, controller, lane, key_axis, policy_axes):
        self.rollouts_last = bool(getattr(controller, "agents_major", False))
        axis = -1 if self.rollouts_last else 0  # the rollouts' axis of one lane's arrays
        self.reset = jax.vmap(env.reset, (0, None), axis)
        self.env_step = lane(
            jax.vmap(env.step, (axis, axis, axis, None), axis), key_axis, 0, 0, None
        )
        if not self.rollouts_last:
            self.act = lane(jax.vmap(controller.act, (0, None, 0)), key_axis, policy_axes, 0)
            move = jax.vmap(controller.next_node, (0, None, 0, 0))
            self.move = lane(move, key_axis, policy_axes, 0, 0)
            return
        self.act = lane(_per_agent(controller.agent_act, 0, None, 0), key_axis, policy_axes, 0)
        # agents-major controllers read the observations themselves (no ``features``)
        self.move = lane(
            _per_agent(controller.agent_next_node, 0, None, 0, -1), key_axis, policy_axes, 0, 0
        )

    def uniform_layout(self, u: jax.Array) -> jax.Array:
        """A step's block ``[*C, R, width]`` in this layout."""
        return jnp.swapaxes(u, -1, -2) if self.rollouts_last else u

    def split_uniforms(self, u: jax.Array, at: int) -> tuple[jax.Array, jax.Array]:
        """The first ``at`` uniforms of each rollout and the rest."""
        if self.rollouts_last:
            return u[..., :at, :], u[..., at:, :]
        return u[..., :at], u[..., at:]

    def initial_nodes(self, num: int, agents: int) -> jax.Array:
        """Every agent in node 0: ``[R, agents]``, or ``[agents, R]`` with the rollouts last."""
        shape = (agents, num) if self.rollouts_last else (num, agents)
        return jnp.zeros(shape, jnp.int32)

    def trajectory_layout(self, x: jax.Array) -> jax.Array:
        """A recorded ``[H, ...]`` array (one step's array stacked over time) as ``[R, H,
        ...]``."""
        return jnp.moveaxis(x, -1, 0) if self.rollouts_last else jnp.swapaxes(x, 0, 1)


def _per_agent(fn, *rollout_axes):
    """``fn`` of one agent (its uniform, its slice of the policy, its node, ...) ``vmap``-ed
    over the rollouts (the last axis of the result; ``rollout_axes`` the ``in_axes``), then
    over the agents (the leading axis of every argument, of the policy's leaves too)."""
    over_rollouts = jax.vmap(fn, rollout_axes, -1)
    return jax.vmap(over_rollouts, tuple(0 for _ in rollout_axes))


def _batched(policy_axes, policies, fn):
    """``fn`` applied to every leaf of ``policies`` that has the candidates' axis."""

    def mapped(ax, sub):
        return sub if ax is None else jax.tree.map(fn, sub)

    return jax.tree.map(mapped, policy_axes, policies, is_leaf=lambda x: x is None)


def _count(policies, policy_axes) -> int:
    """The number of candidates: the leading axis of ``policies``' batched leaves."""
    return jax.tree.leaves(_batched(policy_axes, policies, lambda x: x))[0].shape[0]


def evaluate_candidates(
    env,
    controller,
    key: jax.Array,
    num: int,
    env_params: Any,
    policies: Any,
    policy_axes: Any = 0,
    memory: int | None = None,
    common_random_numbers: bool = True,
) -> jax.Array:
    """Mean return ``[C]`` of C candidate policies, each rolled out ``num`` times: all with the
    same ``key`` (common random numbers) or, with ``common_random_numbers=False``, candidate c
    with ``split(key, C)[c]``. ``policy_axes`` is the vmap ``in_axes`` prefix of ``policies``
    (e.g. batch only the action tables and share the networks). The same numbers, bit for bit,
    as ``vmap`` over the candidates of ``rollouts(...).mean()``.

    ``memory``: bytes the ``C x num`` rollouts in flight may take (None: half the machine,
    ``memory.budget_bytes``). The evaluation of all candidates at once is traced first; when
    the arrays it creates, summed (``memory.traced_bytes``), exceed the budget, the candidates
    are evaluated a chunk at a time (``lax.map`` with ``batch_size``, sized by
    ``memory.candidate_chunk``): every rollout's return is bit for bit the same as unchunked,
    and so is each mean up to its last bit (XLA sums a row in an order that depends on the
    batch shape). One candidate's ``num`` rollouts over the budget raise
    ``errors.ResourceError`` while tracing, before anything compiles.
    """
    count = _count(policies, policy_axes)
    keys = key if common_random_numbers else jax.random.split(key, count)
    lanes = (policy_axes, None if common_random_numbers else 0)

    def every(keys, policies):
        returns = _simulate(env, controller, keys, num, env_params, policies, lanes=lanes)
        return returns.mean(axis=-1)

    traced = jax.make_jaxpr(every)(keys, policies)
    chunk = candidate_chunk(
        lambda k, p, n, e: rollouts(env, controller, k, n, e, p),
        env_params,
        _batched(policy_axes, policies, lambda x: x[0]),
        count,
        num,
        memory,
        cache=(id(env), id(controller)),
        upper_bound=traced_bytes(traced.jaxpr),
    )
    if chunk >= count:  # what was traced, not traced again
        flat = jax.tree.leaves((keys, policies))
        return jax.core.eval_jaxpr(traced.jaxpr, traced.consts, *flat)[0]

    def by_index(i):
        k = keys if common_random_numbers else keys[i]
        policy = _batched(policy_axes, policies, lambda x: x[i])
        shared = common_random_numbers  # ``lax.map`` with a batch size ``vmap``s this
        return _simulate(env, controller, k, num, env_params, policy, shared_key=shared).mean()

    return jax.lax.map(by_index, jnp.arange(count), batch_size=chunk)


def many_returns(
    env, controller, key: jax.Array, env_params: Any, policy: Any, num: int, batch: int = 10_000
) -> jax.Array:
    """Returns ``[num]`` of ``num`` rollouts, computed ``batch`` at a time (bounded memory);
    chunk c uses ``fold_in(key, c)``."""
    if num <= batch:
        return rollouts(env, controller, key, num, env_params, policy)
    chunks = -(-num // batch)
    out = jax.lax.map(
        lambda c: rollouts(env, controller, jax.random.fold_in(key, c), batch, env_params, policy),
        jnp.arange(chunks),
    )
    return out.reshape(-1)[:num]


def mean_and_stderr(returns: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Mean and standard error of a 1-D array of returns."""
    r = returns.astype(jnp.float32)
    return r.mean(), r.std(ddof=1) / jnp.sqrt(r.shape[0])
