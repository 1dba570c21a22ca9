"""Is the learned reward a reward? Train fresh policies on it and measure their ERD (paper §5.2).

    python -m emgail_jax.reoptimize RUN_DIR [--seed S] [--rl-seed R] [--draws N] [--snapshot ITER]
        [--keep-draw most|nearest]
        [--ensemble N | --across-seeds | --consolidate STEPS [--consolidate-*]]
        [--reward-form FORM] [--absorbing-reward learned|random] [--iterations N] [--gamma G]
        [--no-baseline] [--cache DIR] [--env-set KEY=FACTOR ...] [--out PATH]
        [--merge CHECK ...]

For every run seed (or ``--seed S`` alone) and every learned intention, a new policy is trained
from scratch with TRPO on the frozen pseudo-reward R_i(s, a) of that seed (the run's final
networks, or those of the snapshot of ``--snapshot ITER``; with ``--ensemble N`` the mean of
R_i over the last N snapshots up to them; with ``--across-seeds`` the mean of every run seed's
R_i, the seeds' intentions aligned by the demonstrations they hold; with ``--consolidate`` each
seed's discriminator refitted against every snapshot's policy, saved as ``RUN_DIR/rewards/NAME``
for ``load_reward(RUN_DIR, refit=NAME)`` and reused by any later check of it), never
seeing the true reward; the seeds' and intentions' policies are vmapped in one program
(``--rl-seed R``: another draw of their initialisation and samples, to tell a reward that fails
from a search that did; ``--draws N``: N draws, keeping per intention the agent that earns the
most learned reward, as a user without the true reward would, or with ``--keep-draw nearest``
the one nearest what the demonstrations earn; each finished draw, and the
training of the one under way every few minutes, is kept beside the check's file until it is
written, so a check stopped part-way goes on from there; ``--merge`` joins checks of one
seed each, run with ``--seed S`` on other cores or machines, into the check of them all,
training no agent on the learned reward). Their deterministic episodes
(as many per iteration as training evaluates, ``num_envs``) are scored under the true
rewards; the ERD matches each true intention to the learned one the run itself matched it to
(its jointly trained policies' matching at that iteration), one matching for every number
reported. Each env's success measure (the experts' bars: velocity, upright, pitch turn, ball
reached) is reported beside it, over the experts' 10 deterministic episodes.

Every algorithm's run is checked on the reward its own policies were trained on
(:meth:`~emgail_jax.host.saved_run.SavedRun.reward_function`): EM-GAIL's R_i = -log(1 - D(s, a,
i)); Info/IntentionGAIL's -log(1 - D(s, a)) + lambda log P(i | s, a), its final posterior
included (eq. 23); GAIL's one -log(1 - D(s, a)) for the mixed demonstrations, the same for every
intention, so that its K fresh policies are K agents of that one reward, true intention i scored
by the one the run matched to i. Every fresh policy has the same budget whatever the algorithm
(iterations, gamma, ``num_envs`` episodes of ``rollout_length`` steps per iteration: one row of
the ``[K, num_envs]`` envs, although GAIL's single policy trained on all K rows), so that the
algorithms' checks compare the rewards alone. A run trained with AIRL's discriminator
(``--set discriminator_form=airl``) is checked on its state-only reward g_i(s), the one AIRL
claims transfers, not on f - log pi (its policies' training reward, which reads the policy).
A run trained with absorbing states (``--set absorbing_state=true``) is checked the same way:
a fresh policy's termination is worth the learned reward of the absorbing state for every step
left, as in the run's own B-step; the true-reward baseline has no absorbing state. So is a
reward refitted with absorbing states (``--consolidate-absorbing``), whatever the run trained.
``--absorbing-reward random`` pays a termination, in place of that learned value, what
uniformly random actions earn per step under the reward being checked, seed by seed and
intention by intention (:func:`~emgail_jax.host.consolidation.random_actions_reward`).

Beside the learned reward, the **true-reward baseline**: the same TRPO, settings and budget on
the env's true rewards, the floor any learned reward is judged against (computed once per env,
K and budget, then read from ``--cache``; no algorithm enters its key, so one baseline serves
every algorithm's runs). The budget is the run's iterations, gamma and GAE lambda unless
:data:`~emgail_jax.host.reward_check.BUDGETS` or the flags say otherwise.

Also the learned reward per step that the fresh policies earn and that the demonstrations the
run assigned to each intention earn: fresh policies that out-earn the demonstrations yet score
far from the experts have optimised a reward that pays off the demonstrations' support. Writes
``RUN_DIR/reoptimize.json`` (``reoptimize-snapshot-ITER.json`` for a snapshot).

``--env-set`` trains and scores the fresh policies in a variant of the env (changed masses,
gravity, friction or viscosity: docs/environments.md), the test of a reward in dynamics its
demonstrations never saw. ERD there is normalised by the variant's own references: the
true-reward baseline trained in the variant with the same budget (0: per intention the best
of ``--reference-draws`` RL draws, since one draw of TRPO can miss a bar the experts meet) and
random actions in the variant (1). Beside the fresh agents, the run's own jointly trained
policies deployed unchanged in the variant, scored the same way: a reward is worth more than a
policy where its fresh agents beat them.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import os
import sys

from emgail_jax.host import check_progress, jax_setup, reward_check
from emgail_jax.host.command_line import ArgumentParser
from emgail_jax.host.schedule import FINAL_WINDOW  # the iterations averaged, as training's


def budget_of(args: argparse.Namespace, run) -> reward_check.Budget:
    """The env's budget for ``run`` as ``args`` change it (:func:`given_budget`)."""
    return given_budget(args, reward_check.default_budget(run))


