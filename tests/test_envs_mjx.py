"""MJX envs: shapes, finite rollouts, reward semantics, K selection, agreement with native MuJoCo.

MJX compiles are slow on CPU (~10 s per env), so every env's ``reset`` and ``step`` are jitted
once per module (the ``compiled`` fixture) and shared by all tests; checks that only need
shapes trace with ``jax.eval_shape`` instead of compiling.
"""

import dataclasses
import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs
from envs.mjx_base import mjx, mujoco_default_solver, native_rollout

pytestmark = pytest.mark.heavy

MJX_ENVS = ("swimmer", "hopper", "halfcheetah", "reacher")
LOCOMOTION = ("swimmer", "hopper", "halfcheetah")


@dataclasses.dataclass
class Compiled:
    env: envs.Env
    reset: Callable
    step: Callable


@pytest.fixture(scope="module")
def compiled():
    cache: dict[str, Compiled] = {}

    def get(name: str) -> Compiled:
        if name not in cache:
            env = envs.make(name)
            cache[name] = Compiled(env, jax.jit(env.reset), jax.jit(env.step))
        return cache[name]

    return get


def set_physics(state: envs.State, **fields) -> envs.State:
    """``state`` with ``physics`` fields replaced, e.g. ``qvel=...``."""
    return state.replace(physics=state.physics.replace(**fields))


# ---- shapes, jit, finite values -----------------------------------------------------------


def _reset_without_forward_steps_like_with_it(compiled, name):
    c = compiled(name)
    state = c.reset(jax.random.PRNGKey(7))
    forward = jax.jit(lambda s: s.replace(physics=mjx.forward(c.env.mjx_model, s.physics)))
    action = 0.7 * jnp.ones(c.env.action_size)
    a, b = state, forward(state)
    for _ in range(5):
        a, b = c.step(a, action), c.step(b, action)
    np.testing.assert_array_equal(a.physics.qpos, b.physics.qpos)
    np.testing.assert_array_equal(a.obs, b.obs)
    np.testing.assert_array_equal(a.reward, b.reward)


@pytest.mark.slow  # a compile of MJX's forward pass per env, 30-40 s each
@pytest.mark.parametrize("name", MJX_ENVS)
def test_reset_without_forward_steps_like_with_it(compiled, name):
    """The reset leaves out mjx.forward (see MjxEnv.physics_reset): stepping from it gives the
    same states, observations and rewards, to the bit, as stepping from a forwarded reset."""
    _reset_without_forward_steps_like_with_it(compiled, name)


@pytest.mark.parametrize("name", MJX_ENVS)
def test_reset_and_step_shapes(compiled, name):
    c = compiled(name)
    env = c.env
    first = c.reset(jax.random.PRNGKey(0))
    for state in (first, c.step(first, jnp.zeros(env.action_size))):
        assert isinstance(state.physics, mjx.Data)
        assert state.obs.shape == (env.observation_size,) and state.obs.dtype == jnp.float32
        assert state.reward.shape == (env.num_intentions,)
        assert state.done.shape == ()


@pytest.mark.parametrize("name", MJX_ENVS)
def test_hundred_random_steps_stay_finite(compiled, name):
    c = compiled(name)
    key_reset, key_actions = jax.random.split(jax.random.PRNGKey(1))
    state = c.reset(key_reset)
    # Beyond the action box, to exercise the clipping.
    actions = jax.random.uniform(key_actions, (100, c.env.action_size), minval=-1.5, maxval=1.5)
    obs, rewards, dones = [state.obs], [], []
    for action in actions:
        state = c.step(state, action)
        obs.append(state.obs)
        rewards.append(state.reward)
        dones.append(state.done)
    assert np.all(np.isfinite(np.stack(obs))) and np.all(np.isfinite(np.stack(rewards)))
    assert set(np.unique(np.stack(dones))) <= {0.0, 1.0}
    if not c.env.terminates:  # the class says whether its episodes may end early
        assert not np.any(np.stack(dones))


