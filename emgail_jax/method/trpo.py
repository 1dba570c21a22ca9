"""Trust region policy optimisation (Schulman et al., 2015): the B-step's policy update.

Everything is a pure function of flat parameter vectors so that it runs inside ``jit``/``vmap``:
the natural gradient direction comes from conjugate gradient on Fisher-vector products of the mean
KL, the step is scaled to the KL bound, and a backtracking line search accepts the largest step
that really improves the surrogate while staying within ``max_kl``.
"""

from __future__ import annotations

from collections.abc import Callable

import distrax
import jax
import jax.numpy as jnp
from jax.flatten_util import ravel_pytree

from emgail_jax.method.config import TRPOConfig


def fisher_vector_product(
    mean_kl: Callable[[jax.Array], jax.Array], at: jax.Array, damping: float
) -> Callable[[jax.Array], jax.Array]:
    """``v -> (F + damping I) v`` with F the Hessian of ``mean_kl`` at ``at`` (the Fisher matrix
    when ``mean_kl(theta)`` is KL(pi_at || pi_theta)); forward-over-reverse, never forms F."""
    grad_kl = jax.grad(mean_kl)

    def product(v: jax.Array) -> jax.Array:
        return jax.jvp(grad_kl, (at,), (v,))[1] + damping * v

    return product


def conjugate_gradient(
    matvec: Callable[[jax.Array], jax.Array], b: jax.Array, iterations: int
) -> jax.Array:
    """``iterations`` steps of conjugate gradient on ``A x = b``, A symmetric positive definite
    given as ``matvec``, from x = 0.

    A fixed number of steps (a ``scan``, not a ``while_loop``) keeps the cost identical across
    vmapped seeds; a converged residual simply stops the iterate from moving.
    """

    def body(carry, _):
        x, residual, direction, residual_sq = carry
        product = matvec(direction)
        curvature = jnp.dot(direction, product)
        alpha = jnp.where(curvature > 0, residual_sq / jnp.where(curvature > 0, curvature, 1), 0)
        x = x + alpha * direction
        residual = residual - alpha * product
        new_residual_sq = jnp.dot(residual, residual)
        beta = jnp.where(
            residual_sq > 0, new_residual_sq / jnp.where(residual_sq > 0, residual_sq, 1), 0
        )
        return (x, residual, residual + beta * direction, new_residual_sq), None

    init = (jnp.zeros_like(b), b, b, jnp.dot(b, b))
    (x, *_), _ = jax.lax.scan(body, init, None, length=iterations)
    return x


def trpo_step(
    distribution: Callable[[object], distrax.Distribution],
    params,
    actions: jax.Array,
    advantages: jax.Array,
    config: TRPOConfig,
):
    """One TRPO update of ``params``.

    Args:
      distribution: ``params -> `` the policy's action distribution on the batch (batch shape [N]).
      params: policy parameters (any pytree).
      actions: ``[N, A]`` actions taken.
      advantages: ``[N]`` advantage estimates (already normalised).

    Returns:
      ``(new_params, metrics)``; ``new_params`` equals ``params`` when no step is accepted.
    """
    flat, unravel = ravel_pytree(params)
    old = distribution(jax.lax.stop_gradient(params))
    old_log_prob = old.log_prob(actions)

    def surrogate(theta: jax.Array) -> jax.Array:
        log_prob = distribution(unravel(theta)).log_prob(actions)
        return jnp.mean(jnp.exp(log_prob - old_log_prob) * advantages)

    def mean_kl(theta: jax.Array) -> jax.Array:
        return jnp.mean(old.kl_divergence(distribution(unravel(theta))))

    baseline, gradient = jax.value_and_grad(surrogate)(flat)
    fvp = fisher_vector_product(mean_kl, flat, config.cg_damping)
    direction = conjugate_gradient(fvp, gradient, config.cg_iterations)
    curvature = jnp.dot(direction, fvp(direction))
    # The quadratic model of the KL reaches max_kl at this multiple of the direction.
    max_step = jnp.sqrt(2.0 * config.max_kl / jnp.maximum(curvature, 1e-12))
    full_step = max_step * direction
    expected = jnp.dot(gradient, full_step)

    fractions = config.line_search_decay ** jnp.arange(config.line_search_steps)

    def evaluate(fraction):
        theta = flat + fraction * full_step
        return surrogate(theta) - baseline, mean_kl(theta)

    improvement, kl = jax.vmap(evaluate)(fractions)
    acceptable = (
        (kl <= config.max_kl)
        & (improvement > 0.0)
        & (improvement >= config.accept_ratio * expected * fractions)
        & jnp.isfinite(improvement)
        & jnp.isfinite(kl)
    )
    accepted = jnp.any(acceptable)
    first = jnp.argmax(acceptable)  # the largest acceptable step
    fraction = jnp.where(accepted, fractions[first], 0.0)
    new_flat = jnp.where(accepted, flat + fraction * full_step, flat)
    metrics = {
        "policy/kl": jnp.where(accepted, kl[first], 0.0),
        "policy/step_fraction": fraction,
        "policy/step_norm": fraction * jnp.linalg.norm(full_step),
        "policy/surrogate_improvement": jnp.where(accepted, improvement[first], 0.0),
        "policy/expected_improvement": expected,
        "policy/accepted": accepted.astype(jnp.float32),
        "policy/entropy": jnp.mean(old.entropy()),
    }
    return unravel(new_flat), metrics