def given_budget(args: argparse.Namespace, budget: reward_check.Budget) -> reward_check.Budget:
    """``budget`` with ``--iterations``, ``--gamma``, ``--gae-lambda`` and
    ``--[no-]value-target-scaling`` in place where given."""
    given = {
        "iterations": args.iterations,
        "gamma": args.gamma,
        "gae_lambda": args.gae_lambda,
        "value_target_scaling": args.value_target_scaling,
    }
    given = {name: value for name, value in given.items() if value is not None}
    return dataclasses.replace(budget, **given)


def print_result(run, result: dict) -> None:
    from rich.console import Console
    from rich.table import Table

    names = run.problem.env.intention_names
    budget = result["budget"]
    table = Table(
        title=f"fresh TRPO on the learned rewards of iteration {result['iteration']}, "
        f"{budget['iterations']} iterations, gamma {budget['gamma']}, lambda "
        f"{budget.get('gae_lambda', '-')}"
        f"{', value targets scaled' if budget.get('value_target_scaling') else ''}"
        f" (mean of the last {FINAL_WINDOW})"
    )
    for column in ("reward", "norm. ERD", "per intention", "true returns (expert)", "bars met"):
        table.add_column(column)
    expert = result["expert_returns"]
    number = lambda x: "-" if x is None else f"{x:.3f}"
    two = lambda x: "-" if x is None else f"{x:.2f}"

    def row(label, scores):
        returns = ", ".join(
            f"{names[i]} {r:.1f}" + ("" if expert is None else f" ({expert[i]:.1f})")
            for i, r in enumerate(scores["returns"])
        )
        per = scores["erd_per_intention"]
        bars = scores["meets_bar"]
        met = "-" if None in bars else f"{sum(bars)}/{len(bars)}"
        per_text = "-" if per is None else " ".join(f"{e:.2f}" for e in per)
        table.add_row(label, number(scores["erd"]), per_text, returns, met)

    for seed_result in result["per_seed"]:
        seed_result = {**seed_result, "meets_bar": [q["meets_bar"] for q in seed_result["success"]]}
        row(f"seed {seed_result['run_seed']}", seed_result)
    if result.get("baseline"):
        row("true reward", result["baseline"])
    joint = (result.get("variant") or {}).get("joint_policies")
    for seed_result in joint["per_seed"] if joint else []:
        row(
            f"seed {seed_result['run_seed']}: its own policy",
            {**seed_result, "meets_bar": [None], "erd_per_intention": None},
        )
    console = Console(width=140)
    console.print(table)
    if result["erd_mean"] is not None:
        console.print(
            f"re-optimised ERD {result['erd_mean']:.3f} ± {result['erd_std']:.3f} over "
            f"{len(result['seeds'])} seeds"
        )
    reference = (result.get("variant") or {}).get("reference_meets_bar")
    if reference and None not in reference and not all(reference):
        # ERD is |reference - return|: past a weak reference it grows, so say it is weak.
        console.print(
            f"the variant's best true-reward agents, ERD's 0 here, meet {sum(reference)} of "
            f"{len(reference)} of the experts' bars: agents that beat them score ERD > 0 too; "
            "read the bars"
        )
    for seed_result in result["per_seed"] if "draws" in result else []:
        draws_erd = " ".join(two(e) for e in seed_result["draws_erd"])
        console.print(
            f"seed {seed_result['run_seed']}: of {len(result['draws'])} draws, kept by the "
            f"learned reward ({result.get('draw_rule', 'most')}; each draw's ERD {draws_erd}), "
            "true intentions acted by draws "
            + " ".join(str(result["rl_seeds"][d]) for d in seed_result["draw"])
        )
    for seed_number, price in zip(
        result["seeds"], result.get("absorbing_price") or [], strict=False
    ):
        console.print(
            f"seed {seed_number}: a fall paid per step left "
            + ", ".join(
                f"{two(r)} (learned {two(a)})"
                for r, a in zip(price["random_actions"], price["learned"], strict=True)
            )
            + ", what random actions earn"
        )
    for seed_result in result["per_seed"]:
        earned = seed_result["learned_reward_per_step"]
        pairs = zip(earned["fresh_policies"], earned["demonstrations"], strict=True)
        console.print(
            f"seed {seed_result['run_seed']}: learned reward per step, fresh policies / "
            "demonstrations: " + ", ".join(f"{two(a)} / {two(b)}" for a, b in pairs)
        )


