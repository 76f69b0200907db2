"""The counter-based "hash" generator (``run.prng_impl = "hash"``): jax.random works on its keys,
its uniforms have the right moments and no visible dependence between neighbouring draws, sibling
keys or folded-in keys, and a search with it is deterministic and reaches the values it reaches
with threefry."""

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cognet_jax.config import ConfigError
from cognet_jax.driver import train
from cognet_jax.prng import THREEFRY_IMPL, fast_key, make_key
from cognet_jax.registry import load_config

N = 1_000_000


def _uniforms(key, n=N):
    return np.asarray(jax.random.uniform(key, (n,)), np.float64)


def test_jax_random_works_on_hash_keys():
    key = make_key(3, "hash")
    assert jax.random.key_impl(key) is not None
    a, b = jax.random.split(key)
    assert not np.array_equal(jax.random.key_data(a), jax.random.key_data(b))
    assert jax.random.normal(key, (7,)).shape == (7,)
    ints = np.asarray(jax.random.randint(key, (10_000,), 0, 5))
    assert set(ints.tolist()) == {0, 1, 2, 3, 4}
    # the same key gives the same numbers, under jit too
    np.testing.assert_array_equal(
        jax.random.uniform(key, (5,)), jax.jit(lambda k: jax.random.uniform(k, (5,)))(key)
    )
    # different seeds give different streams, seed 0 included
    first = [float(jax.random.uniform(make_key(s, "hash"))) for s in range(5)]
    assert len(set(first)) == 5


@pytest.mark.parametrize("seed", [0, 1, 12345])
def test_uniform_moments(seed):
    u = _uniforms(make_key(seed, "hash"))
    se_mean = np.sqrt(1 / 12 / N)
    assert abs(u.mean() - 0.5) < 5 * se_mean
    assert abs(u.var() - 1 / 12) < 5 * np.sqrt(1 / 180 / N)  # var of (u - 1/2)^2 is 1/180
    assert 0.0 <= u.min() and u.max() < 1.0
    # every decile holds a tenth of the draws (chi-square, 9 dof: 99.99th percentile 33.7)
    counts = np.bincount((u * 10).astype(int), minlength=10)
    chi2 = np.sum((counts - N / 10) ** 2 / (N / 10))
    assert chi2 < 33.7


def _corr(x, y):
    return np.corrcoef(x, y)[0, 1]


def test_no_correlation_between_neighbours_siblings_or_folds():
    limit = 5 / np.sqrt(N)  # 5 standard errors of a correlation of independent draws
    key = make_key(0, "hash")
    u = _uniforms(key)
    assert abs(_corr(u[:-1], u[1:])) < limit  # consecutive counters
    a, b = jax.random.split(key)
    assert abs(_corr(_uniforms(a), _uniforms(b))) < limit
    f1, f2 = jax.random.fold_in(key, 1), jax.random.fold_in(key, 2)
    assert abs(_corr(_uniforms(f1), _uniforms(f2))) < limit
    # a parent's stream and its children's
    assert abs(_corr(u, _uniforms(a))) < limit
    # nor between shifted windows of two siblings (streams are not shifted copies)
    ua, ub = _uniforms(a, 2 * N), _uniforms(b, 2 * N)
    for shift in (1, 7, 1000):
        assert abs(_corr(ua[shift : shift + N], ub[:N])) < limit


def test_bits_of_other_widths():
    key = make_key(5, "hash")
    for dtype in (jnp.uint8, jnp.uint16, jnp.uint32):
        bits = np.asarray(jax.random.bits(key, (100_000,), dtype))
        top = bits.astype(np.uint64) >> (np.iinfo(dtype).bits - 1)
        assert abs(top.mean() - 0.5) < 0.01  # the top bit is fair


def test_config_accepts_hash_and_names_the_field_otherwise():
    config = load_config("tagging-thesis-spec-n3", ['run.prng_impl="hash"'])
    assert config.run.prng_impl == "hash"
    with pytest.raises(ConfigError, match="run.prng_impl"):
        load_config("tagging-thesis-spec-n3", ['run.prng_impl="philox"'])


@pytest.mark.optimised
def test_search_with_hash_is_deterministic_and_as_good(tmp_path):
    """The same seed gives the same run; and the honest value of G-DICE on a small tagging
    problem is the same, within noise, as with threefry (the generator is not what decides)."""
    sets = [
        "algorithm.iterations=40",
        "algorithm.samples=100",
        "algorithm.elites=10",
        "algorithm.eval_rollouts=50",
        "evaluation.rollouts=4000",
        "run.plots=false",
        "run.progress=false",
    ]
    finals = {}
    for impl in ("threefry2x32", "hash", "hash"):
        config = load_config("tagging-paper-gdice-d2", [*sets, f'run.prng_impl="{impl}"'])
        out = tmp_path / f"{impl}-{len(finals)}"
        result = train(config, 0, out, log=lambda *_: None)
        finals.setdefault(impl, []).append(result)
    a, b = finals["hash"]
    assert a["final_value"] == b["final_value"]
    assert a["values_per_iteration"] == b["values_per_iteration"]
    t, h = finals["threefry2x32"][0]["final_value"], a["final_value"]
    assert t["mean"] != h["mean"]  # other random numbers, but the same quality of search:
    for run in (finals["threefry2x32"][0], a):  # both improve on the first iteration ...
        assert run["final_value"]["mean"] > run["values_per_iteration"][0] + 5
    assert abs(t["mean"] - h["mean"]) < 5 * np.hypot(t["stderr"], h["stderr"])  # ... alike


