"""The default COGNet-DICE: cross-entropy over node-network weights (cognet_weights.py)."""

import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.algorithms.cognet_weights import CognetWeights
from cognet_jax.algorithms.cognet_weights_settings import (
    NARROW_INPUTS,
    SEARCH_LONG_HORIZON,
    SEARCH_SHORT_HORIZON,
    WHITEN_FLOOR,
    WeightsHyper,
    WeightsSettings,
    cover_probability,
    covers_rarely,
    input_whitening,
    missed_inputs,
)
from cognet_jax.algorithms.engine import SearchParams
from cognet_jax.algorithms.weight_space import WeightSample, distinct_draw, reproduces_distinct
from cognet_jax.api import build_algorithm, make_train, split_seed_key
from cognet_jax.config import ConfigError
from cognet_jax.envs.tagging import make_tagging
from cognet_jax.observations import input_covariance, input_statistics
from cognet_jax.prng import fast_key
from cognet_jax.registry import load_config

SMALL_SIZES = {"iterations": 2, "candidates": 8, "eval_rollouts": 16, "elites": 4}


def small_algorithm(**kw):
    """``(algorithm, params)``: the weight search on thesis tagging with small sizes."""
    env, env_params = make_tagging("thesis")
    settings = WeightsSettings(**{"nodes": 3, **SMALL_SIZES, **kw})
    return CognetWeights(env, settings), SearchParams(env_params, WeightsHyper())


def test_sampled_policy_is_an_ordinary_neural_policy():
    alg, _ = small_algorithm()
    template = alg.controller.init(jax.random.key(0))
    samples = alg.draw(jax.random.key(1), alg.init_distribution(), 5)
    policy = alg.to_policy(jax.tree.map(lambda x: x[0], samples))
    assert jax.tree.structure(policy) == jax.tree.structure(template)
    for got, want in zip(jax.tree.leaves(policy), jax.tree.leaves(template)):
        assert got.shape == want.shape
    # one-hot actions; each hidden unit votes for exactly one next node
    assert np.allclose(np.asarray(policy.action_probs).sum(-1), 1.0)
    w2 = np.asarray(policy.net_params["params"]["Dense_1"]["kernel"])  # [agents, Q, H, Q]
    assert ((w2 != 0).sum(-1) <= 1).all()


def test_refit_to_identical_elites_concentrates_up_to_the_floors():
    alg, params = small_algorithm(elites=4)
    dist = alg.init_distribution()
    one = jax.tree.map(lambda x: x[0], alg.draw(jax.random.key(2), dist, 1))
    elites = jax.tree.map(lambda x: jnp.stack([x] * 4), one)
    hyper = params.hyper.replace(alpha=1.0, action_floor=0.1, category_floor=0.2)
    new = alg.update_distribution(dist, elites, hyper)
    chosen = np.take_along_axis(
        np.asarray(new.action_probs), np.asarray(one.actions)[..., None], -1
    )
    assert np.allclose(chosen, 0.9 + 0.1 / alg.env.num_actions)
    assert np.allclose(np.asarray(new.w1_mean), np.asarray(one.w1))
    assert np.allclose(np.asarray(new.w1_std), 0.0)
    q = alg.settings.nodes
    top = np.asarray(new.unit_target_probs).max(-1)
    assert np.allclose(top, 0.8 + 0.2 / q)


def test_common_random_numbers_give_equal_values_to_equal_candidates():
    alg, params = small_algorithm()

    @jax.jit
    def values_of_twice():
        one = alg.draw(jax.random.key(3), alg.init_distribution(), 1)
        twice = jax.tree.map(lambda x: jnp.concatenate([x[:1], x[:1]]), one)
        return alg.evaluate(jax.random.key(4), alg.to_policy(twice), params)

    values = values_of_twice()
    assert float(values[0]) == float(values[1])


def best_open_loop_value(alg, params, key) -> float:
    """Largest mean return of any open-loop joint controller of ``alg``'s 3 nodes (node q
    always moves to q + 1: actions fixed per time step, observations ignored), 2000 rollouts
    each with common random numbers (the maximum is biased upwards)."""
    env = alg.env
    a, q = env.num_agents, alg.settings.nodes
    seqs = list(itertools.product(range(env.num_actions), repeat=q))
    joint = np.array(list(itertools.product(seqs, repeat=a)), np.int32)  # [n, agents, Q]
    n = joint.shape[0]
    h = alg.settings.hidden
    f = alg.controller.in_features
    nxt = np.minimum(np.arange(q) + 1, q - 1)
    sample = WeightSample(
        actions=jnp.asarray(joint),
        w1=jnp.zeros((n, a, q, f, h)),
        b1=jnp.zeros((n, a, q, h)),
        unit_targets=jnp.zeros((n, a, q, h), jnp.int32),
        m=jnp.zeros((n, a, q, h)),
        default=jnp.broadcast_to(jnp.asarray(nxt, jnp.int32), (n, a, q)),
        bias=jnp.full((n, a, q), 50.0),
        node_tie=jnp.zeros((n, a), jnp.int32),
        agent_tie=jnp.zeros((n,), jnp.int32),
    )
    blind = CognetWeights(env, WeightsSettings(nodes=q, hidden=h, eval_rollouts=2000))
    return float(jnp.max(jax.jit(blind.evaluate)(key, blind.to_policy(sample), params)))


def test_cognet_dice_learns_to_use_observations_on_tagging():
    """A short default search (seed 0) on the thesis tagging problem beats every open-loop
    controller by a wide margin, and so does the *mode* of its final distribution: a search
    that does not learn (its distribution stays where it started) can at best pick a lucky
    random candidate, never a good mode."""
    sets = [
        "algorithm.iterations=100",
        "algorithm.candidates=100",
        "algorithm.eval_rollouts=200",
        "algorithm.best_rollouts=500",
    ]
    config = load_config("tagging-thesis-n3", sets)
    alg, params = build_algorithm(config)
    key = jax.random.key(0)
    state, metrics = jax.jit(make_train(config))(key)
    _, _, k_eval = split_seed_key(key)
    value_of = jax.jit(lambda p: alg.returns(k_eval, p, 10_000, params).mean())
    best = float(value_of(alg.best_policy(state)))
    mode = jax.jit(lambda d: alg.to_policy(alg.mode(d)))(state.distribution)
    mode_value = float(value_of(mode))
    blind = best_open_loop_value(alg, params, jax.random.key(5))
    assert blind < 0.0
    assert best > blind + 16.0, (best, blind)
    assert mode_value > blind + 12.0, (mode_value, blind)
    assert metrics.value.shape == (100,)


