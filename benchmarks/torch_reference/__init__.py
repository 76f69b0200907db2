"""PyTorch references of COGNet-DICE on the tagging simulator, for speed comparisons.

Implementations of the thesis algorithm and simulator of ``cognet_jax`` (SPEC sections 1, 2,
5 and 7.1; ``cognet_jax.algorithms.cognet_thesis.CognetThesis.step``):

* ``TorchCognetLoop`` (``loop.py``): as the thesis code was written -- one ``nn.Module`` and one
  ``torch.optim`` optimiser per (agent, node), Python loops over rollouts and time steps, batch-1
  forward calls, ``torch.multinomial`` per draw, a Python-float simulator, candidates evaluated one
  rollout at a time.
* ``TorchCognetVectorized`` (``vectorized.py``): rollouts batched per time step, stacked member
  weights applied with ``einsum`` (every member of an agent, then the current node's logits
  gathered), inverse-CDF sampling from one
  uniform block per step, all candidates evaluated in one batch with common random numbers.
* ``TorchCognetCompiled`` (``vectorized.py``): the vectorised one with each rollout time step
  compiled by ``torch.compile`` (inductor); the same draws, so the same numbers.
* ``TorchWeightsSearch`` / ``TorchWeightsCompiled`` (``weights.py``): the default
  ``cognet-dice`` (cross-entropy over the node networks' weights), eager and compiled; its own
  API (``step``, ``run``, ``returns``), settings read from a cognet_jax config.

Common API::

    algo = TorchCognetVectorized(settings, hyper=None, env=None, seed=0)
    metrics = algo.step()             # one full iteration; dict: value, best_value, threshold,
                                      # kept, best_candidate, rollout_mean, injected
    returns = algo.rollout_returns(n) # [n] returns of the current policy (throughput)
    algo.action_probs, algo.best_policy, algo.progress

``settings`` is a ``CognetSettings`` (fields and defaults of cognet_jax's: ``nodes``,
``rollouts``, ``top``, ``keep``, ``eval_rollouts``, ``hidden``, ``train_steps``, ``optimizer``,
``momentum``, ``threshold_rule``, ``separate``, ``common_random_numbers``,
``train_last_transition``, ``entropy_window``); cognet_jax's own ``CognetSettings`` /
``CognetHyper`` objects are accepted too. ``hyper`` is a ``CognetHyper`` (``alpha``,
``learning_rate``, ``entropy=EntropyConfig(enabled, rate, std_threshold, patience)``). ``env`` is
a ``TaggingConfig`` (``make_tagging("thesis")`` by default).

One iteration: (1) ``rollouts`` recorded rollouts of the current policy; (2) the ``top`` best by
return; (3) one candidate per pre-selected rollout: the current action table with the visited
nodes' rows replaced by that rollout's empirical action frequencies; (4) each candidate evaluated
with ``eval_rollouts`` rollouts; (5) elite threshold, keep ``keep`` (or ``threshold_rule="best"``);
(6) count MLE over the kept rollouts, smoothing with ``alpha``, entropy injection; (7)
``train_steps`` full-batch optimiser steps of softmax cross-entropy per member on the kept
rollouts' ``(z_{t+1}, q_{t+1})`` pairs; (8) ``eval_rollouts`` rollouts of the updated policy,
anytime best. ``torch.set_num_threads`` is left at its default.
"""

import importlib

#: public name -> module of ``benchmarks.torch_reference`` that defines it; imported at first use
#: (PEP 562), so a process that runs only the weight-space reference (``torch_run``) imports
#: torch alone, not cognet_jax and JAX (``common`` reads cognet_jax's config declarations)
_EXPORTS = {
    "CognetHyper": "common",
    "CognetSettings": "common",
    "EntropyConfig": "common",
    "Progress": "common",
    "as_hyper": "common",
    "as_settings": "common",
    "TorchCognetLoop": "loop",
    "TaggingConfig": "tagging",
    "make_tagging": "tagging",
    "TorchCognetCompiled": "vectorized",
    "TorchCognetVectorized": "vectorized",
    "TorchWeightsCompiled": "weights",
    "TorchWeightsSearch": "weights",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(importlib.import_module(f"{__name__}.{_EXPORTS[name]}"), name)
