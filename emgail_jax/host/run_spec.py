"""What defines a run, as stored in its ``summary.json``, and how to read it back."""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os

# Episodes of uniformly random actions whose mean return is ERD's reference point 1.
DEFAULT_RANDOM_EPISODES = 50


class RunError(ValueError):
    """A run that cannot start; the message says what to change."""


@dataclasses.dataclass(frozen=True)
class RunSpec:
    """Everything needed to rebuild a run (stored in its ``summary.json``)."""

    env: str
    intentions: int | None
    env_options: dict
    algo: str
    seeds: int
    first_seed: int
    demo_sources: tuple[str, ...]  # --demos (demonstration_sources); empty: the env's own
    demo_seed: int
    config: object  # emgail_jax.method.config.RunConfig
    random_episodes: int = DEFAULT_RANDOM_EPISODES

    @classmethod
    def from_summary(cls, summary: dict) -> RunSpec:
        from emgail_jax.method.config import RunConfig

        try:
            demos = summary["demonstrations"]
            return cls(
                env=summary["env"],
                intentions=summary["intentions"],
                env_options=summary["env_options"],
                algo=summary["algo"],
                seeds=summary["seeds"],
                first_seed=summary["first_seed"],
                demo_sources=_sources(demos["path"]),
                demo_seed=demos["seed"],
                config=RunConfig.from_dict(summary["config"]),
                random_episodes=summary.get("random_episodes", DEFAULT_RANDOM_EPISODES),
            )
        except (KeyError, TypeError) as error:
            raise RunError(f"summary.json does not describe a run (no {error})") from None
        except ValueError as error:  # a hyper-parameter out of its domain
            raise RunError(f"summary.json holds a config this version refuses: {error}") from None

    def to_summary(self) -> dict:
        """The fields of a ``summary.json`` that :meth:`from_summary` reads back (a run's own
        summary holds these, resolved for its env, and much else)."""
        return {
            "env": self.env,
            "intentions": self.intentions,
            "env_options": self.env_options,
            "algo": self.algo,
            "seeds": self.seeds,
            "first_seed": self.first_seed,
            "demonstrations": {"path": stored_sources(self.demo_sources), "seed": self.demo_seed},
            "config": self.config.to_dict(),
            "random_episodes": self.random_episodes,
        }


def _sources(path: str | list[str] | None) -> tuple[str, ...]:
    """``summary.json``'s ``demonstrations.path``: null, one source, or a list of them."""
    if path is None:
        return ()
    return (path,) if isinstance(path, str) else tuple(path)


def stored_sources(sources: tuple[str, ...]) -> str | list[str] | None:
    """The inverse of :func:`_sources` (one source stays a string, as runs have stored it)."""
    if not sources:
        return None
    return sources[0] if len(sources) == 1 else list(sources)


def read_summary(run_dir: str) -> dict:
    path = os.path.join(run_dir, "summary.json")
    if not os.path.exists(path):
        raise RunError(f"'{run_dir}' is not a run directory: it has no summary.json")
    try:
        with open(path) as f:
            return json.load(f)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise RunError(f"'{path}' is not valid JSON ({error})") from None


def stored_seeds(run_dir: str) -> int:
    """The seeds of the run in ``run_dir`` as its summary.json has them (1 when it has no
    readable summary: the command that asks fails later, with its own message)."""
    with contextlib.suppress(RunError, AttributeError, TypeError, ValueError):
        return int(read_summary(run_dir).get("seeds", 1))
    return 1
