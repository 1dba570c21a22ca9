"""The learned reward as a product: refit it after the run, save it, load it, check it.

- :mod:`~emgail_jax.reward.refit`: the refit of each seed's discriminator against every
  snapshot's policy (:mod:`~emgail_jax.reward.ranking`: the snapshots ranked by iteration);
- :mod:`~emgail_jax.reward.recipe`: the refit's and the check's settings (``--set``) and
  ``--refit``'s recipe;
- :mod:`~emgail_jax.reward.saved`: a refit saved in its run directory, made once, then read;
- :mod:`~emgail_jax.reward.load`: ``load_reward`` and ``load_absorbing_reward``;
- :mod:`~emgail_jax.reward.check`: fresh agents trained on a reward and scored (paper §5.2),
  :mod:`~emgail_jax.reward.baseline` the true-reward baseline beside them,
  :mod:`~emgail_jax.reward.draws` the rules that keep one of several draws,
  :mod:`~emgail_jax.reward.progress` what a check stopped part-way goes on from.

Commands: ``python -m emgail_jax.refit`` and ``python -m emgail_jax.reoptimize``. This package
imports the method, its variants and the host side; neither imports it.
"""
