"""``quadruped-gates``: the corridor's model against native MuJoCo, where the gates and clutter
are drawn, the course statistics, the depth observation and the settings' checks.

One compiled step serves every physics check (compiling it is the cost): parity with
``mujoco.mj_step`` from the env's first state, and two pushes into obstacles against native
MuJoCo with every obstacle colliding, run in one test so that xdist's workers do not each
compile it. The tolerances are native MuJoCo's own spread under float32 noise
(``tests/spread.py``), as in ``test_envs_quadruped.py``.
"""

from __future__ import annotations

import copy

import course
import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from iap_mjx import cli, envs
from iap_mjx.envs.pixels import with_pixels
from iap_mjx.envs.quadruped_gates import QuadrupedGates
from iap_mjx.robots import a1

STEPS = 100
PUSH_STEPS = 40
OBSTACLE_GEOMS = ("gate_contact_left", "gate_contact_right", "clutter_contact")


@pytest.fixture(scope="module")
def gates():
    env = envs.make("quadruped-gates")
    return env, jax.jit(env.reset), jax.jit(env.step)


@pytest.fixture(scope="module")
def forward(gates):
    """The env's position stage, compiled once for the module's tests."""
    return jax.jit(gates[0].forward)


def test_corridor_model_collides_feet_with_floor_and_robot_with_the_three_copies():
    env = envs.make("quadruped-gates")
    m = env.mj_model
    from mujoco.mjx._src import collision_driver

    pairs = {frozenset((m.geom(g1).name, m.geom(g2).name)) for g1, g2, _ in collision_driver.geom_pairs(m)}
    robot = {m.geom(g).name for g in range(m.ngeom) if m.geom_group[g] == a1.ROBOT_GROUP}
    assert len(robot) == 13
    expected = {frozenset(("floor", f"{leg}_foot")) for leg in a1.LEGS}
    expected |= {frozenset((copy_name, name)) for copy_name in OBSTACLE_GEOMS for name in robot}
    assert pairs == expected  # the seen gates, clutter and side walls collide with nothing
    # each colliding copy is the shape of what it stands for
    for copy_name, seen in (("gate_contact_left", "gate0_left"), ("gate_contact_right", "gate2_right")):
        np.testing.assert_array_equal(m.geom(copy_name).size, m.geom(seen).size)
    np.testing.assert_array_equal(m.geom("clutter_contact").size, m.geom("clutter1").size)
    assert env.max_geom_pairs is None and env.x_end == 9.0
    # the robot's reach and half-width as the docstrings state them
    assert a1.REACH == pytest.approx(0.646, abs=1e-3) and a1.HALF_WIDTH == pytest.approx(0.154, abs=1e-3)


def test_no_robot_geom_reaches_past_the_reach_in_any_pose():
    """The one-colliding-copy argument of both courses rests on ``a1.REACH``: native MuJoCo's
    kinematics of the model, over joint angles drawn across their ranges (and the knees as
    straight as they go), put no point of a robot geom farther from the trunk's centre."""
    m = envs.make("quadruped-gates").mj_model
    d = mujoco.MjData(m)
    robot = [g for g in range(m.ngeom) if m.geom_group[g] == a1.ROBOT_GROUP]
    rng = np.random.default_rng(0)
    ranges = np.asarray(a1.JOINT_RANGES)
    poses = rng.uniform(ranges[:, 0], ranges[:, 1], (2000, 12))
    poses = np.concatenate([poses, np.tile([[0.0, 0.0, -0.916]], (1, 4))])  # knees as straight as they go
    farthest = 0.0
    for pose in poses:
        d.qpos[:] = 0.0
        d.qpos[3] = 1.0  # identity orientation, trunk at the origin
        d.qpos[7:] = pose
        mujoco.mj_kinematics(m, d)
        for g in robot:
            centre, axis, size = d.geom_xpos[g], d.geom_xmat[g].reshape(3, 3)[:, 2], m.geom_size[g]
            if m.geom_type[g] == mujoco.mjtGeom.mjGEOM_CAPSULE:
                ends = [centre + axis * size[1], centre - axis * size[1]]
                far = max(np.linalg.norm(e) for e in ends) + size[0]
            elif m.geom_type[g] == mujoco.mjtGeom.mjGEOM_SPHERE:
                far = np.linalg.norm(centre) + size[0]
            else:  # the trunk's box
                far = np.linalg.norm(np.abs(centre) + size)
            farthest = max(farthest, far)
    # a bound, not the maximum: it lays thigh and calf in one line, which the knee's range
    # (at most -0.916 rad) does not allow
    assert 0.5 < farthest <= a1.REACH, farthest