def argument_parser() -> argparse.ArgumentParser:
    from emgail_jax.method.config import REWARD_FORMS

    parser = ArgumentParser(
        prog="python -m emgail_jax.reoptimize", description=__doc__.split("\n")[0]
    )
    parser.add_argument("run_dir")
    parser.add_argument(
        "--seed",
        type=int,
        default=None,
        help="one run seed, as run --seed numbers it (default: all)",
    )
    parser.add_argument(
        "--rl-seed",
        type=int,
        default=0,
        metavar="R",
        help="another draw of the fresh policies' initialisation and samples on the same "
        "rewards (default 0)",
    )
    parser.add_argument(
        "--draws",
        type=int,
        default=1,
        metavar="N",
        help="train N draws (RL seeds R .. R + N - 1) and keep per intention the agent that "
        "earns the most learned reward (--keep-draw); the true-reward baseline's the one that "
        "earns the most true reward (default 1); a check stopped part-way goes on where it "
        "stopped",
    )
    parser.add_argument(
        "--keep-draw",
        choices=reward_check.DRAW_RULES,
        default="most",
        help="with --draws: per intention keep the agent that earns the most learned reward "
        "per step (default), or the one nearest what the demonstrations earn, passing over "
        "one that may have found what the reward overpays",
    )
    parser.add_argument(
        "--snapshot", type=int, default=None, metavar="ITER", help="the rewards of this snapshot"
    )
    parser.add_argument("--iterations", type=int, default=None, help="default: the env's budget")
    parser.add_argument("--gamma", type=float, default=None, help="default: the env's budget")
    parser.add_argument(
        "--gae-lambda", type=float, default=None, help="GAE's lambda; default: the env's budget"
    )
    parser.add_argument(
        "--value-target-scaling",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="fit the fresh agents' value baselines to standardised targets; default: the "
        "env's budget",
    )
    parser.add_argument(
        "--no-baseline", dest="baseline", action="store_false", help="skip the true reward"
    )
    parser.add_argument(
        "--cache",
        default=None,
        help=f"true-reward baselines (default {reward_check.default_cache()})",
    )
    parser.add_argument(
        "--refit",
        action="store_true",
        help="the refit that re-optimises best where it was measured: --consolidate "
        f"{REFIT['consolidate']} --consolidate-fresh --consolidate-penalty "
        f"{REFIT['consolidate_penalty']:g} --consolidate-noise {REFIT['consolidate_noise']:g} "
        f"--consolidate-batch {REFIT['consolidate_batch']}, read as log D unless the env's "
        "episodes end early (without --consolidate-absorbing); on hopper also "
        f"{refit_extras('hopper')}, on halfcheetah {refit_extras('halfcheetah')}; a "
        "--consolidate-*, --reward-form, --absorbing-reward, --iterations or "
        "--[no-]value-target-scaling given with it replaces that one",
    )
    parser.add_argument(
        "--consolidate",
        type=int,
        default=None,
        metavar="STEPS",
        help="first refit each discriminator STEPS steps against every snapshot's policy "
        "(emgail_jax.host.consolidation; default 0: the run's reward as it is)",
    )
    parser.add_argument(
        "--consolidate-penalty",
        type=float,
        default=None,
        metavar="WEIGHT",
        help="with --consolidate: the refit's gradient penalty (default 0: none)",
    )
    parser.add_argument(
        "--consolidate-fresh",
        action="store_true",
        help="with --consolidate: refit from new discriminator weights, not the run's final ones",
    )
    parser.add_argument(
        "--consolidate-noise",
        type=float,
        default=None,
        metavar="S",
        help="with --consolidate: a copy of every policy sample moved by noise of standard "
        "deviation S is a further negative (default 0: none)",
    )
    parser.add_argument(
        "--consolidate-batch",
        type=int,
        default=None,
        metavar="M",
        help="with --consolidate: every step sees M samples per intention drawn anew from the "
        "snapshots' (default 0: all of them)",
    )
    parser.add_argument(
        "--consolidate-ranking",
        type=float,
        default=None,
        metavar="WEIGHT",
        help="with --consolidate: rank the snapshots' policies by iteration and the "
        "demonstrations above them, with this weight (emgail_jax.method.ranking; default 0: none)",
    )
    parser.add_argument(
        "--consolidate-ranking-random",
        action="store_true",
        help="with --consolidate-ranking: uniformly random actions rank below the oldest snapshot",
    )
    parser.add_argument(
        "--consolidate-ranking-still",
        action="store_true",
        help="with --consolidate-ranking: actions held at the middle of their range rank below "
        "the oldest snapshot (above random actions with --consolidate-ranking-random)",
    )
    parser.add_argument(
        "--consolidate-agents",
        type=int,
        default=0,
        metavar="ROUNDS",
        help="with --consolidate-batch: refit ROUNDS times more, each against fresh agents "
        "trained on the last refit too, as many negatives per step as the snapshots' "
        "(default 0: none)",
    )
    parser.add_argument(
        "--consolidate-state-only",
        action="store_true",
        help="with --consolidate: refit D(s, i) of the observation alone, every action read as "
        "zeros, and pay the fresh agents that",
    )
    parser.add_argument(
        "--consolidate-absorbing",
        action=argparse.BooleanOptionalAction,
        default=None,
        help="with --consolidate: termination as an absorbing state (DAC) in the refit, learnt "
        "fake from the snapshots' falls; a fresh agent's fall is paid its reward for every "
        "step left, so --refit reads log D on any env whose recipe names no reward form "
        "(from new weights unless the run trained with absorbing states; on hopper --refit "
        "has it, --no-consolidate-absorbing drops it)",
    )
    parser.add_argument(
        "--absorbing-reward",
        default=None,
        choices=ABSORBING_REWARDS,
        help="what a fresh agent's fall is paid for every step left, with a reward that has an "
        "absorbing state: its learned reward (learned), or what uniformly random actions earn "
        "per step under the learned reward (random: a fall costs acting at random for the rest "
        "of the episode); default learned, on hopper --refit random",
    )
    parser.add_argument(
        "--ensemble",
        type=int,
        default=0,
        metavar="N",
        help="the reward is the mean of R_i over the last N snapshots up to the networks "
        "re-optimised (default 0: those networks' alone)",
    )
    parser.add_argument(
        "--across-seeds",
        action="store_true",
        help="each seed's fresh agents train on the mean of every run seed's reward, the seeds' "
        "intentions aligned by the demonstrations they hold (SavedRun.aligned_intentions)",
    )
    parser.add_argument(
        "--reward-form",
        default=None,
        choices=REWARD_FORMS,
        help="the reward the discriminator defines (default: the run's)",
    )
    parser.add_argument(
        "--env-set",
        nargs="+",
        default=[],
        metavar="KEY=FACTOR",
        help="train and score in a variant of the env: mass.BODY, gravity, friction, viscosity "
        "(factors on the model's values; ERD against the variant's own true-reward baseline)",
    )
    parser.add_argument(
        "--reference-draws",
        type=int,
        default=3,
        metavar="N",
        help="with --env-set: ERD's 0 is per intention the best of N true-reward draws in the "
        "variant (default 3)",
    )
    parser.add_argument(
        "--merge",
        nargs="+",
        default=[],
        metavar="CHECK",
        help="train no agent on the learned reward: join these checks, each of one seed "
        "(--seed S) with the options given here, into the check of their seeds, as if trained "
        "together (one seed per core or machine, then merged); the baseline as without it",
    )
    parser.add_argument("--out", default=None, help="default: RUN_DIR/reoptimize[-...].json")
    parser.add_argument("--quiet", action="store_true")
    return parser


