"""PMTG (Iscen et al. 2018, "Policies Modulating Trajectory Generators") for the A1-class quadruped.

A periodic trajectory generator (TG) drives the legs; a policy sets the TG's parameters every
control step and adds bounded residuals to its joint targets. Written from the equations of the
authors' group's public PyBullet code (bullet3's ``pybullet_envs/minitaur``:
``agents/trajectory_generator/tg_simple.py``, ``envs_v2/env_wrappers/pmtg_wrapper_env.py``), as
pure functions:

- One phase ``phi`` in ``[0, 2 pi)``: ``[0, pi)`` is stance, ``[pi, 2 pi)`` swing. It advances
  by ``2 pi f dt`` per step, scaled by ``(k + 1) / (2 k)`` in stance and ``(k + 1) / 2`` in
  swing, ``f`` the frequency (Hz) and ``k`` the swing/stance ratio: a period lasts ``1 / f``
  whatever ``k``, of which stance takes the fraction ``k / (k + 1)``. Equivalently the phase is
  a piecewise-linear warp of the period's elapsed fraction ``tau`` (:func:`phase_to_time`,
  :func:`time_to_phase`), which is how it is computed here: no loops.
- Leg ``i`` runs at the period fraction ``tau + offset_i`` of a gait (:data:`GAITS`).
- Per leg a swing ``S = I a cos(phi_i)`` and an extension ``E = h + I A(phi_i) sin(phi_i)``
  (``a = 0.5``; ``A = -0.02`` in stance, ``0.9`` in swing), intensity ``I``, walking height ``h``;
  joint targets: abduction ``= abduction0``, thigh ``= thigh0 - S - E / 2``, knee
  ``= knee0 + E``, around the standing pose, plus residuals of at most ``residual_range``.

The bounds of ``I`` and ``h`` are ours, chosen for the A1's joint ranges: :class:`TGConfig`
refuses bounds under which some bounded input could put a target outside its joint's range,
so the targets never need clipping.

:class:`PMTGPolicy` is the low level of the paper's hierarchy: a linear map of (latent
command, env observation, ``cos phi``, ``sin phi``) to 16 numbers in ``[-1, 1]`` (``tanh``):
the 12 residuals and the TG's ``(f, I, h, k)``. Its per-episode state (:class:`PMTGState`) is
the TG phase and the latent command (constant here; a high level would write it).
"""

from __future__ import annotations

import dataclasses
import math
from types import MappingProxyType
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from iap_mjx.checks import require_choice, require_int, require_number
from iap_mjx.policies.base import check_options, constructor_options, field_names, split_options
from iap_mjx.robots import a1

#: Phase offsets (fractions of a period) per leg in the PyBullet code's order FL, RL, FR, RR.
GAITS_FL_RL_FR_RR = MappingProxyType(
    {
        "walk": (0.0, 0.25, 0.5, 0.75),
        "trot": (0.0, 0.5, 0.5, 0.0),
        "bound": (0.0, 0.5, 0.0, 0.5),
        "pace": (0.0, 0.0, 0.5, 0.5),
        "pronk": (0.0, 0.0, 0.0, 0.0),
    }
)
#: The same offsets in our legs' order (``a1.LEGS``: FR, FL, RR, RL).
GAITS = MappingProxyType({name: (o[2], o[0], o[3], o[1]) for name, o in GAITS_FL_RL_FR_RR.items()})
TG_PARAMETERS = ("frequency", "intensity", "height", "ratio")


def stance_fraction(ratio: jax.Array) -> jax.Array:
    """Fraction of a period spent in stance for a swing/stance ratio ``k``: ``k / (k + 1)``."""
    return ratio / (ratio + 1.0)


def phase_to_time(phase: jax.Array, ratio: jax.Array) -> jax.Array:
    """The period fraction ``tau`` in ``[0, 1)`` at which the warped phase reaches ``phase``."""
    stance = stance_fraction(ratio)
    in_stance = phase < math.pi
    return jnp.where(in_stance, phase / math.pi * stance, stance + (phase - math.pi) / math.pi * (1.0 - stance))


def time_to_phase(tau: jax.Array, ratio: jax.Array) -> jax.Array:
    """The warped phase in ``[0, 2 pi)`` at period fraction ``tau`` in ``[0, 1)``."""
    stance = stance_fraction(ratio)
    in_stance = tau < stance
    return jnp.where(in_stance, math.pi * tau / stance, math.pi + math.pi * (tau - stance) / (1.0 - stance))


def _wrap(tau: jax.Array) -> jax.Array:
    tau = tau - jnp.floor(tau)
    return jnp.where(tau >= 1.0, 0.0, tau)  # floor rounding can leave exactly 1.0


