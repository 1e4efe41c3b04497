"""The A1-class quadruped on MJX: ``quadruped-flat`` (the low level's gym) and ``quadruped-walls``
(a raised platform with walls across the path, seen through a first-person camera).

Both share the machinery of :class:`iap_mjx.envs.dmc.DmControlEnv` (stepping, done mask, bad
states counted in ``metrics["nan_terminations"]``, contact slots and
``metrics["contact_saturated"]``); the model is ours (:mod:`iap_mjx.robots.a1`).

- Action ``(12,)`` in ``[-1, 1]``: each joint's position target, mapped linearly onto the
  joint's range (the servos' ``ctrlrange``); :func:`iap_mjx.robots.a1.targets_to_action` inverts it.
- Observation ``(17,)``: the IMU's roll and pitch (rad), its angular velocity in the trunk
  frame (3, rad/s; the last is the yaw rate), the 12 joint angles (rad).
- Reward: the forward displacement of the trunk per control step, capped,
  ``max(-c, min(x(t) - x(t-1), c))`` with ``c = v_cap * control_timestep`` (the paper's
  ``f``). ``v_cap`` defaults to 1 m/s: about twice the walking speed we aim for (0.5 m/s)
  and a fast trot for a robot of this size, so the reward pays for walking well and nothing
  for lunges and falls forward, which in a 0.02 s step can cover many times that.
- The episode ends early when the trunk touches the ground (its lowest box corner at or below
  the ground) or, on the platform, when the trunk's centre leaves the platform's footprint;
  past the far end that is the finish, anywhere else a fall, which costs ``fall_penalty``
  metres of reward at that step (default 0: only the distance not walked).
- Control step 0.02 s = 5 physics steps of 0.004 s (Playground's MJX quadrupeds). Episodes:
  500 control steps (10 s) on the flat, 1000 (20 s) on the course.
- On the course ``State.metrics`` also keeps the episode's course statistics (walls passed,
  falls off the platform, wall contacts, distance: :meth:`QuadrupedWalls.course_metrics`),
  read at the episode's end (``iap_mjx.es.episode.run_episode``) and logged per iteration
  (``iap_mjx.es.iteration``: ``metrics.csv``'s ``<name>_mean`` and ``eval_<name>`` columns).

Batch size: vmap at most ``max_chunk_size`` (102 for this robot with the pinned jaxlib) envs
together per device (chunk larger populations, ``lax.map``): a larger vmapped batch can
deadlock XLA:CPU on two or more devices (:func:`iap_mjx.envs.dmc.serial_lapack_batch`).
"""

from __future__ import annotations

from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import collision_driver

from iap_mjx.configs.env import QuadrupedConfig, QuadrupedWallsConfig
from iap_mjx.envs.base import State
from iap_mjx.envs.dmc import DmControlEnv
from iap_mjx.robots import a1
from iap_mjx.robots.a1 import action_to_targets