def parse_args(argv=None, env: str | None = None) -> argparse.Namespace:
    """The command line with ``--refit``'s recipe for ``env`` filled in
    (:func:`with_refit_recipe`)."""
    return with_refit_recipe(argument_parser().parse_args(argv), env)


ABSORBING_REWARDS = ("learned", "random")


# `--refit`: experiment 35's refit of docs/rewards-that-reoptimise.md, from new weights against
# every snapshot's policy and noisy copies of its samples (reacher-2 0.070 over 8 seeds).
REFIT = {
    "consolidate": 4000,
    "consolidate_penalty": 10.0,
    "consolidate_noise": 1.0,
    "consolidate_batch": 5000,
}


# What `--refit` adds on the locomotion envs where the plain refit's agents stay near random
# actions: the snapshots ranked by iteration, read as the logit, and hopper's falls priced by an
# absorbing state at what random actions earn, not at its learned reward, whose price for a
# fall kept agents standing (experiments 43, 61, 63, 64 and 70); halfcheetah's agents are still
# closing on the experts' speed at 400 TRPO iterations and reach them by 1000 (experiment 64),
# and its logit of about +1 per step makes value targets of hundreds, which the value baseline
# follows only standardised (experiments 74 and 75).
REFIT_BY_ENV: dict[str, dict] = {
    "hopper": {
        "consolidate_ranking": 10.0,
        "consolidate_absorbing": True,
        "reward_form": "logit",
        "absorbing_reward": "random",
    },
    "halfcheetah": {
        "consolidate_ranking": 30.0,
        "reward_form": "logit",
        "iterations": 1000,
        "value_target_scaling": True,
    },
}


# The refit's options that are off unless given or in the env's recipe.
OFF_UNLESS_GIVEN = {"consolidate_ranking": 0.0, "consolidate_absorbing": False}


def refit_extras(env: str) -> str:
    """``--refit``'s options on ``env`` beyond :data:`REFIT`, spelled as on the command line."""
    words = []
    for option, value in REFIT_BY_ENV.get(env, {}).items():
        words.append("--" + option.replace("_", "-"))
        if value is not True:
            words.append(f"{value:g}" if isinstance(value, float) else str(value))
    return " ".join(words)


def with_refit_recipe(args: argparse.Namespace, env: str | None = None) -> argparse.Namespace:
    """``args`` with every refit option it left unset at the :data:`REFIT` recipe's value (and
    ``env``'s :data:`REFIT_BY_ENV`) if ``--refit`` was given, and at none otherwise. The reward
    form, where neither the recipe nor the command line names one, is
    :func:`refit_reward_form`'s; the TRPO iterations the env's budget's."""
    args = argparse.Namespace(**vars(args))
    recipe = {**REFIT, **REFIT_BY_ENV.get(env, {})} if args.refit else {}
    unset = {**{option: type(value)(0) for option, value in REFIT.items()}, **OFF_UNLESS_GIVEN}
    for option, off in unset.items():
        if getattr(args, option) is None:
            setattr(args, option, recipe.get(option, off))
    if not args.consolidate_absorbing:  # the recipe prices no absorbing state it was told to drop
        recipe.pop("absorbing_reward", None)
    for option in ("reward_form", "iterations", "absorbing_reward", "value_target_scaling"):
        if getattr(args, option) is None:
            setattr(args, option, recipe.get(option))
    args.consolidate_fresh = args.consolidate_fresh or args.refit
    return args


