"""The README's table of the shipped experts' quality, from their ``meta.json`` files.

    python experiments/expert_table.py

Each ``meta.json`` holds the scores ``python -m emgail_jax.experts`` measured over 10
deterministic episodes per intention (rerun them with ``--evaluate``).
"""

from __future__ import annotations

import json
import os

from emgail_jax.experts import SPECS, checkpoint_dir


def _cell(value, digits: int = 2) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def main() -> None:
    columns = ["env", "intention", "return", "mean x-velocity", "upright", "pitch turn"]
    columns += ["reached", "bar", "met"]
    print("| " + " | ".join(columns) + " |")
    print("|---|---|---:|---:|---:|---:|---:|---|---|")
    for env_name in SPECS:
        path = os.path.join(checkpoint_dir(env_name), "meta.json")
        if not os.path.exists(path):
            print(f"| {env_name} | (no experts shipped) | | | | | | | |")
            continue
        with open(path) as f:
            meta = json.load(f)
        for q in meta["quality"]:
            bar = q["bar"].replace("|", "\\|")  # a literal | inside a markdown table
            upright = q.get("upright") if env_name == "hopper" else None
            turn = q.get("turn")
            reached = q.get("reached")
            velocity = q.get("velocity") if env_name != "reacher" else None
            print(
                f"| {env_name} | {q['intention']} | {q['return']:.1f} | {_cell(velocity)} | "
                f"{_cell(upright)} | {_cell(turn, 1)} | {_cell(reached)} | {bar} | "
                f"{'yes' if q['meets_bar'] else '**no**'} |"
            )


if __name__ == "__main__":
    main()
