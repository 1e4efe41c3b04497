"""The quadruped envs: our MJX model against native MuJoCo, the course, the episode's end,
the reward, the first-person camera, and the registry's task configs.

One compiled step of ``quadruped-walls`` serves every physics check (compiling it is the cost,
about a minute): the parity, reward and episode-end checks run in one test so that xdist's
workers do not each compile it.
"""

from __future__ import annotations

import copy

import course
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from iap_mjx import envs
from iap_mjx.envs.quadruped import QuadrupedConfig, QuadrupedWallsConfig
from iap_mjx.robots import a1

STEPS = 100


@pytest.fixture(scope="module")
def walls():
    env = envs.make("quadruped-walls")
    return env, jax.jit(env.reset), jax.jit(env.step)


@pytest.fixture(scope="module")
def forward(walls):
    """The env's position stage, compiled once for the module's tests."""
    return jax.jit(walls[0].forward)


def test_the_robot_is_built_from_the_figures():
    env = envs.make("quadruped-flat")
    m = env.mj_model
    assert (m.nq, m.nv, m.nu) == (19, 18, 12)
    np.testing.assert_allclose(m.body_subtreemass[m.body("trunk").id], 12.453, atol=1e-6)
    np.testing.assert_allclose(m.jnt_range[1:], a1.JOINT_RANGES, atol=1e-6)
    np.testing.assert_allclose(m.actuator_forcerange, [[-33.5, 33.5]] * 12)
    assert env.control_timestep == pytest.approx(0.02) and m.opt.timestep == pytest.approx(0.004)
    # the env's solver settings are its MJCF's (the config's defaults equal them)
    mjcf = mujoco.MjModel.from_xml_string(a1.world_xml()).opt
    assert (m.opt.solver, m.opt.iterations, m.opt.ls_iterations) == (mjcf.solver, mjcf.iterations, mjcf.ls_iterations)
    assert (mjcf.solver, mjcf.iterations, mjcf.ls_iterations) == (mujoco.mjtSolver.mjSOL_NEWTON, 8, 4)
    # contacts: the feet with the floor only (no self-collision)
    from mujoco.mjx._src import collision_driver

    pairs = {(m.geom(g1).name, m.geom(g2).name) for g1, g2, _ in collision_driver.geom_pairs(m)}
    assert pairs == {("floor", f"{leg}_foot") for leg in a1.LEGS}
    # standing pose: feet just touching the floor
    data = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, data, 0)
    mujoco.mj_forward(m, data)
    feet = [data.geom_xpos[m.geom(f"{leg}_foot").id] for leg in a1.LEGS]
    np.testing.assert_allclose([f[2] for f in feet], a1.FOOT_RADIUS, atol=2e-3)
    np.testing.assert_allclose([f[0] for f in feet], [0.183, 0.183, -0.183, -0.183], atol=1e-6)


@pytest.mark.slow
def test_walls_step_native_parity_reward_and_episode_end(walls, forward):
    """The compiled step, checked three ways (one compile): parity with native MuJoCo, the
    capped-displacement reward, the episode's end."""
    _check_parity_with_native_mujoco(*walls)
    _check_one_colliding_wall_touches_like_all_walls(*walls, forward)
    _check_reward_is_the_capped_forward_displacement(*walls)
    _check_episode_ends_on_falling_off_or_touching_the_ground(*walls)


def _follow(env):
    """Moves the env's one colliding wall after the trunk, as the env does after each step."""

    def follow(data):
        data.mocap_pos[-1] = np.asarray(env.contact_wall_position(data.qpos[0], data.mocap_pos[:-1]))

    return follow


