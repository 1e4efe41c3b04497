"""The PMTG trajectory generator against its equations (``iap_mjx.policies.pmtg``).

The reference for the phase is an independent step-by-step integration written from the
equations: the phase moves at ``2 pi f (k + 1) / (2 k)`` in stance (``phi < pi``) and
``2 pi f (k + 1) / 2`` in swing, carrying what is left of a step across the boundaries. The
legs' phases are checked against the same integration run for each leg's offset (as the
PyBullet code places its legs), with the PyBullet code's offset table; the joint targets'
range against a closed form of the equations' extremes and the compiled MuJoCo model's joint
ranges.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest

from iap_mjx import policies
from iap_mjx.policies import pmtg
from iap_mjx.robots import a1


def _reference_advance(phase: float, frequency: float, ratio: float, dt: float) -> float:
    """Integrates the piecewise-constant phase speed over ``dt`` seconds, segment by segment."""
    left = dt
    while left > 0:
        stance = phase < math.pi
        speed = 2 * math.pi * frequency * ((ratio + 1) / (2 * ratio) if stance else (ratio + 1) / 2)
        end = math.pi if stance else 2 * math.pi
        if speed * left < end - phase:
            return phase + speed * left
        left -= (end - phase) / speed
        phase = end % (2 * math.pi)
    return phase


def test_advance_matches_the_segment_integration():
    rng = np.random.default_rng(0)
    step = jax.jit(pmtg.advance, static_argnums=3)
    for _ in range(200):
        phase, f, k = rng.uniform(0, 2 * math.pi), rng.uniform(0, 3), math.exp(rng.uniform(-1.6, 1.6))
        dt = rng.choice([0.02, 0.1, 0.3])
        ours = float(step(jnp.float32(phase), jnp.float32(f), jnp.float32(k), float(dt)))
        ref = _reference_advance(phase, f, k, dt)
        gap = abs(ours - ref)
        assert min(gap, 2 * math.pi - gap) < 1e-4, (phase, f, k, dt, ours, ref)


@pytest.mark.parametrize("ratio", [0.25, 1.0, 3.0])
def test_period_and_stance_split_at_constant_frequency(ratio):
    """f = 2.5 Hz, dt = 0.02 s: the phase returns to its start after exactly 20 steps (not
    before), and k / (k + 1) of those steps are in stance."""
    config = pmtg.TGConfig(dt=0.02)
    f, steps = 2.5, 20
    phase = jnp.float32(0.3)
    phases = []
    for _ in range(2 * steps):
        phase = pmtg.advance(phase, f, ratio, config.dt)
        phases.append(float(phase))
    phases = np.array(phases)
    start = 0.3 / math.pi * ratio / (ratio + 1)  # 0.3 < pi: in stance, a k / (k + 1) share of the period
    np.testing.assert_allclose(phases[steps - 1], 0.3, atol=1e-4)  # one period: back at the start
    np.testing.assert_allclose(phases[steps:], phases[:steps], atol=1e-4)  # and it repeats
    assert np.all(np.abs(phases[: steps - 1] - 0.3) > 1e-2)  # no earlier return
    # stance steps: the period fractions start + n / 20 below k / (k + 1)
    in_stance = np.sum(phases[:steps] < math.pi)
    expected = np.sum(((start + np.arange(1, steps + 1) / steps) % 1.0) < ratio / (ratio + 1))
    assert in_stance == expected
    np.testing.assert_allclose(in_stance / steps, ratio / (ratio + 1), atol=1.0 / steps)


PYBULLET_GAITS = {
    "walk": (0, 0.25, 0.5, 0.75),
    "trot": (0, 0.5, 0.5, 0),
    "bound": (0, 0.5, 0, 0.5),
    "pace": (0, 0, 0.5, 0.5),
    "pronk": (0, 0, 0, 0),
}
"""The PyBullet code's leg phase offsets as its source states them (``pmtg_wrapper_env.py``,
``_GAIT_PHASE_MAP``): fractions of a period for legs FL, RL, FR, RR (``tg_simple.py``'s order)."""
PYBULLET_LEGS = ("FL", "RL", "FR", "RR")


@pytest.mark.parametrize("gait", sorted(PYBULLET_GAITS))
def test_gait_offsets_between_legs(gait):
    """Each leg's phase is where the TG's phase gets after the leg's offset, a fraction of a
    period: the PyBullet code places its legs so (``calculate_progressed_phase(delta_period)``
    of the TG's integrator), and the reference here is the segment integration above run for
    ``offset`` seconds at 1 Hz, with the offsets of the PyBullet code's table matched to our
    legs by name. 20 random phases and ratios ``k`` in ``[e^-1.6, e^1.6]``; tolerance 1e-4 rad
    (float32 against float64; an offset wrong by 1% of a period moves a leg by 0.037 rad or
    more at these ratios, two legs swapped by a quarter period or more where their offsets
    differ)."""
    offsets = np.asarray([PYBULLET_GAITS[gait][PYBULLET_LEGS.index(leg)] for leg in a1.LEGS])
    np.testing.assert_array_equal(pmtg.GAITS[gait], offsets)
    rng = np.random.default_rng(1)
    for _ in range(20):
        phase, ratio = rng.uniform(0, 2 * math.pi), math.exp(rng.uniform(-1.6, 1.6))
        legs = np.asarray(pmtg.leg_phases(jnp.float32(phase), ratio, pmtg.GAITS[gait]))
        expected = np.array([_reference_advance(phase, 1.0, ratio, offset) for offset in offsets])
        gap = np.abs(legs - expected)
        np.testing.assert_allclose(
            np.minimum(gap, 2 * math.pi - gap), 0, atol=1e-4, err_msg=f"phase {phase}, ratio {ratio}"
        )
    # at k = 1 the warp is the identity: phase differences are 2 pi times the offsets
    legs = np.asarray(pmtg.leg_phases(jnp.float32(0.0), 1.0, offsets))
    np.testing.assert_allclose(legs, 2 * math.pi * offsets, atol=1e-5)


def test_trot_moves_diagonal_legs_together():
    offsets = pmtg.GAITS["trot"]  # legs FR, FL, RR, RL
    legs = np.asarray(pmtg.leg_phases(jnp.float32(1.0), 2.0, offsets))
    assert legs[0] == legs[3] and legs[1] == legs[2] and legs[0] != legs[1]


def test_swing_extend_and_joint_targets_follow_the_equations():
    config = pmtg.TGConfig()
    phases = jnp.asarray([0.3, 2.0, 3.5, 5.5])
    intensity, height = 0.6, 0.2
    residuals = jnp.linspace(-0.1, 0.1, 12)
    targets = np.asarray(pmtg.joint_targets(config, phases, intensity, height, residuals)).reshape(4, 3)
    p = np.asarray(phases)
    lift = np.where(p < math.pi, -0.02, 0.9)
    swing = intensity * 0.5 * np.cos(p)
    extend = height + intensity * lift * np.sin(p)
    expected = np.stack([np.zeros(4), 0.9 - swing - extend / 2, -1.8 + extend], axis=1)
    np.testing.assert_allclose(targets, expected + np.asarray(residuals).reshape(4, 3), atol=1e-6)


def _max_on_arc(c: float, s: float, low: float, high: float) -> float:
    """The largest ``c cos(phi) + s sin(phi)`` over ``phi`` in ``[low, high]``: the peak
    ``hypot(c, s)`` at ``atan2(s, c)`` if that angle is on the arc, else an end's value."""
    values = [c * math.cos(low) + s * math.sin(low), c * math.cos(high) + s * math.sin(high)]
    if low <= math.atan2(s, c) % (2 * math.pi) <= high:
        values.append(math.hypot(c, s))
    return max(values)


def _target_extremes(config: pmtg.TGConfig) -> np.ndarray:
    """``(3, 2)``: per leg joint (abduction, thigh, knee) the lowest and highest target of any
    bounded input, in closed form from the equations (module docstring of ``pmtg``): thigh
    ``= thigh0 - h / 2 - I (a cos phi + A sin phi / 2) + residual``, knee ``= knee0 + h +
    I A sin phi + residual``, ``A`` the stance lift on ``[0, pi)`` and the swing lift on
    ``[pi, 2 pi)``, each term at the end of its range that moves the target the most (the
    intensity at its top when the phase term goes that way, else at 0)."""
    i_max, (h_low, h_high), r = config.intensity_range[1], config.height_range, config.residual_range
    a = config.swing_amplitude
    arcs = [(0.0, math.pi, config.stance_lift), (math.pi, 2 * math.pi, config.swing_lift)]

    def largest(swing: float, lift_share: float) -> float:
        """The largest ``I (swing cos phi + lift_share A sin phi)``, ``I`` in ``[0, i_max]``."""
        peak = max(_max_on_arc(swing, lift_share * lift, low, high) for low, high, lift in arcs)
        return i_max * max(0.0, peak)

    abduction0, thigh0, knee0 = a1.HOME_LEG
    return np.array(
        [
            [abduction0 - r, abduction0 + r],
            [thigh0 - h_high / 2 - r - largest(a, 0.5), thigh0 - h_low / 2 + r + largest(-a, -0.5)],
            [knee0 + h_low - r - largest(0.0, -1.0), knee0 + h_high + r + largest(0.0, 1.0)],
        ]
    )


def test_joint_targets_stay_in_the_joint_ranges_for_all_bounded_inputs():
    """The targets of every bounded input stay inside the joint ranges of the compiled MuJoCo
    model, shown in closed form (:func:`_target_extremes`, from the equations) and checked on
    ``tg_step`` itself.

    - The closed form's extremes lie inside the model's ``jnt_range`` (the closest: the knee's
      lowest target, -2.670, 0.027 rad inside -2.697).
    - 4096 random outputs in ``[-1, 1]^16`` plus every corner of the TG parameters' box with 4
      residual sign patterns, 64 random phases each: ``tg_step``'s targets stay within the
      closed form's range (1e-5 rad: float32) and come within 1e-3 rad of each of its 24 ends
      (both ends of every joint of every leg; measured within 1.9e-4), so the sample reaches
      the extremes the ranges are checked against.
    - ``TGConfig.target_bounds``, which the config validates bounds with, contains the closed
      form's range (so it refuses every config whose targets could leave the ranges) and equals
      it at both ends of abduction and knee and at the thigh's lowest; the thigh's highest
      (1.810) is 0.222 rad above the reachable 1.588: the bound adds the swing's and the
      extension's extremes, which no phase reaches together.
    """
    config = pmtg.TGConfig()
    extremes = _target_extremes(config)
    model = mujoco.MjModel.from_xml_string(a1.world_xml())
    ranges = np.array(
        [model.jnt_range[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)] for name in a1.JOINT_NAMES]
    ).reshape(4, 3, 2)
    assert np.all(ranges[..., 0] < extremes[:, 0]) and np.all(extremes[:, 1] < ranges[..., 1])

    step = jax.jit(jax.vmap(lambda phase, u: pmtg.tg_step(config, phase, u).targets))
    rng = np.random.default_rng(2)
    random_u = rng.uniform(-1, 1, (4096, 16))
    corners = np.array(np.meshgrid(*[[-1.0, 1.0]] * 4)).reshape(4, -1).T  # (16, 4)
    residual_signs = np.array([[1.0] * 12, [-1.0] * 12, [1, -1, 1] * 4, [-1, 1, -1] * 4])
    corner_u = np.concatenate(
        [np.repeat(residual_signs, len(corners), 0), np.tile(corners, (len(residual_signs), 1))], axis=1
    )
    u = np.concatenate([random_u, np.repeat(corner_u, 64, 0)])
    phases = rng.uniform(0, 2 * math.pi, len(u)).astype(np.float32)
    targets = np.asarray(step(jnp.asarray(phases), jnp.asarray(u, jnp.float32))).reshape(-1, 4, 3)
    assert np.all(targets >= extremes[:, 0] - 1e-5) and np.all(targets <= extremes[:, 1] + 1e-5)
    np.testing.assert_allclose(targets.min(0), np.broadcast_to(extremes[:, 0], (4, 3)), atol=1e-3)
    np.testing.assert_allclose(targets.max(0), np.broadcast_to(extremes[:, 1], (4, 3)), atol=1e-3)

    low, high = config.target_bounds()
    assert np.all(low <= extremes[:, 0] + 1e-6) and np.all(high >= extremes[:, 1] - 1e-6)
    np.testing.assert_allclose(low, extremes[:, 0], atol=1e-6)
    np.testing.assert_allclose(high[[0, 2]], extremes[[0, 2], 1], atol=1e-6)