def roll_pitch(quat: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Roll and pitch (rad) of a ``(w, x, y, z)`` unit quaternion (z-y-x Euler angles)."""
    w, x, y, z = quat[0], quat[1], quat[2], quat[3]
    roll = jnp.arctan2(2.0 * (w * x + y * z), 1.0 - 2.0 * (x * x + y * y))
    pitch = jnp.arcsin(jnp.clip(2.0 * (w * y - z * x), -1.0, 1.0))
    return roll, pitch


class QuadrupedFlat(DmControlEnv):
    """Walk forward (+x) on a flat floor. See the module docstring."""

    name = "quadruped-flat"
    domain = None
    n_sub_steps = round(a1.CONTROL_DT / a1.PHYSICS_DT)
    default_max_contacts: ClassVar[int | None] = None  # four foot-floor contacts, every one kept
    default_max_geom_pairs: int | None = None  # None: run every candidate pair
    default_episode_steps = 500
    config_class = QuadrupedConfig
    config: QuadrupedConfig
    #: ``CameraConfig`` settings of the first-person camera (``camera_id`` 0): the world only.
    camera_options: dict[str, Any] = {"geom_groups": (a1.WORLD_GROUP,)}

    def __init__(self, config: QuadrupedConfig | None = None, **overrides: Any):
        super().__init__(config, **overrides)
        model = self.mj_model
        self._quat = self._sensor_address("trunk_quat")
        self._gyro = self._sensor_address("gyro")
        self._joint_pos = self._sensor_address(f"{a1.JOINT_NAMES[0]}_pos")
        self._trunk = self._id(mujoco.mjtObj.mjOBJ_BODY, "trunk")
        self.video_camera_id = self._id(mujoco.mjtObj.mjOBJ_CAMERA, "track")
        corners = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
        self._trunk_corners = (corners * np.asarray(a1.TRUNK_HALF_SIZE)).astype(np.float32)  # (8, 3)
        # The geom pairs of each collision-function group that MJX culls to max_geom_pairs.
        self._culled_pairs: tuple[np.ndarray, ...] = ()
        limit = self.max_geom_pairs
        if limit is not None:
            groups = collision_driver._geom_groups(model)
            self._culled_pairs = tuple(
                np.asarray([(g1, g2) for g1, g2, _ in pairs], np.int32)
                for key, pairs in groups.items()
                if not set(key.types) & collision_driver._GEOM_NO_BROADPHASE and len(pairs) > limit
            )

    @property
    def max_geom_pairs(self) -> int | None:
        """MJX's ``max_geom_pairs`` in force (``None``: no culling)."""
        setting = self.config.max_geom_pairs
        if setting == "all":
            return None
        return setting if isinstance(setting, int) else self.default_max_geom_pairs  # "task"

    def _world_xml(self) -> str:
        return a1.world_xml()

    def _edit_model(self, mj_model: mujoco.MjModel) -> None:
        mj_model.opt.solver = {"newton": mujoco.mjtSolver.mjSOL_NEWTON, "cg": mujoco.mjtSolver.mjSOL_CG}[
            self.config.solver
        ]

    def _model_spec(self) -> mujoco.MjSpec:
        spec = mujoco.MjSpec.from_string(self._world_xml())
        if self.max_geom_pairs is not None:
            # before DmControlEnv adds max_contact_points: MJX reads numeric_data[id]
            spec.add_numeric(name="max_geom_pairs", data=[self.max_geom_pairs])
        return spec

    def _contacts_saturated(self, data: mjx.Data) -> jax.Array:
        """Full contact slots, or a culled group with more pairs whose bounding spheres
        overlap than MJX kept (so a touching pair may have been skipped)."""
        saturated = super()._contacts_saturated(data)
        limit = self.max_geom_pairs
        if limit is None:  # nothing culled
            return saturated
        rbound = jnp.asarray(self.mj_model.geom_rbound, jnp.float32)
        for pairs in self._culled_pairs:
            gap = (
                jnp.linalg.norm(data.geom_xpos[pairs[:, 1]] - data.geom_xpos[pairs[:, 0]], axis=1)
                - rbound[pairs[:, 0]]
                - rbound[pairs[:, 1]]
            )
            saturated = saturated | (jnp.sum(gap <= 0.0) > limit)
        return saturated

    # ---- task hooks ----------------------------------------------------------------------

    def _initial_data(self, key: jax.Array) -> tuple[mjx.Data, dict]:
        joint_key, task_key = jax.random.split(key)
        noise = self.config.joint_noise
        joints = jnp.asarray(a1.HOME_JOINTS) + jax.random.uniform(
            joint_key, (a1.N_JOINTS,), minval=-noise, maxval=noise
        )
        qpos = jnp.concatenate([jnp.array([0.0, 0.0, a1.HOME_HEIGHT, 1.0, 0.0, 0.0, 0.0]), joints])
        data = mjx.make_data(self.mj_model).replace(qpos=qpos, ctrl=joints)
        data = self._place_world(data, task_key)
        return self.forward(data), {}

    def _place_world(self, data: mjx.Data, key: jax.Array) -> mjx.Data:
        """Per-episode placement of the world's movable parts (none on the flat)."""
        del key
        return data

    def step(self, state, action):
        after = super().step(state, action_to_targets(self._checked_action(action)))
        if self.config.fall_penalty:  # 0, the default, leaves the step (and its program) as it was
            after = after.replace(reward=after.reward - self.config.fall_penalty * self.fell(state, after))
        return after

    def fell(self, before, after) -> jax.Array:
        """``()`` float32: 1.0 if the control step ``before -> after`` (two ``State``) ended the
        episode early, the task ending it (:meth:`_terminated`: the trunk on the ground, off the
        platform) anywhere but past the course's end (:meth:`finished`), else 0.0. A step
        that met a non-finite state keeps the state before it, so it is no fall."""
        data = after.data
        ended_here = (before.done == 0) & (after.done > 0)
        return jnp.where(ended_here & self._terminated(data) & ~self.finished(data), 1.0, 0.0)

    def finished(self, data: mjx.Data) -> jax.Array:
        """``()`` bool: the trunk has passed the course's end (never, on the flat)."""
        del data
        return jnp.zeros((), bool)

    def state_observation(self, data: mjx.Data) -> jax.Array:
        s = data.sensordata
        roll, pitch = roll_pitch(s[self._quat : self._quat + 4])
        return jnp.concatenate(
            [
                jnp.stack([roll, pitch]),
                s[self._gyro : self._gyro + 3],
                s[self._joint_pos : self._joint_pos + a1.N_JOINTS],
            ]
        )

    def step_reward(self, before: mjx.Data, after: mjx.Data) -> jax.Array:
        cap = self.config.v_cap * self.control_timestep
        return jnp.clip(after.qpos[0] - before.qpos[0], -cap, cap)

    def trunk_lowest(self, data: mjx.Data) -> jax.Array:
        """Height (m) of the trunk box's lowest corner, ``()``."""
        corners = data.xpos[self._trunk] + jnp.asarray(self._trunk_corners) @ data.xmat[self._trunk].T
        return jnp.min(corners[:, 2])

    def _terminated(self, data: mjx.Data) -> jax.Array:
        return self.trunk_lowest(data) <= 0.0


class QuadrupedCourse(QuadrupedFlat):
    """A course with obstacles: keeps its per-episode statistics in ``State.metrics``, zeros
    at reset, then ``course_metrics(before, after)`` (``()`` float32 each, named by
    ``episode_metrics``) after every control step."""

    episode_metrics: tuple[str, ...] = ()

    def course_metrics(self, before: State, after: State) -> dict[str, jax.Array]:
        """The statistics ``episode_metrics`` names after the control step ``before -> after``."""
        raise NotImplementedError

    def step(self, state: State, action: jax.Array) -> State:
        after = super().step(state, action)
        return after.replace(metrics={**after.metrics, **self.course_metrics(state, after)})

    def _first_state(self, data: mjx.Data, task_info: dict[str, jax.Array]) -> State:
        state = super()._first_state(data, task_info)
        zeros = {name: jnp.zeros((), jnp.float32) for name in self.episode_metrics}
        return state.replace(metrics={**state.metrics, **zeros})

    @staticmethod
    def obstacles_passed(data: mjx.Data, obstacle_x: jax.Array, half_thickness: float) -> jax.Array:
        """``()`` float32: how many obstacles (centres ``(n,)`` along x, ``half_thickness`` m
        each side) the trunk box is wholly beyond (its centre more than the obstacle's and the
        trunk's half-lengths past the obstacle's centre)."""
        beyond = obstacle_x + half_thickness + a1.TRUNK_HALF_SIZE[0]
        return jnp.sum(data.qpos[0] > beyond).astype(jnp.float32)


class QuadrupedWalls(QuadrupedCourse):
    """The course: a raised platform with drop-offs, ``n_walls`` walls across the path.

    The platform spans x in ``[-1, 10]`` m and ``|y| <= 1`` m, its top the ground at z = 0,
    the floor 0.5 m below. Wall ``i`` (1.2 m long, 0.1 m thick, 0.5 m tall) stands at
    ``x = 1.5 + 2.5 i + U(-0.3, 0.3)`` toward a random side of the platform, leaving a gap of
    ``U(0.6, 1.0)`` m between its end and the platform's other edge; the robot starts at the
    origin facing +x, so it must turn to pass each wall. Positions are drawn per episode
    (``mjx.Data.mocap_pos``); shapes never change. The walls are seen; the one that collides
    is ``wall_contact``, kept on the wall nearest the trunk (:meth:`contact_wall_position`), so
    every candidate geom pair can touch and none is culled (``max_geom_pairs`` ``None``).
    """

    name = "quadruped-walls"
    default_max_contacts = 8  # wall contacts (condim 1); the four foot contacts are their own group
    default_episode_steps = 1000
    config_class = QuadrupedWallsConfig
    config: QuadrupedWallsConfig
    PLATFORM = (-1.0, 10.0, 1.0, 0.5)  # x_min, x_max, half-width, drop
    WALL_HALF_SIZE = (0.05, 0.6, 0.25)
    WALL_START, WALL_SPACING, WALL_JITTER = 1.5, 2.5, 0.3
    GAP_RANGE = (0.6, 1.0)
    #: Per-episode course statistics in ``State.metrics`` (:meth:`course_metrics`), read at the
    #: episode's end (``iap_mjx.es.episode.run_episode``).
    episode_metrics = ("walls_passed", "fell_off", "wall_contacts", "distance")

    def _world_xml(self) -> str:
        return a1.world_xml(platform=self.PLATFORM, n_walls=self.config.n_walls, wall_half_size=self.WALL_HALF_SIZE)

    def _place_world(self, data: mjx.Data, key: jax.Array) -> mjx.Data:
        n = self.config.n_walls
        side_key, x_key, gap_key = jax.random.split(key, 3)
        side = jnp.where(jax.random.bernoulli(side_key, 0.5, (n,)), 1.0, -1.0)
        x = (
            self.WALL_START
            + self.WALL_SPACING * jnp.arange(n)
            + jax.random.uniform(x_key, (n,), minval=-self.WALL_JITTER, maxval=self.WALL_JITTER)
        )
        gap = jax.random.uniform(gap_key, (n,), minval=self.GAP_RANGE[0], maxval=self.GAP_RANGE[1])
        half_width, half_length = self.PLATFORM[2], self.WALL_HALF_SIZE[1]
        # the wall spans y +- half_length; `gap` metres remain between its end and the edge
        # of the platform opposite `side`
        y = side * (gap - half_width + half_length)
        z = jnp.full((n,), self.WALL_HALF_SIZE[2])
        return self.place_walls(data, jnp.stack([x, y, z], axis=1))

    def place_walls(self, data: mjx.Data, walls: jax.Array) -> mjx.Data:
        """``data`` with the walls' centres ``(n_walls, 3)`` set and the colliding wall on the
        one nearest the trunk (its position stage is not recomputed)."""
        walls = jnp.asarray(walls, jnp.float32)
        contact = self.contact_wall_position(data.qpos[0], walls)
        return data.replace(mocap_pos=jnp.concatenate([walls, contact[None]], axis=0))

    def contact_wall_position(self, x: jax.Array, walls: jax.Array) -> jax.Array:
        """``(3,)`` where the colliding wall goes: the centre of the wall (of ``walls``,
        ``(n_walls, 3)``) nearest the trunk's ``x`` along x.

        It gives the contacts that every wall colliding would give. No robot geom reaches
        further than ``a1.REACH`` from the trunk's centre (hip at ``(0.183, 0.047)``, thigh
        0.085 m further out, thigh and calf 0.2 m each, foot radius 0.02 m: 0.646 m), so with walls
        0.1 m thick, wall ``i`` can touch the robot only while ``|x - x_i| < 0.7``; walls
        stand at least ``WALL_SPACING - 2 WALL_JITTER`` = 1.9 m apart, so then wall ``i`` is
        the nearest and every other wall is more than 1.2 m away. The env moves the colliding
        wall after every control step (:meth:`_sync_task`), so it lags the trunk by at most
        one control step plus one physics step (0.024 s); the switch happens where the trunk
        is 0.95 m or more from both walls, 0.25 m inside the reach, which covers any trunk
        speed below 10 m/s (the robot's are a few m/s).
        """
        nearest = jnp.argmin(jnp.abs(walls[:, 0] - x))
        return walls[nearest]

    def _sync_task(self, data: mjx.Data, task_info: dict[str, Any]) -> mjx.Data:
        """Moves the colliding wall to the wall nearest the trunk (it collides from the next
        physics step's position stage on)."""
        del task_info
        return self.place_walls(data, self.walls(data))

    def on_platform(self, data: mjx.Data) -> jax.Array:
        """``()`` bool: the trunk's centre is over the platform."""
        x, y = data.qpos[0], data.qpos[1]
        x_min, x_max, half_width, _ = self.PLATFORM
        return (x >= x_min) & (x <= x_max) & (jnp.abs(y) <= half_width)

    def _terminated(self, data: mjx.Data) -> jax.Array:
        return super()._terminated(data) | ~self.on_platform(data)

    def finished(self, data: mjx.Data) -> jax.Array:
        """``()`` bool: the trunk's centre is past the platform's far end (every wall behind it)."""
        return data.qpos[0] > self.PLATFORM[1]

    def walls(self, data: mjx.Data) -> jax.Array:
        """``(n_walls, 3)`` the walls' centres (``mocap_pos``'s last row is the colliding
        wall's)."""
        return data.mocap_pos[: self.config.n_walls]

    # ---- per-episode course statistics ----------------------------------------------------

    def course_metrics(self, before, after) -> dict[str, jax.Array]:
        """The episode's course statistics after the control step ``before -> after`` (two
        ``State``), each ``()`` float32; a step of an ended episode changes none of them.

        - ``walls_passed``: the most walls the trunk box has been wholly beyond
          (:meth:`obstacles_passed`) while its centre was over the platform.
        - ``fell_off``: 1 once the trunk's centre has left the platform's footprint over a
          side or the back (which ends the episode), else 0. Walking off the far end
          (``x > x_max``, past every wall) is the course's finish, not a fall.
        - ``wall_contacts``: control steps at whose end some robot geom touches a wall.
        - ``distance``: the trunk's x (m; it starts at 0), where the episode ended.
        """
        live = before.done == 0
        data, metrics = after.data, before.metrics
        on = self.on_platform(data)
        passed = self.obstacles_passed(data, self.walls(data)[:, 0], self.WALL_HALF_SIZE[0])
        counts = lambda flag: jnp.where(live & flag, 1.0, 0.0)  # noqa: E731
        finished = self.finished(data)
        return {
            "walls_passed": jnp.where(live & on, jnp.maximum(metrics["walls_passed"], passed), metrics["walls_passed"]),
            "fell_off": jnp.maximum(metrics["fell_off"], counts(~on & ~finished)),
            "wall_contacts": metrics["wall_contacts"] + counts(self.touches_wall(data)),
            "distance": jnp.where(live, data.qpos[0], metrics["distance"]),
        }

    def touches_wall(self, data: mjx.Data) -> jax.Array:
        """``()`` bool: a contact of ``data`` (its position stage current) has the colliding
        wall in it at zero or negative distance."""
        contact = data._impl.contact
        wall = self._id(mujoco.mjtObj.mjOBJ_GEOM, "wall_contact")
        return jnp.any(((contact.geom1 == wall) | (contact.geom2 == wall)) & (contact.dist <= 0.0))