@pytest.mark.parametrize("name", MJX_ENVS)
def test_step_keeps_info_it_does_not_own_and_k_sets_the_reward_shape(name):
    """One trace of reset and step each (an MJX step traces in seconds): the info the step does
    not own passes through, and K = 1 selects one reward."""
    env = envs.make(name, intentions=1)
    state = jax.eval_shape(env.reset, jax.random.PRNGKey(0))
    assert state.reward.shape == (1,)
    state = state.replace(info={"steps": jnp.zeros((), jnp.int32), "mine": jnp.zeros((3,))})
    out = jax.eval_shape(env.step, state, jnp.zeros(env.action_size))
    assert set(out.info) == {"steps", "mine"} and out.info["mine"].shape == (3,)
    assert out.reward.shape == (1,)


# ---- reward semantics -----------------------------------------------------------------------


def x_velocity(env, before: envs.State, after: envs.State) -> float:
    return float(after.physics.qpos[0] - before.physics.qpos[0]) / env.dt


@pytest.mark.parametrize("name", LOCOMOTION)
def test_moving_the_root_forward_raises_forward_and_lowers_backward(compiled, name):
    c = compiled(name)
    state = c.reset(jax.random.PRNGKey(2))
    zero = jnp.zeros(c.env.action_size)

    def pushed(speed):  # the root given a horizontal velocity by hand
        return c.step(set_physics(state, qvel=state.physics.qvel.at[0].set(speed)), zero)

    ahead, behind, still = pushed(1.0), pushed(-1.0), pushed(0.0)
    forward, backward = 0, 1
    assert ahead.reward[forward] > still.reward[forward] + 0.5 > behind.reward[forward] + 1.0
    assert ahead.reward[backward] < still.reward[backward] - 0.5 < behind.reward[backward] - 1.0
    if name == "hopper":  # stand penalises motion either way
        stand = 2
        assert still.reward[stand] > ahead.reward[stand] + 0.5
        assert still.reward[stand] > behind.reward[stand] + 0.5


# Hand-computed rewards from the states before and after a step: (ctrl cost c, healthy bonus).
REWARD_CONSTANTS = {"swimmer": (1e-4, 0.0), "hopper": (1e-3, 1.0), "halfcheetah": (0.1, 0.0)}


@pytest.mark.parametrize("name", LOCOMOTION)
def test_rewards_match_their_formulas(compiled, name):
    c = compiled(name)
    before = c.reset(jax.random.PRNGKey(3))
    action = jnp.linspace(-1.5, 0.8, c.env.action_size)  # the first entry is clipped to -1
    after = c.step(before, action)
    cost, healthy = REWARD_CONSTANTS[name]
    ctrl = cost * float(jnp.sum(jnp.clip(action, -1, 1) ** 2))
    v = x_velocity(c.env, before, after)
    expected = [v + healthy - ctrl, -v + healthy - ctrl]
    if name == "hopper":
        expected.append(-abs(v) + healthy - ctrl)
    if name == "halfcheetah":
        pitch_rate = float(after.physics.qpos[2] - before.physics.qpos[2]) / c.env.dt
        expected.append(-c.env.flip_move_weight * abs(v) + c.env.flip_weight * pitch_rate - ctrl)
    np.testing.assert_allclose(after.reward, expected, rtol=1e-4, atol=1e-4)


def test_hopper_terminates_when_it_falls(compiled):
    c = compiled("hopper")
    assert c.env.terminates
    state = c.reset(jax.random.PRNGKey(4))
    zero = jnp.zeros(3)
    assert float(c.step(state, zero).done) == 0.0
    low = set_physics(state, qpos=state.physics.qpos.at[1].set(0.6))  # torso below 0.7
    assert float(c.step(low, zero).done) == 1.0
    tilted = set_physics(state, qpos=state.physics.qpos.at[2].set(0.3))  # |pitch| > 0.2
    assert float(c.step(tilted, zero).done) == 1.0


