"""The machinery shared by the dm_control suite ports: config, model loading, stepping, bad states.

Each task file (``cheetah.py``, ``walker.py``, ...) subclasses ``DmControlEnv`` and supplies
only what dm_control's task class supplies: the initial-state randomisation, the state
observation and the reward. Everything else follows dm_control's ``control.Environment``:

- the model is dm_control's own XML (``dm_control.suite.<domain>.get_model_and_assets()``);
- one control step runs ``n_sub_steps`` physics steps the way dm_control's legacy
  ``Physics.step`` does (``mj_step2`` then ``mj_step1``), so ``State.data`` always has its
  position- and velocity-dependent quantities (``xpos``, ``xmat``, ``site_xpos``, sensors)
  computed at its own ``qpos``/``qvel``; observations and rewards read them directly, as
  dm_control reads them after ``physics.step``;
- an episode is ``1000`` control steps (dm_control's time limits), ``action_repeat`` control
  steps per env step on top, their rewards summed.

Bad states: after every env step, an env whose ``qpos``/``qvel`` are not finite or exceed
``max_abs_state`` is ended (``done = 1``), keeps its last good ``data``, gets reward 0, and
``metrics["nan_terminations"]`` becomes 1. ``done`` is sticky: a done env's ``step`` returns
the same ``data`` and reward 0, so a batch can run to a fixed horizon with a done mask and
one bad env never touches another's numbers.

Beside ``DmControlEnv``: the physics stages, the batch limit of jaxlib's CPU LAPACK
(``serial_lapack_batch``) and the ports of dm_control's joint randomiser and of its
redraw-while-in-contact loop (``first_contact_free``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Callable
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from mujoco import mjx
from mujoco.mjx._src import collision_driver

from iap_mjx.configs.env import EnvConfig
from iap_mjx.envs.base import State
from iap_mjx.loops import batched_like

DM_CONTROL_EPISODE_STEPS = 1000


def position_velocity_stage(model: mjx.Model, data: mjx.Data) -> mjx.Data:
    """MuJoCo's ``mj_step1``: kinematics, contacts, sensors that depend on qpos and qvel."""
    data = mjx.fwd_position(model, data)
    data = mjx.sensor_pos(model, data)
    data = mjx.fwd_velocity(model, data)
    return mjx.sensor_vel(model, data)


def physics_step(model: mjx.Model, data: mjx.Data) -> mjx.Data:
    """One physics step as dm_control takes it: ``mj_step2`` then ``mj_step1``.

    ``data`` must have its position/velocity stage computed (``position_velocity_stage``);
    the result has it too, at the new ``qpos``/``qvel``. The state trajectory is
    ``mjx.step``'s.
    """
    return position_velocity_stage(model, dynamics_stage(model, data))


def dynamics_stage(model: mjx.Model, data: mjx.Data) -> mjx.Data:
    """MuJoCo's ``mj_step2``: actuation, acceleration, constraint solve, integration (the
    position/velocity stage at the old state must be computed)."""
    data = mjx.fwd_actuation(model, data)
    data = mjx.fwd_acceleration(model, data)
    if data._impl.efc_J.size == 0:  # no constraints in this model: nothing to solve
        data = data.replace(qacc=data.qacc_smooth)
    else:
        data = mjx.solve(model, data)
    data = mjx.sensor_acc(model, data)
    if model.opt.integrator == mjx.IntegratorType.RK4:
        data = mjx.rungekutta4(model, data)
    else:
        data = mjx.euler(model, data)
    return data


def _select(pred: jax.Array, on_true: Any, on_false: Any) -> Any:
    """``where(pred, a, b)`` over two pytrees of the same structure (``pred`` a scalar)."""
    return jax.tree.map(lambda a, b: jnp.where(pred, a, b), on_true, on_false)