def test_gates_and_clutter_are_drawn_per_episode_within_the_corridor(gates):
    env, reset, _ = gates
    states = [reset(jax.random.key(k)) for k in range(12)]
    drawn = np.array([np.asarray(env.gates(s.data)) for s in states])  # (12, n, 2)
    boxes = np.array([np.asarray(env.clutter(s.data)) for s in states])
    n = env.config.n_gates
    assert drawn.shape == boxes.shape == (12, n, 2)
    assert len({tuple(d.round(4).ravel()) for d in drawn}) == 12
    spots = env.GATE_START + env.GATE_SPACING * np.arange(n)
    assert np.all(np.abs(drawn[..., 0] - spots) <= env.GATE_JITTER + 1e-6)
    assert np.all(np.abs(drawn[..., 1]) <= env.OPENING_RANGE + 1e-6)
    assert np.all(np.abs(boxes[..., 0] - spots - env.GATE_SPACING / 2) <= env.CLUTTER_JITTER + 1e-6)
    assert np.all(np.abs(boxes[..., 1]) <= env.CLUTTER_RANGE + 1e-6)
    # the openings' centres spread over their range: not all on one side
    assert drawn[..., 1].min() < -0.2 and drawn[..., 1].max() > 0.2
    # each segment runs from the opening's edge into the side wall, never out of its far face
    half = env.segment_half_size()[1]
    for s, d in zip(states, drawn):
        left = np.asarray(s.data.mocap_pos)[env._left]
        right = np.asarray(s.data.mocap_pos)[env._right]
        np.testing.assert_allclose(left[:, 1] - half, d[:, 1] + env.OPENING / 2, atol=1e-5)
        np.testing.assert_allclose(right[:, 1] + half, d[:, 1] - env.OPENING / 2, atol=1e-5)
        outer = env.HALF_WIDTH + 2 * env.SIDE_WALL_HALF_SIZE[0]
        assert np.all(left[:, 1] + half >= env.HALF_WIDTH + env.SEGMENT_OVERLAP - 1e-5)
        assert np.all(left[:, 1] + half <= outer + 1e-5)
        assert np.all(right[:, 1] - half <= -env.HALF_WIDTH - env.SEGMENT_OVERLAP + 1e-5)
        assert np.all(right[:, 1] - half >= -outer - 1e-5)


def test_openings_are_where_drawn_in_the_model(gates):
    """Native ``mj_ray`` along +x at the gates' mid-height across the corridor: a ray passes gate
    ``i`` exactly where its drawn opening is (seen geoms only, the side walls left out)."""
    env, reset, _ = gates
    state = reset(jax.random.key(7))
    m = env.mj_model
    data = mujoco.MjData(m)
    data.qpos[:] = np.asarray(state.data.qpos)
    data.mocap_pos[:] = np.asarray(state.data.mocap_pos)
    mujoco.mj_forward(m, data)
    drawn = np.asarray(env.gates(state.data))
    gate_ids = {m.geom(f"gate{i}_{side}").id: i for i in range(env.config.n_gates) for side in ("left", "right")}
    groups = np.zeros(6, np.uint8)
    groups[a1.WORLD_GROUP] = 1
    hit = np.zeros(1, np.int32)
    for i, (x, centre) in enumerate(drawn):
        for y in np.linspace(-env.HALF_WIDTH + 0.01, env.HALF_WIDTH - 0.01, 81):
            start = np.array([x - 0.2, y, env.GATE_HEIGHT / 2])
            dist = mujoco.mj_ray(m, data, start, np.array([1.0, 0.0, 0.0]), groups, 1, m.body("trunk").id, hit)
            blocked = dist >= 0 and dist < 0.2 and gate_ids.get(int(hit[0])) == i
            in_opening = abs(y - centre) < env.OPENING / 2
            if abs(abs(y - centre) - env.OPENING / 2) > 1e-3:
                assert blocked != in_opening, (i, y, centre, dist, int(hit[0]))


