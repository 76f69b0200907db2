"""The race of best policies (``algorithms.best_pool``): entry, eviction, duplicates, the kept
member, non-finite values."""

import jax.numpy as jnp
import numpy as np

from cognet_jax.algorithms.best_pool import BestPool, race


def policy(v):
    """A stand-in policy: any pytree works; this one carries its own id."""
    return {"id": jnp.float32(v), "w": jnp.full((2, 3), v, jnp.float32)}


def ids(pool) -> list:
    return [float(i) if c > 0 else None for i, c in zip(pool.policies["id"], pool.count)]


def step(pool, values: dict, challenger, value):
    """``race`` with each member's value looked up by its id (``values``; empty slots 0)."""
    member_values = jnp.array([values.get(i, 0.0) for i in ids(pool)], jnp.float32)
    return race(pool, member_values, policy(challenger), jnp.float32(value))


def kept(pool) -> float:
    return float(pool.member(pool.best())["id"])


def test_an_empty_pool_takes_challengers_then_evicts_the_lowest_mean_but_never_the_kept():
    pool = BestPool.create(policy(0), 3)
    assert np.all(np.isneginf(pool.means()))
    pool = step(pool, {}, 1, 5.0)
    pool = step(pool, {1.0: 5.0}, 2, 3.0)
    pool = step(pool, {1.0: 5.0, 2.0: 3.0}, 3, 4.0)
    assert sorted(i for i in ids(pool) if i is not None) == [1.0, 2.0, 3.0]
    assert kept(pool) == 1.0
    pool = step(pool, {1.0: 5.0, 2.0: 3.0, 3.0: 4.0}, 4, 4.5)  # evicts 2 (mean 3)
    assert sorted(ids(pool)) == [1.0, 3.0, 4.0]
    row = ids(pool).index(4.0)
    assert np.asarray(pool.policies["w"])[row].tolist() == [[4.0] * 3] * 2
    before = ids(pool)
    pool = step(pool, {1.0: 5.0, 3.0: 4.0, 4.0: 4.5}, 9, 1.0)  # below every mean: stays out
    assert ids(pool) == before


def test_the_kept_member_is_not_evicted_by_a_lower_mean():
    """A well-measured member can have the lowest mean and the best bound: it stays."""
    pool = BestPool.create(policy(0), 2)
    pool = step(pool, {}, 1, 10.0)
    for v in [12.0, 8.0, 10.0, 11.0, 9.0] * 4:  # mean 10 over 21 evaluations
        pool = step(pool, {1.0: v}, 1, v)
    pool = step(pool, {1.0: 10.0}, 2, 11.5)  # one lucky evaluation: not yet kept
    assert kept(pool) == 1.0
    pool = step(pool, {1.0: 10.0, 2.0: 10.0}, 3, 10.5)  # would evict 1 by mean: evicts nothing
    assert 1.0 in ids(pool) and kept(pool) == 1.0


def test_the_same_policy_does_not_enter_twice():
    pool = BestPool.create(policy(0), 3)
    pool = step(pool, {}, 1, 2.0)
    pool = step(pool, {1.0: 2.5}, 1, 2.5)  # the same value on the same rollouts
    assert int(np.sum(np.asarray(pool.count) > 0)) == 1


def test_the_kept_member_is_the_lower_confidence_bound_not_one_lucky_value():
    pool = BestPool.create(policy(0), 2)
    steady = [10.0, 12.0, 8.0, 10.0, 11.0, 9.0]  # spread about 1.4 per evaluation
    pool = step(pool, {}, 1, steady[0])
    for v in steady[1:]:
        pool = step(pool, {1.0: v}, 1, v)
    pool = step(pool, {1.0: 10.0}, 2, 11.0)  # a newcomer whose single value beats the mean 10
    assert float(np.max(np.asarray(pool.means()))) == 11.0
    assert kept(pool) == 1.0
    for _ in range(6):  # once re-evaluated near its single value, the newcomer is kept
        pool = step(pool, {1.0: 10.0, 2.0: 11.0}, 1, 10.0)
    assert kept(pool) == 2.0


def test_non_finite_values_never_make_the_kept_member():
    pool = BestPool.create(policy(0), 3)
    pool = step(pool, {}, 1, 5.0)
    pool = step(pool, {1.0: 5.0}, 2, float("nan"))  # a NaN challenger stays out
    assert ids(pool).count(None) == 2
    pool = step(pool, {1.0: 5.0}, 2, 6.0)
    pool = step(pool, {1.0: 5.0, 2.0: float("inf")}, 3, 1.0)  # member 2 overflowed
    assert kept(pool) == 1.0 and 2.0 not in ids(pool)  # -inf: evicted at once
    pool = step(pool, {1.0: 5.0, 3.0: float("nan")}, 4, 0.5)
    assert kept(pool) == 1.0 and 3.0 not in ids(pool)
    assert np.isfinite(float(pool.spread()))