def test_config_refuses_bounds_that_leave_the_joint_ranges():
    with pytest.raises(ValueError, match="intensity_range"):
        pmtg.TGConfig(intensity_range=(0.0, 1.5))
    with pytest.raises(ValueError, match="gait"):
        pmtg.TGConfig(gait="gallop")
    with pytest.raises(ValueError, match=r"TGConfig.residual_range must be a finite number >= 0 \(rad\), got -0.1"):
        pmtg.TGConfig(residual_range=-0.1)
    with pytest.raises(ValueError, match=r"TGConfig.dt must be a finite number > 0 \(s\), got 'fast'"):
        pmtg.TGConfig(dt="fast")  # a TypeError past the CLI's handler before


def test_initial_params_give_the_initial_tg_setting():
    """No weights and no residuals; the TG's outputs give ``initial_tg`` in its own units."""
    policy = policies.make("pmtg", (17,), 12, initial_tg=(2.2, 0.5, 0.15, 2.0))
    params = policy.init(jax.random.key(0))
    assert not np.any(np.asarray(params["w"])) and not np.any(np.asarray(params["b"][:12]))
    u = policy.outputs(params, jnp.ones(17), policy.initial_state(jax.random.key(1)))
    tg = {k: float(v) for k, v in policy.tg.parameters(u[12:]).items()}
    np.testing.assert_allclose([tg[k] for k in pmtg.TG_PARAMETERS], [2.2, 0.5, 0.15, 2.0], rtol=1e-5)
    np.testing.assert_allclose(np.asarray(u[:12]), 0.0)
    with pytest.raises(ValueError, match="initial_tg"):
        policies.make("pmtg", (17,), 12, initial_tg=(3.0, 0.5, 0.15, 2.0))  # tanh cannot reach 3 Hz
    with pytest.raises(ValueError, match="frequency"):
        policies.make("pmtg", (17,), 12, initial_tg=(3.5, 0.5, 0.15, 2.0))


def test_policy_state_is_the_phase_and_zero_params_give_the_mid_range_gait():
    policy = policies.make("pmtg", (17,), 12, initial_tg=None)
    params = policy.init(jax.random.key(0))
    assert not np.any(np.asarray(params["b"]))
    state = policy.initial_state(jax.random.key(1))
    assert float(state.phase) == 0.0 and state.latent.shape == (4,)
    action, state = policy.apply(params, jnp.zeros(17), state)
    # zero outputs: f = 1.5 Hz, k = 1, so one 0.02 s step advances 2 pi * 0.03
    np.testing.assert_allclose(float(state.phase), 2 * math.pi * 1.5 * 0.02, rtol=1e-5)
    step = pmtg.tg_step(policy.tg, jnp.float32(0.0), jnp.zeros(16))
    np.testing.assert_allclose(action, a1.targets_to_action(step.targets), atol=1e-6)
    assert np.all(np.abs(np.asarray(action)) <= 1.0)
    with pytest.raises(ValueError, match="12"):
        policies.make("pmtg", (17,), 6)
