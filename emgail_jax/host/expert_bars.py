"""The experts' bars: what each shipped expert must do (velocity, upright, pitch turn, ball
reached) over 10 deterministic episodes, and the measures a policy is held to them by. The
experts are trained to them (:mod:`emgail_jax.experts`) and the reward check's fresh agents
are scored by them (:mod:`emgail_jax.reward.check`)."""

from __future__ import annotations

import numpy as np

# The bars of the shipped experts (docs/environments.md, "Experts and shipped demonstrations"):
# what each must do over 10 deterministic episodes. `velocity` is the mean x-velocity of an
# episode, `upright` the share of episodes that did not end early (hopper's fall), `turn` the
# largest pitch change from the start (halfcheetah), `reached` the share of episodes ending within
# 0.02 of the intended ball.
BARS: dict[tuple[str, str], tuple[str, object]] = {
    ("swimmer", "forward"): ("velocity >= 0.25", lambda q: q["velocity"] >= 0.25),
    ("swimmer", "backward"): ("velocity <= -0.25", lambda q: q["velocity"] <= -0.25),
    ("hopper", "forward"): (
        "velocity >= 0.8, upright >= 90 %",
        lambda q: q["velocity"] >= 0.8 and q["upright"] >= 0.9,
    ),
    ("hopper", "backward"): (
        "velocity <= -0.8, upright >= 90 %",
        lambda q: q["velocity"] <= -0.8 and q["upright"] >= 0.9,
    ),
    ("hopper", "stand"): (
        "|velocity| < 0.1, upright 100 %",
        lambda q: abs(q["velocity"]) < 0.1 and q["upright"] == 1.0,
    ),
    ("halfcheetah", "forward"): ("velocity >= 2.0", lambda q: q["velocity"] >= 2.0),
    ("halfcheetah", "backward"): ("velocity <= -1.5", lambda q: q["velocity"] <= -1.5),
    ("halfcheetah", "flip"): (
        "turn >= pi, |velocity| < 0.5",
        lambda q: q["turn"] >= np.pi and abs(q["velocity"]) < 0.5,
    ),
}
for _ball in range(4):
    BARS[("reacher", f"ball{_ball + 1}")] = ("reached >= 90 %", lambda q: q["reached"] >= 0.9)


def evaluation_keys():
    """``(key_quality, key_demos)``: fixed, so that scores and demos depend on the experts
    only, not on the seed they were trained with."""
    import jax

    key_quality, key_demos = jax.random.split(jax.random.PRNGKey(0))
    return key_quality, key_demos


def quality(env, policy, key, episodes: int = 10) -> list[dict]:
    """Per intention: mean own return, x-velocity, upright share, pitch turn, reached share, and
    whether the bar is met, over ``episodes`` deterministic episodes of ``policy``; and the share
    of those episodes that meet the bar each alone (``episodes_meeting_bar``)."""
    import jax
    import jax.numpy as jnp

    import envs
    from emgail_jax.method.rollout import episodes as run_episodes

    k = env.num_intentions
    rows = jnp.broadcast_to(jnp.arange(k)[:, None], (k, episodes))
    act = lambda state, _: policy(state.obs, rows)
    limited = envs.EpisodeWrapper(env)
    returns, alive, trace = jax.device_get(
        jax.jit(lambda key: run_episodes(limited, act, key, k, episodes, traces=True))(key)
    )  # [K, E, K], [T, K, E], {name: [T, K, E]}
    results = []
    for i, name in enumerate(env.intention_names[:k]):
        per_episode = episode_measures(env, i, alive, trace)  # {measure: [E]}
        q = {"intention": name, "return": float(returns[i, :, i].mean())}
        q.update({measure: float(np.mean(v)) for measure, v in per_episode.items()})
        bar = BARS.get((env.name, name))
        q["bar"] = bar[0] if bar else None
        q["meets_bar"] = bool(bar[1](q)) if bar else None
        q["episodes_meeting_bar"] = episodes_meeting(bar[1], per_episode) if bar else None
        results.append(q)
    return results


def episodes_meeting(meets, measures: dict[str, np.ndarray]) -> float:
    """The share of episodes whose own measures (``measures``: ``{measure: [E]}``) meet the bar
    ``meets`` (a :data:`BARS` test)."""
    count = len(next(iter(measures.values())))
    each = [{name: values[e] for name, values in measures.items()} for e in range(count)]
    return float(np.mean([bool(meets(episode)) for episode in each]))


def episode_measures(env, i: int, alive, trace: dict) -> dict[str, np.ndarray]:
    """``{measure: [E]}`` of intention ``i``'s episodes (``alive [T, K, E]``, ``trace {name:
    [T, K, E]}``): upright (1.0: it did not end early), x-velocity, pitch turn, final distance
    to its ball and reached (1.0: within 0.02), each where the env traces what it needs. A bar
    read on one episode's measures holds that episode to the experts' bar."""
    steps = alive.sum(0).astype(int)  # [K, E]
    last = lambda values: np.take_along_axis(values, steps[None] - 1, 0)[0]  # [K, E]
    measures = {"upright": (steps[i] == env.episode_length).astype(np.float64)}
    if "x" in trace and hasattr(env, "dt"):  # the driver has no time step
        duration = np.maximum(steps[i] - 1, 1) * env.dt
        measures["velocity"] = (last(trace["x"])[i] - trace["x"][0, i]) / duration
    if "pitch" in trace:
        turn = np.abs(trace["pitch"][:, i] - trace["pitch"][0, i]) * alive[:, i]
        measures["turn"] = turn.max(0)
    ball = f"distance to ball {i + 1}"
    if ball in trace:
        measures["final_distance"] = last(trace[ball])[i]
        measures["reached"] = (last(trace[ball])[i] < 0.02).astype(np.float64)
    return measures
