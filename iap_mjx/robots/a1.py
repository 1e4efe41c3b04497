"""An A1-class quadruped and its worlds as MJCF, written from the robot's published figures.

Primitives only (box trunk, capsule thighs and calves, sphere feet), so MJX collides them fast
and the ray-cast camera draws them; nothing is read from disk or downloaded. The figures are
the Unitree A1's as MuJoCo Menagerie's ``unitree_a1`` model (BSD-3) describes it: trunk 4.713 kg,
hips 0.696 kg, thighs 1.013 kg, calves 0.226 kg (12.45 kg in all), hips at
``(+-0.183, +-0.047, 0)``, thighs ``0.08505`` m further out, 0.2 m thighs and calves, 0.02 m
feet; joint ranges and the standing pose below. Inertias other than the trunk's are ours: each link's mass spread as a uniform
rod (thigh, calf) or solid sphere (hip) of the link's size, about its centre of mass.

Legs are ordered FR, FL, RR, RL (front/rear, right/left) and each has (abduction, thigh, knee)
joints, so joint ``3 * leg + j``; ``qpos`` is the trunk's free joint (7) then the 12 joints.

Contacts (``contype``/``conaffinity`` bits; no self-collision, bit 0 ground, bit 1 walls):
feet touch the ground (floor plane or platform box) and walls; trunk, thighs and calves touch
walls only. Walls are frictionless (``condim`` 1, taking precedence by ``priority``), so their
contacts form a contact group of their own that a slot limit can bound without ever dropping
a foot's contact (``condim`` 3, the foot-ground group). The trunk touching the ground is
detected geometrically by the env (it ends the episode), not simulated.

The walls the camera sees do not collide. One more wall, ``wall_contact`` (invisible, group
``CONTACT_GROUP``, alpha 0), does: the env puts it on the wall nearest the trunk along x after
every control step (:meth:`iap_mjx.envs.quadruped.QuadrupedWalls.contact_wall_position`).
MJX collides every candidate pair at every step, however far apart (native MuJoCo's broad
phase skips them), and with three colliding walls two thirds of the wall pairs could never
touch; one colliding wall gives the same contacts at a third of the collision cost (the
argument, with the course's distances, is in that method's docstring). The gates corridor
(:func:`corridor_xml`) does the same per kind of obstacle: one colliding copy of each gate
segment and one of a clutter box (:meth:`iap_mjx.envs.quadruped_gates.QuadrupedGates.contact_positions`).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

LEGS = ("FR", "FL", "RR", "RL")
JOINTS_PER_LEG = ("abduction", "thigh", "knee")
JOINT_NAMES = tuple(f"{leg}_{joint}" for leg in LEGS for joint in JOINTS_PER_LEG)
N_JOINTS = len(JOINT_NAMES)  # 12: the actions, and the joint angles of the state

# The standing ("home") pose: trunk height and each leg's (abduction, thigh, knee).
HOME_HEIGHT = 0.27
HOME_LEG = (0.0, 0.9, -1.8)
HOME_JOINTS = np.tile(np.asarray(HOME_LEG, np.float32), 4)
HOME_JOINTS.setflags(write=False)  # a module constant: read-only, so no caller changes it for all

# Joint ranges (rad) per leg joint, and the same for all 12 joints, (12, 2).
LEG_RANGES = ((-0.803, 0.803), (-1.047, 4.189), (-2.697, -0.916))
JOINT_RANGES = np.tile(np.asarray(LEG_RANGES, np.float32), (4, 1))
JOINT_RANGES.setflags(write=False)

TRUNK_HALF_SIZE = (0.125, 0.04, 0.057)
TRUNK_MASS = 4.713
TRUNK_INERTIA = (0.0159, 0.0378, 0.0457)
HIP_OFFSET = (0.183, 0.047)
HIP_MASS, HIP_RADIUS = 0.696, 0.046
THIGH_OFFSET = 0.08505
LINK_LENGTH = 0.2
THIGH_MASS, THIGH_RADIUS = 1.013, 0.022
CALF_MASS, CALF_RADIUS = 0.226, 0.013
FOOT_RADIUS = 0.02
FOOT_FRICTION = 0.8  # sliding, Menagerie's foot (its torsional and rolling 0.02 and 0.01 too)
FRICTION = f"{FOOT_FRICTION:g} 0.02 0.01"  # MJCF friction: sliding, torsional, rolling

# The robot's half-width (m; 0.154): hip offset, thigh offset and thigh radius sideways.
HALF_WIDTH = HIP_OFFSET[1] + THIGH_OFFSET + THIGH_RADIUS
# A bound on how far any robot geom reaches from the trunk's centre (m; 0.646): the hip's and
# the thigh's offsets, thigh and calf laid in one line, the foot's radius. The courses' one-
# colliding-copy argument rests on it (``QuadrupedWalls.contact_wall_position``).
REACH = float(np.hypot(HIP_OFFSET[0], HIP_OFFSET[1] + THIGH_OFFSET)) + 2 * LINK_LENGTH + FOOT_RADIUS

# Position servos: kp (N m / rad) with the torque limit; joint damping (N m s / rad) acts as
# the servo's kd, implicitly under the Euler integrator; armature as the motors' rotor. Kp, the
# limit and the armature are Menagerie's; its damping is 1 at the abduction joints and 2 at
# thigh and knee, ours 1 at all twelve (and no frictionloss, Menagerie's 0.2).
KP = 100.0
TORQUE_LIMIT = 33.5
JOINT_DAMPING = 1.0
ARMATURE = 0.01

PHYSICS_DT = 0.004
CONTROL_DT = 0.02

# The constraint solver (MuJoCo's ``opt.solver``, ``opt.iterations``, ``opt.ls_iterations``):
# the smallest budget whose trajectories match native MuJoCo at its defaults as closely as
# those defaults in float32 do; smaller budgets leave the contact solve unconverged (the solver
# sweep in BENCHMARKS.md, section physics-quadruped: `python benchmarks/physics.py --quadruped
# --parts sweep`).
SOLVER = "newton"
ITERATIONS = 8
LS_ITERATIONS = 4
_MJCF_SOLVER = {"newton": "Newton", "cg": "CG"}

GROUND_BIT, WALL_BIT = 1, 2
# geom groups: the first-person camera draws the world only; nothing draws the contact wall
ROBOT_GROUP, WORLD_GROUP, CONTACT_GROUP = 1, 0, 3
WALL_RGB, CLUTTER_RGB = "0.75 0.2 0.2", "0.2 0.35 0.75"


def targets_to_action(targets: jax.Array) -> jax.Array:
    """Joint position targets ``(..., 12)`` in rad -> the envs' action in ``[-1, 1]`` (each
    joint's range mapped linearly onto ``[-1, 1]``)."""
    lo, hi = JOINT_RANGES[:, 0], JOINT_RANGES[:, 1]
    return 2.0 * (targets - lo) / (hi - lo) - 1.0


