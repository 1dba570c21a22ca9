"""Which draw of a reward check of several draws each rule keeps, and the ERD it gives, from the
check's file alone (nothing trained):

    python experiments/draw_choice.py RUN/reoptimize-refit.json [CHECK.json ...]

- most: the check's default rule, per learned intention the agent that earns the most learned
  reward per step (``emgail_jax.reward.draws.kept_draws``);
- nearest: ``reoptimize --keep-draw nearest``, the agent whose learned reward per step is
  nearest what the demonstrations earn, as one that out-earns them far may have found what the
  reward overpays;
- by true ERD: per true intention the draw of the lowest ERD, which no user without the true
  reward can choose: what the draws held.

Beside them, the true-reward baseline's ERD as the check keeps it (per intention the most true
return) and the lowest its draws give: per intention where the check recorded each draw's ERD
per intention, else its best whole draw.
"""

from __future__ import annotations

import json
import sys

import numpy as np

from emgail_jax.host.command_line import ArgumentParser
from emgail_jax.reward.draws import BY_TRUE_ERD, DRAW_RULES, kept_per_true_intention, picked

RULES = (*DRAW_RULES, BY_TRUE_ERD)


def rule_erds(check: dict) -> dict[int, dict[str, float]]:
    """Per run seed of ``check`` (a file of several draws), each rule's ERD."""
    found = {}
    for rows in zip(*(d["per_seed"] for d in check["draws"]), strict=True):
        kept = {rule: kept_per_true_intention(rows, rule) for rule in RULES}
        found[rows[0]["run_seed"]] = {rule: picked(rows, kept[rule])["erd"] for rule in RULES}
    return found


def main(argv=None) -> int:
    parser = ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("checks", nargs="+", metavar="CHECK")
    args = parser.parse_args(argv)
    for path in args.checks:
        try:
            with open(path) as f:
                check = json.load(f)
        except (OSError, ValueError) as error:
            print(f"error: cannot read '{path}' ({error})", file=sys.stderr)
            return 2
        if not isinstance(check, dict) or len(check.get("draws") or ()) < 2:
            print(f"error: '{path}' is no check of several draws (--draws N)", file=sys.stderr)
            return 2
        found = rule_erds(check)
        print(path)
        print("  seed  " + "  ".join(f"{rule:>11s}" for rule in RULES))
        for seed, erds in found.items():
            print(f"  {seed:4d}  " + "  ".join(f"{erds[rule]:11.3f}" for rule in RULES))
        means = [np.mean([erds[rule] for erds in found.values()]) for rule in RULES]
        print("  mean  " + "  ".join(f"{mean:11.3f}" for mean in means))
        baseline = check.get("baseline") or {}
        if "erd" in baseline:
            line = f"  true-reward baseline: {baseline['erd']:.3f} (most true return)"
            per_draw = baseline.get("draws_erd_per_intention")
            if per_draw:  # per intention its draw of the lowest ERD
                line += f", {np.min(np.asarray(per_draw, float), 0).mean():.3f} (lowest ERD)"
            elif baseline.get("draws_erd"):  # checks written before: whole draws alone
                line += f", {min(baseline['draws_erd']):.3f} (its draw of the lowest ERD)"
            print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())
