"""The anytime best as a race: a small pool of the best policies seen, re-evaluated every
iteration on the same fresh rollouts as the iteration's challengers.

Why: a search that keeps "the policy with the best fresh value so far" picks the maximum of
hundreds of noisy means (one per iteration), so on a noisy problem it keeps a lucky policy, not
a good one (the winner's curse; experiments/NOTES.md). In a pool every member's estimate is
the mean of all its evaluations since it entered, so it sharpens with every iteration it
survives; the member kept as the best policy is the one with the largest lower confidence
bound ``mean - CONFIDENCE * sigma / sqrt(count)`` (``sigma``: the spread of one evaluation,
pooled over the members evaluated at least twice), so a policy that entered on one lucky
evaluation is not kept before it was checked again.

One update (``race``), pool of ``P >= 2`` members (leaves ``[P, ...]``):

1. the members' values of this iteration (same rollouts as the challenger's, common random
   numbers) update their running means and spreads (Welford's sums, exact in float32 over
   hundreds of evaluations);
2. the challenger replaces the member with the smallest mean -- never the kept one -- when its
   value is larger, unless it is already in the pool (the same deterministic policy gets the
   same value on the same rollouts: a converged distribution proposes its mode again and
   again);
3. the best member by the lower confidence bound is the anytime best.

Empty slots have count 0 and mean ``-inf``; they are filled first. A value that is not finite
(NaN, inf: a simulator's overflow) makes its member's mean ``-inf`` (evicted next, never kept)
and keeps a challenger out.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from flax import struct

#: standard errors below its mean at which a member is ranked: a newcomer as good as the kept
#: policy replaces it on one evaluation only when that evaluation was 2 sigma lucky (2 %)
CONFIDENCE = 2.0


@struct.dataclass
class BestPool:
    """``P`` policies (leaves with a leading ``[P]`` axis) and their fresh values so far:
    ``mean``, ``m2`` (sum of squared deviations from the mean) and ``count [P]``
    (evaluations, each a mean over the search's ``best_rollouts``)."""

    policies: object
    mean: jax.Array  # [P]
    m2: jax.Array  # [P]
    count: jax.Array  # [P] int32

    @classmethod
    def create(cls, policy, size: int) -> BestPool:
        """An empty pool of ``size`` slots (``policy`` fills them until replaced)."""
        stacked = jax.tree.map(lambda x: jnp.broadcast_to(x, (size,) + x.shape), policy)
        empty = jnp.full(size, -jnp.inf, jnp.float32)
        return cls(stacked, empty, jnp.zeros(size, jnp.float32), jnp.zeros(size, jnp.int32))

    def means(self) -> jax.Array:
        """``[P]`` mean fresh value per member, ``-inf`` for empty slots."""
        return jnp.where(self.count > 0, self.mean, -jnp.inf)

    def spread(self) -> jax.Array:
        """``[]`` standard deviation of one evaluation, pooled over the members with >= 2
        finite evaluations (0 when none has)."""
        usable = (self.count >= 2) & jnp.isfinite(self.mean) & jnp.isfinite(self.m2)
        dof = jnp.sum(jnp.where(usable, self.count - 1, 0)).astype(jnp.float32)
        total = jnp.sum(jnp.where(usable, self.m2, 0.0))
        return jnp.sqrt(jnp.maximum(total, 0.0) / jnp.maximum(dof, 1.0))

    def best(self) -> jax.Array:
        """``[]`` index of the member with the largest ``mean - CONFIDENCE x spread /
        sqrt(count)`` (empty and non-finite members last)."""
        spread = CONFIDENCE * self.spread()
        bound = self.means() - spread / jnp.sqrt(jnp.maximum(self.count, 1))
        return jnp.argmax(jnp.where(jnp.isnan(bound), -jnp.inf, bound))

    def member(self, index: jax.Array):
        """The policy in slot ``index``."""
        return jax.tree.map(lambda x: x[index], self.policies)


def race(pool: BestPool, member_values, challenger, challenger_value) -> BestPool:
    """The pool after one iteration: ``member_values [P]`` are this iteration's fresh values of
    the members, ``challenger_value []`` the challenger's on the same rollouts (steps 1-2 of
    the module docstring)."""
    seen = pool.count > 0
    finite = jnp.isfinite(member_values)
    count = pool.count + seen.astype(jnp.int32)
    n = jnp.maximum(count, 1).astype(jnp.float32)
    old = jnp.where(pool.count > 0, pool.mean, 0.0)
    delta = member_values - old
    mean = old + delta / n
    m2 = pool.m2 + delta * (member_values - mean)
    bad = seen & (~finite | ~jnp.isfinite(pool.mean))  # a non-finite value: never kept
    pool = pool.replace(
        mean=jnp.where(bad, -jnp.inf, jnp.where(seen, mean, pool.mean)),
        m2=jnp.where(bad, 0.0, jnp.where(seen, m2, pool.m2)),
        count=count,
    )
    slots = jnp.arange(pool.count.shape[0])
    evictable = jnp.where(slots == pool.best(), jnp.inf, pool.means())  # never the kept one
    worst = jnp.argmin(evictable)
    duplicate = jnp.any(seen & (member_values == challenger_value))
    enter = jnp.isfinite(challenger_value) & (challenger_value > evictable[worst]) & ~duplicate
    put = enter & (slots == worst)  # [P]

    def place(stacked, new):
        mask = put.reshape(put.shape + (1,) * new.ndim)
        return jnp.where(mask, new[None], stacked)

    return BestPool(
        policies=jax.tree.map(place, pool.policies, challenger),
        mean=jnp.where(put, challenger_value, pool.mean),
        m2=jnp.where(put, 0.0, pool.m2),
        count=jnp.where(put, 1, pool.count),
    )