def test_halfcheetah_flip_rewards_pitch_rotation(compiled):
    c = compiled("halfcheetah")
    state = c.reset(jax.random.PRNGKey(5))
    qvel = state.physics.qvel.at[0].set(0.0)
    zero = jnp.zeros(6)
    nose_down = c.step(set_physics(state, qvel=qvel.at[2].set(4.0)), zero)
    nose_up = c.step(set_physics(state, qvel=qvel.at[2].set(-4.0)), zero)
    flip = 2
    assert nose_down.reward[flip] > 2.0 > -2.0 > nose_up.reward[flip]
    # A whole turn later the cheetah looks the same: the observed pitch is wrapped.
    turned = set_physics(state, qpos=state.physics.qpos.at[2].add(2 * math.pi))
    np.testing.assert_allclose(c.step(turned, zero).obs, c.step(state, zero).obs, atol=1e-3)


def test_reacher_reward_of_ball_k_is_highest_at_ball_k(compiled):
    c = compiled("reacher")
    state = c.reset(jax.random.PRNGKey(6))
    zero = jnp.zeros(2)
    # The balls do not touch the arm, so the fingertip ends a zero-action step where it would
    # without them; put ball k exactly there.
    fingertip = c.step(state, zero).physics.xpos[c.env.fingertip_id]
    for k in range(4):
        moved = set_physics(state, mocap_pos=state.physics.mocap_pos.at[k].set(fingertip))
        reward = c.step(moved, zero).reward
        assert int(jnp.argmax(reward)) == k
        assert float(reward[k]) == pytest.approx(0.0, abs=1e-5)


def test_reacher_balls_lie_in_their_own_quarters():
    env = envs.make("reacher")
    balls = jax.jit(jax.vmap(env.sample_balls))(jax.random.split(jax.random.PRNGKey(7), 2000))
    x, y = balls[..., 0], balls[..., 1]
    radius = np.hypot(x, y)
    assert np.all(radius <= env.ball_disc_radius + 1e-6)
    signs = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]])  # ball k's quarter, as (sign x, sign y)
    assert np.all(np.sign(x) == signs[:, 0]) and np.all(np.sign(y) == signs[:, 1])
    # uniform by area: a quarter of the balls within half the radius
    assert np.mean(radius < env.ball_disc_radius / 2) == pytest.approx(0.25, abs=0.03)


def test_reacher_observation_layout(compiled):
    c = compiled("reacher")
    state = c.step(c.reset(jax.random.PRNGKey(8)), jnp.array([0.3, -0.2]))
    d = state.physics
    np.testing.assert_allclose(state.obs[:2], jnp.cos(d.qpos), atol=1e-6)
    np.testing.assert_allclose(state.obs[2:4], jnp.sin(d.qpos), atol=1e-6)
    np.testing.assert_allclose(state.obs[4:6], d.qvel, atol=1e-6)
    np.testing.assert_allclose(state.obs[6:14], d.mocap_pos[:, :2].reshape(-1), atol=1e-6)
    to_balls = d.xpos[c.env.fingertip_id][None] - d.mocap_pos
    np.testing.assert_allclose(state.obs[14:], to_balls.reshape(-1), atol=1e-6)


# ---- K selects the first K intentions -------------------------------------------------------


# (K = 1's reward shape: test_step_keeps_info_it_does_not_own_and_k_sets_the_reward_shape)


@pytest.mark.slow  # a compile of the reacher with K = 2: 20-25 s
def test_k_rewards_are_the_first_k_of_all(compiled):
    full = compiled("reacher")
    two = envs.make("reacher", intentions=2)
    key, action = jax.random.PRNGKey(9), jnp.array([0.5, -0.5])
    rewards = jax.jit(two.step)(jax.jit(two.reset)(key), action).reward
    np.testing.assert_allclose(rewards, full.step(full.reset(key), action).reward[:2], atol=1e-6)


# ---- the same physics as native MuJoCo -------------------------------------------------------