def refit_reward_form(args: argparse.Namespace, terminates: bool) -> str | None:
    """The reward form the fresh agents read: ``--reward-form`` if given; with ``--refit``,
    log D (below 0 wherever D < 1, so nothing off the demonstrations is paid) unless episodes
    end early without an absorbing state, where log D pays for falling and the run's own form
    stays (experiment 11); otherwise None, the run's."""
    from emgail_jax.method.config import RewardForm

    pays_falling = terminates and not args.consolidate_absorbing
    if args.reward_form is not None or not args.refit or pays_falling:
        return args.reward_form
    return RewardForm.LOG_D.value


def _check_options(args: argparse.Namespace) -> None:
    from emgail_jax.host.run_spec import RunError

    if args.rl_seed < 0:
        raise RunError("--rl-seed must be 0 or more")
    if args.draws < 1:
        raise RunError("--draws must be at least 1")
    if args.keep_draw != "most" and args.draws == 1:
        raise RunError("--keep-draw chooses among draws: give --draws N with N > 1 too")
    if args.iterations is not None and args.iterations < 1:
        raise RunError("--iterations must be at least 1")
    if args.gamma is not None and not 0 < args.gamma <= 1:
        raise RunError("--gamma must be in (0, 1]")
    if args.gae_lambda is not None and not 0 <= args.gae_lambda <= 1:
        raise RunError("--gae-lambda must be in [0, 1]")
    if args.consolidate < 0:
        raise RunError("--consolidate must be 0 (none) or more steps")
    if args.consolidate_penalty < 0 or (args.consolidate_penalty and not args.consolidate):
        raise RunError("--consolidate-penalty is a weight >= 0 and goes with --consolidate")
    if args.consolidate_noise < 0 or (args.consolidate_noise and not args.consolidate):
        raise RunError(
            "--consolidate-noise is a standard deviation >= 0 and goes with --consolidate"
        )
    if args.consolidate_batch < 0 or (args.consolidate_batch and not args.consolidate):
        raise RunError(
            "--consolidate-batch is a number of samples >= 0 and goes with --consolidate"
        )
    if args.consolidate_ranking < 0 or (args.consolidate_ranking and not args.consolidate):
        raise RunError("--consolidate-ranking is a weight >= 0 and goes with --consolidate")
    for level in ("random", "still"):
        if getattr(args, f"consolidate_ranking_{level}") and not args.consolidate_ranking:
            raise RunError(f"--consolidate-ranking-{level} goes with --consolidate-ranking WEIGHT")
    if args.consolidate_agents < 0 or (args.consolidate_agents and not args.consolidate_batch):
        raise RunError(
            "--consolidate-agents is a number of rounds >= 0 and goes with --consolidate-batch M"
        )
    if args.consolidate_fresh and not args.consolidate:
        raise RunError("--consolidate-fresh goes with --consolidate STEPS")
    if args.consolidate_state_only and not args.consolidate:
        raise RunError("--consolidate-state-only goes with --consolidate STEPS")
    if args.consolidate_absorbing and not args.consolidate:
        raise RunError("--consolidate-absorbing goes with --consolidate STEPS")
    if args.ensemble < 0 or (args.ensemble and args.consolidate):
        raise RunError("--ensemble is a number of snapshots >= 0, and not with --consolidate")
    if args.across_seeds and (args.ensemble or args.consolidate):
        raise RunError(
            "--across-seeds averages the run's own rewards: not with --ensemble or --consolidate"
        )
    if args.absorbing_reward == "random" and (args.ensemble or args.across_seeds):
        raise RunError(
            "--absorbing-reward random prices one seed's reward: not with --ensemble or "
            "--across-seeds"
        )
    if args.reference_draws < 1:
        raise RunError("--reference-draws must be at least 1")
    if args.env_set and not args.baseline:
        raise RunError(
            "--env-set scores against the variant's true-reward baseline: drop --no-baseline"
        )
    if args.merge and args.seed is not None:
        raise RunError("--merge joins checks of one seed each: drop --seed")


@dataclasses.dataclass
class Chosen:
    """The reward the command line asks for: ``parameters`` (one per seed; None: the run's),
    read by ``function`` and ``absorbing`` (None: the run's reward and absorbing reward), and
    what was done to get them (``result`` keys)."""

    parameters: list | None = None
    function: object = None
    absorbing: object = None
    details: dict = dataclasses.field(default_factory=dict)


