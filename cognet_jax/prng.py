"""PRNG implementations selectable with ``run.prng_impl``, ``make_key`` and ``fast_key``.

``"threefry2x32"`` (the default) is JAX's own implementation. JAX lowers the Threefry hash on CPU as
a rolled loop (a ``while`` of 5 iterations whose state goes to memory between iterations, chosen for
compile time). ``THREEFRY_IMPL`` computes the same stream, bit for bit (same seed, ``split``,
``fold_in`` and ``random_bits``; tests/test_prng.py compares them), with the 20 rounds written out
as plain element-wise operations, several times faster on large blocks (benchmarks/NOTES.md,
"Measurements behind code choices"). ``fast_key`` converts a threefry key (typed, or a raw
``uint32[..., 2]`` key of the old ``jax.random.PRNGKey`` kind) to it. The rollout engine uses it for
its large per-step blocks, whatever key the caller passed; elsewhere keys stay JAX's, because the
unrolled rounds, inlined at each of an iteration's many small draws, double the compile time. With
``jax_threefry_partitionable`` off (JAX's older stream) ``THREEFRY_IMPL`` defers to JAX's functions
and stays exact.

Besides it, ``rbg`` and ``unsafe_rbg`` (JAX's own) and ``"hash"``: a counter-based generator
registered through ``jax.extend.random.define_prng_impl``, so every ``jax.random`` function
(``uniform``, ``split``, ``fold_in``, ...) works on its keys unchanged.

The hash: a key is two 32-bit words ``(k0, k1)``. Word ``c`` of a key's stream is

    fmix32(fmix32(c * 0x9E3779B9 ^ k0) + k1)

with murmur3's 32-bit finaliser ``fmix32`` (a bijection of uint32). For a fixed key the map
``c -> word`` is a bijection, and the key enters non-linearly (through ``fmix32``), so the
streams of two keys are not shifted copies of each other. ``split`` and ``fold_in`` derive
child keys from the same construction with the key's first word tweaked (a stream of its own).
64-bit draws combine two words. It is not a cryptographic generator, nor one that passes every
statistical battery: tests/test_prng.py checks the moments of the uniforms, the independence of
neighbouring draws, of sibling keys and of folded-in keys, and that a search with it reaches
the same values as with threefry. Choosing it changes every random number of a run: results
are reproducible with the same ``run.prng_impl`` only.
"""

from __future__ import annotations

import math

import jax
import jax.extend.random
import jax.numpy as jnp
import numpy as np

from cognet_jax.errors import ResourceError

_GOLDEN = np.uint32(0x9E3779B9)
_SPLIT_TWEAK = np.uint32(0x5BD1E995)
_FOLD_TWEAK = np.uint32(0x27D4EB2F)
_SEED_TWEAK = np.uint32(0x165667B1)
#: unsigned dtype of each ``random_bits`` width
_UINT = {8: jnp.uint8, 16: jnp.uint16, 32: jnp.uint32, 64: jnp.uint64}


# --- Threefry-2x32, unrolled (JAX's stream, bit for bit) -------------------------------------

_THREEFRY_ROTATIONS = ((13, 15, 26, 6), (17, 29, 16, 24))
_THREEFRY_PARITY = np.uint32(0x1BD11BDA)


def _rotate_left(x: jax.Array, d: int) -> jax.Array:
    return (x << np.uint32(d)) | (x >> np.uint32(32 - d))