def advance(phase: jax.Array, frequency: jax.Array, ratio: jax.Array, dt: float) -> jax.Array:
    """The phase after ``dt`` seconds at ``frequency`` Hz and swing/stance ratio ``ratio``."""
    return time_to_phase(_wrap(phase_to_time(phase, ratio) + frequency * dt), ratio)


def leg_phases(phase: jax.Array, ratio: jax.Array, offsets: Any) -> jax.Array:
    """``(4,)`` the legs' phases: the TG's phase moved on by each leg's period offset."""
    tau = phase_to_time(phase, ratio)
    return time_to_phase(_wrap(tau + jnp.asarray(offsets, jnp.float32)), ratio)


@dataclasses.dataclass(frozen=True)
class TGConfig:
    """The trajectory generator's static settings (hashable).

    Attributes:
      gait: a key of :data:`GAITS`.
      frequency_range: Hz, ``f``'s bounds (PyBullet's: 0 to 3).
      intensity_range, height_range: ``I``'s and ``h``'s bounds (ours, for the A1's ranges).
      ratio_range: swing/stance ratio bounds (PyBullet's: 0.2 to 5); mapped geometrically, so
        a zero policy output gives ``k = sqrt(lo hi)`` (1 with the defaults).
      residual_range: bound of the residual joint offsets (rad).
      swing_amplitude: ``a`` in ``S = I a cos(phi)``.
      stance_lift, swing_lift: ``A`` in stance and in swing.
      dt: seconds per step (the env's control step).
    """

    gait: str = "trot"
    frequency_range: tuple[float, float] = (0.0, 3.0)
    intensity_range: tuple[float, float] = (0.0, 0.8)
    height_range: tuple[float, float] = (0.0, 0.45)
    ratio_range: tuple[float, float] = (0.2, 5.0)
    residual_range: float = 0.15
    swing_amplitude: float = 0.5
    stance_lift: float = -0.02
    swing_lift: float = 0.9
    dt: float = a1.CONTROL_DT

    def __post_init__(self):
        require_choice("TGConfig.gait", self.gait, GAITS)
        for name in ("frequency_range", "intensity_range", "height_range", "ratio_range"):
            value = tuple(float(v) for v in getattr(self, name))
            if len(value) != 2 or not value[0] <= value[1]:
                raise ValueError(f"TGConfig.{name} must be (low, high) with low <= high, got {getattr(self, name)!r}.")
            object.__setattr__(self, name, value)
        for name, low_open in (("frequency_range", False), ("intensity_range", False), ("ratio_range", True)):
            low = getattr(self, name)[0]
            if low < 0 or (low_open and low == 0):
                raise ValueError(
                    f"TGConfig.{name} must be (low, high) with low {'>' if low_open else '>='} 0, got {getattr(self, name)!r}."
                )
        require_number("TGConfig.residual_range", self.residual_range, 0, high_open=True, unit="rad")
        require_number("TGConfig.dt", self.dt, 0, low_open=True, high_open=True, unit="s")
        lo, hi = self.target_bounds()
        outside = (lo < a1.JOINT_RANGES[:3, 0] - 1e-6) | (hi > a1.JOINT_RANGES[:3, 1] + 1e-6)
        if np.any(outside):
            raise ValueError(
                f"TGConfig: with these bounds the (abduction, thigh, knee) targets can reach "
                f"{np.round(lo, 3).tolist()}..{np.round(hi, 3).tolist()}, outside the joint ranges "
                f"{a1.LEG_RANGES}; narrow intensity_range, height_range or residual_range"
            )

    def target_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Per leg joint, ``(3,)`` lowest and highest targets any bounded input can give."""
        i_max = self.intensity_range[1]
        # I A sin(phi): sin in [0, 1] in stance, [-1, 0] in swing
        lift_lo = i_max * min(0.0, self.stance_lift, -self.swing_lift)
        lift_hi = i_max * max(0.0, self.stance_lift, -self.swing_lift)
        e_lo, e_hi = self.height_range[0] + lift_lo, self.height_range[1] + lift_hi
        s = i_max * abs(self.swing_amplitude)
        r = self.residual_range
        home = np.asarray(a1.HOME_LEG)
        lo = home + np.array([-r, -s - e_hi / 2 - r, e_lo - r])
        hi = home + np.array([r, s - e_lo / 2 + r, e_hi + r])
        return lo, hi

    @property
    def offsets(self) -> tuple[float, ...]:
        return GAITS[self.gait]

    def parameters(self, u: jax.Array) -> dict[str, jax.Array]:
        """``u`` ``(4,)`` in ``[-1, 1]`` -> ``{"frequency", "intensity", "height", "ratio"}``."""

        def linear(x, bounds):
            return bounds[0] + (x + 1.0) * 0.5 * (bounds[1] - bounds[0])

        lo, hi = self.ratio_range
        return {
            "frequency": linear(u[0], self.frequency_range),
            "intensity": linear(u[1], self.intensity_range),
            "height": linear(u[2], self.height_range),
            "ratio": jnp.exp(linear(u[3], (math.log(lo), math.log(hi)))),
        }

    def outputs_for(self, frequency: float, intensity: float, height: float, ratio: float) -> np.ndarray:
        """The inverse of :meth:`parameters`: ``(4,)`` outputs in ``[-1, 1]`` giving these TG
        parameters (each must lie inside its range)."""
        values = {"frequency": frequency, "intensity": intensity, "height": height, "ratio": ratio}
        out = []
        for name, value in values.items():
            lo, hi = getattr(self, f"{name}_range")
            if not lo <= value <= hi:
                raise ValueError(f"TG {name} = {value!r} is outside TGConfig.{name}_range = {(lo, hi)}")
            if name == "ratio":
                value, lo, hi = math.log(value), math.log(lo), math.log(hi)
            out.append(0.0 if hi == lo else 2.0 * (value - lo) / (hi - lo) - 1.0)
        return np.asarray(out, np.float64)


def swing_extend(
    config: TGConfig, phases: jax.Array, intensity: jax.Array, height: jax.Array
) -> tuple[jax.Array, jax.Array]:
    """Per leg ``(4,)`` swing ``S`` and extension ``E`` at the legs' phases."""
    lift = jnp.where(phases < math.pi, config.stance_lift, config.swing_lift)
    swing = intensity * config.swing_amplitude * jnp.cos(phases)
    extend = height + intensity * lift * jnp.sin(phases)
    return swing, extend


