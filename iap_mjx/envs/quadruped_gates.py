"""``quadruped-gates``: the A1-class quadruped in a corridor of narrow gates and clutter, a
procedural stand-in for the paper's Figure 9 (navigating Gibson scans with a front depth camera;
those scans cannot be redistributed).

The corridor (numbers for the default ``n_gates`` = 3):

- The floor is the ground (z = 0). Two side walls (1 m thick, 0.6 m tall; seen, not collided)
  leave a corridor of inner half-width ``HALF_WIDTH`` = 0.8 m from ``x = -1`` to
  ``x_end = GATE_START + GATE_SPACING n_gates`` = 9 m. The robot starts at the origin facing +x.
- Gate ``i`` is a wall across the corridor (0.1 m thick, 0.5 m tall: taller than the robot and
  its camera, so what lies behind it is seen through the opening only) at
  ``x = 1.5 + 2.5 i + U(-0.3, 0.3)``, with one opening ``OPENING`` = 0.5 m wide centred at
  ``y = U(-0.45, 0.45)``. The robot is 0.30 m wide at its feet (feet at ``y = +-0.132``, radius
  0.02; the trot keeps abduction at 0) and 0.41 m long from hip to hip plus feet, so 0.5 m lets
  it through square-on with 0.1 m each side for the trot's sway, and at up to about 25 degrees
  of heading (``0.30 cos a + 0.45 sin a <= 0.5``): narrow enough that crossing needs aiming, wide
  enough that a trot can. A robot walking straight down the middle meets the gate unless the
  opening's centre lies within about 0.1 m of the centre line (a fifth of the draws).
- One clutter column per gate (0.3 x 0.3 m, 0.4 m tall: medium, between the trunk's top at
  0.33 m and the gates' 0.5 m, so it crosses the camera's horizon at 0.29 m and cannot be stepped
  or climbed over) at ``x = 1.5 + 2.5 (i + 0.5) + U(-0.2, 0.2)``, midway to the next gate, and
  ``y = U(-0.55, 0.55)``: at least 0.55 m of floor before and after it along x, and 1.2 m of
  corridor beside it. Not lower: a box below the trunk's top lets the trunk's box strike its
  top edge, where MJX's box-box contact parts from native MuJoCo's (the column's side contact
  agrees with it), and a kerb below the trunk's bottom
  would offer its frictionless top (obstacles are ``condim`` 1) as a floor to slip on.
- Each gate is two fixed boxes, the segments left and right of the opening; each segment is
  1.1 m long, so that wherever the opening is drawn its outer end lies inside the side wall
  (``SEGMENT_OVERLAP`` = 0.1 m at least, hidden at most up to the wall's outer face).
  Positions are drawn per episode (``mjx.Data.mocap_pos``); shapes never change.

Contacts stay as cheap as on ``quadruped-walls``: the gates and clutter seen do not collide;
three invisible copies do, ``gate_contact_left``/``_right`` on the nearest gate's two segments
and ``clutter_contact`` on the nearest clutter box, moved after every control step
(:meth:`QuadrupedGates.contact_positions`, which says why that gives every contact all
obstacles colliding would). 39 candidate pairs (3 boxes x 13 robot geoms) where every obstacle
colliding would be 117.

The episode ends when the trunk touches the ground (as on the flat), when the trunk's centre
comes within the robot's half-width (0.154 m: hip 0.047, thigh 0.085, thigh radius 0.022) of
a side wall or goes back past the corridor's start (it leaves the corridor), or when it goes
past the corridor's end (the finish). Reward: the capped forward displacement (the flat's).
``State.metrics`` keeps the episode's gates passed, obstacle contacts, whether it left the
corridor or fell over, and the distance (:meth:`QuadrupedGates.course_metrics`), which training
logs per iteration as it logs the walls course's.

The high level sees the first-person camera's depth (``obs_mode="depth+state"``,
``iap_mjx.envs.pixels``): 24x32 by default, world geoms only.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx

from iap_mjx.configs.env import QuadrupedGatesConfig
from iap_mjx.envs.quadruped import QuadrupedCourse
from iap_mjx.robots import a1


class QuadrupedGates(QuadrupedCourse):
    """The gates corridor (module docstring): ``n_gates`` gates, each followed by a clutter box."""

    name = "quadruped-gates"
    # obstacle contacts (condim 1), their own group: the robot can touch both segments of an
    # opening and a clutter box at once
    default_max_contacts = 12
    default_episode_steps = 1000
    config_class = QuadrupedGatesConfig
    config: QuadrupedGatesConfig
    X_START, HALF_WIDTH = -1.0, 0.8
    SIDE_WALL_HALF_SIZE = (0.5, 0.3)  # half-thickness, half-height
    GATE_START, GATE_SPACING, GATE_JITTER = 1.5, 2.5, 0.3
    OPENING, OPENING_RANGE = 0.5, 0.45  # width; the centre's |y| bound
    GATE_THICKNESS, GATE_HEIGHT = 0.1, 0.5
    SEGMENT_OVERLAP = 0.1  # how far a segment reaches into the side wall, at least
    CLUTTER_HALF_SIZE = (0.15, 0.15, 0.2)
    CLUTTER_JITTER, CLUTTER_RANGE = 0.2, 0.55
    #: Per-episode course statistics in ``State.metrics`` (:meth:`course_metrics`).
    episode_metrics = ("gates_passed", "collisions", "left_corridor", "fell_over", "distance")

    def __init__(self, config: QuadrupedGatesConfig | None = None, **overrides: Any):
        super().__init__(config, **overrides)
        mocap = lambda name: int(self.mj_model.body_mocapid[self._id(mujoco.mjtObj.mjOBJ_BODY, name)])  # noqa: E731
        n = self.config.n_gates
        self._left = np.array([mocap(f"gate{i}_left") for i in range(n)])
        self._right = np.array([mocap(f"gate{i}_right") for i in range(n)])
        self._clutter = np.array([mocap(f"clutter{i}") for i in range(n)])
        self._contact_rows = np.array(
            [mocap(f"gate_contact_{side}") for side in ("left", "right")] + [mocap("clutter_contact")]
        )
        self._contact_geoms = np.array(
            [
                self._id(mujoco.mjtObj.mjOBJ_GEOM, name)
                for name in ("gate_contact_left", "gate_contact_right", "clutter_contact")
            ]
        )

    @classmethod
    def segment_half_size(cls) -> tuple[float, float, float]:
        """Half-size of a gate segment: long enough to reach ``SEGMENT_OVERLAP`` into the side
        wall from the opening's edge wherever the opening is drawn."""
        length = cls.HALF_WIDTH + cls.OPENING_RANGE - cls.OPENING / 2 + cls.SEGMENT_OVERLAP
        return (cls.GATE_THICKNESS / 2, length / 2, cls.GATE_HEIGHT / 2)

    @property
    def x_end(self) -> float:
        """The corridor's far end along x (m): the finish."""
        return self.GATE_START + self.GATE_SPACING * self.config.n_gates

    def _world_xml(self) -> str:
        return a1.corridor_xml(
            x_range=(self.X_START, self.x_end),
            half_width=self.HALF_WIDTH,
            side_wall_half_size=self.SIDE_WALL_HALF_SIZE,
            n_gates=self.config.n_gates,
            gate_half_size=self.segment_half_size(),
            n_clutter=self.config.n_gates,
            clutter_half_size=self.CLUTTER_HALF_SIZE,
        )

    # ---- per-episode placement ----------------------------------------------------------

    def _place_world(self, data: mjx.Data, key: jax.Array) -> mjx.Data:
        n = self.config.n_gates
        gate_key, opening_key, clutter_x_key, clutter_y_key = jax.random.split(key, 4)
        uniform = lambda k, bound: jax.random.uniform(k, (n,), minval=-bound, maxval=bound)  # noqa: E731
        spots = self.GATE_START + self.GATE_SPACING * jnp.arange(n)
        gates = jnp.stack([spots + uniform(gate_key, self.GATE_JITTER), uniform(opening_key, self.OPENING_RANGE)], 1)
        clutter = jnp.stack(
            [
                spots + self.GATE_SPACING / 2 + uniform(clutter_x_key, self.CLUTTER_JITTER),
                uniform(clutter_y_key, self.CLUTTER_RANGE),
            ],
            1,
        )
        return self.place_course(data, gates, clutter)

    def place_course(self, data: mjx.Data, gates: jax.Array, clutter: jax.Array) -> mjx.Data:
        """``data`` with the course set: ``gates`` ``(n_gates, 2)`` each gate's ``(x, y of its
        opening's centre)``, ``clutter`` ``(n_gates, 2)`` each box's ``(x, y)``; the colliding
        copies on the nearest gate and box (their position stage is not recomputed)."""
        gates, clutter = jnp.asarray(gates, jnp.float32), jnp.asarray(clutter, jnp.float32)
        _, segment_half_length, gate_half_height = self.segment_half_size()
        offset = self.OPENING / 2 + segment_half_length  # from the opening's centre to a segment's
        column = lambda values: jnp.broadcast_to(jnp.float32(values), gates[:, :1].shape)  # noqa: E731
        left = jnp.concatenate([gates[:, :1], gates[:, 1:] + offset, column(gate_half_height)], 1)
        right = jnp.concatenate([gates[:, :1], gates[:, 1:] - offset, column(gate_half_height)], 1)
        boxes = jnp.concatenate([clutter, column(self.CLUTTER_HALF_SIZE[2])], 1)
        mocap = data.mocap_pos.at[self._left].set(left).at[self._right].set(right).at[self._clutter].set(boxes)
        return self._with_contacts(data.replace(mocap_pos=mocap))

    def _with_contacts(self, data: mjx.Data) -> mjx.Data:
        contacts = self.contact_positions(data.qpos[0], data.mocap_pos)
        return data.replace(mocap_pos=data.mocap_pos.at[self._contact_rows].set(contacts))

    def contact_positions(self, x: jax.Array, mocap_pos: jax.Array) -> jax.Array:
        """``(3, 3)``: where the colliding copies go, the left and right segments of the gate
        nearest the trunk's ``x`` along x, and the clutter box nearest it.

        They give the contacts every obstacle colliding would give (the walls course's
        argument, ``QuadrupedWalls.contact_wall_position``, per kind). No robot geom reaches
        further than ``a1.REACH`` (0.646 m) from the trunk's centre, so a gate (0.1 m thick)
        can touch the robot only while ``|x - x_gate| < 0.7`` and a clutter box (0.3 m deep)
        only while ``|x - x_box| < 0.8``. Gates stand at least ``2.5 - 2 * 0.3`` = 1.9 m apart
        and boxes at least ``2.5 - 2 * 0.2`` = 2.1 m apart, so while one of a kind can touch it
        is the nearest of its kind, and the copy switches where the trunk is at least 0.95 m
        (gates) or 1.05 m (boxes) from both neighbours: 0.25 m beyond the reach of either.
        The copies lag the trunk by at most one control step plus a physics step (0.024 s),
        so this holds below 10 m/s. Both segments of a gate share its x, so they move
        together: the robot in an opening touches whichever side it leans on.
        """
        gate_x = mocap_pos[self._left, 0]
        box_x = mocap_pos[self._clutter, 0]
        gate = jnp.argmin(jnp.abs(gate_x - x))
        box = jnp.argmin(jnp.abs(box_x - x))
        return jnp.stack([mocap_pos[self._left][gate], mocap_pos[self._right][gate], mocap_pos[self._clutter][box]])

    def _sync_task(self, data: mjx.Data, task_info: dict[str, Any]) -> mjx.Data:
        """Moves the colliding copies to the nearest gate and clutter box (they collide from the
        next physics step's position stage on)."""
        del task_info
        return self._with_contacts(data)

    def gates(self, data: mjx.Data) -> jax.Array:
        """``(n_gates, 2)``: each gate's x and its opening's centre y (as :meth:`place_course`
        takes them)."""
        _, segment_half_length, _ = self.segment_half_size()
        left = data.mocap_pos[self._left]
        return jnp.stack([left[:, 0], left[:, 1] - self.OPENING / 2 - segment_half_length], 1)

    def clutter(self, data: mjx.Data) -> jax.Array:
        """``(n_gates, 2)``: each clutter box's ``(x, y)``."""
        return data.mocap_pos[self._clutter, :2]

    # ---- the episode's end --------------------------------------------------------------

    def in_corridor(self, data: mjx.Data) -> jax.Array:
        """``()`` bool: the trunk's centre is far enough inside for the robot to clear the side
        walls (``a1.HALF_WIDTH`` from them), not behind the start, not past the end."""
        x, y = data.qpos[0], data.qpos[1]
        return (x >= self.X_START) & (x <= self.x_end) & (jnp.abs(y) <= self.HALF_WIDTH - a1.HALF_WIDTH)

    def finished(self, data: mjx.Data) -> jax.Array:
        """``()`` bool: the trunk's centre is past the corridor's end (every gate behind it)."""
        return data.qpos[0] > self.x_end

    def _terminated(self, data: mjx.Data) -> jax.Array:
        return super()._terminated(data) | ~self.in_corridor(data)

    # ---- per-episode course statistics ---------------------------------------------------

    def course_metrics(self, before, after) -> dict[str, jax.Array]:
        """The episode's course statistics after the control step ``before -> after`` (two
        ``State``), each ``()`` float32; a step of an ended episode changes none of them.

        - ``gates_passed``: the most gates the trunk box has been wholly beyond
          (``obstacles_passed``) while in the corridor or at its finish.
        - ``collisions``: control steps at whose end some robot geom touches a gate or a
          clutter box.
        - ``left_corridor``: 1 once the trunk's centre has come within the robot's half-width
          of a side wall or gone back past the start (which ends the episode), else 0.
          Going past the far end is the finish, not a leaving.
        - ``fell_over``: 1 once the trunk has touched the ground (which ends the episode).
        - ``distance``: the trunk's x (m; it starts at 0), where the episode ended.
        """
        live = before.done == 0
        data, metrics = after.data, before.metrics
        counts = lambda flag: jnp.where(live & flag, 1.0, 0.0)  # noqa: E731
        finished = self.finished(data)
        inside = self.in_corridor(data) | finished
        passed = self.obstacles_passed(data, self.gates(data)[:, 0], self.GATE_THICKNESS / 2)
        return {
            "gates_passed": jnp.where(
                live & inside, jnp.maximum(metrics["gates_passed"], passed), metrics["gates_passed"]
            ),
            "collisions": metrics["collisions"] + counts(self.touches_obstacle(data)),
            "left_corridor": jnp.maximum(metrics["left_corridor"], counts(~inside)),
            "fell_over": jnp.maximum(metrics["fell_over"], counts(self.trunk_lowest(data) <= 0.0)),
            "distance": jnp.where(live, data.qpos[0], metrics["distance"]),
        }

    def touches_obstacle(self, data: mjx.Data) -> jax.Array:
        """``()`` bool: a contact of ``data`` (its position stage current) has a colliding copy
        (a gate segment or the clutter box) in it at zero or negative distance."""
        contact = data._impl.contact
        geoms = jnp.asarray(self._contact_geoms)
        involved = jnp.isin(contact.geom1, geoms) | jnp.isin(contact.geom2, geoms)
        return jnp.any(involved & (contact.dist <= 0.0))