def action_to_targets(action: jax.Array) -> jax.Array:
    """The envs' action ``(..., 12)`` (clipped to ``[-1, 1]``) -> joint position targets in rad."""
    lo, hi = JOINT_RANGES[:, 0], JOINT_RANGES[:, 1]
    return jnp.add(lo, (jnp.clip(action, -1.0, 1.0) + 1.0) * 0.5 * (hi - lo))


def _rod_inertia(mass: float, length: float, radius: float) -> str:
    across = mass * (3 * radius**2 + length**2) / 12
    along = mass * radius**2 / 2
    return f"{across:.6g} {across:.6g} {along:.6g}"


def _leg(leg: str) -> str:
    front = leg[0] == "F"
    right = leg[1] == "R"
    x = HIP_OFFSET[0] if front else -HIP_OFFSET[0]
    y = -HIP_OFFSET[1] if right else HIP_OFFSET[1]
    side = -THIGH_OFFSET if right else THIGH_OFFSET
    hip_inertia = 0.4 * HIP_MASS * HIP_RADIUS**2
    ranges = {name: f"{lo:g} {hi:g}" for name, (lo, hi) in zip(JOINTS_PER_LEG, LEG_RANGES)}
    half = LINK_LENGTH / 2
    return f"""
      <body name="{leg}_hip" pos="{x:g} {y:g} 0">
        <inertial pos="0 0 0" mass="{HIP_MASS:g}" diaginertia="{hip_inertia:.6g} {hip_inertia:.6g} {hip_inertia:.6g}"/>
        <joint name="{leg}_abduction" axis="1 0 0" range="{ranges["abduction"]}"/>
        <body name="{leg}_thigh" pos="0 {side:g} 0">
          <inertial pos="0 0 {-half:g}" mass="{THIGH_MASS:g}" diaginertia="{_rod_inertia(THIGH_MASS, LINK_LENGTH, THIGH_RADIUS)}"/>
          <joint name="{leg}_thigh" axis="0 1 0" range="{ranges["thigh"]}"/>
          <geom name="{leg}_thigh" class="limb" size="{THIGH_RADIUS:g}" fromto="0 0 0 0 0 {-LINK_LENGTH:g}"/>
          <body name="{leg}_calf" pos="0 0 {-LINK_LENGTH:g}">
            <inertial pos="0 0 {-half:g}" mass="{CALF_MASS:g}" diaginertia="{_rod_inertia(CALF_MASS, LINK_LENGTH, CALF_RADIUS)}"/>
            <joint name="{leg}_knee" axis="0 1 0" range="{ranges["knee"]}"/>
            <geom name="{leg}_calf" class="limb" size="{CALF_RADIUS:g}" fromto="0 0 0 0 0 {-LINK_LENGTH:g}"/>
            <geom name="{leg}_foot" class="foot" pos="0 0 {-LINK_LENGTH:g}"/>
          </body>
        </body>
      </body>"""


