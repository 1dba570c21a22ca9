"""A run's learned reward, reusable: the refit it saved (``RUN/reward/``), or the run's own.

>>> import emgail_jax
>>> reward = emgail_jax.load_reward("runs/driver-emgail", seed=0)  # R_i(s, a), jittable
>>> reward
LearnedReward(run='runs/driver-emgail', seed=0, source='refit', form='log-d')
>>> r = reward(obs, action, 1)
>>> fall = reward.termination(1)   # paid per step left when an episode ends early

Intentions are the *learned* ones, numbered as the learner numbered them; ``evaluate`` prints
which true intention each one matches. ``python -m emgail_jax.refit RUN`` writes the refit
(:mod:`~emgail_jax.reward.product`); the refits kept by name under ``RUN/rewards/`` are read
with ``refit=NAME`` (:func:`~emgail_jax.reward.saved.saved_refits` lists them).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from flax import struct

from emgail_jax.host.run_spec import RunError
from emgail_jax.host.saved_run import SavedRun, across_seeds_reward
from emgail_jax.reward import product, saved
from emgail_jax.reward.refit import priced_absorbing_reward, random_actions_reward

SOURCES = ("refit", "paper")


@struct.dataclass
class LearnedReward:
    """A learned reward, jittable: ``reward(obs [..., D], action [..., A], intention [...])
    -> [...]``, and :meth:`termination`, what it pays per step left when an episode ends
    before its time limit. ``source``: ``refit`` (``RUN/reward/`` or a refit saved by name)
    or ``paper`` (the run's own discriminator, eq. 20/23). A pytree: its parameters are
    leaves, so a jitted program that takes the reward as an argument reads the ones given."""

    parameters: dict
    # [K] what a termination is paid per step left; None: an episode's end is worth 0.
    termination_values: jax.Array | None
    function: Callable = struct.field(pytree_node=False)
    run: str = struct.field(pytree_node=False)
    seed: int = struct.field(pytree_node=False)
    source: str = struct.field(pytree_node=False)
    form: str = struct.field(pytree_node=False)

    # One reward is one function to jit: compared and hashed by identity, not by its arrays.
    __eq__ = object.__eq__
    __hash__ = object.__hash__

    def __call__(self, obs, action, intention) -> jax.Array:
        return self.function(self.parameters, obs, action, intention)

    def termination(self, intention) -> jax.Array:
        """``[...]`` what a termination of ``intention [...]``'s episode is paid for every step
        left to the time limit, as the check paid its fresh agents (0 without)."""
        intention = jnp.asarray(intention, jnp.int32)
        if self.termination_values is None:
            return jnp.zeros(intention.shape)
        return jnp.take(jnp.asarray(self.termination_values), intention)

    def __repr__(self) -> str:
        return (
            f"LearnedReward(run={self.run!r}, seed={self.seed}, source={self.source!r}, "
            f"form={self.form!r})"
        )


def load_reward(
    run_dir: str,
    seed: int | None = None,
    across_seeds: bool = False,
    refit: str | None = None,
    reward_form: str | None = None,
    source: str | None = None,
) -> LearnedReward:
    """The learned reward of a run's ``seed`` (as ``run --seed`` numbered it; None: the run's
    first), a :class:`LearnedReward`: the refit saved in ``RUN/reward/`` when there is one
    (``source="refit"`` refuses without it), the run's own otherwise or with
    ``source="paper"``; with ``across_seeds``, the mean of every run seed's own, named as
    ``seed``'s intentions; with ``refit``, the refit of that name kept under ``RUN/rewards/``.
    ``reward_form`` reads the discriminator as another of ``REWARD_FORMS`` (``log-d``: below
    0 wherever D < 1) than the refit's or the run's.

    Raises:
      RunError: an unknown ``source``, ``source="refit"`` of a run without a refit, or a
        refit asked for with ``across_seeds``.
    """
    if source not in (None, *SOURCES):
        raise RunError(f"unknown reward source '{source}': {' or '.join(SOURCES)}")
    paper = source == "paper" or (source is None and (across_seeds or not product.exists(run_dir)))
    if refit is not None or paper:
        if source == "paper" and refit is not None:
            raise RunError("refit names a refitted reward: not with source='paper'")
        run = _opened_for(run_dir, refit, reward_form)
        return reward_of(run, run.seed_index(seed), across_seeds, refit)
    if across_seeds:
        raise RunError("across_seeds averages the run's own rewards: give source='paper'")
    run, description = product.opened(run_dir, reward_form)
    return saved_reward(run, description, run.seed_index(seed), run_dir)


def saved_reward(run: SavedRun, description: dict, seed: int, run_dir: str) -> LearnedReward:
    """The :class:`LearnedReward` of ``seed`` (an index of the run's seeds) of the reward saved
    in ``RUN/reward/``, ``run`` and ``description`` as :func:`~emgail_jax.reward.product.opened`
    gives them; ``run_dir`` as the user named the run. A form other than the saved one prices
    the termination anew in it, at the saved price."""
    parameters = product.parameters(run, description, seed)
    values = parameters.pop(product.PRICE, None)
    form = str(run.algorithm.reward_form)
    if values is not None and form != description["form"]:
        # The price was what the reward of the saved form pays: priced anew in this one.
        values = product.termination_values(run, parameters, description["termination"]["price"])
    return LearnedReward(
        parameters=parameters,
        termination_values=values,
        function=run.reward_function(),
        run=run_dir,
        seed=run.seed_number(seed),
        source="refit",
        form=form,
    )


def reward_of(
    run: SavedRun, seed: int = 0, across_seeds: bool = False, refit: str | None = None
) -> LearnedReward:
    """The :class:`LearnedReward` of ``run``'s own reward of ``seed`` (:meth:`SavedRun.reward`)
    or, with ``refit``, of the refit kept by that name (:func:`refitted_parameters`); its
    termination the learned absorbing state's, if it has one."""
    if refit is not None and across_seeds:
        raise RunError("across_seeds averages the run's own rewards, not a refitted one")
    function, absorbing = run.reward_function(), run.absorbing_reward_function()
    if across_seeds:
        parameters = run.across_seeds_parameters(seed)
        function = across_seeds_reward(function)
        absorbing = absorbing and across_seeds_reward(absorbing)
    elif refit is not None:
        run = run_for_refit(run, refit)
        function, absorbing = run.reward_function(), run.absorbing_reward_function()
        parameters = refitted_parameters(run, refit, seed)
    else:
        parameters = run.reward_parameters(seed)
    values = None
    if absorbing is not None:
        values = absorbing(parameters, jnp.arange(run.num_intentions))
    airl = run.config.method.m_step.form.airl
    return LearnedReward(
        parameters=parameters,
        termination_values=values,
        function=function,
        run=run.run_dir,
        seed=run.seed_number(seed),
        source="paper" if refit is None else "refit",
        form="airl-g" if airl else str(run.algorithm.reward_form),
    )


def load_absorbing_reward(
    run_dir: str,
    seed: int | None = None,
    refit: str | None = None,
    reward_form: str | None = None,
    price: str = "learned",
):
    """What a fall is worth under the reward ``load_reward(..., source="paper")`` gives for
    the same arguments (or ``refit``'s): jittable ``R_abs(intention) -> reward``, paid for
    every step left to the time limit when an episode ends early (:func:`absorbing_reward_of`);
    None when that reward has no absorbing state. :meth:`LearnedReward.termination` gives the
    same in one call."""
    run = _opened_for(run_dir, refit, reward_form)
    return absorbing_reward_of(run, run.seed_index(seed), refit, price)


def _opened_for(run_dir: str, refit: str | None, reward_form: str | None) -> SavedRun:
    """The run as its reward (``refit``, read as ``reward_form``) is read."""
    snapshot = None
    if refit is not None:
        snapshot = saved.read_description(run_dir, refit)["snapshot"]
    run = SavedRun.open(run_dir, snapshot=snapshot)
    return run if reward_form is None else run.with_reward_form(reward_form)


def run_for_refit(run: SavedRun, name: str) -> SavedRun:
    """``run`` as its saved refitted reward ``name`` is read: with absorbing states if the
    refit learnt them."""
    absorbing = saved.read_description(run.run_dir, name)["refit"]["absorbing"]
    return run.with_absorbing_states() if absorbing else run


def refitted_parameters(run: SavedRun, name: str, seed: int = 0) -> dict:
    """:meth:`~SavedRun.reward_parameters` of ``seed`` with the discriminator of the saved
    refitted reward ``name``.

    Raises:
      RunError: the refit was made from another snapshot, or not for ``seed``.
      CheckpointError: no saved reward ``name``, one that does not fit, or one refitted
        from the networks of another iteration (the run resumed since).
    """
    description = saved.read_description(run.run_dir, name)
    if description["snapshot"] != run.snapshot:
        raise RunError(
            f"the reward '{name}' was refitted from snapshot {description['snapshot']}; "
            f"this run was opened at {run.snapshot}"
        )
    parameters = saved.saved_parameters(run, name, seed)
    if parameters is None:
        number = run.seed_number(seed)
        raise RunError(
            f"seed {number} of '{run.run_dir}' has no refitted reward '{name}': refit it with "
            f"python -m emgail_jax.refit {run.run_dir} --seed {number} and the same options"
        )
    return parameters


def absorbing_reward_of(
    run: SavedRun, seed: int = 0, refit: str | None = None, price: str = "learned"
) -> Callable[[jax.Array], jax.Array] | None:
    """What :func:`reward_of` (of ``seed`` and ``refit``) pays a termination for every step
    left to the time limit, as the fresh agents of ``reoptimize`` are paid it:
    ``R_abs(intention [...]) -> [...]``, the absorbing state's learned reward, or with
    ``price="random"`` what uniformly random actions earn per step under that reward
    (``reoptimize --set absorbing_reward=random``); None for a reward without an absorbing
    state, whose episodes simply end."""
    run = run_for_refit(run, refit) if refit is not None else run
    learned = run.absorbing_reward_function()
    if learned is None:
        return None
    if refit is None:
        parameters = run.reward_parameters(seed)
    else:
        parameters = refitted_parameters(run, refit, seed)
    if price == "learned":
        return lambda intention: learned(parameters, intention)
    if price != "random":
        raise ValueError(f"unknown absorbing price '{price}': learned or random")
    paid = random_actions_reward(run, parameters, run.reward_function())
    priced = {"absorbing_price": paid}
    return lambda intention: priced_absorbing_reward(priced, intention)
