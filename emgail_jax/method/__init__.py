"""The method as pure JAX functions: the networks, the E-, M- and B-steps, TRPO and GAE,
rollouts, one training iteration and the paper's metrics.

Nothing here reads or writes files or places arrays on devices; it imports only ``envs``,
libraries and itself. The host side (:mod:`emgail_jax.host`) runs it.
"""