# jaxlib 0.10's CPU LAPACK kernels (jaxlib/cpu/lapack_kernels.cc, GetLapackBatchChunkSize)
# split a batched call into tasks on XLA's intra-op thread pool once batch x flops per matrix
# reaches this, and block the calling thread until the tasks are done.
_LAPACK_MIN_WORK_PER_TASK = 200_000


def serial_lapack_batch(nv: int) -> int | None:
    """Largest batch of ``nv x nv`` Cholesky factorizations that jaxlib's CPU LAPACK kernel
    runs on its calling thread (``None``: any batch; jaxlib >= 0.11.1 never splits).

    MJX factors the dense mass matrix (``smooth.factor_m``, twice per physics step with the
    Euler integrator's implicit damping) and the Newton solver's Hessian with
    ``jax.scipy.linalg.cho_factor``, one batched LAPACK ``potrf`` call per factorization over
    the vmapped envs. jaxlib 0.10 splits such a call into tasks on XLA's intra-op pool (one
    thread per core) when ``batch * (nv**3 // 3) >= 200,000`` and blocks the calling thread on
    them. XLA:CPU runs a program's thunks on that same pool, so when every pool thread is
    blocked in such a call at once (one per device, when a ``shard_map`` runs the same program
    on as many devices as there are pool threads), nobody runs the tasks: XLA:CPU deadlocks,
    every thread parked on a futex (for example 128 quadruped envs per device on 2 devices).
    The Cholesky dominates MJX's other LAPACK call (``cho_solve``'s triangular solves, ``nv**2``
    flops per env). jaxlib removed the split from open-source builds after 0.11.0
    (jax commit 859992407d, "Don't try to parallelize LAPACK kernels in opensource builds").
    """
    import jaxlib.version

    if tuple(jaxlib.version.__version_info__[:3]) >= (0, 11, 1):
        return None
    return (_LAPACK_MIN_WORK_PER_TASK - 1) // (nv**3 // 3)


def _compile(spec: mujoco.MjSpec) -> mujoco.MjModel:
    """``spec`` compiled, its compiler's ``settotalmass`` applied after compiling: MuJoCo 3.17
    deprecates the compiler's settotalmass (cheetah sets it), so the spec compiles without it
    and the masses are scaled as it would have scaled them (the same model, to the last bit)."""
    total_mass = float(spec.compiler.settotalmass)
    spec.compiler.settotalmass = -1.0
    mj_model = spec.compile()
    if total_mass > 0:
        mujoco.mj_setTotalmass(mj_model, total_mass)
        mujoco.mj_setConst(mj_model, mujoco.MjData(mj_model))
    return mj_model


