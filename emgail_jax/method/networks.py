"""The four networks of the paper (§5.3): policy, value, discriminator and posterior.

All are 64-64 tanh MLPs. The intention enters the policy, the value and (for EM-GAIL) the
discriminator in one of two ways (docs/defaults.md, `intention_input`):

- one-hot (``heads=False``): a one-hot vector concatenated to the input, as the paper's
  parameter counts (Table 2) imply. The intentions share every hidden unit and differ only by a
  bias of the first layer, so a policy update for one intention moves the others too.
- K heads (``heads=True``): one MLP per intention, the one of the sample's intention selected
  by the one-hot vector, as the paper's public code does. The intentions share nothing.

An unconditioned network (GAIL's policy, Info/IntentionGAIL's discriminator) receives an empty
condition vector and is a single MLP either way, so the same modules serve all three algorithms.
Modules hold no data: parameters live in the train state and are passed to ``apply``.
"""

from __future__ import annotations

from collections.abc import Sequence

import distrax
import flax.linen as nn
import jax
import jax.numpy as jnp

from emgail_jax.method import normalizer as obs_norm


class MLP(nn.Module):
    """Tanh MLP whose last layer starts ``final_scale`` times smaller than a LeCun-normal one.

    Not the orthogonal initialiser common in RL code: its QR decomposition is a LAPACK call
    that deadlocks XLA:CPU when seeds are sharded over several host devices.
    """

    hidden: Sequence[int]
    out: int
    final_scale: float = 0.01

    @nn.compact
    def __call__(self, x: jax.Array) -> jax.Array:
        for width in self.hidden:
            x = nn.tanh(nn.Dense(width)(x))
        final_init = nn.initializers.variance_scaling(self.final_scale**2, "fan_in", "normal")
        return nn.Dense(self.out, kernel_init=final_init)(x)


def conditioned_mlp(
    hidden: Sequence[int],
    out: int,
    x: jax.Array,
    condition: jax.Array,
    heads: bool,
    *,
    final_scale: float = 1.0,
    intention_major: bool = False,
) -> jax.Array:
    """An MLP of ``x [..., D]`` for the intention one-hot ``condition [..., K]`` (K may be 0);
    the leading dimensions of the two broadcast against each other. Call inside a compact method.

    One-hot (``heads=False``): a single MLP of ``[x, condition]`` (parameters ``MLP_0``).
    Heads: K MLPs of ``x`` (parameters ``heads``, stacked on a leading K axis). In general all K
    are evaluated on every row and the row's own is selected by its one-hot condition (K times
    the work). ``intention_major`` says that the leading axis of the inputs is the intention,
    row k belonging to intention k (the layout of rollouts, ``[K, ...]``): then head k runs on
    row k only and the condition is not read.
    """
    k = condition.shape[-1]
    batch = jnp.broadcast_shapes(x.shape[:-1], condition.shape[:-1])
    x = jnp.broadcast_to(x, (*batch, x.shape[-1]))
    if not heads or k == 0:
        condition = jnp.broadcast_to(condition, (*batch, k))
        return MLP(hidden, out, final_scale)(jnp.concatenate([x, condition], -1))
    stacked = nn.vmap(
        MLP,
        variable_axes={"params": 0},
        split_rngs={"params": True},
        in_axes=0 if intention_major else None,
        axis_size=k,
    )(hidden, out, final_scale, name="heads")
    if intention_major:
        return stacked(x)  # [K, ..., out]
    return jnp.einsum("k...o,...k->...o", stacked(x), condition)


class GaussianPolicy(nn.Module):
    """pi(a | s, i): mean from an MLP of (normalised obs, condition); state-independent log-std
    (shared by the intentions, as in the paper's code)."""

    action_size: int
    hidden: Sequence[int] = (64, 64)
    init_log_std: float = 0.0
    heads: bool = False

    @nn.compact
    def __call__(
        self, obs: jax.Array, condition: jax.Array, intention_major: bool = False
    ) -> tuple[jax.Array, jax.Array]:
        mean = conditioned_mlp(
            self.hidden,
            self.action_size,
            obs,
            condition,
            self.heads,
            final_scale=0.01,
            intention_major=intention_major,
        )
        log_std = self.param(
            "log_std", nn.initializers.constant(self.init_log_std), (self.action_size,)
        )
        return mean, jnp.broadcast_to(log_std, mean.shape)


class ScalarNet(nn.Module):
    """A conditioned MLP with one output per input row (the value and the discriminator)."""

    hidden: Sequence[int] = (64, 64)
    heads: bool = False