@pytest.mark.parametrize(
    "field,value",
    [
        ("elites", 1),
        ("elites", 300),
        ("candidates", 0),
        ("alpha", 1.5),
        ("action_floor", -0.1),
        ("best_rollouts", 0),
        ("vote_std", float("nan")),
        ("refine_redraw", 1.5),
    ],
)
def test_bad_settings_name_the_field(field, value):
    with pytest.raises(ConfigError) as err:
        load_config("tagging-thesis-n3", [f"algorithm.{field}={value}"])
    assert f"algorithm.{field}" in str(err.value)


def test_thesis_algorithm_keeps_its_own_name():
    config = load_config("tagging-thesis-spec-n3")
    assert config.experiment.algorithm == "cognet-dice-thesis"
    assert type(build_algorithm(config)[0]).__name__ == "CognetThesis"
    assert type(build_algorithm(load_config("tagging-thesis-n3"))[0]).__name__ == "CognetWeights"


def heatmap_algorithm(**kw):
    """The weight search on the heatmap; with ``standardize_inputs`` the input statistics of
    the default params (as ``cognet_weights_entry.build`` computes them)."""
    from cognet_jax.envs.heatmap import make_heatmap

    env, env_params = make_heatmap("default")
    settings = WeightsSettings(**{"nodes": 3, "candidates": 4, "eval_rollouts": 16, **kw})
    stats = None
    if settings.standardize_inputs is True:  # "auto" (the default) made in code: as no stats
        plain = {**kw, "standardize_inputs": False, "whiten_inputs": False}
        controller = CognetWeights(env, settings.__class__(**plain))
        measured = (env, controller.controller, controller.pipeline, env_params)
        stats = input_statistics(*measured)
        if settings.whiten_inputs is True:
            stats = input_whitening(stats, input_covariance(*measured))
    return CognetWeights(env, settings, input_stats=stats)


def test_standardized_inputs_fold_into_the_first_layer():
    """With ``standardize_inputs`` the sampled weights act on ``(x - mean) / scale``: the
    policy's first layer applied to a raw patch equals the sample's weights applied to the
    standardised patch, and the statistics are those of real patches (pixels in [0, 1],
    spread > 0)."""
    from cognet_jax.envs.heatmap import all_patches

    alg = heatmap_algorithm(standardize_inputs=True, hidden=5)
    mean, scale = (np.asarray(x) for x in alg.input_stats)
    assert mean.shape == scale.shape == (2, 16)
    assert ((mean > 0) & (mean < 1)).all() and (scale > 0.01).all()
    samples = alg.draw(jax.random.key(7), alg.init_distribution(), 3)
    policy = alg.to_policy(samples)  # a leading candidate axis
    x = jnp.asarray(all_patches()[:10])  # [10, 16]
    layer = policy.net_params["params"]["Dense_0"]
    got = jnp.einsum("pf,cagfh->cagph", x, layer["kernel"]) + layer["bias"][:, :, :, None]
    z = (x[None, None] - mean[None, :, None]) / scale[None, :, None]  # [1, agents, 10, 16]
    want = jnp.einsum("capf,cagfh->cagph", z[None, 0], samples.w1) + samples.b1[:, :, :, None]
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-4, atol=1e-3)
    plain = heatmap_algorithm(hidden=5)
    assert plain.input_stats is None
    with pytest.raises(ValueError, match="input_stats"):
        CognetWeights(plain.env, WeightsSettings(nodes=3, hidden=5, standardize_inputs=True))
    same = plain.to_policy(samples).net_params["params"]["Dense_0"]["kernel"]
    np.testing.assert_array_equal(np.asarray(same), np.asarray(samples.w1))


def test_whitened_inputs_fold_into_the_first_layer():
    """With ``whiten_inputs`` the sampled weights act on ``(x - mean) @ transform``, whose
    covariance over the measured patches is the identity: the policy's first layer applied
    to a raw patch equals the sample's weights applied to the whitened patch."""
    from cognet_jax.envs.heatmap import all_patches

    alg = heatmap_algorithm(standardize_inputs=True, whiten_inputs=True, hidden=5)
    assert alg.settings.whiten_inputs is True
    mean, transform = (np.asarray(x, np.float64) for x in alg.input_stats)
    assert mean.shape == (2, 16) and transform.shape == (2, 16, 16)
    # the transform whitens the covariance it came from, T' C T = I, along every direction
    # above the floor (the heatmap's noise-free patches have a singular covariance)
    env, controller = alg.env, alg.controller
    covariance = input_covariance(env, controller, alg.pipeline, env.default_params())
    covariance = np.asarray(covariance, np.float64)
    for a in range(2):
        values = np.linalg.eigvalsh(covariance[a])
        floor = WHITEN_FLOOR * values.max()
        want = np.sort(np.clip(values / np.maximum(values, floor), 0.0, 1.0))
        got = np.linalg.eigvalsh(transform[a].T @ covariance[a] @ transform[a])
        np.testing.assert_allclose(np.sort(got), want, atol=2e-2)
        assert (values >= floor).sum() >= 3  # the mean level and two gradients whitened
    samples = alg.draw(jax.random.key(7), alg.init_distribution(), 3)
    policy = alg.to_policy(samples)
    x = jnp.asarray(all_patches()[:10])  # [10, 16]
    layer = policy.net_params["params"]["Dense_0"]
    got = jnp.einsum("pf,cagfh->cagph", x, layer["kernel"]) + layer["bias"][:, :, :, None]
    z = jnp.einsum("apf,afg->apg", jnp.asarray(x[None] - mean[:, None], jnp.float32), transform)
    want = jnp.einsum("apf,cagfh->cagph", z, samples.w1) + samples.b1[:, :, :, None]
    np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-3, atol=2e-2)