class DmControlEnv:
    """A MuJoCo task on MJX: the dm_control suite's ports and, on the same machinery, our own
    models (the quadruped's tasks, ``domain = None``, which build their model in
    ``_model_spec``). Subclasses set the class constants and task hooks.

    Attributes:
      config: the ``EnvConfig``.
      mj_model: the ``mujoco.MjModel`` built from the task's XML (dm_control's, for its
        ports), with this env's solver settings (and, for cartpole, the energy flag off),
        exactly what went into ``mjx_model``.
      mjx_model: the ``mjx.Model`` the env steps.
    """

    name: ClassVar[str]
    # the dm_control.suite module (e.g. dm_control.suite.cheetah) of a port; None for our own models
    domain: ClassVar[Any]
    n_sub_steps: ClassVar[int] = 1
    default_max_contacts: ClassVar[int | None] = None  # None: keep every candidate contact
    default_episode_steps: ClassVar[int] = DM_CONTROL_EPISODE_STEPS  # control steps
    config_class: ClassVar[type[EnvConfig]] = EnvConfig  # the registry validates settings against it

    def __init__(self, config: EnvConfig | None = None, **overrides: Any):
        if config is not None and type(config) is not self.config_class:
            raise ValueError(f"{self.name} takes a {self.config_class.__name__}, got a {type(config).__name__}.")
        config = config if config is not None else self.config_class()
        self.config = dataclasses.replace(config, **overrides) if overrides else config
        spec = self._model_spec()
        spec.add_numeric(name="max_contact_points", data=[-1])  # -1: MJX keeps every candidate
        self._edit_spec(spec)
        mj_model = _compile(spec)  # once: the contact limit is set in the compiled model below
        all_condims = collision_driver.make_condim(mj_model)
        self.max_contacts = self._resolve_max_contacts(all_condims)
        if self.max_contacts is not None:
            self._limit_contacts(mj_model, self.max_contacts)
        # MJX does not compute energy (cartpole's XML enables it); no dynamics depend on it
        mj_model.opt.enableflags &= ~int(mujoco.mjtEnableBit.mjENBL_ENERGY)
        mj_model.opt.iterations = self.config.solver_iterations
        mj_model.opt.ls_iterations = self.config.ls_iterations
        self._edit_model(mj_model)
        self.mj_model = mj_model
        self.mjx_model = mjx.put_model(mj_model)
        self._action_size = int(mj_model.nu)
        # The contact slots of each condim group that lost candidates to the limit.
        kept = collision_driver.make_condim(mj_model)
        self._limited_slots = tuple(
            np.flatnonzero(kept == c) for c in np.unique(all_condims) if np.sum(kept == c) < np.sum(all_condims == c)
        )

    def _limit_contacts(self, mj_model: mujoco.MjModel, max_contacts: int) -> None:
        """Writes ``max_contacts`` into the model's ``max_contact_points`` numeric, which MJX
        reads as the number of contact slots it keeps."""
        slot = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_NUMERIC, "max_contact_points")
        # MJX reads numeric_data[id] (not numeric_adr[id]): the same cell while every numeric
        # before ours has size 1, as in every suite model (they define none).
        if mj_model.numeric_adr[slot] != slot:
            raise ValueError(
                f"{self.name}: a model numeric of size > 1 precedes max_contact_points, "
                "where MJX would read the wrong cell; use max_contacts='all'"
            )
        mj_model.numeric_data[slot] = max_contacts

    # ---- the Env protocol -------------------------------------------------------------

    @property
    def action_size(self) -> int:
        return self._action_size

    @property
    def observation_shape(self) -> tuple[int, ...]:
        return (self.observation_size,)

    @functools.cached_property
    def observation_size(self) -> int:
        data = mjx.make_data(self.mj_model)
        return int(jax.eval_shape(self.state_observation, data).shape[0])

    @property
    def max_chunk_size(self) -> int | None:
        """Most envs to ``vmap`` together on one device (``None``: no limit): a larger vmapped
        batch can deadlock XLA:CPU on two or more devices (:func:`serial_lapack_batch`)."""
        return serial_lapack_batch(int(self.mj_model.nv))

    @property
    def episode_length(self) -> int:
        """Env steps (``step`` calls) an episode lasts."""
        return self.episode_length_for(self.config)

    @classmethod
    def episode_length_for(cls, config: EnvConfig) -> int:
        """``config.episode_length``, else the task's default control steps over the action
        repeat: the episode length without building the model."""
        if config.episode_length is not None:
            return config.episode_length
        return math.ceil(cls.default_episode_steps / config.action_repeat)

    @property
    def control_timestep(self) -> float:
        """Seconds per control step (before action repeat), as in dm_control."""
        return float(self.mj_model.opt.timestep) * self.n_sub_steps

    def reset(self, key: jax.Array) -> State:
        """dm_control's ``initialize_episode`` randomisation, drawn from ``key``."""
        data, task_info = self._initial_data(key)
        return self._first_state(data, task_info)

    def reset_to(self, qpos: jax.Array, qvel: jax.Array, **task_info: jax.Array) -> State:
        """A first state at given ``qpos`` ``(nq,)`` and ``qvel`` ``(nv,)`` (no randomisation).

        ``task_info`` carries task variables that are not in the physics state (reacher's
        ``target``). Used to start from a dm_control state.
        """
        data = mjx.make_data(self.mj_model).replace(
            qpos=jnp.asarray(qpos, jnp.float32), qvel=jnp.asarray(qvel, jnp.float32)
        )
        task_info = {k: jnp.asarray(v, jnp.float32) for k, v in task_info.items()}
        return self._first_state(self.forward(data, task_info), task_info)

    def step(self, state: State, action: jax.Array) -> State:
        """Holds ``action`` ``(action_size,)`` for ``action_repeat`` control steps."""
        action = self._checked_action(action)
        data = state.data.replace(ctrl=action)

        def physics_substep(_: Any, carry: tuple[mjx.Data, jax.Array]):
            data, saturated = carry
            data = physics_step(self.mjx_model, data)
            return data, saturated | self._contacts_saturated(data)

        def control_step(carry: tuple[mjx.Data, jax.Array], _: Any):
            before = carry[0]
            data, saturated = jax.lax.fori_loop(0, self.n_sub_steps, physics_substep, carry)
            data = self._sync_task(data, state.info)
            return (data, saturated), self.step_reward(before, data)

        carry = batched_like((data, jnp.zeros((), bool)), data.qpos)
        (data, saturated), rewards = jax.lax.scan(control_step, carry, length=self.config.action_repeat)
        reward = jnp.sum(rewards)

        bad = ~self._state_is_good(data)
        ended = state.done > 0
        frozen = ended | bad
        data = _select(frozen, state.data, data)
        reward = jnp.where(frozen, 0.0, reward)
        steps = state.info["steps"] + jnp.where(ended, 0, 1).astype(jnp.int32)
        done = frozen | self._terminated(data) | (steps >= self.episode_length)
        metrics = dict(state.metrics)
        metrics["nan_terminations"] = jnp.maximum(state.metrics["nan_terminations"], jnp.where(bad & ~ended, 1.0, 0.0))
        metrics["contact_saturated"] = jnp.maximum(
            state.metrics["contact_saturated"], jnp.where(saturated & ~ended, 1.0, 0.0)
        )
        return state.replace(
            data=data,
            obs=self.state_observation(data),
            reward=reward.astype(jnp.float32),
            done=done.astype(jnp.float32),
            metrics=metrics,
            info={**state.info, "steps": steps},
        )

    # ---- task hooks (the dm_control Task's methods) -------------------------------------

    def state_observation(self, data: mjx.Data) -> jax.Array:
        """dm_control's observation dict flattened in its key order, ``(observation_size,)``."""
        raise NotImplementedError

    def reward(self, data: mjx.Data) -> jax.Array:
        """dm_control's ``get_reward`` on ``data`` (position/velocity stage current), ``()``."""
        raise NotImplementedError

    def step_reward(self, before: mjx.Data, after: mjx.Data) -> jax.Array:
        """The reward of one control step from ``before`` to ``after`` (default:
        ``reward(after)``, as dm_control's tasks)."""
        return self.reward(after)

    def _terminated(self, data: mjx.Data) -> jax.Array:
        """``()`` bool: the task ends the episode at ``data`` (default: never; dm_control's
        tasks only end at the time limit). The step that got there keeps its reward."""
        return jnp.zeros((), bool)

    def _model_spec(self) -> mujoco.MjSpec:
        """The task's model (default: dm_control's XML for ``domain``)."""
        xml, assets = self.domain.get_model_and_assets()
        return mujoco.MjSpec.from_string(xml, assets)

    def _initial_data(self, key: jax.Array) -> tuple[mjx.Data, dict[str, jax.Array]]:
        """Randomised first physics state (stage computed) and task variables."""
        raise NotImplementedError

    def _edit_spec(self, spec: mujoco.MjSpec) -> None:
        """Task edits of the model before it is compiled (default: none); collision filters
        go here, so that the contact slots are counted after them."""

    def _edit_model(self, mj_model: mujoco.MjModel) -> None:
        """Task edits of the compiled model before ``mjx.put_model`` (default: none)."""

    def _sync_task(self, data: mjx.Data, task_info: dict[str, Any]) -> mjx.Data:
        """Writes task variables that live outside the physics into ``data`` (default: none)."""
        return data

    # ---- helpers ----------------------------------------------------------------------

    def forward(self, data: mjx.Data, task_info: dict[str, Any] | None = None) -> mjx.Data:
        """``data`` with its position/velocity stage computed (dm_control's ``after_reset``)."""
        data = position_velocity_stage(self.mjx_model, data)
        return self._sync_task(data, task_info or {})

    def _first_state(self, data: mjx.Data, task_info: dict[str, jax.Array]) -> State:
        data = data.replace(time=jnp.zeros_like(data.time))
        return State(
            data=data,
            obs=self.state_observation(data),
            reward=jnp.zeros((), jnp.float32),
            done=jnp.zeros((), jnp.float32),
            metrics={
                "nan_terminations": jnp.zeros((), jnp.float32),
                "contact_saturated": jnp.zeros((), jnp.float32),
            },
            info={**task_info, "steps": jnp.zeros((), jnp.int32)},
        )

    def _checked_action(self, action: Any) -> jax.Array:
        shape = getattr(action, "shape", None)
        if shape != (self.action_size,):
            raise ValueError(
                f"{self.name}: action must have shape ({self.action_size},) per env, got "
                f"{shape!r} (vmap over the batch axis)."
            )
        dtype = getattr(action, "dtype", None)
        if dtype is None or not jnp.issubdtype(dtype, jnp.floating):
            raise TypeError(f"{self.name}: action must be a floating-point array, got {dtype}.")
        return jnp.asarray(action, jnp.float32)

    def _resolve_max_contacts(self, all_condims: np.ndarray) -> int | None:
        """The ``max_contact_points`` to set, or ``None`` for no limit."""
        setting = self.config.max_contacts
        if setting == "all":
            return None
        limit = setting if isinstance(setting, int) else self.default_max_contacts  # "task"
        if limit is None or limit >= len(all_condims):
            return None
        return int(limit)

    def _contacts_saturated(self, data: mjx.Data) -> jax.Array:
        """``()`` bool: some limited condim group has every kept slot touching."""
        contact = data._impl.contact
        touching = contact.dist < contact.includemargin
        saturated = jnp.zeros((), bool)
        for slots in self._limited_slots:
            saturated = saturated | jnp.all(touching[slots])
        return saturated

    def _state_is_good(self, data: mjx.Data) -> jax.Array:
        state = jnp.concatenate([data.qpos, data.qvel])
        return jnp.all(jnp.isfinite(state)) & jnp.all(jnp.abs(state) <= self.config.max_abs_state)

    def _settle(self, data: mjx.Data, n_steps: int) -> mjx.Data:
        """``n_steps`` physics steps from ``data`` (its position/velocity stage not computed)
        with ``data.ctrl`` held (zero for a fresh ``make_data``), then that stage: cheetah's
        ``physics.step(nstep=200)`` and the ``mj_forward`` of dm_control's reset, whose
        position/velocity stage the last step has computed (its acceleration fields, which no
        task here reads, are not refreshed). Unlike dm_control, whose first ``mj_step2`` uses
        the stage its reset computed at ``qpos0``, the first step here starts from the stage at
        ``data``'s own ``qpos``.

        One loop of ``n_steps + 1`` rounds, each the position/velocity stage then the dynamics
        (kept in all rounds but the last), so the program holds one copy of each stage, not a
        forward pass before the loop as well: the last round's dynamics, one step in
        ``n_steps + 1``, is discarded.
        """
        model = self.mjx_model

        def round_(i, d):
            d = position_velocity_stage(model, d)
            return _select(i < n_steps, dynamics_stage(model, d), d)

        return jax.lax.fori_loop(0, n_steps + 1, round_, batched_like(data, data.qpos))

    def _id(self, obj: mujoco.mjtObj, name: str) -> int:
        """The id of the model's ``obj`` named ``name`` (``ValueError`` if there is none)."""
        index = mujoco.mj_name2id(self.mj_model, obj, name)
        if index < 0:
            raise ValueError(f"{self.name}: no {obj.name} named {name!r} in the model.")
        return int(index)

    def _qpos_address(self, joint: str) -> int:
        """Where joint ``joint``'s coordinates start in ``qpos``."""
        return int(self.mj_model.jnt_qposadr[self._id(mujoco.mjtObj.mjOBJ_JOINT, joint)])

    def _sensor_address(self, sensor: str) -> int:
        """Where sensor ``sensor``'s values start in ``sensordata``."""
        return int(self.mj_model.sensor_adr[self._id(mujoco.mjtObj.mjOBJ_SENSOR, sensor)])