def joint_targets(
    config: TGConfig, phases: jax.Array, intensity: jax.Array, height: jax.Array, residuals: jax.Array
) -> jax.Array:
    """``(12,)`` joint targets (rad, legs in ``a1.LEGS`` order): the TG's legs at ``phases``
    around the standing pose, plus ``residuals`` ``(12,)`` (already bounded)."""
    swing, extend = swing_extend(config, phases, intensity, height)
    abduction0, thigh0, knee0 = a1.HOME_LEG
    legs = jnp.stack([jnp.full_like(swing, abduction0), thigh0 - swing - extend / 2, knee0 + extend], axis=1)  # (4, 3)
    return legs.reshape(a1.N_JOINTS) + residuals


class TGStep(NamedTuple):
    """What one TG step produced: the new phase ``()`` and the joint targets ``(12,)``."""

    phase: jax.Array
    targets: jax.Array


def tg_step(config: TGConfig, phase: jax.Array, u: jax.Array) -> TGStep:
    """One PMTG step from the policy's output ``u`` ``(16,)`` in ``[-1, 1]`` (12 residuals,
    then ``(f, I, h, k)``): advance the phase, then the legs' targets at the new phase."""
    params = config.parameters(u[a1.N_JOINTS :])
    phase = advance(phase, params["frequency"], params["ratio"], config.dt)
    phases = leg_phases(phase, params["ratio"], config.offsets)
    targets = joint_targets(
        config, phases, params["intensity"], params["height"], config.residual_range * u[: a1.N_JOINTS]
    )
    return TGStep(phase, targets)


class PMTGState(struct.PyTreeNode):
    """One episode's low-level state (a leading batch axis under ``vmap``).

    Attributes:
      latent: ``(latent_size,)`` float32, the command the linear map sees (constant alone; a
        high level writes it every step).
      phase: ``()`` float32, the TG phase in ``[0, 2 pi)``.
    """

    latent: jax.Array
    phase: jax.Array


