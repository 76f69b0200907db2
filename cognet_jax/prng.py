"""PRNG implementations selectable with ``run.prng_impl``, and ``make_key``.

Besides JAX's own ``threefry2x32`` (the default), ``rbg`` and ``unsafe_rbg``, this module
defines ``"hash"``: a counter-based generator registered through
``jax.extend.random.define_prng_impl``, so every ``jax.random`` function (``uniform``,
``split``, ``fold_in``, ...) works on its keys unchanged.

Why: on a CPU, threefry2x32 is most of the cost of a rollout step. One ``[1e5, 11]`` block of
uniforms takes about 13 ms with threefry and 1.2 ms with this hash (benchmarks/NOTES.md), and
100,000 rollouts of a 6-node tagging controller run about 1.35x faster.

How: a key is two 32-bit words ``(k0, k1)``. Word ``c`` of a key's stream is

    fmix32(fmix32(c * 0x9E3779B9 ^ k0) + k1)

with murmur3's 32-bit finaliser ``fmix32`` (a bijection of uint32). For a fixed key the map
``c -> word`` is a bijection, and the key enters non-linearly (through ``fmix32``), so the
streams of two keys are not shifted copies of each other. ``split`` and ``fold_in`` derive
child keys from the same construction with the key's first word tweaked (a stream of its own).
64-bit draws combine two words.

What it is not: a cryptographic generator, nor one that passes every statistical battery.
tests/test_prng.py checks the moments of the uniforms, the independence of neighbouring draws,
of sibling keys and of folded-in keys, and that a search with it reaches the same values as
with threefry. Choosing it changes every random number of a run: results are reproducible
with the same ``run.prng_impl`` only.
"""

from __future__ import annotations

import math

import jax
import jax.extend.random
import jax.numpy as jnp
import numpy as np

_GOLDEN = np.uint32(0x9E3779B9)
_SPLIT_TWEAK = np.uint32(0x5BD1E995)
_FOLD_TWEAK = np.uint32(0x27D4EB2F)
_SEED_TWEAK = np.uint32(0x165667B1)


def fmix32(x: jax.Array) -> jax.Array:
    """murmur3's 32-bit finaliser: a bijection of uint32 with full avalanche."""
    x = x ^ (x >> 16)
    x = x * jnp.uint32(0x85EBCA6B)
    x = x ^ (x >> 13)
    x = x * jnp.uint32(0xC2B2AE35)
    return x ^ (x >> 16)


def _words(key: jax.Array, counters: jax.Array) -> jax.Array:
    """Words ``[*counters.shape]`` (uint32) of ``key``'s stream at ``counters``."""
    k0, k1 = key[0], key[1]
    return fmix32(fmix32((counters * _GOLDEN) ^ k0) + k1)


def _bits(key: jax.Array, bit_width: int, shape: tuple[int, ...]) -> jax.Array:
    n = math.prod(shape)
    if bit_width == 64:
        w = _words(key, jnp.arange(2 * n, dtype=jnp.uint32)).reshape(n, 2).astype(jnp.uint64)
        return ((w[:, 0] << 32) | w[:, 1]).reshape(shape)
    w = _words(key, jnp.arange(n, dtype=jnp.uint32)).reshape(shape)
    dtype = {8: jnp.uint8, 16: jnp.uint16, 32: jnp.uint32}[bit_width]
    return w if bit_width == 32 else (w >> (32 - bit_width)).astype(dtype)


def _seed(seed: jax.Array) -> jax.Array:
    s = jnp.asarray(seed)
    lo = s.astype(jnp.uint32)
    hi = (s.astype(jnp.uint64) >> 32).astype(jnp.uint32) if s.dtype.itemsize == 8 else lo * 0
    return jnp.stack([fmix32(lo ^ _SEED_TWEAK), fmix32(fmix32(hi ^ _GOLDEN) + lo)])


def _split(key: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    tweaked = jnp.stack([key[0] ^ _SPLIT_TWEAK, key[1]])
    n = math.prod(shape)
    return _words(tweaked, jnp.arange(2 * n, dtype=jnp.uint32)).reshape(*shape, 2)


def _fold_in(key: jax.Array, data: jax.Array) -> jax.Array:
    tweaked = jnp.stack([key[0] ^ _FOLD_TWEAK, key[1]])
    d = fmix32(jnp.asarray(data).astype(jnp.uint32))
    return _words(tweaked, jnp.stack([2 * d, 2 * d + 1]))


HASH_IMPL = jax.extend.random.define_prng_impl(
    key_shape=(2,),
    seed=_seed,
    split=_split,
    random_bits=_bits,
    fold_in=_fold_in,
    name="hash",
    tag="hsh",
)

#: ``run.prng_impl`` values: JAX's own implementations by name, and this module's.
IMPLS = {
    "threefry2x32": "threefry2x32",
    "rbg": "rbg",
    "unsafe_rbg": "unsafe_rbg",
    "hash": HASH_IMPL,
}


def impl_of(name: str):
    """The ``impl`` argument of ``jax.random.key`` for a ``run.prng_impl`` name."""
    try:
        return IMPLS[name]
    except KeyError:
        raise ValueError(
            f"unknown PRNG implementation {name!r}; choose from {sorted(IMPLS)}"
        ) from None


def make_key(seed: int, name: str = "threefry2x32") -> jax.Array:
    """A typed PRNG key of implementation ``name`` (``run.prng_impl``)."""
    return jax.random.key(seed, impl=impl_of(name))