def randomize_limited_and_rotational_joints(mj_model: mujoco.MjModel, key: jax.Array, qpos: jax.Array) -> jax.Array:
    """dm_control's ``randomizers.randomize_limited_and_rotational_joints`` for hinges/slides.

    Limited hinges and slides uniform in their range, unlimited hinges uniform in
    ``[-pi, pi]``; other joints keep ``qpos`` ``(nq,)``. (Ball and free joints are not used by
    the six tasks and are rejected.)
    """
    lows, highs, addresses = [], [], []
    for joint in range(mj_model.njnt):
        joint_type = mj_model.jnt_type[joint]
        if joint_type in (mujoco.mjtJoint.mjJNT_BALL, mujoco.mjtJoint.mjJNT_FREE):
            raise NotImplementedError("ball and free joints are not randomised here.")
        if mj_model.jnt_limited[joint]:
            low, high = mj_model.jnt_range[joint]
        elif joint_type == mujoco.mjtJoint.mjJNT_HINGE:
            low, high = -np.pi, np.pi
        else:
            continue
        lows.append(low)
        highs.append(high)
        addresses.append(mj_model.jnt_qposadr[joint])
    values = jax.random.uniform(key, (len(addresses),), minval=np.asarray(lows), maxval=np.asarray(highs))
    return qpos.at[np.asarray(addresses, np.int32)].set(values)