@pytest.mark.slow
def test_gates_step_native_parity_and_obstacle_contacts(gates, forward):
    """The compiled step against native MuJoCo, three ways (one compile)."""
    _check_parity_with_native_mujoco(*gates)
    _check_pushes_touch_like_every_obstacle_colliding(*gates, forward)


def _follow(env):
    """Moves the colliding obstacle copies to the nearest obstacles, as the env does after each
    step."""

    def follow(data):
        positions = np.asarray(env.contact_positions(data.qpos[0], data.mocap_pos.astype(np.float32)))
        data.mocap_pos[env._contact_rows] = positions

    return follow


def _check_parity_with_native_mujoco(env, reset, step):
    """From the env's first state, the standing pose plus uniform +-0.3 rad as PD targets in MJX
    (float32) and ``mujoco.mj_step`` (float64) on the same compiled model, up to the step where
    the episode ends: these targets walk the robot backwards and sideways until, at step 85 of
    100, its trunk's centre comes within the robot's half-width of the right side wall. Native
    MuJoCo's trajectory must cross that line at the same step (its float32 spread there is
    ~2e-5 m, the crossing 4e-3 m past the line)."""
    state = reset(jax.random.key(0))
    rng = np.random.default_rng(0)
    targets = a1.HOME_JOINTS + rng.uniform(-0.3, 0.3, (STEPS, 12)).astype(np.float32)
    actions = np.asarray(a1.targets_to_action(targets), np.float32)
    start, ours, done = state.data, [], []
    for action in actions:
        state = step(state, jnp.asarray(action))
        ours.append(np.asarray(state.data.qpos))
        done.append(float(state.done))
    live = int(np.argmax(done)) + 1 if max(done) else STEPS  # the steps up to the ending one
    assert live >= 80
    targets = np.asarray(a1.action_to_targets(actions[:live]), np.float64)
    theirs, _ = course.check_against_native(
        env, env.mj_model, start, targets, ours[:live], follow=_follow(env), what="gates qpos"
    )
    inside = np.abs(theirs[:, 1]) <= env.HALF_WIDTH - a1.HALF_WIDTH
    assert inside[:-1].all() and (live == STEPS or not inside[-1])
    assert np.max(np.abs(theirs[:, 0] - theirs[0, 0])) > 0.3  # the robot moved


def every_obstacle_collides(env) -> mujoco.MjModel:
    """The env's model with every seen gate segment and clutter box colliding as its copy does,
    and the copies not colliding: the corridor as native MuJoCo would run it without the env's
    nearest-copy scheme."""
    m = copy.deepcopy(env.mj_model)
    kinds = {"gate_contact_left": "gate{}_left", "gate_contact_right": "gate{}_right", "clutter_contact": "clutter{}"}
    for copy_name, pattern in kinds.items():
        contact = m.geom(copy_name).id
        for i in range(env.config.n_gates):
            seen = m.geom(pattern.format(i)).id
            for field in ("contype", "conaffinity", "condim", "priority"):
                getattr(m, f"geom_{field}")[seen] = getattr(m, f"geom_{field}")[contact]
            m.body_contype[m.geom_bodyid[seen]] = m.geom_contype[contact]  # the broad phase's filter
        m.geom_contype[contact] = m.body_contype[m.geom_bodyid[contact]] = 0
    return m