def _run_opened(args: argparse.Namespace):
    """``(args, run)`` of the command line: ``args`` with the reward form resolved for the
    run's env (:func:`refit_reward_form`), the saved run with that form, in the variant if
    asked."""
    import envs
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.host.saved_run import SavedRun

    _check_options(args)
    run = SavedRun.open(args.run_dir, snapshot=args.snapshot)
    if args.env_set:
        run.problem = reward_check.variant_problem(run, args.env_set)
    if run.config.method.m_step.form.airl and (args.reward_form or args.consolidate):
        # Its reward is g_i(s), no reading of a GAIL discriminator's logit, nor refitted as one.
        raise RunError(
            "an AIRL run's reward is g_i(s): --reward-form, --consolidate and --refit do not apply"
        )
    form = refit_reward_form(args, envs.env_class(run.spec.env).terminates)
    args = argparse.Namespace(**{**vars(args), "reward_form": form})
    if args.reward_form is not None:
        run = run.with_reward_form(args.reward_form)
    return args, run


def _opened(args: argparse.Namespace):
    """``(args, run, seeds, Chosen)`` of the command line (:func:`_run_opened`), with its
    consolidated or ensemble rewards if asked."""
    from emgail_jax.host.run_spec import RunError
    from emgail_jax.host.saved_run import across_seeds_reward

    args, run = _run_opened(args)
    seeds = list(range(run.spec.seeds)) if args.seed is None else [run.seed_index(args.seed)]
    chosen = Chosen(
        details={
            "consolidation": None,
            "ensemble": None,
            "across_seeds": None,
            "absorbing_price": None,
        }
    )
    if args.consolidate:
        name, refit = "-".join(refit_parts(args)), refit_of(args)
        if refit.absorbing:
            if not (refit.fresh or run.trained_with_absorbing_states):
                raise RunError(
                    "--consolidate-absorbing needs --consolidate-fresh: the run's "
                    "discriminator was trained without absorbing states"
                )
            run = run.with_absorbing_states()
        chosen.parameters, chosen.details["consolidation"] = reward_check.consolidated(
            run, seeds, refit, name, budget_of(args, run), progress=not args.quiet
        )
        chosen.details["saved_reward"] = name
        if refit.state_only:
            chosen.function = run.reward_function(state_only=True)
    if args.ensemble:
        chosen.parameters, iterations = reward_check.ensemble_parameters(run, seeds, args.ensemble)
        chosen.function = reward_check.ensemble_reward(run.reward_function())
        if run.absorbing_reward_function() is not None:
            chosen.absorbing = reward_check.ensemble_reward(run.absorbing_reward_function())
        chosen.details["ensemble"] = iterations
    if args.across_seeds:
        if run.spec.seeds < 2:
            raise RunError("--across-seeds needs a run of 2 or more seeds")
        chosen.parameters = [run.across_seeds_parameters(seed) for seed in seeds]
        chosen.function = across_seeds_reward(run.reward_function())
        if run.absorbing_reward_function() is not None:
            chosen.absorbing = across_seeds_reward(run.absorbing_reward_function())
        # [seed][t][i]: seed t's intention averaged into intention i of each checked seed
        chosen.details["across_seeds"] = [p["intentions"] for p in chosen.parameters]
    if args.absorbing_reward == "random":
        priced_at_random_actions(run, seeds, chosen)
    return args, run, seeds, chosen


# Details of the reward checked with one entry per seed; the others are alike for every seed.
PER_SEED_DETAILS = ("consolidation", "across_seeds", "absorbing_price")


def _merge_opened(args: argparse.Namespace):
    """``(args, run, seeds, Chosen, draws)`` of ``--merge``: its checks' draws joined over
    their seeds (:func:`~emgail_jax.host.reward_check.joined_seeds`), each check verified to
    be one seed's of this run with these options (its recorded ``check``,
    :func:`check_identity`)."""
    from emgail_jax.host import records
    from emgail_jax.host.run_spec import RunError

    args, run = _run_opened(args)
    expected = records.to_json_value(check_identity(args, run))
    rl_seeds = list(range(args.rl_seed, args.rl_seed + args.draws))
    parts = {}
    for path in args.merge:
        part = _read_check(path)
        recorded = part.get("check")
        options = recorded.get("options") if isinstance(recorded, dict) else None
        if not isinstance(options, dict) or options.get("seed") is None:
            raise RunError(f"'{path}' is no check of one seed: write each with --seed S")
        seed = recorded["options"]["seed"]
        other = {**recorded, "options": {**recorded["options"], "seed": None}}
        if other != expected:
            differ = sorted(_differing(other["options"], expected["options"]))
            if other["iteration"] != expected["iteration"]:
                differ.append("the networks' iteration")
            raise RunError(
                f"'{path}' was checked otherwise ({', '.join(differ)}): give the options "
                "its --seed checks were run with"
            )
        if part.get("rl_seeds", [part.get("rl_seed")]) != rl_seeds:
            raise RunError(f"'{path}' trained other draws: give the --draws and --rl-seed it had")
        if seed in parts:
            raise RunError(f"seed {seed} is checked twice: give each seed's check once")
        parts[seed] = part
    ordered = [parts[seed] for seed in sorted(parts)]
    try:
        draws = [
            reward_check.joined_seeds([part.get("draws", [part])[d] for part in ordered])
            for d in range(args.draws)
        ]
    except ValueError as error:
        raise RunError(f"--merge: {error}") from None
    details = {name: ordered[0].get(name) for name in ("ensemble", "saved_reward")}
    for name in PER_SEED_DETAILS:
        entries = [part.get(name) for part in ordered]
        details[name] = None if None in entries else [e for entry in entries for e in entry]
    if details["saved_reward"] is None:
        del details["saved_reward"]
    seeds = [run.seed_index(seed) for seed in sorted(parts)]
    return args, run, seeds, Chosen(details=details), draws