def test_whitening_standardises_and_cannot_be_asked_without_it():
    """``whiten_inputs`` (off by default) decides ``standardize_inputs = "auto"`` on; with
    standardisation off it is refused, naming the field."""
    sizes = [f"algorithm.{k}={v}" for k, v in SMALL_SIZES.items()]
    assert load_config("plume-n5", sizes).algorithm.whiten_inputs is False
    whiten = [*sizes, "algorithm.whiten_inputs=true"]
    decided = load_config("tagging-thesis-n3", whiten).algorithm
    assert decided.whiten_inputs is True and decided.standardize_inputs is True
    with pytest.raises(ValueError, match="whiten_inputs"):
        load_config("plume-n5", [*whiten, "algorithm.standardize_inputs=false"])


def test_paired_best_keeps_the_best_unless_a_challenger_beats_it_on_the_same_rollouts():
    """A step whose candidates are all much worse than the best so far keeps the best policy
    (and reports its own paired estimate as the best value, no stale maximum); a best that a
    challenger beats is replaced."""
    alg, params = small_algorithm(paired_best=True, best_pool=0, best_rollouts=200, elites=2)
    state = alg.init(jax.random.key(0), params)
    assert alg.rollouts_per_iteration == 8 * 16 + 3 * 200
    # a known good reactive controller as the best so far
    good = reactive_tagging_policy(alg)
    kept = state.replace(best_policy=good, progress=state.progress.replace(in_loop_best=1e9))
    new, metrics = jax.jit(alg.step)(jax.random.key(1), kept, params)
    chex_equal = jax.tree.map(lambda a, b: bool(jnp.all(a == b)), new.best_policy, good)
    assert all(jax.tree.leaves(chex_equal))
    assert 10.0 < float(metrics.in_loop_best) < 1e9  # the paired estimate, not the stale 1e9
    # the worst possible best (always tag: -40 per step) is replaced
    bad = good.replace(action_probs=jax.nn.one_hot(jnp.zeros((2, 3), jnp.int32), 3))
    new, metrics = jax.jit(alg.step)(jax.random.key(1), state.replace(best_policy=bad), params)
    assert not bool(jnp.all(new.best_policy.action_probs == bad.action_probs))
    assert float(metrics.in_loop_best) > -120.0


def test_the_pool_keeps_its_member_with_the_best_bound_as_the_best_policy():
    """With ``best_pool`` the best policy is the pool's member with the largest lower
    confidence bound, its value the member's mean over the iterations it was raced; a known
    good controller put in the pool stays the best policy against poor challengers."""
    alg, params = small_algorithm(best_pool=3, best_rollouts=200, elites=2)
    assert alg.rollouts_per_iteration == 8 * 16 + (2 + 3) * 200
    state = alg.init(jax.random.key(0), params)
    step = jax.jit(alg.step)
    for i in range(3):
        state, metrics = step(jax.random.key(i + 1), state, params)
    pool = state.pool
    best = int(pool.best())
    same = jax.tree.map(lambda a, b: bool(jnp.all(a == b)), state.best_policy, pool.member(best))
    assert all(jax.tree.leaves(same))
    assert float(metrics.in_loop_best) == pytest.approx(float(pool.means()[best]))
    good = reactive_tagging_policy(alg)
    stacked = jax.tree.map(lambda x: jnp.stack([x] * 3), good)
    start = pool.replace(
        policies=stacked,
        mean=jnp.array([15.0, -jnp.inf, -jnp.inf]),
        m2=jnp.zeros(3),
        count=jnp.array([1, 0, 0]),
    )
    state = state.replace(pool=start)
    for i in range(2):
        state, metrics = step(jax.random.key(10 + i), state, params)
    same = jax.tree.map(lambda a, b: bool(jnp.all(a == b)), state.best_policy, good)
    assert all(jax.tree.leaves(same)) and int(state.pool.count.max()) == 3


def reactive_tagging_policy(alg):
    """SPEC 8's reactive 3-node controller as a node network of ``alg`` (thesis tagging):
    node 0 moves left, 1 tags, 2 moves right; every node goes to node 0 below -1, node 2
    above 1 and node 1 in between (two ReLU units voting strongly)."""
    a, q, h = 2, 3, alg.settings.hidden
    w1 = np.zeros((a, q, 1, h), np.float32)
    b1 = np.zeros((a, q, h), np.float32)
    targets = np.zeros((a, q, h), np.int32)
    m = np.zeros((a, q, h), np.float32)
    w1[..., 0, 0], b1[..., 0], targets[..., 0], m[..., 0] = -100.0, -100.0, 0, 1.0  # z < -1
    w1[..., 0, 1], b1[..., 1], targets[..., 1], m[..., 1] = 100.0, -100.0, 2, 1.0  # z > 1
    sample = WeightSample(
        actions=jnp.broadcast_to(jnp.asarray([1, 0, 2], jnp.int32), (a, q)),
        w1=jnp.asarray(w1),
        b1=jnp.asarray(b1),
        unit_targets=jnp.asarray(targets),
        m=jnp.asarray(m),
        default=jnp.ones((a, q), jnp.int32),
        bias=jnp.full((a, q), 20.0),
        node_tie=jnp.zeros((a,), jnp.int32),
        agent_tie=jnp.zeros((), jnp.int32),
    )
    return alg.to_policy(sample)


