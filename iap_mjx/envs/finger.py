"""finger-spin: dm_control's ``suite.finger.spin`` on MJX."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import mujoco
from mujoco import mjx

from iap_mjx.envs.dm_control_suite import finger
from iap_mjx.envs.dmc import DmControlEnv, first_contact_free, randomize_limited_and_rotational_joints

_SPIN_VELOCITY = 15.0
_HINGE_DAMPING = 0.03
_MAX_ATTEMPTS = 1000  # dm_control's _set_random_joint_angles
# Geoms that no pose brings into contact with anything (see FingerSpin).
_NEVER_TOUCHING = ("ground", "proximal", "proximal_decoration")


class FingerSpin(DmControlEnv):
    """A planar two-link finger flicks a free-spinning body; reward 1 while the body spins at
    ``hinge_velocity <= -15`` rad/s.

    Observation (9,), all from sensors as dm_control reads them: ``position`` = proximal and
    distal joint angles, then the tip site's (x, z) relative to the spinner (4),
    ``velocity`` = proximal, distal and hinge joint velocities (3), ``touch`` =
    ``log1p`` of the two fingertip touch sensors (2). The touch sensors are computed in the
    acceleration stage of the last physics step (MuJoCo's ``mj_step2``), i.e. from the contact
    forces at that step's start, as after dm_control's ``physics.step``.

    dm_control's ``initialize_episode`` edits the model: the spinner's hinge damping becomes
    0.03 (the XML says 0.5) and the ``target`` and ``tip`` sites are made transparent (spin has
    no target); both edits are made once here. Control step 0.02 s = 2 physics steps of 0.01 s;
    elliptic friction cones and frictionloss on the hinge, no gravity, as in the XML.

    One edit of ours: the geoms that can never touch anything lose their collision flags
    (``_NEVER_TOUCHING``), because MJX computes every candidate pair at every step whether it
    touches or not (native MuJoCo's broad phase skips them), and the cylinder pairs run MJX's
    iterative SDF collision: dropping them removes that work and changes no contact that can
    happen. Why they cannot touch, from the XML's rigid geometry (both bodies hinge
    about fixed points 0.4 apart at height 0.4): the finger reaches at most
    0.18 + 0.161 + 0.03 = 0.371 from its base and the spinner's capsules 0.132 from its
    hinge, so nothing reaches the ground (z = 0); the proximal capsule (reach 0.2) and its
    decoration (radius 0.034 at the base) stay >= 0.068 from anything of the spinner, and the
    distal link and fingertip do not collide with their parent body (MuJoCo's parent filter).
    Left: the fingertip against the spinner's two capsules and its decoration.
    ``tests/test_envs_finger.py`` checks the clearances with ``mj_geomDistance`` over random
    poses, and that dm_control's own simulation never has another contact.
    """

    name = "finger-spin"
    domain = finger
    n_sub_steps = 2
    default_max_contacts = None  # all 4 candidate slots; dm_control: <= 2 touching (test_envs_contacts.py)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)

        def sensor(name: str, width: int = 1) -> slice:
            adr = self._sensor_address(name)
            return slice(adr, adr + width)

        self._joint_angles = [sensor("proximal"), sensor("distal")]
        self._velocities = [sensor("proximal_velocity"), sensor("distal_velocity"), sensor("hinge_velocity")]
        self._tip, self._spinner = sensor("tip", 3), sensor("spinner", 3)
        self._touch = [sensor("touchtop"), sensor("touchbottom")]
        self._hinge_velocity = sensor("hinge_velocity").start

    def _edit_spec(self, spec: mujoco.MjSpec) -> None:
        for name in _NEVER_TOUCHING:
            geom = spec.geom(name)
            geom.contype = geom.conaffinity = 0

    def _edit_model(self, mj_model: mujoco.MjModel) -> None:
        hinge = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_JOINT, "hinge")
        mj_model.dof_damping[mj_model.jnt_dofadr[hinge]] = _HINGE_DAMPING
        for site in ("target", "tip"):
            mj_model.site_rgba[mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_SITE, site), 3] = 0.0

    def _initial_data(self, key: jax.Array) -> tuple[mjx.Data, dict]:
        """dm_control's ``_set_random_joint_angles``: limited hinges uniform in their range,
        the spinner uniform in ``[-pi, pi]``, redrawn while anything is in contact.

        Exactly dm_control's distribution (the first collision-free draw of i.i.d. candidates;
        about 90% of draws are collision-free); after ``_MAX_ATTEMPTS`` draws, where dm_control
        raises, the last draw is kept (probability ~``0.1 ** 1000``).
        """
        blank = mjx.make_data(self.mj_model)

        def place(key):
            qpos = randomize_limited_and_rotational_joints(self.mj_model, key, blank.qpos)
            return self.forward(blank.replace(qpos=qpos))

        return first_contact_free(place, key, _MAX_ATTEMPTS), {}

    def hinge_velocity(self, data: mjx.Data) -> jax.Array:
        """The spinner's hinge velocity ``()`` (rad/s), from the model's sensor."""
        return data.sensordata[self._hinge_velocity]

    def tip_position(self, data: mjx.Data) -> jax.Array:
        """The tip site's (x, z) relative to the spinner's body, ``(2,)``."""
        relative = data.sensordata[self._tip] - data.sensordata[self._spinner]
        return relative[jnp.array([0, 2])]

    def state_observation(self, data: mjx.Data) -> jax.Array:
        sensors = data.sensordata
        angles = [sensors[s] for s in self._joint_angles]
        velocities = [sensors[s] for s in self._velocities]
        touch = jnp.log1p(jnp.concatenate([sensors[s] for s in self._touch]))
        return jnp.concatenate([*angles, self.tip_position(data), *velocities, touch])

    def reward(self, data: mjx.Data) -> jax.Array:
        return (self.hinge_velocity(data) <= -_SPIN_VELOCITY).astype(jnp.float32)