def _check_parity_with_native_mujoco(env, reset, step):
    """From the env's first state, 100 control steps of the same PD targets (the standing pose
    plus uniform +-0.3 rad) in MJX (float32) and ``mujoco.mj_step`` (float64) on the same
    compiled model, within 1e-3 plus native MuJoCo's own spread under float32 noise
    (``tests/spread.py``).

    The robot stumbles: at step 82 a foot grazes the floor (penetration ~2e-5 m), and whether
    it touches at the next physics steps depends on rounding; where it does, qpos moves by
    0.063 within two steps. MJX compiled with the tests' XLA flags stays on one side (max gap
    8.5e-5 over the 100 steps); with XLA's default flags, or on an AVX2 machine, it lands on
    the other. Native MuJoCo itself lands there in 6 of its 16 float32-noise runs, so the
    bound opens to ~6 there; before step 82 the spread is below 3e-4 and the bound is ~1e-3
    plus 100x that. A wrong physics step (4 physics steps per control step instead of 5) is
    0.098 off at step 5, where the bound is 1e-3 plus ~1e-4: the test checks that it fails.
    A 1-ulp move of the start state alone is not noise enough: native's spread from it
    stays below 1.3e-5 (16 directions), 10x under MJX's own drift before step 82."""
    state = reset(jax.random.key(0))
    rng = np.random.default_rng(0)
    targets = a1.HOME_JOINTS + rng.uniform(-0.3, 0.3, (STEPS, 12)).astype(np.float32)
    actions = np.asarray(a1.targets_to_action(targets), np.float32)
    start, ours = state.data, []
    for action in actions:
        state = step(state, jnp.asarray(action))
        ours.append(np.asarray(state.data.qpos))
    targets = np.asarray(a1.action_to_targets(actions), np.float64)
    theirs, _ = course.check_against_native(
        env, env.mj_model, start, targets, ours, follow=_follow(env), what="quadruped qpos"
    )
    assert float(np.max(np.asarray(state.done))) == 0.0
    assert theirs[-1, 0] != theirs[0, 0]  # the robot moved


def _all_walls_collide(env) -> mujoco.MjModel:
    """The env's model with every seen wall colliding as ``wall_contact`` does, and
    ``wall_contact`` not colliding: the course as native MuJoCo would run it without the env's
    one colliding wall."""
    m = copy.deepcopy(env.mj_model)
    contact = m.geom("wall_contact").id
    for i in range(env.config.n_walls):
        wall = m.geom(f"wall{i}").id
        for field in ("contype", "conaffinity", "condim", "priority"):
            getattr(m, f"geom_{field}")[wall] = getattr(m, f"geom_{field}")[contact]
        m.body_contype[m.geom_bodyid[wall]] = m.geom_contype[contact]  # the broad phase's filter
    m.geom_contype[contact] = m.body_contype[m.geom_bodyid[contact]] = 0
    return m


def _check_one_colliding_wall_touches_like_all_walls(env, reset, step, forward):
    """The second wall 0.1 m ahead of the trunk's front, the robot pushed into it: MJX (one
    colliding wall, moved to the nearest) against native MuJoCo with every wall colliding, 40
    control steps. The native run must touch the wall, and the trajectories agree."""
    state = reset(jax.random.key(4))
    walls = np.asarray(env.walls(state.data)).copy()
    walls[1] = [a1.TRUNK_HALF_SIZE[0] + 0.1 + env.WALL_HALF_SIZE[0], 0.0, env.WALL_HALF_SIZE[2]]
    data0 = forward(
        env.place_walls(state.data, walls).replace(qvel=state.data.qvel.at[0].set(1.5))
    )  # walking into the wall at 1.5 m/s
    state = state.replace(data=data0)
    assert int(np.argmin(np.abs(walls[:, 0]))) == 1  # the colliding wall is on wall 1, not wall 0
    m = _all_walls_collide(env)
    hold = np.asarray(a1.targets_to_action(a1.HOME_JOINTS), np.float32)
    ours = []
    for _ in range(40):
        state = step(state, jnp.asarray(hold))
        ours.append(np.asarray(state.data.qpos))
    targets = np.tile(np.asarray(a1.HOME_JOINTS, np.float64), (40, 1))
    _, touched = course.check_against_native(
        env, m, data0, targets, ours, follow=None, what="walking into the wall", touch_geom=m.geom("wall1").id
    )
    assert touched > 0


def test_walls_are_placed_per_episode_within_the_course(walls):
    env, reset, _ = walls
    states = [reset(jax.random.key(k)) for k in range(8)]
    positions = np.array([np.asarray(env.walls(s.data)) for s in states])  # (8, n_walls, 3)
    assert positions.shape == (8, env.config.n_walls, 3)
    assert len({tuple(p.round(4).ravel()) for p in positions}) == 8
    half_width, half_length = env.PLATFORM[2], env.WALL_HALF_SIZE[1]
    gap = half_width - (np.abs(positions[..., 1]) + half_length) + 2 * np.abs(positions[..., 1])
    assert np.all((gap >= 0.6 - 1e-5) & (gap <= 1.0 + 1e-5))  # the free side's width
    spots = env.WALL_START + env.WALL_SPACING * np.arange(env.config.n_walls)
    assert np.all(np.abs(positions[..., 0] - spots) <= env.WALL_JITTER + 1e-6)