def test_auto_sizes_grow_with_the_budget_and_keep_given_settings():
    from cognet_jax.algorithms.cognet_weights_settings import CognetWeightsSection
    from cognet_jax.algorithms.sizing import sized
    from cognet_jax.envs.tagging import make_tagging

    env, _ = make_tagging("cogdice-paper")
    per_rollout = env.horizon * env.num_agents
    previous = None
    for budget in (1e6, 1e8, 1e9, 1e10, 1e11, 3e11, 1e12):
        s = sized(CognetWeightsSection(budget=budget), env)
        spent = s.iterations * s.candidates * s.eval_rollouts * per_rollout
        assert spent <= 1.05 * budget or s.iterations == 1
        assert 2 <= s.elites <= s.candidates
        if previous is not None:  # every size is non-decreasing in the budget
            assert s.iterations >= previous.iterations
            assert s.eval_rollouts >= previous.eval_rollouts
            assert s.candidates >= previous.candidates
        previous = s
    assert spent >= 0.95 * 1e12  # a large budget is spent (population grown)
    mine = sized(CognetWeightsSection(budget=1e10, iterations=50, elites=7), env)
    assert mine.iterations == 50 and mine.elites == 7
    assert mine.candidates * mine.eval_rollouts * 50 * per_rollout <= 1.05e10


def test_a_loaded_config_holds_the_sizes_it_runs_with():
    from cognet_jax.registry import load_config

    config = load_config("beacon-n5", ["algorithm.budget=9e8"])
    a = config.algorithm
    assert all(isinstance(getattr(a, f), int) for f in ("iterations", "candidates", "elites"))
    assert a.iterations * a.candidates * a.eval_rollouts * 30 * 3 <= 9.5e8


def test_tied_candidates_run_node_0s_network_everywhere_and_agent_0s_controller():
    alg, _ = small_algorithm()
    dist = alg.init_distribution()
    dist = dist.replace(
        node_tie_probs=jnp.asarray([[0.0, 1.0], [1.0, 0.0]]),  # agent 0 tied, agent 1 not
        agent_tie_probs=jnp.asarray([1.0, 0.0]),
    )
    s = alg.draw(jax.random.key(5), dist, 6)
    w1 = np.asarray(s.w1)  # [6, agents, Q, F, H]
    assert np.array_equal(s.node_tie, np.tile([1, 0], (6, 1)))
    for q in range(1, 3):
        np.testing.assert_array_equal(w1[:, 0, q], w1[:, 0, 0])
        np.testing.assert_array_equal(np.asarray(s.unit_targets)[:, 0, q], s.unit_targets[:, 0, 0])
    assert not np.array_equal(w1[:, 1, 1], w1[:, 1, 0])
    both = alg.draw(jax.random.key(5), dist.replace(agent_tie_probs=jnp.asarray([0.0, 1.0])), 6)
    for field in ("actions", "w1", "bias", "node_tie"):
        x = np.asarray(getattr(both, field))
        np.testing.assert_array_equal(x[:, 1], x[:, 0])


def test_a_converged_distribution_restarts_and_the_best_policy_stays():
    alg, params = small_algorithm(restart_tol=0.5)
    state = alg.init(jax.random.key(0), params)
    shrunk = state.distribution.replace(w1_std=state.distribution.w1_std * 0.1)
    state = state.replace(distribution=shrunk)
    after, metrics = jax.jit(alg.step)(jax.random.key(1), state, params)
    assert bool(metrics.restarted)
    np.testing.assert_array_equal(after.distribution.w1_std, alg.init_distribution().w1_std)
    kept, m2 = jax.jit(alg.step)(jax.random.key(2), after, params)  # not converged: refit
    assert not bool(m2.restarted)
    assert not np.array_equal(kept.distribution.w1_mean, after.distribution.w1_mean)


def test_a_config_written_before_the_pool_with_paired_best_still_runs_without_it():
    """results.json configs of paired-best runs have no ``best_pool``: the default pool must
    not make them invalid or change their search (``paired_best`` replaces the pool)."""
    from cognet_jax.algorithms.cognet_weights_settings import pool_size, rollouts_per_iteration

    alg, params = small_algorithm(paired_best=True, best_rollouts=200, elites=2)
    assert pool_size(alg.settings) == 0 and alg.init(jax.random.key(0), params).pool is None
    assert rollouts_per_iteration(alg.settings) == 8 * 16 + 3 * 200
    data = load_config("tagging-thesis-n3").to_dict()
    data["algorithm"].pop("best_pool")
    data["algorithm"]["paired_best"] = True
    from cognet_jax.registry import config_from_dict

    assert config_from_dict(data).algorithm.paired_best


@pytest.mark.parametrize(
    "standardize", [False, True, "whitened", "tied-votes", "sharp", "kept-sharp"]
)
def test_a_distribution_centred_on_a_policy_has_that_policy_as_its_mode(standardize):
    """The refine phase's distribution around a policy (``centered_distribution``): its mode
    runs exactly the policy (tied and untied draws, raw and standardised inputs, votes scaled),
    and its spreads are ``refine_scale`` of the initial ones."""
    if standardize == "tied-votes":  # tied candidates' default votes x 10
        alg, _ = small_algorithm(refine_scale=0.2, tied_vote_scale=10.0)
    elif standardize == "sharp":  # every vote x 10 (and the tied default votes x 10 more)
        alg, _ = small_algorithm(refine_scale=0.2, tied_vote_scale=10.0, vote_sharpness=10.0)
    elif standardize == "kept-sharp":  # the kept policy's votes x 100
        alg, _ = small_algorithm(refine_scale=0.2, vote_sharpness=10.0, kept_sharpness=100.0)
    elif standardize == "whitened":
        kw = {"standardize_inputs": True, "whiten_inputs": True, "refine_scale": 0.2}
        alg = heatmap_algorithm(hidden=5, **kw)
    elif standardize:
        alg = heatmap_algorithm(standardize_inputs=True, hidden=5, refine_scale=0.2)
    else:
        alg, _ = small_algorithm(refine_scale=0.2)
    init = alg.init_distribution()
    for mix in (0.0, 1.0):  # untied and tied draws
        dist = init.replace(
            node_tie_probs=jnp.full_like(init.node_tie_probs, 0.5)
            .at[:, 1]
            .set(mix)
            .at[:, 0]
            .set(1 - mix)
        )
        samples = alg.draw(jax.random.key(3), dist, 2)
        for c in range(2):
            policy = alg.kept_policy(jax.tree.map(lambda x: x[c], samples))  # noqa: B023
            centred = alg.centered_distribution(policy)
            back = alg.kept_policy(alg.mode(centred))
            for got, want in zip(jax.tree.leaves(back), jax.tree.leaves(policy)):
                np.testing.assert_allclose(np.asarray(got), np.asarray(want), rtol=1e-5, atol=1e-4)
            assert np.asarray(jnp.argmax(centred.node_tie_probs, -1)).tolist() == [int(mix)] * 2
            np.testing.assert_allclose(centred.w1_std, 0.2 * init.w1_std, rtol=1e-6)
            np.testing.assert_allclose(centred.m_std, 0.2 * init.m_std, rtol=1e-6)
            peak = 0.8 + 0.2 / alg.env.num_actions
            assert np.allclose(np.asarray(centred.action_probs).max(-1), peak)