# Env steps compared deterministically (the hopper soon falls, contacts make the cheetah
# chaotic; measured errors are 2e-4 for the hopper and ~1e-6 for the others), with tolerances on
# qpos against native MuJoCo with the env's settings (float32 vs float64) and with MuJoCo's
# defaults (adds the settings' effect). experiments/check_mjx_dynamics.py compares long runs.
NATIVE = {"swimmer": 50, "hopper": 25, "halfcheetah": 10, "reacher": 50}


@pytest.mark.parametrize("name", MJX_ENVS)
def test_short_open_loop_run_matches_native_mujoco(compiled, name):
    c = compiled(name)
    env = c.env
    state = c.reset(jax.random.PRNGKey(10))
    t = np.arange(NATIVE[name])[:, None] * env.dt
    actions = 0.8 * np.sin(2 * np.pi * 2.0 * t + 0.5 * np.pi * np.arange(env.action_size))
    mjx_q = [np.asarray(state.physics.qpos)]
    for action in actions:
        state = c.step(state, jnp.asarray(action, jnp.float32))
        mjx_q.append(np.asarray(state.physics.qpos))
    start = jax.device_get(c.reset(jax.random.PRNGKey(10)).physics)
    mocap = start.mocap_pos if env.mj_model.nmocap else None
    for model, tol in ((env.mj_model, 1e-3), (env.native_model(mujoco_default_solver()), 5e-3)):
        native_q = native_rollout(model, env.frame_skip, start.qpos, start.qvel, actions, mocap)
        np.testing.assert_allclose(np.stack(mjx_q), native_q, atol=tol)


# ---- with the training wrappers --------------------------------------------------------------


@pytest.mark.slow  # a compile of the wrapped hopper: 25-30 s (the falling itself is checked above)
def test_wrapped_hopper_falls_and_starts_a_new_episode():
    env = envs.wrap_for_training(envs.make("hopper"))
    reset, step = jax.jit(env.reset), jax.jit(env.step)
    state = reset(jax.random.PRNGKey(11))
    steps = 0
    for key in jax.random.split(jax.random.PRNGKey(12), 300):
        state = step(state, jax.random.uniform(key, (3,), minval=-1.0, maxval=1.0))
        steps += 1
        if state.done:
            break
    assert state.done == 1.0 and state.info["truncation"] == 0.0, "a random hopper falls"
    assert 1 < steps < 300
    # The state after the last step is the first of a fresh episode.
    assert int(state.info["steps"]) == 0
    assert float(state.obs[0]) == pytest.approx(1.25, abs=0.01)
    assert env.unwrapped.is_healthy(state.physics.qpos, state.physics.qvel) == 1.0


# ---- replaying recorded pairs ---------------------------------------------------------------


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_hopper_replay_gives_back_an_episodes_steps(compiled):
    """An episode stepped by the env (its root far from 0, its foot spinning beyond the
    observation's clip all along), then replayed pair by pair from its observations alone:
    the same next observations and rewards, the clipped velocity fitted to the next pair's
    positions (all but the last pair, which has no next one)."""
    c = compiled("hopper")
    env = c.env
    physics = c.reset(jax.random.PRNGKey(8)).physics
    start = env.initial_state(
        physics.replace(qpos=physics.qpos.at[0].set(3.0), qvel=physics.qvel.at[5].set(14.0))
    )
    assert float(jnp.abs(start.obs[-1])) == env.obs_max_velocity  # the observation clipped it
    actions = jax.random.uniform(jax.random.PRNGKey(9), (6, 3), minval=-1.0, maxval=1.0)
    states = [start]
    for action in actions:
        states.append(c.step(states[-1], action))
    observations = jnp.stack([s.obs for s in states])  # [T + 1, D]
    rewards = np.stack([s.reward for s in states[1:]])  # [T, K]
    padded = lambda x: jnp.concatenate([x, x[:2]])  # two pairs of padding after the episode
    next_obs, replayed, done = jax.jit(env.replay)(padded(observations[:-1]), padded(actions), 6)
    np.testing.assert_allclose(next_obs[:5], observations[1:6], atol=1e-4)
    np.testing.assert_allclose(replayed[:5], rewards[:5], atol=5e-4)
    assert not done[:6].any()
    # The last pair's clipped velocity has nothing to be fitted to: its step is off.
    assert np.abs(replayed[5] - rewards[5]).max() > 10 * np.abs(replayed[:5] - rewards[:5]).max()


