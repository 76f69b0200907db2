"""The race of best policies (``algorithms.best_pool``): entry, duplicates, the kept member."""

import jax.numpy as jnp
import numpy as np

from cognet_jax.algorithms.best_pool import BestPool, race


def policy(v):
    """A stand-in policy: any pytree works; this one carries its own id."""
    return {"id": jnp.float32(v), "w": jnp.full((2, 3), v, jnp.float32)}


def test_an_empty_pool_takes_challengers_then_evicts_the_lowest_mean():
    pool = BestPool.create(policy(0), 2)
    assert np.all(np.isneginf(pool.means()))
    pool = race(pool, jnp.zeros(2), policy(1), jnp.float32(5.0))
    pool = race(pool, jnp.array([5.0, 0.0]), policy(2), jnp.float32(3.0))
    assert sorted(np.asarray(pool.policies["id"]).tolist()) == [1.0, 2.0]
    # member 1 now has mean 5 over 2 evaluations, member 2 mean 3 over 1
    pool = race(pool, jnp.array([5.0, 3.0]), policy(3), jnp.float32(4.0))
    ids = np.asarray(pool.policies["id"]).tolist()
    assert 2.0 not in ids and 3.0 in ids and 1.0 in ids
    assert np.asarray(pool.policies["w"])[ids.index(3.0)].tolist() == [[3.0] * 3] * 2
    # a challenger below every mean stays out
    before = np.asarray(pool.policies["id"]).copy()
    pool = race(pool, jnp.array([5.0, 4.0]), policy(9), jnp.float32(1.0))
    assert np.array_equal(np.asarray(pool.policies["id"]), before)


def test_the_same_policy_does_not_enter_twice():
    pool = BestPool.create(policy(0), 3)
    pool = race(pool, jnp.zeros(3), policy(1), jnp.float32(2.0))
    slot = int(np.argmax(np.asarray(pool.count)))
    values = jnp.zeros(3).at[slot].set(2.5)
    pool = race(pool, values, policy(1), jnp.float32(2.5))  # the same value on the same rollouts
    assert int(np.sum(np.asarray(pool.count) > 0)) == 1


def test_the_kept_member_is_the_lower_confidence_bound_not_one_lucky_value():
    pool = BestPool.create(policy(0), 2)
    steady = [10.0, 12.0, 8.0, 10.0, 11.0, 9.0]  # spread about 1.4 per evaluation
    pool = race(pool, jnp.zeros(2), policy(1), jnp.float32(steady[0]))
    for v in steady[1:]:
        pool = race(pool, jnp.array([v, v]), policy(1), jnp.float32(v))
    lucky = 11.0  # a newcomer whose single value beats the steady mean of 10
    pool = race(pool, jnp.array([10.0, 0.0]), policy(2), jnp.float32(lucky))
    means = np.asarray(pool.means())
    assert means.max() == lucky
    assert float(pool.member(pool.best())["id"]) == 1.0
    # once re-evaluated near its single value, the newcomer is kept
    for _ in range(6):
        index = np.asarray(pool.policies["id"]).tolist()
        values = jnp.array([10.0 if i == 1.0 else 11.0 for i in index])
        pool = race(pool, values, policy(1), jnp.float32(10.0))
    assert float(pool.member(pool.best())["id"]) == 2.0