def test_the_last_iterations_search_around_the_kept_policy():
    """With ``refine = 0.5`` of 4 iterations, the step that ends iteration 2 recentres the
    distribution on the kept policy with the narrow spreads; the first step refits as before;
    without ``refine`` no step recentres."""
    alg, params = small_algorithm(iterations=4, refine=0.5, restart_tol=0.0)
    step = jax.jit(alg.step)
    state = alg.init(jax.random.key(0), params)
    first, _ = step(jax.random.key(1), state, params)
    assert float(first.distribution.w1_std.mean()) > 0.5 * float(state.distribution.w1_std.mean())
    second, _ = step(jax.random.key(2), first, params)
    want = alg.centered_distribution(second.best_policy)
    for got, expected in zip(jax.tree.leaves(second.distribution), jax.tree.leaves(want)):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(expected))
    plain, plain_params = small_algorithm(iterations=4, refine=0.0, restart_tol=0.0)
    s = plain.init(jax.random.key(0), plain_params)
    for k in (1, 2):
        s, _ = jax.jit(plain.step)(jax.random.key(k), s, plain_params)
    assert float(s.distribution.w1_std.mean()) > 2 * float(want.w1_std.mean())


def test_starts_split_the_search_before_the_refine_phase_into_fresh_searches():
    """``starts = 3`` of 8 iterations with a quarter refining: fresh starts after iterations 2
    and 4, none at 6 (the refine phase begins there) or elsewhere."""
    from cognet_jax.algorithms.cognet_weights_settings import fresh_start

    alg, params = small_algorithm(iterations=8, refine=0.25, starts=3, restart_tol=0.0)
    assert [d for d in range(9) if bool(fresh_start(alg.settings, jnp.int32(d)))] == [2, 4]
    step = jax.jit(alg.step)
    state = alg.init(jax.random.key(0), params)
    for k in (1, 2):
        state, _ = step(jax.random.key(k), state, params)
    for got, want in zip(
        jax.tree.leaves(state.distribution), jax.tree.leaves(alg.init_distribution())
    ):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_the_default_vote_is_drawn_at_its_own_scale():
    """``default_vote_scale`` scales the default vote's Gaussian (the output bias of the node
    networks) and nothing else: drawn default votes spread about that many times wider."""
    draws = {}
    for scale in (1.0, 10.0):
        alg, _ = small_algorithm(default_vote_scale=scale)
        dist = alg.init_distribution()
        assert np.allclose(np.asarray(dist.bias_mean), 5.0 * scale)
        assert np.allclose(np.asarray(dist.m_mean), 5.0)  # the units' votes unchanged
        policies = alg.to_policy(alg.draw(jax.random.key(3), dist, 256))
        bias = np.asarray(policies.net_params["params"]["Dense_1"]["bias"])
        draws[scale] = bias.sum(-1)  # one non-zero entry per network: the default vote B
    ratio = draws[10.0].std() / draws[1.0].std()
    assert 8.0 < ratio < 12.5


def test_alternating_searches_switch_the_default_vote_scale_at_each_fresh_start():
    """``vote_alternate``: search 0 starts at scale 1, the fresh start after iteration 2
    (``starts = 3``) at ``default_vote_scale``, the one after iteration 4 at 1 again; the
    counter of searches is in the state."""
    alg, params = small_algorithm(
        iterations=8,
        refine=0.25,
        starts=3,
        restart_tol=0.0,
        default_vote_scale=10.0,
        vote_alternate=True,
    )
    step = jax.jit(alg.step)
    state = alg.init(jax.random.key(0), params)
    assert int(state.searches) == 0
    assert np.allclose(np.asarray(state.distribution.bias_mean), 5.0)
    means = []
    for k in range(1, 5):
        state, _ = step(jax.random.key(k), state, params)
        means.append(float(np.asarray(state.distribution.bias_mean).mean()))
    assert int(state.searches) == 2
    assert means[1] == 50.0 and means[3] == 5.0  # fresh after iterations 2 and 4
    plain, _ = small_algorithm(default_vote_scale=10.0)
    assert plain.init(jax.random.key(0), params).searches is None


def test_vote_first_and_the_voting_searches_own_restart_tolerance():
    """``vote_first``: search 0 draws at ``default_vote_scale``; ``vote_restart_tol``: a
    distribution shrunk to 0.3 of its spread has converged in a search at that scale (0.5) and
    not in one at scale 1 (``restart_tol`` 0.1)."""
    alg, params = small_algorithm(
        default_vote_scale=10.0,
        vote_alternate=True,
        vote_first=True,
        restart_tol=0.1,
        vote_restart_tol=0.5,
    )
    state = alg.init(jax.random.key(0), params)
    assert np.allclose(np.asarray(state.distribution.bias_mean), 50.0)
    shrunk = alg.init_distribution().replace(w1_std=alg.init_distribution().w1_std * 0.3)
    refining = jnp.bool_(False)
    assert bool(alg.converged(shrunk, refining, jnp.int32(0)))  # search 0: at scale 10
    assert not bool(alg.converged(shrunk, refining, jnp.int32(1)))  # search 1: at scale 1
    step = jax.jit(alg.step)
    after, metrics = step(jax.random.key(1), state.replace(distribution=shrunk), params)
    assert bool(metrics.restarted) and int(after.searches) == 1
    assert np.allclose(np.asarray(after.distribution.bias_mean), 5.0)  # search 1 at scale 1