@dataclasses.dataclass(frozen=True)
class PMTGPolicy:
    """Linear PMTG low level: ``u = tanh(W [latent, obs, cos phi, sin phi] + b)`` -> TG.

    Attributes:
      obs_size: the env's observation size (IMU and joint angles: 17 on the quadruped envs).
      action_size: must be 12 (the envs' joint targets in ``[-1, 1]``).
      latent: the constant latent command, one float per latent input (a high level would
        replace it through the policy state; with a constant latent its weights act as a bias).
      tg: the trajectory generator's settings.
      initial_tg: the TG's ``(frequency Hz, intensity, height, ratio)`` that the initial
        params give (through the output bias; all weights zero, no residuals): where ES
        starts. The default is a trot from ``benchmarks/quadruped_tg.py``'s grid on
        ``quadruped-flat`` with no residuals, an interior point (not the range's corner, which
        ``tanh`` reaches only with large weights) that already walks; ``None``: all-zero
        params, the TG's mid-range (1.5 Hz, 0.4, 0.225, 1), about a third as fast (both
        speeds: RESULTS.md, section ``quadruped-walking``). The speed grows towards the high
        frequency and low height bounds, which ``tanh`` outputs reach only with large weights,
        so ES from the mid-range spends most of its iterations travelling there.
    """

    obs_size: int
    action_size: int = a1.N_JOINTS
    latent: tuple[float, ...] = (0.0, 0.0, 0.0, 0.0)
    tg: TGConfig = TGConfig()
    initial_tg: tuple[float, float, float, float] | None = (2.5, 0.6, 0.1, 1.0)

    def __post_init__(self):
        require_int("PMTGPolicy.obs_size", self.obs_size)
        if self.action_size != len(a1.JOINT_NAMES):
            raise ValueError(
                f"PMTGPolicy.action_size must be {len(a1.JOINT_NAMES)} (PMTG drives the quadruped's "
                f"joints: use env quadruped-flat or quadruped-walls), got {self.action_size!r}."
            )
        object.__setattr__(self, "latent", tuple(float(v) for v in self.latent))
        if self.initial_tg is not None:
            initial = tuple(float(v) for v in self.initial_tg)
            if len(initial) != len(TG_PARAMETERS):
                raise ValueError(
                    f"PMTGPolicy.initial_tg must be {len(TG_PARAMETERS)} numbers {TG_PARAMETERS} or None, "
                    f"got {self.initial_tg!r}."
                )
            units = self.tg.outputs_for(*initial)
            if np.any(np.abs(units) >= 1.0 - 1e-3):
                raise ValueError(
                    f"PMTGPolicy.initial_tg = {initial}: each value must lie strictly inside its "
                    f"TGConfig range (frequency {self.tg.frequency_range}, intensity "
                    f"{self.tg.intensity_range}, height {self.tg.height_range}, ratio "
                    f"{self.tg.ratio_range}): tanh outputs cannot reach the bounds"
                )
            object.__setattr__(self, "initial_tg", initial)

    @property
    def input_size(self) -> int:
        return len(self.latent) + self.obs_size + 2

    @property
    def output_size(self) -> int:
        return self.action_size + len(TG_PARAMETERS)

    def init(self, key: jax.Array) -> dict[str, jax.Array]:
        """``{"w": (input_size, 16), "b": (16,)}``: zero weights and residuals; the TG's bias
        gives ``initial_tg`` (zero with ``initial_tg=None``: the TG's mid-range gait)."""
        del key
        bias = np.zeros(self.output_size, np.float32)
        if self.initial_tg is not None:
            bias[self.action_size :] = np.arctanh(self.tg.outputs_for(*self.initial_tg))
        return {"w": jnp.zeros((self.input_size, self.output_size), jnp.float32), "b": jnp.asarray(bias)}

    def initial_state(self, key: jax.Array) -> PMTGState:
        """The policy's ``latent`` and the TG phase at 0."""
        del key
        return PMTGState(latent=jnp.asarray(self.latent, jnp.float32), phase=jnp.zeros((), jnp.float32))

    def outputs(self, params, obs: jax.Array, policy_state: PMTGState) -> jax.Array:
        """The linear map's ``(16,)`` outputs in ``[-1, 1]``."""
        phase = policy_state.phase
        x = jnp.concatenate([policy_state.latent, jnp.ravel(obs), jnp.stack([jnp.cos(phase), jnp.sin(phase)])])
        return jnp.tanh(x @ params["w"] + params["b"])

    def apply(self, params, obs: jax.Array, policy_state: PMTGState) -> tuple[jax.Array, PMTGState]:
        """One control step: ``(action (12,) in [-1, 1], new policy state)``."""
        step = tg_step(self.tg, policy_state.phase, self.outputs(params, obs, policy_state))
        action = a1.targets_to_action(step.targets)
        return action, policy_state.replace(phase=step.phase)


def make_pmtg_policy(observation_shape: Any, action_size: int, **options: Any) -> PMTGPolicy:
    """Factory for ``policies.make("pmtg", ...)``: TG fields (``gait``, ``residual_range``, ...)
    go to :class:`TGConfig`, the rest to :class:`PMTGPolicy`."""
    if not (isinstance(observation_shape, tuple) and len(observation_shape) == 1):
        raise ValueError(f"the pmtg policy needs a state vector observation, got shape {observation_shape!r}")
    tg_options, rest = split_options(options, TGConfig)
    check_options(
        "pmtg", options, field_names(TGConfig) | constructor_options(PMTGPolicy, "obs_size", "action_size", "tg")
    )
    return PMTGPolicy(int(observation_shape[0]), action_size, tg=TGConfig(**tg_options), **rest)