def test_an_observation_without_the_state_is_not_replayed():
    reacher = envs.make("reacher")
    with pytest.raises(envs.EnvError, match="do not give back"):
        reacher.replay(jnp.zeros((2, 26)), jnp.zeros((2, 2)), 2)


def test_dynamics_scale_exactly_what_they_name():
    plain = envs.make("hopper").mj_model
    varied = envs.make("hopper", dynamics=["mass.torso=1.5", "gravity=0.8", "friction=0.5"])
    model, torso = varied.mj_model, plain.body("torso").id
    assert model.body_mass[torso] == pytest.approx(1.5 * plain.body_mass[torso])
    np.testing.assert_allclose(model.body_inertia[torso], 1.5 * plain.body_inertia[torso])
    others = np.arange(plain.nbody) != torso
    np.testing.assert_array_equal(model.body_mass[others], plain.body_mass[others])
    np.testing.assert_allclose(model.opt.gravity, 0.8 * plain.opt.gravity)
    np.testing.assert_allclose(model.geom_friction[:, 0], 0.5 * plain.geom_friction[:, 0])
    np.testing.assert_array_equal(model.geom_friction[:, 1:], plain.geom_friction[:, 1:])
    assert model.stat.meaninertia > plain.stat.meaninertia  # the solver's statistics follow
    assert varied.options()["dynamics"] == ["mass.torso=1.5", "gravity=0.8", "friction=0.5"]
    assert "dynamics" not in envs.make("hopper").options()  # a run's summary is unchanged


def test_dynamics_keep_a_total_mass_the_model_sets():
    # halfcheetah's XML fixes its total mass; one body's factor still applies exactly.
    plain = envs.make("halfcheetah").mj_model
    model = envs.make("halfcheetah", dynamics=["mass.torso=2"]).mj_model
    torso = plain.body("torso").id
    assert model.body_mass[torso] == pytest.approx(2 * plain.body_mass[torso])
    assert model.body_mass.sum() == pytest.approx(plain.body_mass.sum() + plain.body_mass[torso])


@pytest.mark.slow  # end to end (make test-slow); cheaper tests cover its parts
def test_the_swimmers_viscosity_changes_its_motion(compiled):
    plain, thick = compiled("swimmer"), envs.make("swimmer", dynamics=["viscosity=3"])
    assert thick.mj_model.opt.viscosity == pytest.approx(3 * plain.env.mj_model.opt.viscosity)
    # One step from the same start (the viscosity plays no part in the reset); the plain
    # swimmer's programs are the module's, the thick one's step its one compile.
    start, action = plain.reset(jax.random.PRNGKey(0)), jnp.ones(thick.action_size)
    states = [plain.step(start, action), jax.jit(thick.step)(start, action)]
    assert not np.allclose(states[0].obs, states[1].obs)


@pytest.mark.parametrize(
    "env, setting, message",
    [
        ("hopper", "viscosity=2", "has no viscosity"),
        ("hopper", "mass.nose=2", "its bodies: torso, thigh, leg, foot"),
        ("hopper", "gravity=-1", "must be a positive number"),
        ("hopper", "gravity", "must be a positive number"),
        ("swimmer", "wind=2", "use mass.BODY, gravity, friction, viscosity"),
    ],
)
def test_dynamics_out_of_their_domain_are_refused_in_one_line(env, setting, message):
    with pytest.raises(envs.EnvError, match=message) as error:
        envs.make(env, dynamics=[setting])
    assert "\n" not in str(error.value)