def test_tied_candidates_default_votes_are_scaled_and_the_others_not():
    """``tied_vote_scale``: a candidate agent whose nodes are tied runs its default vote times
    the factor; an untied one runs the drawn vote."""
    alg, _ = small_algorithm(tied_vote_scale=10.0)
    samples = alg.draw(jax.random.key(5), alg.init_distribution(), 64)
    policies = alg.to_policy(samples)
    votes = np.asarray(policies.net_params["params"]["Dense_1"]["bias"]).sum(-1)  # [C, agents, Q]
    tied = np.asarray(samples.node_tie)[..., None] == 1
    factor = np.where(tied, 10.0, 1.0)
    np.testing.assert_allclose(votes, np.asarray(samples.bias) * factor, rtol=1e-6)
    assert tied.any() and (~tied).any()


def test_auto_standardisation_turns_on_for_missed_inputs_only():
    """``standardize_inputs = "auto"``: the plume's 3 x 3 patch (pixels spread about 0.25)
    is standardised, tagging's signed distance (spread about 5, centred) is not; the resolved
    config holds the decision. For centred features the rule is the spread against
    ``NARROW_INPUTS x sqrt(F)``, at any number of features; a reading far off centre, or in
    units a hundred times smaller, is standardised too."""
    sizes = [f"algorithm.{k}={v}" for k, v in SMALL_SIZES.items()]
    auto = ['algorithm.standardize_inputs="auto"', *sizes]
    assert load_config("plume-n5", auto).algorithm.standardize_inputs is True
    assert load_config("tagging-thesis-n3", auto).algorithm.standardize_inputs is False
    for f in (1, 2, 9, 16):
        zero = jnp.zeros((2, f))
        limit = NARROW_INPUTS * math.sqrt(f)
        assert missed_inputs((zero, jnp.full((2, f), 0.95 * limit)))
        assert not missed_inputs((zero, jnp.full((2, f), 1.05 * limit)))
    distance = jnp.full((2, 1), 4.2)  # the README simulator's signed distance
    assert not missed_inputs((jnp.zeros((2, 1)), distance))
    assert missed_inputs((jnp.full((2, 1), 50.0), distance))  # offset by 50
    assert missed_inputs((jnp.full((2, 1), 10.0), distance))  # offset by 10
    assert missed_inputs((jnp.zeros((2, 1)), distance / 100))  # in units 100 times larger
    assert not missed_inputs((jnp.zeros((2, 1)), distance * 100))  # ... smaller: centred
    metres = jnp.stack([jnp.full((2,), 50.0), jnp.zeros((2,))], -1)  # a distance, a bearing
    assert missed_inputs((metres, jnp.stack([jnp.full((2,), 29.0), jnp.full((2,), 1.8)], -1)))


def test_auto_search_fields_follow_the_horizon_against_the_nodes():
    """``default_vote_scale``, ``restart_tol`` and ``refine_tol`` "auto": the long-horizon
    values where the horizon exceeds the nodes (beacon, h 30, 5 nodes), the short-horizon ones
    where it does not (tagging thesis, h 3, 3 nodes); numbers given are kept, the resolved
    config holds numbers, and settings made in code resolve the same way."""
    sizes = [f"algorithm.{k}={v}" for k, v in SMALL_SIZES.items()]
    auto = [f'algorithm.{f}="auto"' for f in SEARCH_LONG_HORIZON]
    beacon = load_config("beacon-n5", sizes).algorithm
    tagging = load_config("tagging-thesis-n3", [*auto, *sizes]).algorithm
    for field, value in SEARCH_LONG_HORIZON.items():
        assert getattr(beacon, field) == value
        assert getattr(tagging, field) == SEARCH_SHORT_HORIZON[field]
    kept = load_config("beacon-n5", [*sizes, "algorithm.restart_tol=0.3"]).algorithm
    assert kept.restart_tol == 0.3 and kept.default_vote_scale == 10.0
    alg, _ = small_algorithm(nodes=2)  # tagging thesis: h 3 > 2 nodes
    assert alg.settings.default_vote_scale == 10.0 and alg.settings.refine_tol == 0.1
    alg, _ = small_algorithm()
    assert alg.settings.default_vote_scale == 1.0 and alg.settings.restart_tol == 0.02


def test_distinct_draw_runs_every_action_before_any_twice():
    u = jax.random.uniform(jax.random.key(3), (500, 2, 6))
    probs = jnp.full((2, 6, 4), 0.25).at[1, :, 3].set(0.0)  # agent 1 has 3 actions
    support = jnp.asarray([[[True] * 4], [[True, True, True, False]]])
    actions = np.asarray(distinct_draw(u, probs, support))
    assert all(sorted(row[:4]) == [0, 1, 2, 3] for row in actions[:, 0])
    assert all(sorted(row[:3]) == [0, 1, 2] for row in actions[:, 1])
    assert (actions[:, 1] < 3).all()  # never an action the agent lacks, also after covering
    peaked = probs.at[:, :, 0].set(5.0)  # every node prefers action 0
    mode = np.asarray(distinct_draw(None, peaked, support))
    assert mode[0, 0] == 0 and len(set(mode[0, :4])) == 4 and (mode[0, 4:] == 0).all()


def test_distinct_actions_auto_is_on_where_independent_draws_rarely_cover():
    assert cover_probability(3, 3) == pytest.approx(6 / 27)
    assert cover_probability(5, 4) == 0.0
    assert covers_rarely((5, 5), 5)  # 0.038: beacon, chase, plume
    assert not covers_rarely((5, 5), 4)  # fewer nodes than actions: no draw covers
    assert not covers_rarely((3, 3), 3) and not covers_rarely((3, 3), 7)


