"""Heatmap experiments with COGNet-DICE: configuration, observation pipelines (raw / encoded),
augmentation and evaluation under observation noise."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.api import build_algorithm, build_env, make_train, seed_key
from cognet_jax.config import ConfigError
from cognet_jax.envs.heatmap import START_RANGES
from cognet_jax.observations import ObservationPipeline, trained_vae
from cognet_jax.registry import config_from_dict


def heatmap_config(env=None, network=None, algorithm=None, **sections):
    data = {
        "experiment": {"name": "heat-test", "algorithm": "cognet-dice-thesis"},
        "env": {"name": "heatmap", "start": "thesis", **(env or {})},
        "algorithm": {
            "nodes": 4,
            "iterations": 3,
            "rollouts": 64,
            "top": 8,
            "keep": 4,
            "eval_rollouts": 16,
            **(algorithm or {}),
        },
        "network": {"hidden": 8, "train_steps": 5, **(network or {})},
        "evaluation": {"rollouts": 200},
        "run": {"progress": False, "plots": False},
    }
    data.update(sections)
    return config_from_dict(data)


@pytest.mark.parametrize(
    "env,field",
    [
        ({"start": "anywhere"}, "env.start"),
        ({"horizon": 0}, "env.horizon"),
        ({"obs_noise_std": -0.1}, "env.obs_noise_std"),
        ({"obs_noise_amplitude": -1.0}, "env.obs_noise_amplitude"),
        ({"discount": 0.0}, "env.discount"),
        ({"setting": "thesis"}, "env.setting"),  # a tagging key is unknown here
        ({"obs_noise_std": "big"}, "env.obs_noise_std"),
    ],
)
def test_bad_heatmap_env_values_name_the_field(env, field):
    with pytest.raises(ConfigError) as err:
        heatmap_config(env=env)
    assert err.value.field == field


def test_env_section_reaches_the_params():
    config = heatmap_config(
        env={"obs_noise_std": 0.05, "obs_noise_mean": 0.01, "obs_noise_amplitude": 1.1}
    )
    env, params = build_env(config)
    assert env.horizon == 4 and env.obs_shape == (16,)
    assert (int(params.start_low), int(params.start_high)) == START_RANGES["thesis"]
    assert float(params.obs_noise_std) == pytest.approx(0.05)
    assert float(params.obs_noise_mean) == pytest.approx(0.01)
    assert float(params.obs_noise_amplitude) == pytest.approx(1.1)
    env, params = build_env(heatmap_config(env={"start": "default", "horizon": 6}))
    assert env.horizon == 6
    assert (int(params.start_low), int(params.start_high)) == START_RANGES["default"]


# ------------------------------------------------------------------------------------------
# observation pipelines
# ------------------------------------------------------------------------------------------
#: a quickly trained VAE for the tests (the pipeline only needs a working encoder)
FAST_VAE = {"vae_epochs": 8}


def encoded_config(**network):
    return heatmap_config(network={"observation": "encoded", **FAST_VAE, **network})


@pytest.mark.parametrize(
    "network,field",
    [
        ({"observation": "pixels"}, "network.observation"),
        ({"vae_epochs": 0}, "network.vae_epochs"),
        ({"augment_samples": 0}, "network.augment_samples"),
        ({"vae_seed": -1}, "network.vae_seed"),
        ({"vae_path": "/no/such/vae.msgpack", "observation": "encoded"}, "network.vae_path"),
    ],
)
def test_bad_network_values_name_the_field(network, field):
    with pytest.raises(ConfigError) as err:
        build_algorithm(heatmap_config(network=network))
    assert err.value.field == field


def test_vae_pipelines_need_continuous_observations_of_several_numbers():
    """A VAE encodes an observation of several numbers: tagging's single number is refused
    with the config, naming the field that asked for it."""
    for network, field in (
        ({"observation": "encoded"}, "network.observation"),
        ({"augment": True}, "network.augment"),
    ):
        with pytest.raises(ConfigError, match="a single number") as err:
            build_algorithm(  # (the thesis algorithm's pipeline is built with its search)
                config_from_dict(
                    {
                        "experiment": {"algorithm": "cognet-dice-thesis"},
                        "env": {"name": "tagging"},
                        "network": network,
                        "algorithm": {"iterations": 2},
                    }
                )
            )
        assert err.value.field == field


def test_encoded_controller_reads_the_encoder_mean():
    algorithm, params = build_algorithm(encoded_config())
    ctrl, pipe = algorithm.controller, algorithm.pipeline
    assert ctrl.obs_shape == (1,) and ctrl.in_features == 1
    policy = algorithm.init(jax.random.key(0), params).policy
    rng = np.random.default_rng(0)
    obs = jnp.asarray(rng.uniform(0, 1, (2, 16)), jnp.float32)
    u = jnp.asarray(rng.uniform(size=(64, 2)), jnp.float32)
    nodes = jnp.array([1, 3])

    @jax.jit
    def parts(policy, obs, u):  # one program for every number compared below
        mu = pipe.vae.encode(obs)[0]
        bare = [
            ctrl.one_net_logits(
                jax.tree.map(lambda p, i=i: p[i, nodes[i]], policy.net_params), mu[i]
            )
            for i in range(2)
        ]
        probs = jax.nn.softmax(ctrl.node_logits(policy.net_params, nodes, mu), -1)
        expect = jax.vmap(
            lambda v: jax.vmap(lambda p, w: jnp.searchsorted(jnp.cumsum(p), w))(probs, v)
        )(u)
        got = jax.vmap(lambda v: ctrl.next_node(v, policy, nodes, obs))(u)
        encoded = ctrl.node_logits(policy.net_params, nodes, pipe.features(obs))
        return mu, pipe.features(obs), encoded, jnp.stack(bare), got, expect

    mu, features, encoded, bare, got, expect = (np.asarray(x) for x in parts(policy, obs, u))
    np.testing.assert_allclose(features, mu, rtol=1e-6)
    # the encoded controller on patches == the bare networks on the encoder mean
    np.testing.assert_allclose(encoded, bare, rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(got, expect)


def test_raw_pipeline_keeps_patches_and_hidden_size():
    algorithm, params = build_algorithm(heatmap_config(network={"hidden": 12}))
    assert algorithm.pipeline.is_identity and algorithm.pipeline.vae is None
    assert algorithm.controller.obs_shape == (16,) and algorithm.controller.features is None
    state = algorithm.init(jax.random.key(0), params)
    kernel = state.policy.net_params["params"]["Dense_0"]["kernel"]
    assert kernel.shape == (2, 4, 16, 12)


def test_encoded_search_runs_and_is_deterministic():
    config = encoded_config()
    train = jax.jit(make_train(config))
    state_a, metrics_a = train(seed_key(config, 1))
    state_b, metrics_b = train(seed_key(config, 1))
    _, metrics_c = train(seed_key(config, 2))
    np.testing.assert_array_equal(np.asarray(metrics_a.value), np.asarray(metrics_b.value))
    assert not np.array_equal(np.asarray(metrics_a.value), np.asarray(metrics_c.value))
    assert np.all(np.isfinite(np.asarray(metrics_a.value)))
    # returns are sums of 2 agents x 4 steps of rewards in {-1, 1, 50}
    assert np.all(np.asarray(metrics_a.value) >= -8) and np.all(np.asarray(metrics_a.value) <= 400)
    probs = np.asarray(state_a.policy.action_probs)
    np.testing.assert_allclose(probs.sum(-1), 1.0, atol=1e-5)
    kernel = state_a.policy.net_params["params"]["Dense_0"]["kernel"]
    assert kernel.shape == (2, 4, 1, 8)


# ------------------------------------------------------------------------------------------
# augmentation
# ------------------------------------------------------------------------------------------
def _pairs(rng, agents=2, p=6):
    from cognet_jax.vae import reachable_patches

    patches = reachable_patches()
    obs = jnp.asarray(patches[rng.integers(0, len(patches), (agents, p))])
    src = jnp.asarray(rng.integers(0, 4, (agents, p)), jnp.int32)
    tgt = jnp.asarray(rng.integers(0, 4, (agents, p)), jnp.int32)
    valid = jnp.asarray(rng.uniform(size=(agents, p)) < 0.7)
    return obs, src, tgt, valid


@pytest.mark.parametrize("kind", ["encoded", "raw"])
def test_augmentation_adds_sampled_pairs(kind):
    vae = trained_vae(0, FAST_VAE["vae_epochs"])
    m = 400
    pipe = ObservationPipeline(kind, (16,), vae, augment_samples=m)
    obs, src, tgt, valid = _pairs(np.random.default_rng(3))
    feats, src2, tgt2, valid2 = pipe.training_pairs(jax.random.key(5), obs, src, tgt, valid)
    width = 1 if kind == "encoded" else 16
    assert feats.shape == (2, 6 * (1 + m), width)
    for new, old in ((src2, src), (tgt2, tgt), (valid2, valid)):
        assert new.shape == (2, 6 * (1 + m))
        np.testing.assert_array_equal(
            np.asarray(new).reshape(2, 1 + m, 6), np.asarray(old)[:, None].repeat(1 + m, 1)
        )
    np.testing.assert_allclose(np.asarray(feats[:, :6]), np.asarray(pipe.features(obs)), rtol=1e-6)
    extra = np.asarray(feats[:, 6:]).reshape(2, m, 6, width)
    mu, logvar = (np.asarray(a) for a in vae.encode(obs))
    sigma = np.exp(0.5 * logvar)
    if kind == "encoded":  # latent samples ~ N(mu, sigma): check mean and spread
        np.testing.assert_allclose(extra.mean(1), mu, atol=4 * sigma.max() / np.sqrt(m))
        np.testing.assert_allclose(extra.std(1), sigma, rtol=0.2)
    else:  # decoded samples: patches in (0, 1) that vary around decode(mu)
        assert extra.min() > 0 and extra.max() < 1
        assert np.all(extra.std(1).max(-1) > 0)
        center = np.asarray(vae.decode(jnp.asarray(mu)))
        assert np.abs(np.median(extra, 1) - center).max() < 0.1
    # no augmentation: the pairs are the features only
    plain = ObservationPipeline(kind, (16,), vae).training_pairs(
        jax.random.key(5), obs, src, tgt, valid
    )
    assert plain[0].shape == (2, 6, width)


def test_augmentation_changes_training_not_rollouts():
    one = {"iterations": 1}
    plain = heatmap_config(network={**FAST_VAE, "observation": "encoded"}, algorithm=one)
    aug = heatmap_config(
        network={**FAST_VAE, "observation": "encoded", "augment": True, "augment_samples": 2},
        algorithm=one,
    )
    assert build_algorithm(aug)[0].pipeline.augment_samples == 2
    assert build_algorithm(plain)[0].pipeline.augment_samples == 0
    (s0, m0), (s1, m1) = (jax.jit(make_train(c))(seed_key(c, 0)) for c in (plain, aug))
    # same rollouts and selection in iteration 1 -> same action distributions ...
    np.testing.assert_array_equal(
        np.asarray(s0.policy.action_probs), np.asarray(s1.policy.action_probs)
    )
    np.testing.assert_array_equal(np.asarray(m0.kept), np.asarray(m1.kept))
    # ... but the networks were trained on different pair sets
    k0 = np.asarray(s0.policy.net_params["params"]["Dense_0"]["kernel"])
    k1 = np.asarray(s1.policy.net_params["params"]["Dense_0"]["kernel"])
    assert not np.allclose(k0, k1)


# ------------------------------------------------------------------------------------------
# built-in experiments and the command line
# ------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "name,nodes,observation,hidden",
    [
        ("heatmap-2d-spec-n4", 4, "raw", 160),
        ("heatmap-2d-spec-n5", 5, "raw", 160),
        ("heatmap-encoded-spec-n4", 4, "encoded", 10),
        ("heatmap-encoded-spec-n5", 5, "encoded", 10),
    ],
)
def test_builtin_heatmap_experiments(name, nodes, observation, hidden):
    from cognet_jax.registry import load_config

    c = load_config(name)
    assert (c.env.name, c.env.start, c.env.horizon) == ("heatmap", "thesis", 4)
    a = c.algorithm
    assert (a.nodes, a.iterations, a.rollouts, a.top, a.keep, a.eval_rollouts) == (
        nodes,
        500,
        1000,
        100,
        10,
        100,
    )
    assert a.alpha == 0.2 and a.entropy_injection
    assert (c.network.observation, c.network.hidden, c.network.augment) == (
        observation,
        hidden,
        False,
    )
    assert load_config(name, ["env.start=default"]).env.start == "default"


def test_cli_train_then_evaluate_under_observation_noise(tmp_path, capsys):
    import json

    from cognet_jax.cli import main
    from cognet_jax.saved_runs import load_run

    out = tmp_path / "run"
    small = [
        "algorithm.iterations=2",
        "algorithm.rollouts=64",
        "algorithm.top=8",
        "algorithm.keep=4",
        "algorithm.eval_rollouts=16",
        "evaluation.rollouts=200",
        "network.vae_epochs=8",
        "run.plots=false",
    ]
    args = ["train", "heatmap-encoded-spec-n4", "--no-progress", "--out", str(out)]
    assert main(args + [x for o in small for x in ("--set", o)]) == 0
    assert (out / "vae.msgpack").is_file()
    kept = json.loads((out / "results.json").read_text())["run_files"]  # the search's run files
    assert kept["vae.msgpack"]["field"] == "network.vae_path"
    values = {}
    for std in (0.0, 0.2):
        code = main(
            ["evaluate", str(out), "--rollouts", "2000", "--set", f"env.obs_noise_std={std}"]
        )
        assert code == 0
        values[std] = json.loads((out / "evaluations.jsonl").read_text().splitlines()[-1])
        assert values[std]["overrides"] == [f"env.obs_noise_std={std}"]
    assert "env.obs_noise_std=0.2" in capsys.readouterr().out
    # same evaluation seed: the noise is the only difference, and it changes the value
    assert values[0.0]["mean"] != values[0.2]["mean"]
    run = load_run(out, ["env.obs_noise_std=0.2", "network.vae_seed=9"])
    algorithm = run.algorithm
    assert float(run.params.env.obs_noise_std) == pytest.approx(0.2)
    # the run's own VAE file is used, whatever the VAE settings say
    saved = trained_vae(0, 8)
    for a, b in zip(jax.tree.leaves(algorithm.pipeline.vae.params), jax.tree.leaves(saved.params)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # a bad override still names the field
    assert main(["evaluate", str(out), "--set", "env.obs_noise_std=-1"]) == 2
    assert "env.obs_noise_std" in capsys.readouterr().err
    # a results.json written before run_files (its VAE's digest as vae_sha256) reads as before
    results = json.loads((out / "results.json").read_text())
    results["vae_sha256"] = results.pop("run_files")["vae.msgpack"]["sha256"]
    (out / "results.json").write_text(json.dumps(results))
    assert main(["evaluate", str(out), "--rollouts", "2000"]) == 0
    legacy = json.loads((out / "evaluations.jsonl").read_text().splitlines()[-1])
    assert legacy["mean"] == values[0.0]["mean"]  # the run's own VAE, as the field said
    from cognet_jax.vae import save_vae

    save_vae(out / "vae.msgpack", trained_vae(1, 8))  # a VAE, but not the run's
    capsys.readouterr()
    assert main(["evaluate", str(out)]) == 2
    assert "vae_sha256" in capsys.readouterr().err
    # a run_files entry that names a file outside the folder, or the policy: a corrupt file
    for name in ("../vae.msgpack", "policy.msgpack"):
        results["run_files"] = {name: {"field": "network.vae_path", "sha256": None}}
        (out / "results.json").write_text(json.dumps(results))
        assert main(["evaluate", str(out)]) == 2
        assert "run_files" in capsys.readouterr().err


def test_random_value_by_dp_matches_monte_carlo():
    from cognet_jax.controllers.neural import NeuralController
    from cognet_jax.envs.heatmap import make_heatmap, random_value
    from cognet_jax.rollout import mean_and_stderr, rollouts

    ctrl = NeuralController(2, 1, 4, obs_shape=(16,), hidden=4)
    policy = ctrl.init(jax.random.key(0))  # one node, uniform actions
    env = make_heatmap("thesis")[0]  # the start range lives in the params
    run = jax.jit(lambda k, p: rollouts(env, ctrl, k, 100_000, p, policy))
    for start in ("thesis", "default"):
        ret = run(jax.random.key(7), make_heatmap(start)[1])
        mean, se = mean_and_stderr(ret)
        assert abs(float(mean) - random_value(start)) < 3 * float(se), (start, float(mean))


def test_a_foreign_or_torn_vae_file_and_a_latent_that_differs_name_the_field(tmp_path):
    """``network.vae_path`` naming a file that is not a VAE (a policy, JSON, a torn VAE) is
    refused naming the field (these were internal errors); a VAE of another latent size than
    ``network.vae_latent`` names that field instead of training with a value it ignores."""
    from cognet_jax.vae import save_vae, train_vae

    vae = train_vae(seed=0, epochs=1, latent=2)[0]
    good = tmp_path / "vae.msgpack"
    save_vae(good, vae)
    torn = tmp_path / "torn.msgpack"
    torn.write_bytes(good.read_bytes()[:200])
    foreign = tmp_path / "vae.json"
    foreign.write_text('{"latent": 2}')
    for path in (torn, foreign):
        network = {"vae_path": str(path), "observation": "encoded", "vae_latent": 2}
        with pytest.raises(ConfigError) as err:
            build_algorithm(heatmap_config(network=network))
        assert err.value.field == "network.vae_path"
    network = {"vae_path": str(good), "observation": "encoded", "vae_latent": 3}
    with pytest.raises(ConfigError) as err:
        build_algorithm(heatmap_config(network=network))
    assert err.value.field == "network.vae_latent"
