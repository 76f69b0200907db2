"""The torch reference of the default cognet-dice (benchmarks/torch_reference/weights.py) does
the work of cognet_jax's: the same tying, the same refit, the same returns of a policy (in
distribution: torch draws its own uniforms), and its search climbs."""

import importlib
import importlib.util

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.api import build_algorithm
from cognet_jax.registry import load_config
from cognet_jax.rollout import rollouts

pytestmark = pytest.mark.skipif(
    importlib.util.find_spec("torch") is None, reason="torch is not installed"
)
DEFAULTS = ["algorithm.tie_structure=true", "algorithm.restart_tol=0.02", "algorithm.best_pool=4"]
#: WeightSample field -> the reference's key
FIELDS = {
    "actions": "actions",
    "w1": "w1",
    "b1": "b1",
    "unit_targets": "targets",
    "m": "m",
    "default": "default",
    "bias": "bias",
    "node_tie": "node_tie",
    "agent_tie": "agent_tie",
}


def _setup(sets=()):
    torch = importlib.import_module("torch")
    weights = importlib.import_module("benchmarks.torch_reference.weights")
    config = load_config("tagging-thesis-n3", [*DEFAULTS, *sets])
    algorithm, params = build_algorithm(config)
    return torch, weights, config, algorithm, params


def _to_torch(torch, sample) -> dict:
    out = {}
    for theirs, mine in FIELDS.items():
        x = np.array(getattr(sample, theirs))  # a writable copy
        out[mine] = torch.from_numpy(x.astype(np.int64) if x.dtype.kind == "i" else x)
    return out


def test_tie_and_refit_equal_cognet_jax():
    torch, weights, config, algorithm, _ = _setup()
    dist = algorithm.init_distribution()
    # untied draws, so the reference's tie is applied to the same raw sample
    raw = algorithm.draw(jax.random.key(3), dist, 64)
    flags = raw.replace(
        node_tie=jax.random.bernoulli(jax.random.key(4), 0.5, raw.node_tie.shape).astype(jnp.int32),
        agent_tie=jax.random.bernoulli(jax.random.key(5), 0.5, raw.agent_tie.shape).astype(
            jnp.int32
        ),
    )
    from cognet_jax.algorithms.weight_space import tie

    tied_jax = _to_torch(torch, tie(flags))
    tied_torch = weights.tie(_to_torch(torch, flags))
    for k in FIELDS.values():
        torch.testing.assert_close(tied_torch[k], tied_jax[k])

    reference = weights.TorchWeightsSearch(weights.settings_from_config(config), seed=0)
    from cognet_jax.algorithms.cognet_weights import WeightsHyper

    elites = jax.tree.map(lambda x: x[:10], tie(flags))
    new_jax = algorithm.update_distribution(dist, elites, WeightsHyper())
    new_torch = reference.refit(reference.initial_distribution(), _to_torch(torch, elites))
    pairs = {
        "action_probs": "actions",
        "w1_mean": "w1_mean",
        "w1_std": "w1_std",
        "b1_std": "b1_std",
        "unit_target_probs": "targets",
        "m_mean": "m_mean",
        "default_probs": "default",
        "bias_std": "bias_std",
        "node_tie_probs": "node_tie",
        "agent_tie_probs": "agent_tie",
    }
    for theirs, mine in pairs.items():
        expected = torch.from_numpy(np.array(getattr(new_jax, theirs)))
        torch.testing.assert_close(new_torch[mine], expected, rtol=1e-5, atol=1e-5)


def test_returns_of_a_policy_match_cognet_jax_in_distribution():
    """Eight candidates of the initial distribution, 20,000 rollouts each on both sides: every
    mean within 5 standard errors of the other (the draws differ, the policies and the
    simulator do not)."""
    torch, weights, config, algorithm, params = _setup()
    sample = algorithm.draw(jax.random.key(7), algorithm.init_distribution(), 8)
    policies = algorithm.to_policy(sample)
    num = 20_000
    jax_returns = jax.vmap(
        lambda pol: rollouts(
            algorithm.env, algorithm.controller, jax.random.key(1), num, params.env, pol
        )
    )(policies)
    jax_returns = np.asarray(jax_returns).reshape(8, num)
    reference = weights.TorchWeightsSearch(
        weights.settings_from_config(config), weights.env_from_config(config), seed=1
    )
    torch_returns = reference.returns(_to_torch(torch, sample), num, crn=False).numpy()
    se = np.sqrt(jax_returns.var(1) / num + torch_returns.var(1) / num)
    gap = np.abs(jax_returns.mean(1) - torch_returns.mean(1))
    assert np.all(gap <= 5 * se + 1e-6), (jax_returns.mean(1), torch_returns.mean(1), se)
    # and the candidates differ, so the comparison could fail
    assert np.ptp(jax_returns.mean(1)) > 10 * se.max()


def test_search_climbs_and_the_compiled_one_draws_the_same_numbers():
    torch, weights, config, _, _ = _setup(
        ["algorithm.candidates=40", "algorithm.eval_rollouts=50", "algorithm.elites=4"]
    )
    settings = weights.settings_from_config(config)
    assert (settings.candidates, settings.eval_rollouts, settings.best_pool) == (40, 50, 4)
    eager = weights.TorchWeightsSearch(settings, seed=2)
    first = eager.step()
    for _ in range(15):
        last = eager.step()
    assert last["mean_value"] > first["mean_value"] + 5
    compiled = weights.TorchWeightsCompiled(settings, seed=2)
    again = compiled.step()
    assert again["value"] == pytest.approx(first["value"], abs=1e-3)
    assert again["mean_value"] == pytest.approx(first["mean_value"], abs=1e-3)
