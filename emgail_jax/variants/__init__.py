"""Research variants of EM-GAIL, apart from the paper's method (:mod:`emgail_jax.method`).

Each plugs into the update through the named hooks of :mod:`emgail_jax.method.hooks`:

- :mod:`~emgail_jax.variants.airl`: AIRL's discriminator (a form; ``discriminator_form=airl``);
- :mod:`~emgail_jax.variants.absorbing`: absorbing states (a form, a loss hook and a
  termination hook; ``absorbing_state``);
- :mod:`~emgail_jax.variants.replay`: past iterations' samples as further negatives
  (``discriminator_replay``);
- :mod:`~emgail_jax.variants.support`: noisy copies of the samples as further negatives
  (``discriminator_support_noise``);
- :mod:`~emgail_jax.variants.penalty`: the discriminator's gradient penalty (a loss hook;
  ``discriminator_gradient_penalty``);
- :mod:`~emgail_jax.variants.tempering`: the trajectory E-step's evidence tempered early (the
  evidence hook; ``trajectory_temper_iterations``).

:func:`hooks_for` builds the hooks a config asks for, :func:`make_train` the update with them.
The method never imports this package.
"""

from emgail_jax.variants.assembly import hooks_for, make_train

__all__ = ["hooks_for", "make_train"]