def _pushed(env, forward, state, gates, clutter):
    """``state`` with the course placed at ``gates``/``clutter`` and the trunk moving at
    1.5 m/s along +x (its position stage computed by ``forward``, the env's compiled position
    stage)."""
    data = env.place_course(state.data, jnp.asarray(gates), jnp.asarray(clutter))
    data = forward(data.replace(qvel=state.data.qvel.at[0].set(1.5)))
    return state.replace(data=data)


def _check_pushes_touch_like_every_obstacle_colliding(env, reset, step, forward):
    """The robot pushed into gate 1's right segment (its opening off to the left), then into
    clutter box 1: MJX (nearest copies) against native MuJoCo with every obstacle colliding,
    40 control steps each. Native must touch the obstacle; the trajectories agree, and after
    every step the env's collision flag is native MuJoCo's at the same state."""
    front = a1.TRUNK_HALF_SIZE[0] + 0.1
    far_gates = [[3.0, 0.0], [5.0, 0.0], [7.0, 0.0]]
    far_clutter = [[4.0, 0.0], [6.0, 0.0], [8.0, 0.0]]
    gate_push = ([far_gates[0], [front + env.GATE_THICKNESS / 2, 0.3], far_gates[2]], far_clutter)
    clutter_push = (far_gates, [far_clutter[0], [front + env.CLUTTER_HALF_SIZE[0], 0.05], far_clutter[2]])
    m = every_obstacle_collides(env)
    touches = course.mjx_touches(m)
    hold = jnp.asarray(a1.targets_to_action(a1.HOME_JOINTS), jnp.float32)
    targets = np.tile(np.asarray(a1.HOME_JOINTS, np.float64), (PUSH_STEPS, 1))
    for (gates, clutter), obstacle in ((gate_push, "gate1_right"), (clutter_push, "clutter1")):
        state = _pushed(env, forward, reset(jax.random.key(4)), gates, clutter)
        copies = np.asarray(state.data.mocap_pos)[env._contact_rows]
        seen = np.asarray(state.data.mocap_pos)[m.body(obstacle).mocapid[0]]
        assert any(np.allclose(c, seen) for c in copies)  # a copy stands on the pushed obstacle
        start, ours, collided, states = state.data, [], [], []
        for _ in range(PUSH_STEPS):
            state = step(state, hold)
            ours.append(np.asarray(state.data.qpos))
            collided.append(bool(env.touches_obstacle(state.data)))
            states.append(state.data)
        _, touched = course.check_against_native(
            env,
            m,
            start,
            targets,
            ours,
            follow=None,
            what=f"pushed into {obstacle}",
            touch_geom=m.geom(obstacle).id,
        )
        assert touched > 0, obstacle
        assert float(state.metrics["collisions"]) == sum(collided) > 0
        course.check_touches(collided, m, states, m.geom(obstacle).id, at_least=1, touches=touches)