def _read_check(path: str) -> dict:
    import json

    from emgail_jax.host.run_spec import RunError

    try:
        with open(path) as f:
            found = json.load(f)
    except (OSError, ValueError) as error:
        raise RunError(f"--merge: cannot read '{path}' ({error})") from None
    if not isinstance(found, dict):
        raise RunError(f"--merge: '{path}' is not a reoptimize check")
    return found


def _differing(given: dict, expected: dict) -> list[str]:
    """The options, spelled as flags, in which two checks' recorded options differ."""
    names = sorted(set(given) | set(expected))
    return ["--" + n.replace("_", "-") for n in names if given.get(n) != expected.get(n)]


def priced_at_random_actions(run, seeds: list[int], chosen: Chosen) -> None:
    """``chosen`` with its absorbing state paid, seed by seed, what uniformly random actions
    earn per step under its reward (``--absorbing-reward random``)."""
    import jax.numpy as jnp
    import numpy as np

    from emgail_jax.host import consolidation
    from emgail_jax.host.run_spec import RunError

    learned_absorbing = chosen.absorbing or run.absorbing_reward_function()
    if learned_absorbing is None:
        raise RunError(
            "--absorbing-reward prices an absorbing state, and this reward has none: refit it "
            "with --consolidate-absorbing, or check a run trained with absorbing_state"
        )
    function = chosen.function or run.reward_function()
    parameters = chosen.parameters or [run.reward_parameters(seed) for seed in seeds]
    intentions = jnp.arange(run.num_intentions)
    chosen.parameters, chosen.details["absorbing_price"] = [], []
    for seed_parameters in parameters:
        price = consolidation.random_actions_reward(run, seed_parameters, function)
        chosen.parameters.append({**seed_parameters, "absorbing_price": price})
        learned = np.asarray(learned_absorbing(seed_parameters, intentions))
        chosen.details["absorbing_price"].append({"learned": learned, "random_actions": price})
    chosen.absorbing = consolidation.priced_absorbing_reward


def main(argv=None) -> int:
    given = argument_parser().parse_args(argv)
    jax_setup.setup(host_devices=1)

    import envs
    from emgail_jax.host import run_lock
    from emgail_jax.host.checkpoints import CheckpointError
    from emgail_jax.host.demonstration_files import DemonstrationError
    from emgail_jax.host.run_spec import RunError, read_summary

    with contextlib.ExitStack() as held:
        try:
            held.enter_context(run_lock.reading(given.run_dir))  # no live run writes it
            env = read_summary(given.run_dir).get("env")
            args = with_refit_recipe(given, env)
            opened = _merge_opened(args) if args.merge else (*_opened(args), None)
        except (RunError, CheckpointError, envs.EnvError, DemonstrationError) as error:
            print(f"error: {error}", file=sys.stderr)
            return 2
        return _reoptimized(*opened)


def _reoptimized(
    args: argparse.Namespace, run, seeds: list[int], chosen: Chosen, merged: list | None
) -> int:
    """The rest of :func:`main`: the fresh agents trained (or ``merged``'s draws taken),
    scored and written."""
    from emgail_jax.host import records

    budget = budget_of(args, run)
    cache = args.cache or reward_check.default_cache()
    variant = None
    if args.env_set:  # the variant's own expert, its best true-reward agents, first
        reference = reward_check.variant_reference(
            run, budget, cache, args.reference_draws, not args.quiet
        )
        variant = {
            "dynamics": args.env_set,
            "reference_draws": args.reference_draws,
            "reference_draw": reference["draw"],
            "reference_returns": reference["draws_returns"],
            "original_experts_erd": reference["original_experts_erd"],
            "reference_meets_bar": reference["meets_bar"],
        }
        run.problem = reward_check.with_expert_returns(run.problem, reference["returns"])
    rl_seeds = range(args.rl_seed, args.rl_seed + args.draws)
    path = args.out or os.path.join(args.run_dir, default_name(args))
    finished = check_progress.FinishedDraws(path, check_identity(args, run))
    draws = merged or []
    for rl_seed in rl_seeds if merged is None else ():
        draw = finished.read(rl_seed, not args.quiet)
        if draw is None:
            draw = reward_check.reoptimize(
                run,
                seeds,
                budget,
                progress=not args.quiet,
                parameters=chosen.parameters,
                reward_function=chosen.function,
                absorbing_function=chosen.absorbing,
                rl_seed=rl_seed,
                partial=finished.partial(rl_seed),
            )
            finished.write(rl_seed, draw)
        draws.append(draw)
    result = (
        draws[0]
        if args.draws == 1
        else reward_check.chosen_by_learned_reward(draws, args.keep_draw)
    )
    # What the fresh agents were paid: an AIRL run's policies trained on f - log pi, its
    # fresh agents on g_i(s).
    airl = run.config.method.m_step.form.airl
    result["reward_form"] = "airl-g" if airl else run.algorithm.reward_form
    result.update(chosen.details)
    if variant is not None:
        variant["joint_policies"] = reward_check.joint_policies(run, seeds, result["iteration"])
    result["variant"] = variant
    result["check"] = check_identity(args, run)  # what --merge matches its parts by
    result["baseline"] = None
    if args.baseline:
        # The baseline's own draws: how far the search varies on the true reward.
        baselines = [
            reward_check.true_reward_baseline(run, budget, cache, not args.quiet, rl_seed=rl_seed)
            for rl_seed in rl_seeds
        ]
        result["baseline"] = (
            baselines[0] if args.draws == 1 else reward_check.best_baseline(baselines)
        )
    records.write_json(path, result)
    finished.remove()
    print_result(run, records.to_json_value(result))
    print(f"wrote {path}")
    return 0


