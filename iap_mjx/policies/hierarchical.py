"""The paper's hierarchical quadruped policy (section 5.3, appendix A.2): a high level that sees
the first-person camera and a linear PMTG low level that walks.

Per control step, on ``"pixels+state"`` observations ``{"pixels": (H, W, 3), "state": (17,)}``:

- The **high level** (IAP, :class:`IAPPolicy`, whose presets choose the paper's deterministic
  ReLU features, ``kernel="relu"``; or the paper's CNN,
  :class:`~iap_mjx.policies.convnet.ConvNet`) maps the image to ``1 + latent_size``
  numbers in ``[-1, 1]``: a duration, then a latent command. It sees the camera only, no state
  sensors (``high_level_imu=True`` adds the IMU's roll, pitch and angular velocity, the state's
  first 5 entries): with no heading sensor on the robot, where the walls are is in the image
  alone, and the blind control below then has nothing else to go on either.
- The duration ``d`` maps linearly to ``round(lo + (d + 1) / 2 (hi - lo))`` control steps,
  ``(lo, hi) = duration_range``. The command is **held** that many steps: a counter in the
  policy state (:class:`HierarchyState`) counts them down, and only where it has run out
  (``counter == 0``, as at an episode's first step) do the latent and the counter take the
  high level's new output, through ``jnp.where``: under ``vmap`` each episode keeps its own
  schedule, with no data-dependent Python control flow. The high level is evaluated every step
  (a batched program computes both sides of a ``where`` anyway); its output is used only where
  the counter runs out. This is the authors' ``HierarchicalLevel`` (google-deepmind/iris,
  ``iris/policies/hierarchical_policy.py``): act when the countdown is 0, set it to the
  duration, count down by one every step.
- The **low level**, :class:`~iap_mjx.policies.pmtg.PMTGPolicy`, runs every control step on the
  held latent, the 17-d state (IMU and joint angles) and its TG phase.

``duration_range`` defaults to ``(10, 50)`` control steps, 0.2 s to 1 s (ours: the paper's text
gives no range). 0.2 s is half a period of the 2.5 Hz trot the low level starts from, one step of a
leg pair: a command held for less cannot change the gait's course before the next replaces
it. 1 s walks about 0.8 m at that trot (RESULTS.md, `quadruped-walking`), less than half the
1.9 m that at least separate two walls, so one command cannot carry the robot from the sight
of a wall past it unseen.

``blind=True`` zeroes the image before the high level sees it (its output is then a constant
of its parameters, the latent and duration it settles on): the control that tells whether the
other policies use their eyes.

ES trains both levels together, one flat parameter vector (``{"high": ..., "low": ...}``). The
low level starts at the PMTG policy's ``initial_tg`` (a trot that walks with no residuals), or,
with ``low_level_init`` (an ``.npz`` of ``w`` and ``b``, e.g. a trained ``quadruped-flat-pmtg``
run's, :func:`fold_normalisation`), from those weights; the presets start from ``initial_tg``.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from iap_mjx.attention import AttentionConfig
from iap_mjx.checks import is_int, require_choice, require_int
from iap_mjx.policies.base import check_options, constructor_options, field_names, lists_as_tuples, param_count
from iap_mjx.policies.convnet import ConvNet
from iap_mjx.policies.iap import IAPPolicy
from iap_mjx.policies.observations import pixel_shape
from iap_mjx.policies.pmtg import PMTGPolicy, PMTGState, TGConfig

HIGH_LEVELS = ("iap", "cnn")
IMU_SIZE = 5  # roll, pitch and the 3 angular velocities: the quadruped state's first entries


class HierarchyState(struct.PyTreeNode):
    """One episode's policy state (a leading batch axis under ``vmap``).

    Attributes:
      high: the high level's own per-episode state (IAP's ``(projections, carry)``: no arrays
        for ReLU features and a linear controller; ``()`` for the CNN).
      latent: ``(latent_size,)`` float32, the command held.
      counter: ``()`` int32, control steps the command still holds; 0: ask the high level.
      phase: ``()`` float32, the low level's TG phase.
    """

    high: Any
    latent: jax.Array
    counter: jax.Array
    phase: jax.Array


def duration_steps(duration: jax.Array, duration_range: tuple[int, int]) -> jax.Array:
    """``duration`` in ``[-1, 1]`` -> ``round(lo + (duration + 1) / 2 (hi - lo))`` int32 control
    steps in ``[lo, hi]`` (outside ``[-1, 1]`` it is clipped first)."""
    lo, hi = duration_range
    fraction = (jnp.clip(duration, -1.0, 1.0) + 1.0) * 0.5
    return jnp.round(lo + fraction * (hi - lo)).astype(jnp.int32)


def hold(counter: jax.Array, held: jax.Array, new: jax.Array, new_duration: jax.Array) -> tuple[jax.Array, jax.Array]:
    """One step of the countdown: ``(latent, counter)`` after this step.

    Where ``counter <= 0`` the command is replaced by ``new`` and the counter set to
    ``new_duration``; elsewhere ``held`` stays. Either way the counter then counts this step
    (minus one). Shapes: counters ``()`` int32, commands ``(k,)`` (one episode; ``vmap`` it).
    """
    expired = counter <= 0
    latent = jnp.where(expired, new, held)
    return latent, jnp.where(expired, new_duration, counter) - 1


@dataclasses.dataclass(frozen=True)
class HierarchicalPolicy:
    """High level (camera -> duration, latent) held by a countdown; PMTG low level every step.

    Attributes:
      high: the high level, an :class:`IAPPolicy` or a :class:`ConvNet` with
        ``1 + latent_size`` outputs in ``[-1, 1]``.
      low: the :class:`PMTGPolicy` low level (its ``latent`` sets ``latent_size``; its value is
        unused, the high level writes it).
      state_size: the length of the observation's ``"state"`` (the low level's input).
      duration_range: ``(lo, hi)`` control steps a command is held (module docstring).
      blind: zero the image before the high level sees it.
      high_level_imu: the high level also sees the IMU (the state's first 5 entries).
      low_level_init: ``None`` or an ``.npz`` with the low level's ``w`` and ``b``.
    """

    high: Any
    low: PMTGPolicy
    state_size: int
    duration_range: tuple[int, int] = (10, 50)
    blind: bool = False
    high_level_imu: bool = False
    low_level_init: str | None = None

    def __post_init__(self):
        lo_hi = tuple(self.duration_range)
        if len(lo_hi) != 2 or not all(is_int(v) for v in lo_hi) or not 1 <= lo_hi[0] <= lo_hi[1]:
            raise ValueError(
                "HierarchicalPolicy.duration_range must be (lo, hi) control steps, integers with "
                f"1 <= lo <= hi, got {self.duration_range!r}."
            )
        object.__setattr__(self, "duration_range", lo_hi)
        require_int("HierarchicalPolicy.state_size", self.state_size)
        if self.low.obs_size != self.state_size:
            raise ValueError(
                f"HierarchicalPolicy: the low level sees obs_size = {self.low.obs_size}, "
                f"the observation's state has {self.state_size}"
            )
        if self.high_output_size != 1 + self.latent_size:
            raise ValueError(
                f"HierarchicalPolicy: the high level gives {self.high_output_size} outputs; "
                f"it must give 1 + latent_size = {1 + self.latent_size} (a duration, the latent)"
            )
        if self.high_level_imu and self.state_size < IMU_SIZE:
            raise ValueError(
                f"HierarchicalPolicy.high_level_imu needs the state's first {IMU_SIZE} "
                f"entries (the IMU), the state has {self.state_size}"
            )
        if self.low_level_init is not None:
            self.low_level_params()  # a missing file or wrong shapes fail here, before compiling

    @property
    def action_size(self) -> int:
        return self.low.action_size

    @property
    def latent_size(self) -> int:
        return len(self.low.latent)

    @property
    def high_output_size(self) -> int:
        high = self.high
        return high.action_size if isinstance(high, IAPPolicy) else high.output_size

    def low_level_params(self) -> dict[str, jax.Array]:
        """The low level's ``{"w", "b"}`` read from ``low_level_init``, checked against its shapes."""
        if self.low_level_init is None:
            raise ValueError("policy.low_level_init is not set: no low level to load")
        return _load_low_level(self.low_level_init, self.low.input_size, self.low.output_size)

    def level_param_counts(self, params: dict[str, Any]) -> dict[str, int]:
        """``{"high": n, "low": n}``: the scalars in each level's params."""
        return {level: param_count(params[level]) for level in ("high", "low")}

    def init(self, key: jax.Array) -> dict[str, Any]:
        """``{"high": the high level's params, "low": {"w": (input, 16), "b": (16,)}}``."""
        high_key, low_key = jax.random.split(key)
        low = self.low.init(low_key) if self.low_level_init is None else self.low_level_params()
        return {"high": self.high.init(high_key), "low": low}

    def initial_state(self, key: jax.Array) -> HierarchyState:
        """The high level's state, a zero latent, the counter at 0 (the first step asks the
        high level), the TG phase at 0."""
        return HierarchyState(
            high=self.high.initial_state(key),
            latent=jnp.zeros((self.latent_size,), jnp.float32),
            counter=jnp.zeros((), jnp.int32),
            phase=jnp.zeros((), jnp.float32),
        )

    def high_observation(self, obs: dict[str, jax.Array]) -> Any:
        """What the high level sees of ``obs``: the image (zeros if ``blind``), with the IMU if
        ``high_level_imu``."""
        pixels = obs["pixels"]
        if self.blind:
            pixels = jnp.zeros_like(pixels)
        if self.high_level_imu:
            return {"pixels": pixels, "state": jnp.ravel(obs["state"])[:IMU_SIZE]}
        return pixels

    def apply(self, params: dict[str, Any], obs: dict[str, jax.Array], policy_state: HierarchyState):
        """One control step: ``(action (12,) in [-1, 1], new HierarchyState)``."""
        if not isinstance(obs, dict):
            raise ValueError(
                "the hierarchical policy needs {'pixels', 'state'} observations: make the "
                "env with obs_mode='pixels+state'"
            )
        out, high_state = self.high.apply(params["high"], self.high_observation(obs), policy_state.high)
        expired = policy_state.counter <= 0
        high_state = jax.tree.map(lambda new, old: jnp.where(expired, new, old), high_state, policy_state.high)
        latent, counter = hold(
            policy_state.counter, policy_state.latent, out[1:], duration_steps(out[0], self.duration_range)
        )
        action, low_state = self.low.apply(
            params["low"], jnp.ravel(obs["state"]), PMTGState(latent=latent, phase=policy_state.phase)
        )
        return action, HierarchyState(high=high_state, latent=latent, counter=counter, phase=low_state.phase)


@dataclasses.dataclass(frozen=True)
class AttentiveHierarchicalPolicy(HierarchicalPolicy):
    """A :class:`HierarchicalPolicy` whose high level is IAP and sees: it also shows which
    patches it selects (``layer``, ``select``: the videos outline them)."""

    @property
    def layer(self):
        """The high level's attention layer."""
        return self.high.layer

    def select(self, params: dict[str, Any], obs: dict[str, jax.Array], policy_state: HierarchyState):
        """The high level's ``Selection`` on ``obs`` (what it would pick were it asked now)."""
        return self.high.select(params["high"], self.high_observation(obs), policy_state.high)


def fold_normalisation(
    w: np.ndarray, b: np.ndarray, mean: np.ndarray, var: np.ndarray, latent_size: int
) -> tuple[np.ndarray, np.ndarray]:
    """A PMTG low level trained on normalised observations (``iap_mjx.es.normalizer``:
    ``(obs - mean) / sqrt(var + 1e-8)``, clipped at 5 standard deviations) as weights on raw
    observations: ``w`` ``(latent + obs + 2, 16)``, ``b`` ``(16,)``, ``mean``/``var``
    ``(obs,)``. Exact while no observation is clipped (beyond 5 standard deviations)."""
    w, b = np.asarray(w, np.float64), np.asarray(b, np.float64)
    std = np.sqrt(np.asarray(var, np.float64) + 1e-8)
    rows = slice(latent_size, latent_size + std.shape[0])
    folded = w.copy()
    folded[rows] = w[rows] / std[:, None]
    bias = b - (np.asarray(mean, np.float64) / std) @ w[rows]
    return folded.astype(np.float32), bias.astype(np.float32)


def commanded_low_level(w: np.ndarray, b: np.ndarray, latent_size: int) -> tuple[np.ndarray, np.ndarray]:
    """A PMTG low level trained on ``quadruped-turn`` as the hierarchy's: the command it observed
    becomes the latent's first entry.

    ``w`` ``(latent_size + 1 + state + 2, 16)`` reads ``[latent (constant zero in training, so
    its rows are dropped), command, state, cos phi, sin phi]`` on raw observations (fold a run's
    normalisation in first: :func:`fold_normalisation`). The result, ``(latent_size + state + 2,
    16)``, reads ``[latent, state, cos phi, sin phi]``: the command's row as the latent's first,
    zero rows for the others, so the hierarchy's low level on latent ``(c, 0, ...)`` acts exactly
    as the trained policy on command ``c``. ``b`` is unchanged."""
    w = np.asarray(w, np.float32)
    latent = np.zeros((latent_size, w.shape[1]), np.float32)
    latent[0] = w[latent_size]
    return np.concatenate([latent, w[latent_size + 1 :]]), np.asarray(b, np.float32)


def low_level_weights(policy: PMTGPolicy, params: dict[str, Any], obs_stats: Any, env_name: str):
    """``(w, b)`` of a trained ``quadruped-flat-pmtg`` or ``quadruped-turn-pmtg`` run (its
    ``policy``, centre ``params``, observation statistics and env's name) as the hierarchy's low
    level reads them (an ``.npz`` of them is ``policy.low_level_init``): the normalisation folded
    in (:func:`fold_normalisation`), a turn run's command moved into the latent
    (:func:`commanded_low_level`)."""
    latent = len(policy.latent)
    w, b = fold_normalisation(params["w"], params["b"], obs_stats.mean, obs_stats.var, latent)
    if env_name == "quadruped-turn":
        w, b = commanded_low_level(w, b, latent)
    return w, b


def _load_low_level(path: str, input_size: int, output_size: int) -> dict[str, jax.Array]:
    if not Path(path).is_file():
        raise ValueError(
            f"HierarchicalPolicy.low_level_init = {path!r}: no such file (an .npz with the low level's w and b)"
        )
    with np.load(path) as stored:
        if "w" not in stored or "b" not in stored:
            raise ValueError(
                f"HierarchicalPolicy.low_level_init = {path!r} must hold arrays 'w' and 'b', "
                f"it holds {sorted(stored.files)}"
            )
        w, b = np.asarray(stored["w"], np.float32), np.asarray(stored["b"], np.float32)
    if w.shape != (input_size, output_size) or b.shape != (output_size,):
        raise ValueError(
            f"HierarchicalPolicy.low_level_init = {path!r}: w {w.shape}, b {b.shape}; the low "
            f"level needs w ({input_size}, {output_size}) and b ({output_size},)"
        )
    return {"w": jnp.asarray(w), "b": jnp.asarray(b)}


# What a ``policy.*`` option can set on each part: its constructor's arguments but those the
# factory below passes itself (shapes, sizes, the parts, sub-configs).
_IAP_FIELDS = constructor_options(IAPPolicy, "image_shape", "action_size", "attention", "state_size")
_CNN_FIELDS = constructor_options(ConvNet, "image_shape", "output_size", "state_size")
_HIERARCHY_FIELDS = constructor_options(HierarchicalPolicy, "high", "low", "state_size")
_LOW_FIELDS = constructor_options(PMTGPolicy, "obs_size", "action_size", "latent", "tg")


def make_hierarchical_policy(
    observation_shape: Any, action_size: int, *, high_level: str = "iap", latent_size: int = 4, **options: Any
) -> HierarchicalPolicy:
    """Factory for ``policies.make("hierarchical", ...)`` on ``"pixels+state"`` observations.

    ``high_level``: ``"iap"`` (the IAP high level; its attention options ``kernel``,
    ``patch_size``, ``stride``, ``top_l``, ... and ``controller``, ``hidden_sizes``, ...) or
    ``"cnn"`` (:class:`ConvNet`: ``channels``, ``strides``, ``filter_size``, ``pool``,
    ``hidden_size``). ``latent_size``: the latent command's length. The TG's fields
    (``gait``, ``residual_range``, ...) and ``initial_tg`` go to the low level;
    ``duration_range``, ``blind``, ``high_level_imu``, ``low_level_init`` to the hierarchy.
    An option that belongs to neither raises ``ValueError`` naming it.
    """
    require_choice("HierarchicalPolicy.high_level", high_level, HIGH_LEVELS)
    require_int("HierarchicalPolicy.latent_size", latent_size)
    if not isinstance(observation_shape, dict) or set(observation_shape) != {"pixels", "state"}:
        raise ValueError(
            f"the hierarchical policy needs {{'pixels', 'state'}} observations, got shape "
            f"{observation_shape!r}: make the env with obs_mode='pixels+state' or 'depth+state'"
        )
    image_shape, state_size = pixel_shape(observation_shape)
    options = lists_as_tuples(options)
    attention_fields = field_names(AttentionConfig)
    tg_fields = field_names(TGConfig)
    high_fields = attention_fields | _IAP_FIELDS if high_level == "iap" else _CNN_FIELDS
    valid = high_fields | tg_fields | _HIERARCHY_FIELDS | _LOW_FIELDS | {"high_level", "latent_size"}
    # high_level and latent_size come as keywords, never in options: listed in valid so that a
    # misspelt option's error names them among the settings there are
    check_options("hierarchical", options, valid)
    pick = lambda names: {k: v for k, v in options.items() if k in names}  # noqa: E731
    imu = IMU_SIZE if options.get("high_level_imu") else 0
    outputs = 1 + latent_size
    high: IAPPolicy | ConvNet
    if high_level == "iap":
        attention = AttentionConfig(**pick(attention_fields))
        high = IAPPolicy(image_shape, outputs, attention, state_size=imu, **pick(_IAP_FIELDS))
    else:
        high = ConvNet(image_shape, outputs, state_size=imu, **pick(_CNN_FIELDS))
    low = PMTGPolicy(
        state_size, action_size, latent=(0.0,) * latent_size, tg=TGConfig(**pick(tg_fields)), **pick(_LOW_FIELDS)
    )
    cls = AttentiveHierarchicalPolicy if high_level == "iap" and not options.get("blind") else HierarchicalPolicy
    return cls(high, low, state_size, **pick(_HIERARCHY_FIELDS))


__all__ = [
    "AttentiveHierarchicalPolicy",
    "HierarchicalPolicy",
    "HierarchyState",
    "duration_steps",
    "fold_normalisation",
    "hold",
    "make_hierarchical_policy",
]