def _placed(state, **qpos):
    index = {"x": 0, "y": 1, "z": 2}
    q = state.data.qpos
    for name, value in qpos.items():
        q = q.at[index[name]].set(value)
    return state.replace(data=state.data.replace(qpos=q))


def _check_reward_is_the_capped_forward_displacement(env, reset, step):
    state = reset(jax.random.key(1))
    hold = a1.targets_to_action(state.data.qpos[7:])
    slow = step(state, hold)
    np.testing.assert_allclose(slow.reward, slow.data.qpos[0] - state.data.qpos[0], atol=1e-7)
    assert abs(float(slow.reward)) < env.config.v_cap * 0.02
    fast = state.replace(data=state.data.replace(qvel=state.data.qvel.at[0].set(3.0)))
    after = step(fast, hold)
    assert float(after.data.qpos[0] - state.data.qpos[0]) > 0.03  # 3 m/s for 0.02 s
    np.testing.assert_allclose(after.reward, env.config.v_cap * 0.02, rtol=1e-6)
    back = step(state.replace(data=state.data.replace(qvel=state.data.qvel.at[0].set(-3.0))), hold)
    np.testing.assert_allclose(back.reward, -env.config.v_cap * 0.02, rtol=1e-6)


def _check_episode_ends_on_falling_off_or_touching_the_ground(env, reset, step):
    state = reset(jax.random.key(2))
    hold = a1.targets_to_action(state.data.qpos[7:])
    standing = step(state, hold)
    assert float(standing.done) == 0.0
    off = step(_placed(state, y=1.05), hold)  # the trunk's centre beyond the platform's edge
    assert float(off.done) == 1.0 and float(off.metrics["nan_terminations"]) == 0.0
    down = step(_placed(state, z=0.0), hold)  # the trunk's bottom below the ground
    assert float(down.done) == 1.0 and float(down.metrics["nan_terminations"]) == 0.0
    frozen = step(down, hold)
    np.testing.assert_array_equal(frozen.data.qpos, down.data.qpos)
    assert float(frozen.reward) == 0.0
    bad = step(state, jnp.full((12,), jnp.nan))
    assert float(bad.done) == 1.0 and float(bad.metrics["nan_terminations"]) == 1.0


def test_first_person_camera_sees_the_world_not_the_robot(walls, forward):
    env, reset, _ = walls
    pixels = envs.make("quadruped-walls", obs_mode="pixels+state")
    assert pixels.observation_shape == {"pixels": (24, 32, 3), "state": (17,)}
    state = reset(jax.random.key(3))
    wall = np.array([[0.8, 0.0, env.WALL_HALF_SIZE[2]]] + [[5.0 + i, 0.0, 0.25] for i in range(env.config.n_walls - 1)])
    data = forward(env.place_walls(state.data, wall))
    depth, ids = jax.jit(pixels.camera.trace)(data)
    ids = np.asarray(ids)
    robot = {m for m in range(env.mj_model.ngeom) if env.mj_model.geom_group[m] == a1.ROBOT_GROUP}
    assert not robot & set(ids.ravel().tolist())
    assert ids[12, 16] == env.mj_model.geom("wall0").id  # straight ahead: the wall 0.8 m away
    np.testing.assert_allclose(depth[12, 16], 0.8 - 0.05 - (a1.TRUNK_HALF_SIZE[0] + 0.01), atol=0.02)
    assert env.mj_model.geom("platform").id in ids[-1]  # the bottom row: the platform
    rgb = np.asarray(jax.jit(pixels.render)(data))
    assert rgb.shape == (24, 32, 3) and np.all((rgb >= 0) & (rgb <= 1))