def test_course_statistics_on_a_scripted_trajectory(gates, forward):
    """Gates passed, leaving the corridor, falls, contacts and distance, on states placed by
    hand along a path through the corridor (``course_metrics`` step by step)."""
    env, reset, _ = gates
    state = reset(jax.random.key(5))
    assert {name: float(state.metrics[name]) for name in env.episode_metrics} == dict.fromkeys(env.episode_metrics, 0.0)
    course = ([[1.5, 0.2], [4.0, -0.3], [6.5, 0.0]], [[2.75, -0.5], [5.25, 0.5], [7.75, -0.5]])
    state = state.replace(data=env.place_course(state.data, *map(jnp.asarray, course)))
    metrics = jax.jit(env.course_metrics)
    clear = env.GATE_THICKNESS / 2 + a1.TRUNK_HALF_SIZE[0]  # the trunk box wholly past a gate

    def at(x, y=0.0, z=a1.HOME_HEIGHT, done=0.0, metrics_from=None):
        q = state.data.qpos.at[0].set(x).at[1].set(y).at[2].set(z)
        placed = state.replace(data=forward(state.data.replace(qpos=q)), done=jnp.asarray(done, jnp.float32))
        return placed if metrics_from is None else placed.replace(metrics=metrics_from)

    # a scripted walk: through each opening, past each gate, to the finish
    path = [(0.5, 0.0), (1.5 + clear - 0.01, 0.2), (1.5 + clear + 0.01, 0.2), (3.0, 0.0), (4.0 + clear + 0.02, -0.3)]
    path += [(6.5 + clear + 0.02, 0.0), (8.5, 0.0), (env.x_end + 0.02, 0.0)]
    previous, counted = state, []
    for x, y in path:
        now = at(x, y, metrics_from=previous.metrics)
        now = now.replace(metrics={**previous.metrics, **metrics(previous, now)})
        counted.append(float(now.metrics["gates_passed"]))
        previous = now
    assert counted == [0.0, 0.0, 1.0, 1.0, 2.0, 3.0, 3.0, 3.0]
    assert float(previous.metrics["left_corridor"]) == 0.0  # the finish is not a leaving
    assert float(previous.metrics["fell_over"]) == 0.0
    np.testing.assert_allclose(previous.metrics["distance"], env.x_end + 0.02, rtol=1e-6)
    # leaving over a side: within the robot's half-width of the wall; a gate passed there does not count
    side = env.HALF_WIDTH - a1.HALF_WIDTH
    inside, out = metrics(state, at(0.5, y=side - 0.01)), metrics(state, at(1.5 + clear + 0.5, y=side + 0.01))
    assert float(inside["left_corridor"]) == 0.0
    assert (float(out["left_corridor"]), float(out["gates_passed"])) == (1.0, 0.0)
    assert float(metrics(state, at(env.X_START - 0.01))["left_corridor"]) == 1.0  # back past the start
    # falling over: the trunk's bottom on the ground
    assert float(metrics(state, at(0.5, z=a1.TRUNK_HALF_SIZE[2] - 0.001))["fell_over"]) == 1.0
    assert float(metrics(state, at(0.5, z=a1.TRUNK_HALF_SIZE[2] + 0.01))["fell_over"]) == 0.0
    # contacts: the trunk inside gate 0's left segment (y = 0.2 + 0.25 + 0.1), none in the open
    assert float(metrics(state, at(1.5, y=0.55))["collisions"]) == 1.0
    assert float(metrics(state, at(1.5, y=0.2))["collisions"]) == 0.0
    assert float(metrics(state, at(2.75, y=-0.5))["collisions"]) == 1.0  # standing in clutter box 0
    # an ended episode's statistics stay as they were
    ended = metrics(at(0.0, done=1.0), at(1.5 + clear + 0.5, y=1.0, z=0.0))
    assert {k: float(v) for k, v in ended.items()} == dict.fromkeys(env.episode_metrics, 0.0)
    # and the env's own step ends the episode where the statistics say so
    terminated = jax.jit(env._terminated)
    assert bool(terminated(at(0.5, y=side + 0.01).data))
    assert not bool(terminated(at(0.5, y=side - 0.01).data))