def threefry2x32(
    k1: jax.Array, k2: jax.Array, x1: jax.Array, x2: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """The Threefry-2x32 block function (20 rounds) on counter words ``x1, x2`` (uint32, any
    shape) under the key ``(k1, k2)``, written out round by round (JAX's CPU lowering is a
    rolled loop). Returns the two output words, shaped like ``x1``."""
    ks = (k1, k2, k1 ^ k2 ^ _THREEFRY_PARITY)
    a, b = x1 + ks[0], x2 + ks[1]
    for i in range(5):
        for r in _THREEFRY_ROTATIONS[i % 2]:
            a = a + b
            b = a ^ _rotate_left(b, r)
        a = a + ks[(i + 1) % 3]
        b = b + ks[(i + 2) % 3] + np.uint32(i + 1)
    return a, b


def _partitionable() -> bool:
    return bool(jax.config.jax_threefry_partitionable)


def _as_threefry(key: jax.Array) -> jax.Array:
    return jax.random.wrap_key_data(key, impl="threefry2x32")


def _counters(key: jax.Array, shape: tuple[int, ...]) -> tuple[jax.Array, jax.Array]:
    """The 64-bit flat index of every element of ``shape`` as (high, low) uint32 words.

    The low words are the index plus a zero XLA cannot prove is zero (``key[0] > 2**32 - 1``),
    so they depend on the key: in a rollout's time loop, whose key changes every step, XLA
    then computes them inside the generator's loop instead of hoisting them out as a
    ``[*shape]`` array that every step reads back from memory (benchmarks/NOTES.md,
    "Ninth pass"). The same numbers."""
    n = math.prod(shape)
    if n >= 2**32:
        raise ResourceError(  # a user's sizes, found where the draws are traced or lowered
            f"random draws of {n} >= 2**32 elements at once are not supported; lower the sizes "
            "in the config (nodes, samples, candidates, rollouts)"
        )
    zero = (key[0] > np.uint32(2**32 - 1)).astype(jnp.uint32)
    low = (jax.lax.iota(jnp.uint32, n) + zero).reshape(shape)
    return jnp.zeros(shape, jnp.uint32), low


def _threefry_bits(key: jax.Array, bit_width: int, shape: tuple[int, ...]) -> jax.Array:
    if not _partitionable():
        return jax.random.bits(_as_threefry(key), shape, _UINT[bit_width])
    b1, b2 = threefry2x32(key[0], key[1], *_counters(key, shape))
    if bit_width == 64:
        return (b1.astype(jnp.uint64) << np.uint64(32)) | b2.astype(jnp.uint64)
    bits = b1 ^ b2
    return bits.astype(_UINT[bit_width])


def _threefry_seed(seed: jax.Array) -> jax.Array:
    return jax.random.key_data(jax.random.key(seed, impl="threefry2x32"))


def _threefry_split(key: jax.Array, shape: tuple[int, ...]) -> jax.Array:
    if not _partitionable():
        return jax.random.key_data(jax.random.split(_as_threefry(key), shape))
    b1, b2 = threefry2x32(key[0], key[1], *_counters(key, shape))
    return jnp.stack([b1, b2], axis=-1)


def _threefry_fold_in(key: jax.Array, data: jax.Array) -> jax.Array:
    # JAX: threefry_2x32(key, threefry_seed(data)); a 2-word count is split into halves
    seeded = _threefry_seed(data)
    b1, b2 = threefry2x32(key[0], key[1], seeded[:1], seeded[1:])
    return jnp.concatenate([b1, b2])


def _define(name: str, tag: str, seed, split, bits, fold_in):
    """A JAX PRNG implementation of two 32-bit key words."""
    functions = dict(seed=seed, split=split, random_bits=bits, fold_in=fold_in)
    return jax.extend.random.define_prng_impl(key_shape=(2,), name=name, tag=tag, **functions)


THREEFRY_IMPL = _define(
    "threefry2x32_unrolled",
    "fru",
    _threefry_seed,
    _threefry_split,
    _threefry_bits,
    _threefry_fold_in,
)


# --- counter-based hash (opt-in) ---------------------------------------------------------


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
    dtype = _UINT[bit_width]
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


HASH_IMPL = _define("hash", "hsh", _seed, _split, _bits, _fold_in)

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


def fast_key(key: jax.Array) -> jax.Array:
    """``key`` with JAX's threefry implementation swapped for ``THREEFRY_IMPL`` (the same
    stream, computed faster on CPU); keys of other implementations are returned unchanged. A
    raw ``uint32[..., 2]`` key (``jax.random.PRNGKey``) is read as JAX's default implementation
    and converted only when that is threefry. Works on traced keys (inside ``jit``)."""
    if jax.dtypes.issubdtype(key.dtype, jax.dtypes.prng_key):
        if str(jax.random.key_impl(key)) != "threefry2x32":
            return key
        return jax.random.wrap_key_data(jax.random.key_data(key), impl=THREEFRY_IMPL)
    if key.dtype == jnp.uint32 and key.shape[-1:] == (2,):
        if jax.config.jax_default_prng_impl != "threefry2x32":
            return key
        return jax.random.wrap_key_data(key, impl=THREEFRY_IMPL)
    return key