def in_contact(data: mjx.Data) -> jax.Array:
    """``()`` bool: anything touches, dm_control's ``physics.data.ncon > 0``.

    ``mj_collision`` keeps a contact iff ``dist < margin``; MJX keeps the closest candidates
    (``max_contacts``) with their distances, the closest always among them.
    """
    contact = data._impl.contact
    return jnp.any(contact.dist < contact.includemargin)


def first_contact_free(
    place: Callable[[jax.Array], mjx.Data], key: jax.Array, max_attempts: int | None = None
) -> mjx.Data:
    """dm_control's rejection sampling of an initial state: ``place(k)`` (a forwarded
    ``mjx.Data`` drawn from key ``k``) on fresh keys split from ``key`` until nothing is in
    contact, so the result has exactly the distribution of the first contact-free draw.

    ``max_attempts``: draws after which the last is kept where dm_control raises (``None``: no
    cap, as dm_control's loops without one). A ``while_loop`` under ``vmap`` draws again only
    where still in contact.
    """

    def redraw(carry):
        key, attempts, _ = carry
        key, sub = jax.random.split(key)
        return key, attempts + 1, place(sub)

    def again(carry):
        touching = in_contact(carry[2])
        return touching if max_attempts is None else touching & (carry[1] < max_attempts)

    key, sub = jax.random.split(key)
    first = batched_like((key, jnp.ones((), jnp.int32), place(sub)), key)
    return jax.lax.while_loop(again, redraw, first)[2]