TRACK_CAMERA = 'pos="-0.6 -1.6 0.7" xyaxes="0.94 -0.34 0 0.12 0.34 0.93" fovy="50"'
"""The ``track`` camera (videos and strips; no policy sees it): its offset from the robot's
centre of mass and its world-fixed orientation (``mode="trackcom"``), behind the robot on its
right and above it, the platform's edge and the walls ahead in view."""
CORRIDOR_TRACK_CAMERA = 'pos="-1.8 -0.2 1.3" xyaxes="0.06 -1 0 0.38 0.02 0.93" fovy="55"'
"""The ``track`` camera in the gates corridor: behind the robot and high, looking down the
corridor over the robot to the gate ahead; from the side, as :data:`TRACK_CAMERA` sits, the
corridor's side wall would hide the robot and the gates."""


def robot_xml(track_camera: str = TRACK_CAMERA) -> tuple[str, str, str, str]:
    """The robot's ``<default>``, ``<body>`` (named ``trunk``, free joint; its ``track`` camera
    placed by ``track_camera``, MJCF attributes), actuators and sensors, as MJCF fragments to
    splice into a world (see :func:`world_xml`)."""
    sx, sy, sz = TRUNK_HALF_SIZE
    ix, iy, iz = TRUNK_INERTIA
    defaults = f"""
    <default class="robot">
      <joint damping="{JOINT_DAMPING:g}" armature="{ARMATURE:g}"/>
      <position kp="{KP:g}" forcerange="{-TORQUE_LIMIT:g} {TORQUE_LIMIT:g}"/>
      <geom group="{ROBOT_GROUP}" contype="0" conaffinity="{WALL_BIT}" condim="1" rgba="0.25 0.27 0.3 1"/>
      <default class="limb"><geom type="capsule"/></default>
      <default class="foot">
        <geom type="sphere" size="{FOOT_RADIUS:g}" conaffinity="{GROUND_BIT | WALL_BIT}" condim="3"
              friction="{FRICTION}" rgba="0.1 0.1 0.1 1"/>
      </default>
    </default>"""
    body = f"""
    <body name="trunk" pos="0 0 {HOME_HEIGHT:g}" childclass="robot">
      <freejoint name="root"/>
      <inertial pos="0 0 0" mass="{TRUNK_MASS:g}" diaginertia="{ix:g} {iy:g} {iz:g}"/>
      <geom name="trunk" type="box" size="{sx:g} {sy:g} {sz:g}" rgba="0.85 0.55 0.15 1"/>
      <site name="imu" pos="0 0 0"/>
      <camera name="eye" pos="{sx + 0.01:g} 0 0.02" xyaxes="0 -1 0 0 0 1" fovy="70"/>
      <camera name="track" mode="trackcom" {track_camera}/>
      {"".join(_leg(leg) for leg in LEGS)}
    </body>"""
    actuators = "\n".join(
        f'    <position class="robot" name="{name}" joint="{name}" ctrlrange="{lo:g} {hi:g}"/>'
        for name, (lo, hi) in zip(JOINT_NAMES, JOINT_RANGES)
    )
    sensors = "\n".join(
        [
            '    <framequat name="trunk_quat" objtype="body" objname="trunk"/>',
            '    <gyro name="gyro" site="imu"/>',
            '    <framelinvel name="trunk_linvel" objtype="body" objname="trunk"/>',
        ]
        + [f'    <jointpos name="{name}_pos" joint="{name}"/>' for name in JOINT_NAMES]
    )
    return defaults, body, actuators, sensors