class ValueNet(ScalarNet):
    """V(s, i, t): the normalised time t/T is an input because the horizon is fixed."""

    @nn.compact
    def __call__(self, obs, condition, time, intention_major: bool = False) -> jax.Array:
        x = jnp.concatenate([obs, time[..., None]], -1)
        value = conditioned_mlp(
            self.hidden, 1, x, condition, self.heads, intention_major=intention_major
        )
        return value[..., 0]


class Discriminator(ScalarNet):
    """The logit f of D = sigmoid(f): f(s, a, i) for EM-GAIL, f(s, a) for the baselines.

    With ``absorbing``, one input more: the absorbing-state indicator (DAC), ``absorbed [...]``
    where given and 0 (a real pair) otherwise, so that every caller scoring real pairs is
    unchanged."""

    absorbing: bool = False

    @nn.compact
    def __call__(
        self, obs, action, condition, intention_major: bool = False, absorbed=None
    ) -> jax.Array:
        x = jnp.concatenate([obs, action], -1)
        if self.absorbing:
            indicator = jnp.zeros(x.shape[:-1]) if absorbed is None else absorbed
            x = jnp.concatenate([x, jnp.broadcast_to(indicator, x.shape[:-1])[..., None]], -1)
        logit = conditioned_mlp(
            self.hidden, 1, x, condition, self.heads, intention_major=intention_major
        )
        return logit[..., 0]


class StateScalar(ScalarNet):
    """A conditioned MLP of the observation alone, one output per row: AIRL's g and h."""

    @nn.compact
    def __call__(self, obs, condition, intention_major: bool = False) -> jax.Array:
        out = conditioned_mlp(
            self.hidden, 1, obs, condition, self.heads, intention_major=intention_major
        )
        return out[..., 0]


class AIRLDiscriminator(ScalarNet):
    """AIRL's f(s, a, s', i) = g_i(s) + discount * h_i(s') - h_i(s) (Fu et al. 2018, eq. 13):
    g the state-only reward, h the state-only shaping, each conditioned on the intention as
    :class:`Discriminator` is. It takes :class:`Discriminator`'s place in every call, the
    ``successor [..., D + 1]`` (:func:`~emgail_jax.variants.airl.successor`) in the action's:
    the next observation and 1 where the episode goes on after it, 0 where it terminated
    (h(s') = 0 there). The logit of D is f - log pi_i(a | s), which the callers subtract.

    The continuation flag is data, not a place where f should be smooth: its input gradient is
    stopped, so that the M-step's gradient penalty reads d f / d(s, s') alone."""

    discount: float = 0.99

    def setup(self):
        self.reward_net = StateScalar(self.hidden, self.heads)
        self.shaping_net = StateScalar(self.hidden, self.heads)

    def __call__(self, obs, successor, condition, intention_major: bool = False) -> jax.Array:
        next_obs, going_on = successor[..., :-1], jax.lax.stop_gradient(successor[..., -1])
        shaping = lambda x: self.shaping_net(x, condition, intention_major)
        reward = self.reward_net(obs, condition, intention_major)
        return reward + self.discount * going_on * shaping(next_obs) - shaping(obs)

    def reward(self, obs, condition, intention_major: bool = False) -> jax.Array:
        """g_i(s), the state-only reward that AIRL claims transfers (``reoptimize``'s)."""
        return self.reward_net(obs, condition, intention_major)


class Posterior(nn.Module):
    """Logits of P(i | s, a) over the K intentions."""

    num_intentions: int
    hidden: Sequence[int] = (64, 64)

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = jnp.concatenate([obs, action], -1)
        return MLP(self.hidden, self.num_intentions, final_scale=1.0)(x)


def action_distribution(mean: jax.Array, log_std: jax.Array) -> distrax.MultivariateNormalDiag:
    return distrax.MultivariateNormalDiag(mean, jnp.exp(log_std))


def policy_action(
    policy: GaussianPolicy,
    params,
    normalizer: obs_norm.RunningStats,
    obs: jax.Array,
    condition: jax.Array,
    *,
    obs_clip: float,
    key: jax.Array | None = None,
    explore: bool | jax.Array = False,
    intention_major: bool = False,
) -> jax.Array:
    """The action ``[..., A]`` of the policy ``params`` for raw ``obs [..., D]`` (normalised
    here) under ``condition [..., C]``: a sample of pi(. | s, i) where ``explore`` (a possibly
    traced bool; needs ``key``), the mean otherwise. The one policy of training, the experts,
    re-optimisation and saved runs."""
    normalized = obs_norm.normalize(normalizer, obs, obs_clip)
    mean, log_std = policy.apply(params, normalized, condition, intention_major=intention_major)
    if key is None:
        return mean
    noise = jax.random.normal(key, mean.shape)
    return mean + jnp.where(explore, jnp.exp(log_std) * noise, 0.0)