# --- the unrolled Threefry (THREEFRY_IMPL): JAX's stream, bit for bit ------------------------


def _fast(seed):
    return jax.random.wrap_key_data(jax.random.key_data(jax.random.key(seed)), impl=THREEFRY_IMPL)


@functools.partial(jax.jit, static_argnums=(1, 2))
def _bits_both_ways(key_data, shape, dtype):
    """``random_bits`` of one key's data with ``THREEFRY_IMPL`` and with JAX's threefry, in
    one program (a program per shape and dtype, not one per function and seed)."""
    fast = jax.random.wrap_key_data(key_data, impl=THREEFRY_IMPL)
    return jax.random.bits(fast, shape, dtype), jax.random.bits(
        jax.random.wrap_key_data(key_data), shape, dtype
    )


@pytest.mark.parametrize("shape", [(), (1,), (7,), (3, 5), (100_001, 11), (2, 3, 4), (0, 3)])
@pytest.mark.parametrize("dtype", [jnp.uint8, jnp.uint16, jnp.uint32, jnp.uint64])
def test_threefry_impl_bits_equal_jax(shape, dtype):
    with jax.enable_x64(dtype == jnp.uint64):  # 64-bit draws need x64
        for seed in (0, 1, 2**31 + 5):
            data = jax.random.key_data(jax.random.key(seed))
            got, expected = _bits_both_ways(data, shape, dtype)
            assert got.dtype == expected.dtype == dtype and got.shape == expected.shape == shape
            np.testing.assert_array_equal(got, expected)


def test_threefry_impl_split_fold_in_seed_and_distributions_equal_jax():
    ref, fast = jax.random.key(42), _fast(42)
    for shape in [(2,), (3,), (4, 5)]:
        np.testing.assert_array_equal(
            jax.random.key_data(jax.random.split(fast, shape)),
            jax.random.key_data(jax.random.split(ref, shape)),
        )
    for data in (0, 1, 17, 2**32 - 1):
        np.testing.assert_array_equal(
            jax.random.key_data(jax.random.fold_in(fast, data)),
            jax.random.key_data(jax.random.fold_in(ref, data)),
        )
    for seed in (0, 3, 2**40 + 9):
        np.testing.assert_array_equal(
            jax.random.key_data(jax.random.key(seed, impl=THREEFRY_IMPL)),
            jax.random.key_data(jax.random.key(seed)),
        )
    draws = {
        "uniform": lambda k: jax.random.uniform(k, (1000, 3)),
        "normal": lambda k: jax.random.normal(k, (999,)),
        "categorical": lambda k: jax.random.categorical(
            k, jnp.log(jnp.arange(1.0, 6.0)), shape=(500,)
        ),
        "beta": lambda k: jax.random.beta(k, 2.0, 3.0, (200,)),
        "chained": lambda k: jax.random.uniform(
            jax.random.split(jax.random.fold_in(k, 3))[1], (9,)
        ),
    }
    for name, draw in draws.items():
        np.testing.assert_array_equal(jax.jit(draw)(fast), draw(ref), err_msg=name)
        # under vmap over keys too
        keys_ref, keys_fast = jax.random.split(ref, 4), jax.random.split(fast, 4)
        np.testing.assert_array_equal(
            jax.vmap(draw)(keys_fast), jax.vmap(draw)(keys_ref), err_msg=name
        )


def test_threefry_impl_follows_the_non_partitionable_stream_too():
    previous = jax.config.jax_threefry_partitionable
    jax.config.update("jax_threefry_partitionable", False)
    try:
        for shape in [(5,), (4, 3)]:
            np.testing.assert_array_equal(
                jax.random.uniform(_fast(9), shape), jax.random.uniform(jax.random.key(9), shape)
            )
        np.testing.assert_array_equal(
            jax.random.key_data(jax.random.split(_fast(9), 3)),
            jax.random.key_data(jax.random.split(jax.random.key(9), 3)),
        )
    finally:
        jax.config.update("jax_threefry_partitionable", previous)


def test_fast_key_converts_threefry_keys_only():
    assert jax.random.key_impl(fast_key(jax.random.key(1))) == jax.random.key_impl(_fast(1))
    raw = jax.random.PRNGKey(1)  # the old raw uint32[2] kind
    np.testing.assert_array_equal(jax.random.key_data(fast_key(raw)), raw)
    assert jax.random.key_impl(fast_key(raw)) == jax.random.key_impl(_fast(1))
    batch = jax.random.split(jax.random.key(1), 3)
    assert fast_key(batch).shape == (3,)
    for other in (make_key(1, "hash"), jax.random.key(1, impl="rbg")):
        assert jax.random.key_impl(fast_key(other)) == jax.random.key_impl(other)
    # inside jit, on a traced key
    u = jax.jit(lambda k: jax.random.uniform(fast_key(k), (4,)))(jax.random.key(2))
    np.testing.assert_array_equal(u, jax.random.uniform(jax.random.key(2), (4,)))