def world_xml(
    *,
    platform: tuple[float, float, float, float] | None = None,
    n_walls: int = 0,
    wall_half_size: tuple[float, float, float] = (0.05, 0.6, 0.25),
) -> str:
    """A whole model: the robot on a floor, optionally on a raised platform with walls.

    Args:
      platform: ``None`` (the floor plane is the ground, at z = 0) or ``(x_min, x_max,
        half_width, drop)``: a box whose top is the ground at z = 0, spanning
        ``x_min..x_max`` and ``|y| <= half_width``, with the floor ``drop`` metres below it
        (the floor is then scenery: nothing collides with it).
      n_walls: boxes of half-size ``wall_half_size`` standing on the platform; each is a
        mocap body (``wall0``, ``wall1``, ...), so an env places them per episode through
        ``mjx.Data.mocap_pos`` without changing any array shape. They are seen, not
        collided: with walls, a last mocap body ``wall_contact`` (the same box, invisible)
        is the one wall that collides (module docstring).
    """
    if platform is None:
        floor_z, floor_bits = 0.0, (GROUND_BIT, 0)
        ground = ""
    else:
        x_min, x_max, half_width, drop = platform
        floor_z, floor_bits = -drop, (0, 0)
        ground = (
            f'    <geom name="platform" type="box" pos="{(x_min + x_max) / 2:g} 0 {-drop / 2:g}" '
            f'size="{(x_max - x_min) / 2:g} {half_width:g} {drop / 2:g}" contype="{GROUND_BIT}" '
            f'conaffinity="0" condim="3" friction="{FRICTION}" '
            f'group="{WORLD_GROUP}" rgba="0.55 0.57 0.6 1"/>'
        )
    walls = "\n".join(
        _mocap_box(f"wall{i}", (2.0 * (i + 1), 0.0, wall_half_size[2]), wall_half_size, WALL_RGB)
        for i in range(n_walls)
    )
    if n_walls:
        walls += "\n" + _mocap_box(
            "wall_contact", (2.0, 0.0, wall_half_size[2]), wall_half_size, WALL_RGB, colliding=True
        )
    return _model_xml(floor_z, floor_bits, f"{ground}\n{walls}")


def corridor_xml(
    *,
    x_range: tuple[float, float],
    half_width: float,
    side_wall_half_size: tuple[float, float],
    n_gates: int,
    gate_half_size: tuple[float, float, float],
    n_clutter: int,
    clutter_half_size: tuple[float, float, float],
) -> str:
    """A whole model: the robot on the floor (the ground, z = 0) in a corridor of gates and
    clutter (``quadruped-gates``).

    Args:
      x_range: ``(x_min, x_max)``, the corridor's extent along x.
      half_width: the corridor's inner half-width: its side walls' inner faces at
        ``|y| = half_width``.
      side_wall_half_size: ``(half_thickness, half_height)`` of the two side walls (boxes
        along x over ``x_range``; seen, not collided).
      n_gates: gates, each two mocap boxes ``gate{i}_left``, ``gate{i}_right`` of half-size
        ``gate_half_size`` (the segments either side of the opening; the env places them).
      n_clutter: mocap boxes ``clutter{i}`` of half-size ``clutter_half_size``.

    Gates and clutter are seen, not collided; three more mocap bodies, invisible, collide:
    ``gate_contact_left``, ``gate_contact_right`` (one gate's two segments) and
    ``clutter_contact`` (one clutter box), which the env moves onto the nearest gate and
    clutter box (as ``wall_contact`` on the walls course, module docstring).
    """
    x_min, x_max = x_range
    thickness, height = side_wall_half_size
    centre, half_length = (x_min + x_max) / 2, (x_max - x_min) / 2
    sides = "\n".join(
        f'    <geom name="side_{side}" type="box" pos="{centre:g} {sign * (half_width + thickness):g} {height:g}" '
        f'size="{half_length:g} {thickness:g} {height:g}" contype="0" conaffinity="0" group="{WORLD_GROUP}" '
        'rgba="0.62 0.62 0.66 1"/>'
        for side, sign in (("left", 1.0), ("right", -1.0))
    )
    gates = [
        _mocap_box(f"gate{i}_{side}", (1.0 + i, 0.0, gate_half_size[2]), gate_half_size, WALL_RGB)
        for i in range(n_gates)
        for side in ("left", "right")
    ]
    clutter = [
        _mocap_box(f"clutter{i}", (1.5 + i, 0.0, clutter_half_size[2]), clutter_half_size, CLUTTER_RGB)
        for i in range(n_clutter)
    ]
    contacts = [
        _mocap_box(f"gate_contact_{side}", (1.0, 0.0, gate_half_size[2]), gate_half_size, WALL_RGB, colliding=True)
        for side in ("left", "right")
    ]
    contacts.append(
        _mocap_box("clutter_contact", (1.5, 0.0, clutter_half_size[2]), clutter_half_size, CLUTTER_RGB, colliding=True)
    )
    return _model_xml(
        0.0, (GROUND_BIT, 0), "\n".join([sides, *gates, *clutter, *contacts]), track_camera=CORRIDOR_TRACK_CAMERA
    )


