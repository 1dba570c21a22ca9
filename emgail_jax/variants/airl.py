"""AIRL's discriminator (Fu et al. 2018), a form of the M-step's discriminator (``--set
discriminator_form=airl``; off by default): :class:`AirlForm`.

Per intention i, D_i(s, a, s') = exp f_i / (exp f_i + pi_i(a | s)) with the paper's eq. 13 form
f_i(s, a, s') = g_i(s) + gamma h_i(s') - h_i(s)
(:class:`~emgail_jax.method.networks.AIRLDiscriminator`): the logit of D_i is f_i - log pi_i(a |
s), so the M-step's logistic loss and the B-step's reward log D - log(1 - D) = f - log pi are
those of the GAIL discriminator with that logit. pi_i is the *current* policy of intention i,
for the demonstrations too (their actions' density under it), read with its gradient stopped:
the discriminator learns f, not the policy. ``reoptimize`` pays fresh agents g_i(s) alone, the
reward that AIRL claims transfers (:meth:`~emgail_jax.host.saved_run.SavedRun.reward_function`).

What f reads after a pair is its *successor* ``[..., D + 1]``: the normalised next observation
and 1 where the episode goes on, 0 where it terminated (h(s') = 0 there, AIRL's end of an
episode). At a time limit the episode does not terminate: s' is the observation the
transition reached, which the rollout records before the auto-reset replaces it
(:meth:`envs.AutoResetWrapper.step_and_observe`), and for a demonstration the next pair's
observation, or at its end the final observation the demonstrations store.

The densities are of the *executed* (clipped) actions, which is what the discriminator sees on
both sides (the demonstrations hold no other). They are recomputed whenever the discriminator
reads a sample, a replayed one included: a density stored with a sample would be that of the
policy that made it, not of the pi in D's definition.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import jax
import jax.numpy as jnp

import envs
from emgail_jax.method.algorithms import Algorithm
from emgail_jax.method.batches import NormalizedBatch
from emgail_jax.method.config import MethodConfig
from emgail_jax.method.discriminator import LossHook, Read
from emgail_jax.method.hooks import Form, Sampling
from emgail_jax.method.networks import AIRLDiscriminator, action_distribution
from emgail_jax.method.rollout import Transitions, intention_major, terminations
from emgail_jax.variants.extras import attached, extras_of


def successor(next_obs: jax.Array, terminal: jax.Array) -> jax.Array:
    """``[..., D + 1]``: the next observation ``next_obs [..., D]`` (normalised) and 1 -
    ``terminal [...]``, what f reads after a pair."""
    return jnp.concatenate([next_obs, (1.0 - terminal)[..., None]], -1)


def own_log_densities(
    policy_apply: Callable, params, obs: jax.Array, executed: jax.Array, conditions: jax.Array
) -> jax.Array:
    """``[K, M]``: log pi(a | s, c) of the samples ``obs [K, M, D]`` (normalised), ``executed
    [K, M, A]`` under the policy ``params`` and their own conditions ``conditions [K, M, c]``
    (row k is intention k's, the intention-major layout), gradient stopped."""
    mean, log_std = policy_apply(params, obs, conditions, intention_major=True)
    return jax.lax.stop_gradient(action_distribution(mean, log_std).log_prob(executed))


def expert_log_densities(
    policy_apply: Callable, params, obs: jax.Array, executed: jax.Array, conditions: jax.Array
) -> jax.Array:
    """``[N, C]``: log pi(a | s, c) of every pair ``obs [N, D]``, ``executed [N, A]`` under every
    condition ``conditions [C, c]`` (as :func:`~emgail_jax.method.discriminator.expert_logits`
    scores them), gradient stopped."""
    c = conditions.shape[0]
    every = lambda x: jnp.broadcast_to(x, (c, *x.shape))
    conditioned = jnp.broadcast_to(conditions[:, None, :], (c, obs.shape[0], conditions.shape[1]))
    return own_log_densities(policy_apply, params, every(obs), every(executed), conditioned).T


def with_log_densities(
    batch: NormalizedBatch, policy_apply: Callable, params, algorithm: Algorithm
) -> NormalizedBatch:
    """``batch`` with log pi of its samples (each under its own intention) and of its expert
    pairs (under every discriminator condition) under the policy ``params``. The policy is
    conditioned as the discriminator is (EM-GAIL's and GAIL's; Info/IntentionGAIL's is not,
    and AIRL refuses it), so the discriminator's conditions are the policy's too."""
    k = batch.obs.shape[0]
    own = algorithm.policy_condition(batch.own_intention(), k)
    every = algorithm.discriminator_conditions(k)
    return attached(
        batch,
        log_policy=own_log_densities(policy_apply, params, batch.obs, batch.executed, own),
        expert_log_policy=expert_log_densities(
            policy_apply, params, batch.expert_obs, batch.expert_actions, every
        ),
    )


def successors(transitions: Transitions, env: envs.Env, normalize=lambda x: x) -> jax.Array:
    """``[K, M, D + 1]`` the successor of every sample of a rollout that recorded its next
    observations (``normalize``d; raw by default), grouped by intention."""
    terminal = terminations(transitions, env.episode_length)
    return intention_major(successor(normalize(transitions.next_obs), terminal))


class AirlForm(Form):
    """AIRL's discriminator as the M-step's form (module docstring): f reads each pair's
    successor, and its logit is f - log pi under the policy that made the rollout."""

    def network(self, config: MethodConfig) -> AIRLDiscriminator:
        shape = config.networks
        # f's shaping discounts as the B-step does
        return AIRLDiscriminator(shape.hidden, shape.intention_input.heads, config.b_step.gamma)

    def init_input(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        return successor(obs, jnp.zeros(obs.shape[0]))

    def observed(self, batch: NormalizedBatch, sampling: Sampling) -> NormalizedBatch:
        """``batch`` with the successors of its samples and expert pairs, and log pi of
        them."""
        demos, env = sampling.demos, sampling.env
        batch = attached(
            batch,
            successor=successors(sampling.transitions, env, sampling.normalize),
            expert_successor=successor(
                sampling.normalize(demos.next_observations), demos.terminations(env.episode_length)
            ),
        ).check()
        return self.densities(batch, sampling)

    def densities(self, batch: NormalizedBatch, sampling: Sampling) -> NormalizedBatch:
        """``batch`` with log pi of its samples and expert pairs, recomputed whenever the
        discriminator reads a sample (module docstring)."""
        apply, params = sampling.policy
        return with_log_densities(batch, apply, params, sampling.algorithm)

    def read(self, batch: NormalizedBatch) -> Read:
        extras = extras_of(batch)
        return Read(
            extras.successor, extras.expert_successor, extras.log_policy, extras.expert_log_policy
        )


@dataclass(frozen=True)
class LogitOffsets(LossHook):
    """The loss's logits less AIRL's log pi: ``offsets [C, M]`` of the policy samples,
    ``expert_offsets [N, C]`` of the expert pairs."""

    offsets: jax.Array
    expert_offsets: jax.Array

    def logits(self, real: jax.Array, fake: jax.Array) -> tuple[jax.Array, jax.Array]:
        return real - self.expert_offsets, fake - self.offsets