def test_task_settings_are_validated_by_the_task_config():
    with pytest.raises(ValueError, match="v_cap") as error:
        envs.check("quadruped-walls", vcap=2.0)
    assert "n_walls" in str(error.value) and "v_cap" in str(error.value)
    with pytest.raises(ValueError, match="n_walls") as error:  # the flat has no walls
        envs.check("quadruped-flat", n_walls=2)
    assert "v_cap" in str(error.value) and "max_geom_pairs" in str(error.value)
    with pytest.raises(ValueError, match="QuadrupedWallsConfig"):
        envs.check("quadruped-walls", QuadrupedConfig())
    with pytest.raises(ValueError, match="v_cap"):
        envs.check("quadruped-walls", v_cap=0.0)
    with pytest.raises(ValueError, match="max_geom_pairs"):
        envs.check("quadruped-walls", max_geom_pairs=0)
    with pytest.raises(ValueError, match="v_cap"):
        envs.check("cheetah-run", v_cap=1.0)  # not a dm_control setting
    with pytest.raises(ValueError, match="QuadrupedConfig"):
        envs.check("quadruped-flat", envs.EnvConfig())
    assert envs.check("quadruped-walls", n_walls=2) == QuadrupedWallsConfig(n_walls=2)
    with pytest.raises(ValueError, match="n_walls"):
        QuadrupedWallsConfig(n_walls=0)
    assert envs.make("quadruped-walls").max_geom_pairs is None
    with pytest.raises(ValueError, match="solver"):
        envs.check("quadruped-flat", solver="pgs")
    for bad in (-1.0, True, "1"):
        with pytest.raises(ValueError, match=r"fall_penalty must be a number >= 0 \(m\)"):
            envs.check("quadruped-walls", fall_penalty=bad)


def test_the_config_defaults_are_the_models_own_solver_settings():
    """The config's solver defaults (what MJX runs) and the MJCF's ``<option>`` (what native
    MuJoCo runs in the parity tests) are written in two places; they must agree."""
    model = mujoco.MjModel.from_xml_string(a1.world_xml())
    config = QuadrupedConfig()
    solvers = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}
    assert (solvers[config.solver], config.solver_iterations, config.ls_iterations) == (
        model.opt.solver,
        model.opt.iterations,
        model.opt.ls_iterations,
    )


@pytest.mark.parametrize("version", [(0, 10, 2), (0, 11, 0), (0, 11, 1)])
def test_max_chunk_size_keeps_the_batched_cholesky_on_its_calling_thread(monkeypatch, version):
    """jaxlib 0.10's LAPACK Cholesky splits a batch over XLA's intra-op pool, and blocks on it,
    from ``batch * (nv**3 // 3) >= 200,000`` (jaxlib/cpu/lapack_kernels.cc,
    GetLapackBatchChunkSize); sharded over 2 devices, 104 quadrupeds per device deadlocked
    XLA:CPU and 64 or 102 did not. The limit is the largest batch below that threshold; the
    open-source jaxlib from 0.11.1 on never splits the batch (no limit). Each version is
    checked whichever jaxlib is installed."""
    import jaxlib.version

    monkeypatch.setattr(jaxlib.version, "__version_info__", version)
    env = envs.make("quadruped-walls")
    cost = env.mj_model.nv**3 // 3
    if version < (0, 11, 1):
        assert env.max_chunk_size * cost < 200_000 <= (env.max_chunk_size + 1) * cost
        assert env.max_chunk_size == 102
    else:
        assert env.max_chunk_size is None


def test_a_fall_penalty_is_taken_once_at_a_fall_and_never_at_the_finish(walls):
    """``fall_penalty`` takes its metres from the reward of the step that falls (off the
    platform's side, the trunk on the ground), not from a step past the far end (the finish),
    a standing step, a step after the fall or a non-finite one; the rest of the state is the
    penalty-free env's."""
    env, reset, step = walls
    penalised = envs.make("quadruped-walls", fall_penalty=2.0)
    step2 = jax.jit(penalised.step)
    state = reset(jax.random.key(2))
    hold = a1.targets_to_action(state.data.qpos[7:])
    off, down = _placed(state, y=1.05), _placed(state, z=0.0)
    finish = _placed(state, x=env.PLATFORM[1] + 0.02)
    for start, taken in ((off, 2.0), (down, 2.0), (finish, 0.0), (state, 0.0)):
        base, after = step(start, hold), step2(start, hold)
        np.testing.assert_allclose(float(after.reward), float(base.reward) - taken, rtol=0, atol=1e-6)
        np.testing.assert_array_equal(after.data.qpos, base.data.qpos)
        assert float(after.done) == float(base.done) == (1.0 if start is not state else 0.0)
    fallen = step2(off, hold)
    assert float(step2(fallen, hold).reward) == 0.0  # once: an ended episode's steps pay nothing
    assert float(step2(state, jnp.full((12,), jnp.nan)).reward) == 0.0  # a bad state is no fall