def test_distinct_flag_draws_on_its_own_stream_and_is_refit():
    off, params = small_algorithm(distinct_actions=False)
    on, _ = small_algorithm(distinct_actions=True)
    d_off, d_on = off.init_distribution(), on.init_distribution()
    assert d_off.distinct_probs is None and d_on.distinct_probs.shape == (2, 2)
    a, b = off.draw(jax.random.key(4), d_off, 64), on.draw(jax.random.key(4), d_on, 64)
    for name in ("w1", "b1", "unit_targets", "m", "default", "bias", "node_tie", "agent_tie"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    flag = np.asarray(b.distinct)  # [64, agents]
    assert 0 < flag.mean() < 1
    acts = np.asarray(b.actions)
    np.testing.assert_array_equal(acts[flag == 0], np.asarray(a.actions)[flag == 0])
    assert all(len(set(row)) == 3 for row in acts[flag == 1])
    elites = jax.tree.map(lambda x: x[np.flatnonzero(flag[:, 0] == 1)[:4]], b)
    new = on.update_distribution(d_on, elites, params.hyper.replace(alpha=1.0))
    assert float(new.distinct_probs[0, 1]) > 0.9


def test_distinct_flags_do_not_reuse_a_stream_of_the_other_draws():
    on, _ = small_algorithm(distinct_actions=True)
    key = jax.random.key(5)
    flags = on.draw(key, on.init_distribution(), 64).distinct  # agent tie copies agent 0's
    split = jax.random.split(fast_key(key), 9)
    for k in split:  # the flags are not the first uniforms of any stream of ``draw``
        u = np.asarray(jax.random.uniform(k, (64, 2)))
        assert not np.array_equal((u >= 0.5)[:, 0], np.asarray(flags)[:, 0])


def test_distinct_draw_never_picks_an_action_the_agent_lacks():
    support = jnp.asarray([[[True, True, True, False]]])
    probs = jnp.asarray([[[0.0, 1.0, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0]]])  # no mass on unused ones
    u = jnp.asarray([[[0.3, 0.9]]])
    assert (np.asarray(distinct_draw(u, probs, support)) < 3).all()
    assert (np.asarray(distinct_draw(None, probs, support)) < 3).all()


def test_refine_centres_the_flag_on_whether_distinct_draws_give_the_kept_actions():
    support = jnp.ones((2, 1, 3), bool)
    actions = jnp.asarray([[2, 0, 1], [0, 0, 1]])  # agent 1 repeats 0 before running 2
    np.testing.assert_array_equal(reproduces_distinct(actions, support), [1, 0])


def test_checkpoints_and_configs_written_before_distinct_actions_read_as_they_ran():
    from flax import serialization

    from cognet_jax.checkpoint import restore_state
    from cognet_jax.config import with_added_fields

    off, _ = small_algorithm(distinct_actions=False)
    dist = off.init_distribution()
    stored = serialization.to_state_dict(dist)
    del stored["distinct_probs"]  # what a checkpoint of an earlier version holds
    back = restore_state(dist, {"state": stored})
    assert back.distinct_probs is None
    np.testing.assert_array_equal(back.w1_std, dist.w1_std)
    old = {"experiment": {"algorithm": "cognet-dice"}, "algorithm": {"nodes": 5}}
    assert with_added_fields(old)["algorithm"]["distinct_actions"] is False
    assert "distinct_actions" not in old["algorithm"]  # a copy
    given = {"algorithm": {"nodes": 5, "distinct_actions": "auto"}}
    assert with_added_fields(given)["algorithm"]["distinct_actions"] == "auto"
    gdice = {"experiment": {"algorithm": "gdice"}, "algorithm": {"nodes": 5}}
    assert with_added_fields(gdice) == gdice


def test_a_run_folder_written_before_distinct_actions_evaluates_to_its_own_value():
    from pathlib import Path

    from cognet_jax.saved_runs import evaluate_run, load_run

    folder = Path(__file__).parent.parent / (
        "experiments/results/suite/cognet-bearing-chase-before-distinct/seed0"
    )
    run = load_run(folder)  # its results.json has no distinct_actions: false, as it ran
    assert run.config.algorithm.distinct_actions is False
    assert evaluate_run(folder, rollouts=1000)["mean"] == pytest.approx(13.5, abs=0.3)


def test_refine_redraw_changes_one_unit_of_the_network_a_candidate_runs():
    """Centred on a policy with ``refine_redraw = 1``, every candidate differs from the draws
    without it in exactly one hidden unit (input weights, bias, target, vote) of one agent's
    network -- node 0's where that agent's nodes are tied -- and in nothing else; with the
    share at 0 the draws are those of before, and the exploring distribution redraws none."""
    alg, params = small_algorithm(refine=0.5, refine_redraw=1.0, distinct_actions=False)
    plain, _ = small_algorithm(refine=0.5, refine_redraw=0.0, distinct_actions=False)
    assert alg.init_distribution().redraw is not None
    assert plain.init_distribution().redraw is None
    state = alg.init(jax.random.key(0), params)
    centred = alg.centered_distribution(state.best_policy)
    assert float(centred.redraw) == 1.0
    never = centred.replace(redraw=jnp.float32(0.0))
    key = jax.random.key(3)
    got, want = alg.draw(key, centred, 32), alg.draw(key, never, 32)
    kept = plain.draw(key, plain.centered_distribution(state.best_policy), 32)
    for name in ("w1", "b1", "unit_targets", "m", "actions", "default", "bias"):
        np.testing.assert_array_equal(getattr(want, name), getattr(kept, name))
    for name in ("actions", "default", "bias", "node_tie", "agent_tie"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    b1_changed = np.asarray(got.b1) != np.asarray(want.b1)  # [32, agents, Q, H]
    node_tie = np.asarray(got.node_tie)
    agent_tie = np.asarray(got.agent_tie)
    for c in range(32):
        agents, nodes, units = np.nonzero(b1_changed[c])
        # one unit: in every node of a tied agent (node 0's copied), in every agent if tied
        assert len(set(units)) == 1
        q = b1_changed.shape[2]
        assert len(set(agents)) == (2 if agent_tie[c] == 1 else 1)
        for a in set(agents):
            assert len([n for n, x in zip(nodes, agents) if x == a]) == (
                q if node_tie[c, a] == 1 else 1
            )
    explore = alg.draw(key, alg.init_distribution(), 32)
    base = plain.draw(key, plain.init_distribution(), 32)
    np.testing.assert_array_equal(explore.w1, base.w1)  # the exploring searches redraw none


def test_sharper_votes_run_the_same_argmax_with_every_vote_scaled():
    """``vote_sharpness`` multiplies the policy's output layer (unit votes and default votes)
    and nothing else: the same draws give the same first layer and actions."""
    plain, _ = small_algorithm()
    sharp, _ = small_algorithm(vote_sharpness=10.0)
    samples = plain.draw(jax.random.key(2), plain.init_distribution(), 4)
    a, b = plain.to_policy(samples), sharp.to_policy(samples)
    la, lb = a.net_params["params"], b.net_params["params"]
    np.testing.assert_array_equal(la["Dense_0"]["kernel"], lb["Dense_0"]["kernel"])
    np.testing.assert_array_equal(a.action_probs, b.action_probs)
    for name in ("kernel", "bias"):
        np.testing.assert_allclose(10.0 * la["Dense_1"][name], lb["Dense_1"][name], rtol=1e-6)


def test_refine_redraw_auto_redraws_units_on_scalar_observations_only():
    from cognet_jax.algorithms.cognet_weights_settings import REDRAW_SCALAR, redraw_share

    assert redraw_share(()) == REDRAW_SCALAR and redraw_share((1,)) == REDRAW_SCALAR
    assert redraw_share((2,)) == 0.0 and redraw_share((9,)) == 0.0
    alg, _ = small_algorithm(refine=0.25)  # tagging: a scalar observation
    assert alg.settings.refine_redraw == REDRAW_SCALAR


def test_refine_levels_split_the_refine_phase_coarse_to_fine():
    """``refine_levels = 2`` with 4 of 8 iterations refining: the step that ends iteration 4
    centres on the kept policy at ``refine_scale`` of the initial spreads, the one that ends
    iteration 6 at ``refine_tol`` of that."""
    alg, params = small_algorithm(
        iterations=8,
        refine=0.5,
        refine_levels=2,
        refine_scale=0.2,
        refine_tol=0.1,
        restart_tol=0.0,
    )
    init = alg.init_distribution()
    step = jax.jit(alg.step)
    state = alg.init(jax.random.key(0), params)
    spreads = []
    for k in range(6):
        state, _ = step(jax.random.key(k + 1), state, params)
        spreads.append(float(state.distribution.b1_std.mean() / init.b1_std.mean()))
    assert spreads[3] == pytest.approx(0.2, rel=1e-5)  # after iteration 4: level 0
    assert spreads[4] != pytest.approx(0.2, rel=1e-3)  # refit within the level
    assert spreads[5] == pytest.approx(0.02, rel=1e-5)  # after iteration 6: level 1
    assert [int(alg.refine_level(jnp.int32(d))) for d in range(3, 9)] == [0, 0, 0, 1, 1, 1]


def test_results_count_the_searches_restarts_under_their_own_name(tmp_path):
    """A cognet-dice run's results.json counts restarts as ``restarts`` (its distribution
    started afresh), not as entropy injections, which it never makes."""
    import json

    from shared_files import TINY_TRAIN

    from cognet_jax import cli

    out = tmp_path / "run"
    assert cli.main(["train", "--out", str(out), *TINY_TRAIN]) == 0
    results = json.loads((out / "results.json").read_text())
    assert isinstance(results["restarts"], int) and "entropy_injections" not in results


def test_a_drawn_start_runs_the_controller_from_that_nodes_role():
    """``start_draw``: the other draws are those without it; a candidate's policy is the
    policy of its draws with node 0 and its start node swapped per agent (the polish's
    START move of the same swap); the start categorical is refit to the elites."""
    from cognet_jax.algorithms.weight_polish import START, apply_move
    from cognet_jax.controllers.base import action_support

    off, params = small_algorithm(start_draw=False)
    on, _ = small_algorithm(start_draw=True, start_spread=1.0)
    d_off, d_on = off.init_distribution(), on.init_distribution()
    assert d_off.start_probs is None and d_on.start_probs.shape == (2, 3)
    a, b = off.draw(jax.random.key(4), d_off, 64), on.draw(jax.random.key(4), d_on, 64)
    for name in ("actions", "w1", "b1", "unit_targets", "m", "default", "bias", "node_tie"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    start = np.asarray(b.start)  # [64, agents]: not tied with the agents
    assert {0, 1, 2} <= set(start[:, 1]) and (start[:, 0] != start[:, 1]).any()
    support = action_support(on.env)[:, 0, :]
    ones = jnp.ones((2, on.controller.in_features))
    for c in np.flatnonzero((start[:, 0] == 0) & (start[:, 1] > 0))[:3]:
        draws = jax.tree.map(lambda x, c=c: x[c], b)
        want = apply_move(
            off.to_policy(draws.replace(start=None)),
            jnp.array([START, 1, 0, 0, int(start[c, 1]) - 1]),
            ones,
            support,
            jnp.zeros_like(ones),
        )
        for got, exp in zip(jax.tree.leaves(on.to_policy(draws)), jax.tree.leaves(want)):
            np.testing.assert_allclose(np.asarray(got), np.asarray(exp), rtol=1e-6)
    elites = jax.tree.map(lambda x: x[np.flatnonzero(start[:, 1] == 2)[:4]], b)
    new = on.update_distribution(d_on, elites, params.hyper.replace(alpha=1.0))
    assert float(new.start_probs[1, 2]) > 0.9
    peaked, _ = small_algorithm(start_draw=True, start_spread=0.3)
    probs = np.asarray(peaked.init_distribution().start_probs)  # [agents, nodes]
    np.testing.assert_allclose(probs, [[0.8, 0.1, 0.1]] * 2, rtol=1e-6)
    np.testing.assert_array_equal(np.asarray(d_on.start_probs), np.full((2, 3), 1 / 3, np.float32))