def check_identity(args: argparse.Namespace, run) -> dict:
    """What a check's draws depend on: its options (not how many draws, nor where and how it
    reports) and the iteration of the networks checked."""
    unrelated = ("draws", "keep_draw", "quiet", "out", "baseline", "cache", "merge")
    options = {k: v for k, v in sorted(vars(args).items()) if k not in unrelated}
    # Left out when not given, as before the option existed, so that those checks resume.
    if options["value_target_scaling"] is None:
        del options["value_target_scaling"]
    return {"options": options, "iteration": run.snapshot or run.iteration}


def default_name(args) -> str:
    """``reoptimize[-seed-S][-rl-R][-draws-N][-it-N][-gamma-G][-lambda-L][-[no-]scaled-values][-snapshot-ITER][-consolidated-STEPS
    [-penalty-W][-fresh][-noise-S][-batch-M]][-ensemble-N][-across-seeds][-FORM][-env-...].json``: a
    check of one seed, or at another budget, does not overwrite the check of every seed at the
    env's budget."""
    parts = ["reoptimize"]
    if args.seed is not None:
        parts.append(f"seed-{args.seed}")
    if args.rl_seed:
        parts.append(f"rl-{args.rl_seed}")
    if args.draws > 1:
        parts.append(f"draws-{args.draws}")
        if args.keep_draw != "most":
            parts.append(f"keep-{args.keep_draw}")
    if args.iterations is not None:
        parts.append(f"it-{args.iterations}")
    if args.gamma is not None:
        parts.append(f"gamma-{args.gamma:g}")
    if args.gae_lambda is not None:
        parts.append(f"lambda-{args.gae_lambda:g}")
    if args.value_target_scaling is not None:
        parts.append("scaled-values" if args.value_target_scaling else "no-scaled-values")
    parts += reward_parts(args)
    if args.env_set:
        parts.append("env-" + "-".join(args.env_set))
    return "-".join(parts) + ".json"


def reward_parts(args) -> list[str]:
    """The parts of :func:`default_name` that say which reward was checked: the snapshot, the
    refit or ensemble, the reward form."""
    parts = refit_parts(args)
    if args.ensemble:
        parts.append(f"ensemble-{args.ensemble}")
    if args.across_seeds:
        parts.append("across-seeds")
    if args.reward_form:
        parts.append(args.reward_form)
    if args.absorbing_reward == "random":
        parts.append("absorbing-random")
    return parts


def refit_parts(args) -> list[str]:
    """The snapshot and the refit's options: with ``--consolidate``, the name of the refitted
    discriminator it saves (``RUN/rewards/NAME``), whatever reward form reads it."""
    parts = []
    if args.snapshot is not None:
        parts.append(f"snapshot-{args.snapshot}")
    if args.consolidate:
        parts.append(f"consolidated-{args.consolidate}")
    if args.consolidate_penalty:
        parts.append(f"penalty-{args.consolidate_penalty:g}")
    if args.consolidate_fresh:
        parts.append("fresh")
    if args.consolidate_noise:
        parts.append(f"noise-{args.consolidate_noise:g}")
    if args.consolidate_batch:
        parts.append(f"batch-{args.consolidate_batch}")
    if args.consolidate_ranking:
        parts.append(f"ranking-{args.consolidate_ranking:g}")
    if args.consolidate_ranking_random:
        parts.append("random")
    if args.consolidate_ranking_still:
        parts.append("still")
    if args.consolidate_agents:
        parts.append(f"agents-{args.consolidate_agents}")
    if args.consolidate_state_only:
        parts.append("state-only")
    if args.consolidate_absorbing:
        parts.append("absorbing")
    return parts


def refit_of(args):
    """The :class:`~emgail_jax.host.consolidation.Refit` the ``--consolidate*`` options ask for."""
    from emgail_jax.host.consolidation import Refit

    return Refit(
        steps=args.consolidate,
        gradient_penalty=args.consolidate_penalty,
        fresh=args.consolidate_fresh,
        support_noise=args.consolidate_noise,
        batch=args.consolidate_batch,
        ranking=args.consolidate_ranking,
        ranking_random=args.consolidate_ranking_random,
        ranking_still=args.consolidate_ranking_still,
        agent_rounds=args.consolidate_agents,
        state_only=args.consolidate_state_only,
        absorbing=args.consolidate_absorbing,
    )


if __name__ == "__main__":
    sys.exit(main())
