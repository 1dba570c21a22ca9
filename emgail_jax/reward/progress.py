"""What a reward check keeps while it runs, so that a check stopped part-way (Ctrl-C, a killed
or timed-out job) goes on where it stopped, to the numbers of one never stopped: its
finished draws (:class:`FinishedDraws`, ``NAME.draws/rl-R.json`` beside the check's file) and
the fresh agents' training under way (:class:`PartialTraining`, ``rl-R.partial.npz``), both
kept until the check is written and read back only for the same check."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import shutil
import zipfile

import numpy as np

# How often fresh agents' training is saved when it may be resumed: a check stopped part-way
# (Ctrl-C, a killed job) loses at most about this much of it.
PARTIAL_EVERY_S = 120.0


@dataclasses.dataclass
class PartialTraining:
    """Fresh agents' training so far, saved to ``path`` (``.npz``, renamed into place once
    written) at most every ``every_s`` seconds, so that a stopped check goes on from its last
    save as if never stopped. A save of another check (``identity``) or another layout of the
    agents' state is not read."""

    path: str
    identity: dict
    every_s: float = PARTIAL_EVERY_S

    def _identity_value(self):
        from emgail_jax.host import records

        return records.to_json_value(self.identity)

    def _is_mine(self, kept_identity) -> bool:
        try:
            return json.loads(str(kept_identity)) == self._identity_value()
        except ValueError:
            return False

    def read(self, states, chunk: int, iterations: int):
        """``(done, states, returns [done, ...], earned [done, ...], train_s)`` saved for
        ``states``' layout, or None when there is none to go on from."""
        import jax

        from emgail_jax.host.checkpoints import layout

        try:
            with np.load(self.path, allow_pickle=False) as saved:
                kept = {name: saved[name] for name in saved.files}
        except (OSError, ValueError, EOFError, zipfile.BadZipFile):  # none, or cut short
            return None
        treedef = jax.tree.structure(states)
        done = int(kept.get("done", -1))
        fits = (
            self._is_mine(kept.get("identity"))
            and str(kept.get("layout")) == layout(states)
            and 0 < done <= iterations
            and done % chunk == 0
            and treedef.num_leaves == sum(name.startswith("leaf_") for name in kept)
        )
        if not fits:
            return None
        leaves = [kept[f"leaf_{i}"] for i in range(treedef.num_leaves)]
        restored = jax.tree.unflatten(treedef, leaves)
        return done, restored, kept["returns"], kept["earned"], float(kept["train_s"])

    def write(self, done: int, states, returns, earned, train_s: float) -> None:
        import jax

        from emgail_jax.host.checkpoints import layout

        leaves = {f"leaf_{i}": np.asarray(x) for i, x in enumerate(jax.tree.leaves(states))}
        os.makedirs(os.path.dirname(os.path.abspath(self.path)), exist_ok=True)
        with open(self.path + ".tmp", "wb") as f:
            np.savez(
                f,
                identity=np.array(json.dumps(self._identity_value())),
                layout=np.array(layout(states)),
                done=np.array(done),
                returns=returns,
                earned=earned,
                train_s=np.array(train_s),
                **leaves,
            )
        os.replace(self.path + ".tmp", self.path)

    def remove(self) -> None:
        with contextlib.suppress(FileNotFoundError):
            os.remove(self.path)


@dataclasses.dataclass(frozen=True)
class FinishedDraws:
    """The draws of a check finished so far, kept beside its file (``NAME.draws/rl-R.json``)
    until the check is written, and the draw in training saved as it goes
    (``rl-R.partial.npz``, :class:`PartialTraining`), so that a check stopped part-way goes on
    from where it stopped. A draw kept for other options or networks is done again."""

    check_path: str
    identity: dict

    @property
    def directory(self) -> str:
        return os.path.splitext(self.check_path)[0] + ".draws"

    def draw_path(self, rl_seed: int) -> str:
        return os.path.join(self.directory, f"rl-{rl_seed}.json")

    def read(self, rl_seed: int, progress: bool) -> dict | None:
        from emgail_jax.host import records

        try:
            with open(self.draw_path(rl_seed)) as f:
                kept = json.load(f)
        except (OSError, ValueError):
            return None
        if kept.get("check") != records.to_json_value(self.identity):
            return None
        if progress:
            print(f"RL draw {rl_seed}: finished before, reused")
        return kept["draw"]

    def partial(self, rl_seed: int) -> PartialTraining:
        """Where draw ``rl_seed``'s training is saved until it finishes."""
        path = os.path.join(self.directory, f"rl-{rl_seed}.partial.npz")
        return PartialTraining(path, {**self.identity, "rl_seed": rl_seed})

    def write(self, rl_seed: int, draw: dict) -> None:
        from emgail_jax.host import records

        os.makedirs(self.directory, exist_ok=True)
        records.write_json(self.draw_path(rl_seed), {"check": self.identity, "draw": draw})
        self.partial(rl_seed).remove()

    def remove(self) -> None:
        shutil.rmtree(self.directory, ignore_errors=True)


def draws_done(check_path: str, draws: int, iterations: int) -> float:
    """How many of the check's ``draws`` (RL seeds 0 .. draws - 1) are done, the one in
    training counted by the fraction of its ``iterations`` saved: for a time estimate, so it
    does not ask whose options the kept draws were for."""
    finished = FinishedDraws(check_path, {})
    done = 0.0
    for rl_seed in range(draws):
        if os.path.exists(finished.draw_path(rl_seed)):
            done += 1.0
            continue
        try:
            with np.load(finished.partial(rl_seed).path, allow_pickle=False) as saved:
                done += min(int(saved["done"]), iterations) / iterations
        except (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile):
            pass
    return done
