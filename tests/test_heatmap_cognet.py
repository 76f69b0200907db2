"""Heatmap experiments with COGNet-DICE: configuration, observation pipelines (raw / encoded),
augmentation and evaluation under observation noise."""

import pytest

from cognet_jax.api import build_env
from cognet_jax.config import ConfigError, config_from_dict
from cognet_jax.envs.heatmap import START_RANGES


def heatmap_config(env=None, network=None, algorithm=None, **sections):
    data = {
        "experiment": {"name": "heat-test", "algorithm": "cognet-dice"},
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
