"""The learned reward as a product: refit it after the run, save it, load it, check it.

- :mod:`~emgail_jax.reward.refit`: the refit of each seed's discriminator against every
  snapshot's policy (:mod:`~emgail_jax.reward.ranking`: the snapshots ranked by iteration);
- :mod:`~emgail_jax.reward.recipe`: the refit's and the check's settings (``--set``) and
  ``--refit``'s recipe;
- :mod:`~emgail_jax.reward.saved`: a refit saved in its run directory, made once, then read;
- :mod:`~emgail_jax.reward.product`: the reward to take away, ``RUN/reward/``;
- :mod:`~emgail_jax.reward.load`: ``load_reward`` (a :class:`LearnedReward`) and
  ``load_absorbing_reward``;
- :mod:`~emgail_jax.reward.wrapper`: :class:`LearnedRewardEnv`, an env paying a learned
  reward; :mod:`~emgail_jax.reward.agent`: :func:`train_agent`, a fresh agent on an env's reward;
- :mod:`~emgail_jax.reward.check`: fresh agents trained on a reward and scored (paper §5.2),
  :mod:`~emgail_jax.reward.baseline` the true-reward baseline beside them,
  :mod:`~emgail_jax.reward.draws` the rules that keep one of several draws,
  :mod:`~emgail_jax.reward.progress` what a check stopped part-way goes on from.

Commands: ``python -m emgail_jax.refit`` and ``python -m emgail_jax.reoptimize``. This package
imports the method, its variants and the host side; neither imports it.
"""

import importlib

# Imported on first use, as the top level's: ``import emgail_jax.reward`` stays light.
_EXPORTS = {
    "LearnedReward": "load",
    "load_reward": "load",
    "load_absorbing_reward": "load",
    "LearnedRewardEnv": "wrapper",
    "Agent": "agent",
    "train_agent": "agent",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'emgail_jax.reward' has no attribute {name!r}")
    return getattr(importlib.import_module(f"emgail_jax.reward.{_EXPORTS[name]}"), name)