def test_depth_observation_is_the_cameras_depth_scaled():
    """``"depth+state"``: ``{"pixels": (24, 32, 1), "state": (17,)}``, the pixels
    ``min(depth, depth_max) / depth_max`` of the camera's depth, at reset and after a step, and
    the depth MuJoCo's ``mj_ray`` measures on a few pixels."""
    env = envs.make("quadruped-gates", obs_mode="depth+state", depth_max=3.0)
    assert env.observation_shape == {"pixels": (24, 32, 1), "state": (17,)} and env.channels == 1
    state = jax.jit(env.reset)(jax.random.PRNGKey(3))
    after = jax.jit(env.step)(state, jnp.asarray(a1.targets_to_action(a1.HOME_JOINTS), jnp.float32))
    trace = jax.jit(env.camera.trace)
    for s in (state, after):
        depth, ids = (np.asarray(a) for a in trace(s.data))
        pixels = np.asarray(s.obs["pixels"])
        assert pixels.shape == (24, 32, 1) and pixels.min() >= 0.0 and pixels.max() <= 1.0
        np.testing.assert_allclose(pixels[..., 0], np.minimum(depth, 3.0) / 3.0, atol=1e-5)
        np.testing.assert_allclose(s.obs["state"], env.state_observation(s.data), rtol=1e-6)
    assert (pixels < 1.0).mean() > 0.3 and (pixels == 1.0).any()  # near walls and the far sky
    # the robot is not in view; the first gate is
    robot = {g for g in range(env.mj_model.ngeom) if env.mj_model.geom_group[g] == a1.ROBOT_GROUP}
    assert not robot & set(ids.ravel().tolist())
    assert any(env.mj_model.geom(f"gate0_{side}").id in ids for side in ("left", "right"))
    # against native mj_ray, the world's geoms only, on every 5th pixel
    m = env.mj_model
    data = mujoco.MjData(m)
    data.qpos[:], data.mocap_pos[:] = np.asarray(after.data.qpos), np.asarray(after.data.mocap_pos)
    mujoco.mj_forward(m, data)
    cam = env.camera.config.camera_id
    dirs = env.camera.ray_directions().reshape(-1, 3).astype(np.float64) @ data.cam_xmat[cam].reshape(3, 3).T
    groups = np.zeros(6, np.uint8)
    groups[a1.WORLD_GROUP] = 1
    hit = np.zeros(1, np.int32)
    flat = pixels.reshape(-1)
    for index in range(0, dirs.shape[0], 5):
        dist = mujoco.mj_ray(m, data, data.cam_xpos[cam], dirs[index], groups, 1, -1, hit)
        expected = 1.0 if dist < 0 else min(dist, 3.0) / 3.0
        assert abs(flat[index] - expected) <= 1e-4, (index, flat[index], expected)


def test_bad_settings_raise_before_compiling(tmp_path, capsys):
    with pytest.raises(ValueError, match="depth_max") as error:
        envs.check("quadruped-gates", obs_mode="pixels+state", depth_max=3.0)
    assert "depth+state" in str(error.value)
    with pytest.raises(ValueError, match="depth_max"):
        envs.check("quadruped-gates", obs_mode="depth+state", depth_max=0.0)
    with pytest.raises(ValueError, match="depth_max"):
        envs.check("quadruped-gates", obs_mode="depth+state", depth_max=float("inf"))
    with pytest.raises(ValueError, match="obs_mode") as error:
        envs.check("quadruped-gates", obs_mode="depth")
    assert "depth+state" in str(error.value) and "pixels+state" in str(error.value)
    with pytest.raises(ValueError, match="n_gates"):
        envs.check("quadruped-gates", n_gates=0)
    with pytest.raises(ValueError, match="n_walls") as error:  # the walls course's setting
        envs.check("quadruped-gates", n_walls=2)
    assert "n_gates" in str(error.value) and "depth_max" in str(error.value)
    with pytest.raises(ValueError, match="n_gates"):
        envs.check("quadruped-walls", n_gates=2)
    # from the command line: refused before anything compiles, naming the setting
    for bad in (["env.depth_max=-1"], ["env.obs_mode=pixels+state", "env.depth_max=3"]):
        argv = ["train", "quadruped-gates-iap", *bad, "--no-progress", "--run-dir", str(tmp_path / "run")]
        assert cli.main(argv) == 2
        assert "depth_max" in capsys.readouterr().err
    with pytest.raises(ValueError, match="depth_max"):  # the wrapper checks too
        with_pixels(QuadrupedGates(), obs_mode="pixels", depth_max=2.0)
    assert envs.check("quadruped-gates", obs_mode="depth+state", depth_max=2.5).depth_max == 2.5