def _mocap_box(
    name: str,
    pos: tuple[float, float, float],
    half_size: tuple[float, float, float],
    rgb: str,
    *,
    colliding: bool = False,
) -> str:
    """One MJCF line: a mocap body ``name`` at ``pos`` with a box geom of the same name.

    Seen and not collided (group ``WORLD_GROUP``), or, ``colliding``, the invisible copy that
    collides (group ``CONTACT_GROUP``, alpha 0; frictionless and taking precedence, module
    docstring)."""
    x, y, z = pos
    hx, hy, hz = half_size
    if colliding:
        bits = f'contype="{WALL_BIT}" conaffinity="0" condim="1" priority="1" group="{CONTACT_GROUP}"'
    else:
        bits = f'contype="0" conaffinity="0" group="{WORLD_GROUP}"'
    return (
        f'    <body name="{name}" mocap="true" pos="{x:g} {y:g} {z:g}">'
        f'<geom name="{name}" type="box" size="{hx:g} {hy:g} {hz:g}" {bits} rgba="{rgb} {0 if colliding else 1}"/></body>'
    )


def _model_xml(floor_z: float, floor_bits: tuple[int, int], world: str, *, track_camera: str = TRACK_CAMERA) -> str:
    """The whole MJCF around ``world`` (MJCF lines of the world's geoms and bodies, spliced
    between the floor plane at ``floor_z`` with contact bits ``floor_bits`` and the robot, its
    ``track`` camera placed by ``track_camera``)."""
    defaults, body, actuators, sensors = robot_xml(track_camera)
    return f"""
<mujoco model="a1_class_quadruped">
  <compiler angle="radian" autolimits="true"/>
  <option timestep="{PHYSICS_DT:g}" integrator="Euler" cone="pyramidal" solver="{_MJCF_SOLVER[SOLVER]}"
          iterations="{ITERATIONS}" ls_iterations="{LS_ITERATIONS}"/>
  <visual><headlight ambient="0.35 0.35 0.35" diffuse="0.5 0.5 0.5"/><map znear="0.01" zfar="50"/></visual>
  <asset>
    <texture name="sky" type="skybox" builtin="gradient" rgb1="0.45 0.6 0.8" rgb2="0.9 0.93 0.97" width="64" height="64"/>
    <texture name="grid" type="2d" builtin="checker" rgb1="0.3 0.42 0.3" rgb2="0.22 0.32 0.22" width="64" height="64"/>
    <material name="grid" texture="grid" texrepeat="1 1" texuniform="true"/>
  </asset>
  <default>{defaults}
  </default>
  <worldbody>
    <light name="sun" directional="true" pos="0 0 5" dir="-0.3 0.2 -1" diffuse="0.5 0.5 0.5"/>
    <geom name="floor" type="plane" size="0 0 1" pos="0 0 {floor_z:g}" material="grid" group="{WORLD_GROUP}"
          contype="{floor_bits[0]}" conaffinity="{floor_bits[1]}" condim="3" friction="{FRICTION}"/>
{world}
{body}
  </worldbody>
  <actuator>
{actuators}
  </actuator>
  <sensor>
{sensors}
  </sensor>
  <keyframe>
    <key name="home" qpos="0 0 {HOME_HEIGHT:g} 1 0 0 0 {" ".join(f"{q:g}" for q in HOME_JOINTS)}"
         ctrl="{" ".join(f"{q:g}" for q in HOME_JOINTS)}"/>
  </keyframe>
</mujoco>
"""
