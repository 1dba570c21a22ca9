"""A run's learned reward, reusable: the run's own, or a refit it saved.

>>> import emgail_jax
>>> reward = emgail_jax.load_reward("runs/driver-emgail")   # R_i(s, a), jittable
>>> shared = emgail_jax.load_reward("runs/driver-emgail", across_seeds=True)  # every seed's
>>> r = reward(obs, action, 1)

Intentions are the *learned* ones, numbered as the learner numbered them; ``evaluate`` prints
which true intention each one matches. A refit (``python -m emgail_jax.refit RUN``) is read by
its name under ``RUN/rewards/`` (:func:`~emgail_jax.reward.saved.saved_refits` lists them).
"""

from __future__ import annotations

from collections.abc import Callable

import jax

from emgail_jax.host.run_spec import RunError
from emgail_jax.host.saved_run import SavedRun
from emgail_jax.reward import saved
from emgail_jax.reward.refit import priced_absorbing_reward, random_actions_reward


def load_reward(
    run_dir: str,
    seed: int | None = None,
    across_seeds: bool = False,
    refit: str | None = None,
    reward_form: str | None = None,
):
    """The learned reward of a run: jittable ``R(obs, action, intention) -> reward`` of its
    ``seed``, as ``run --seed`` numbered it (None: the run's first); with
    ``across_seeds``, the mean of every run seed's, named as ``seed``'s intentions; with
    ``refit``, the refitted reward of that name saved under ``RUN/rewards/``;
    ``reward_form`` reads the discriminator as another of ``REWARD_FORMS`` than the run's
    (``log-d``: below 0 wherever D < 1, as ``reoptimize --set reward_form=log-d``). Where
    episodes end early, what a fall is worth: :func:`load_absorbing_reward`."""
    run = _opened_for(run_dir, refit, reward_form)
    return reward_of(run, run.seed_index(seed), across_seeds, refit)


def load_absorbing_reward(
    run_dir: str,
    seed: int | None = None,
    refit: str | None = None,
    reward_form: str | None = None,
    price: str = "learned",
):
    """What a fall is worth under the reward :func:`load_reward` gives for the same arguments:
    jittable ``R_abs(intention) -> reward``, paid for every step left to the time limit
    when an episode ends early (:func:`absorbing_reward_of`); None when that reward has
    no absorbing state. An agent trained on the reward alone, its falls worth nothing, is not
    trained on what ``reoptimize`` checked."""
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


def reward_of(
    run: SavedRun, seed: int = 0, across_seeds: bool = False, refit: str | None = None
) -> Callable[[jax.Array, jax.Array, jax.Array], jax.Array]:
    """:meth:`SavedRun.reward` of ``seed``, or with ``refit`` the saved refitted reward of
    that name (:func:`refitted_parameters`) in place of the run's own."""
    if refit is None:
        return run.reward(seed, across_seeds)
    if across_seeds:
        raise RunError("across_seeds averages the run's own rewards, not a refitted one")
    run = run_for_refit(run, refit)
    parameters = refitted_parameters(run, refit, seed)
    reward = run.reward_function()
    return lambda obs, action, intention: reward(parameters, obs, action, intention)


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