def test_course_statistics_count_walls_passed_falls_contacts_and_distance(walls, forward):
    """The per-episode course statistics (``QuadrupedWalls.course_metrics``) on states placed
    by hand, and over a push into a wall against native MuJoCo's contacts."""
    env, reset, step = walls
    state = reset(jax.random.key(5))
    assert {name: float(state.metrics[name]) for name in env.episode_metrics} == dict.fromkeys(env.episode_metrics, 0.0)
    metrics = jax.jit(env.course_metrics)
    wall0 = float(env.walls(state.data)[0, 0])
    beyond = wall0 + env.WALL_HALF_SIZE[0] + a1.TRUNK_HALF_SIZE[0]  # the trunk box wholly past wall 0

    def at(x, y=0.0, done=0.0):
        placed = _placed(state, x=x, y=y)
        return placed.replace(data=forward(placed.data), done=jnp.asarray(done, jnp.float32))

    short, past = metrics(state, at(beyond - 0.01)), metrics(state, at(beyond + 0.01))
    assert (float(short["walls_passed"]), float(past["walls_passed"])) == (0.0, 1.0)
    np.testing.assert_allclose(past["distance"], beyond + 0.01, rtol=1e-6)
    # there the rear legs (hips 0.183 m behind the trunk's centre) stand inside wall 0; a metre
    # on, nothing touches
    clear = metrics(state, at(wall0 + 1.0))
    assert (float(past["wall_contacts"]), float(clear["wall_contacts"])) == (1.0, 0.0)
    assert float(clear["walls_passed"]) == 1.0
    assert float(past["fell_off"]) == 0.0 and float(clear["fell_off"]) == 0.0
    # over the side: a fall, and a wall passed off the platform does not count
    side = metrics(state, at(beyond + 0.5, y=1.05))
    assert (float(side["fell_off"]), float(side["walls_passed"])) == (1.0, 0.0)
    # past the far end: the finish, every wall passed on the way (the step before), no fall
    end = metrics(
        at(env.PLATFORM[1] - 0.02).replace(metrics={**state.metrics, "walls_passed": jnp.float32(3.0)}),
        at(env.PLATFORM[1] + 0.02),
    )
    assert (float(end["fell_off"]), float(end["walls_passed"])) == (0.0, 3.0)
    # an ended episode's statistics stay as they were, wherever its (frozen) state says it is
    ended = metrics(at(0.0, done=1.0), at(beyond + 0.5, y=1.05))
    assert {k: float(v) for k, v in ended.items()} == dict.fromkeys(env.episode_metrics, 0.0)

    # walking into wall 1 (placed 0.1 m ahead of the trunk's front) at 1.5 m/s for 40 steps:
    # after each step, whether the robot touches a wall, ours against native MuJoCo's contacts
    # (every wall colliding) at the same state
    walls_now = np.asarray(env.walls(state.data)).copy()
    walls_now[1] = [a1.TRUNK_HALF_SIZE[0] + 0.1 + env.WALL_HALF_SIZE[0], 0.0, env.WALL_HALF_SIZE[2]]
    data0 = forward(env.place_walls(state.data, walls_now).replace(qvel=state.data.qvel.at[0].set(1.5)))
    pushed = state.replace(data=data0)
    hold = jnp.asarray(a1.targets_to_action(a1.HOME_JOINTS), jnp.float32)
    ours, states = [], []
    for _ in range(40):
        pushed = step(pushed, hold)
        ours.append(bool(env.touches_wall(pushed.data)))
        states.append(pushed.data)
    assert float(pushed.metrics["wall_contacts"]) == sum(ours)
    # the push keeps the robot on the wall for several steps
    m = _all_walls_collide(env)
    course.check_touches(ours, m, states, m.geom("wall1").id, at_least=5)
