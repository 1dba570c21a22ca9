"""EM-GAIL and its two baselines, as the few choices in which they differ.

Everything else (rollouts, the E-step's posterior training, the discriminator loss, GAE, TRPO, the
value fit, the metrics) is shared code; an algorithm only says:

========================  ==================  ==================  ===================
                          EM-GAIL (Sol. 1)    Info/IntentionGAIL  GAIL
========================  ==================  ==================  ===================
policy                    pi(a | s, i)        pi(a | s, i)        pi(a | s)
posterior P(i | s, a)     trained (E-step)    trained (eq. 21)    none
discriminator             D(s, a, i)          D(s, a)             D(s, a)
expert pairs in the loss  weighted by gamma   weight one          weight one
reward of (s, a, i)       -log(1 - D(s,a,i))  -log(1 - D(s,a))    -log(1 - D(s,a))
                                              + lambda log P(i|s,a)
========================  ==================  ==================  ===================
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import jax
import jax.numpy as jnp

from emgail_jax.method.config import NAMES, AlgorithmName, RewardForm


def imitation_reward(logit: jax.Array, form: RewardForm | str = RewardForm.GAIL) -> jax.Array:
    """The reward of a pair the discriminator scores ``logit``, high where D takes it for the
    expert's. GAIL's is positive everywhere, so where episodes can end early it also pays for
    staying alive; the logit is negative where D rejects the pair, so survival alone earns
    nothing. log D is bounded above by 0, so no pair, however far from the data D's guess
    strays, earns more than log 2 above a demonstration the discriminator cannot tell apart."""
    form = RewardForm(form)
    if form is RewardForm.LOGIT:
        return logit
    if form is RewardForm.LOG_D:
        return -jax.nn.softplus(-logit)
    return jax.nn.softplus(logit)


@dataclass(frozen=True)
class Algorithm:
    name: AlgorithmName
    conditional_policy: bool
    conditional_discriminator: bool
    info_reward: bool = False  # the reward adds lambda log P(i | s, a) (eq. 23)
    # lambda of eq. 23: a float, or a traced scalar when the program takes it as an argument
    # (runs that differ only in lambda then share one compiled program).
    info_weight: float | jax.Array = 0.0
    reward_form: RewardForm = RewardForm.GAIL

    @property
    def learns_posterior(self) -> bool:
        return self.name.learns_posterior

    def policy_condition(self, intentions: jax.Array, num_intentions: int) -> jax.Array:
        """``[..., K]`` one-hot of ``intentions [...]``; ``[..., 0]`` if unconditioned."""
        return _condition(intentions, num_intentions, self.conditional_policy)

    def discriminator_condition(self, intentions: jax.Array, num_intentions: int) -> jax.Array:
        return _condition(intentions, num_intentions, self.conditional_discriminator)

    def discriminator_conditions(self, num_intentions: int) -> jax.Array:
        """``[C, c]``: every condition an expert pair is scored under in the M-step."""
        if self.conditional_discriminator:
            return jnp.eye(num_intentions)
        return jnp.zeros((1, 0))

    def expert_weights(self, gamma: jax.Array) -> jax.Array:
        """``[N, C]`` weights of the expert pairs: gamma (eq. 19) or one (eq. 22)."""
        if self.conditional_discriminator:
            return gamma
        return jnp.ones((gamma.shape[0], 1))

    def pseudo_reward(self, logit: jax.Array, posterior_log_prob: jax.Array) -> jax.Array:
        """The B-step reward of a policy sample from its discriminator logit (under its own
        condition) and log P(i | s, a) of the intention that generated it."""
        reward = imitation_reward(logit, self.reward_form)
        if self.info_reward:
            reward = reward + self.info_weight * posterior_log_prob
        return reward


def _condition(intentions: jax.Array, num_intentions: int, conditional: bool) -> jax.Array:
    if conditional:
        return jax.nn.one_hot(intentions, num_intentions)
    return jnp.zeros((*jnp.shape(intentions), 0))


ALGORITHMS = {
    AlgorithmName.EMGAIL: Algorithm(
        AlgorithmName.EMGAIL,
        conditional_policy=True,
        conditional_discriminator=True,
    ),
    AlgorithmName.INFOGAIL: Algorithm(
        AlgorithmName.INFOGAIL,
        conditional_policy=True,
        conditional_discriminator=False,
        info_reward=True,
    ),
    AlgorithmName.GAIL: Algorithm(
        AlgorithmName.GAIL,
        conditional_policy=False,
        conditional_discriminator=False,
    ),
}


def make_algorithm(
    name: AlgorithmName | str,
    info_weight: float | jax.Array = 1.0,
    reward_form: RewardForm | str = RewardForm.GAIL,
) -> Algorithm:
    """The algorithm ``name`` with its reward's form and, for Info/IntentionGAIL, lambda."""
    if name not in NAMES:
        raise ValueError(f"unknown algorithm '{name}': choose one of {', '.join(NAMES)}")
    algorithm = ALGORITHMS[AlgorithmName(name)]
    return dataclasses.replace(
        algorithm,
        info_weight=info_weight if algorithm.info_reward else 0.0,
        reward_form=RewardForm(reward_form),
    )
