"""The shared setting checks: ``bool`` is never an int, and the error names the setting."""

import jax.numpy as jnp
import pytest

from iap_mjx import policies
from iap_mjx.attention import AttentionConfig, IAPAttention
from iap_mjx.attention.features import closed_form_mse
from iap_mjx.attention.patches import patch_grid
from iap_mjx.checks import is_int, is_number, require_bool, require_choice, require_int, require_number
from iap_mjx.policies import pmtg
from iap_mjx.render import CameraConfig


def test_bool_is_neither_int_nor_number():
    assert is_int(3) and is_int(0) and is_int(-2)
    assert not is_int(True) and not is_int(False) and not is_int(2.0) and not is_int(None)
    assert is_number(3) and is_number(0.5)
    assert not is_number(True) and not is_number("1") and not is_number(None)


def test_require_int_names_the_setting_and_the_range():
    require_int("es.population", 1)
    require_int("seed", 0, 0)
    require_int("stride", None, none_ok=True)
    with pytest.raises(ValueError, match=r"^es\.population must be an int >= 1, got 0\.$"):
        require_int("es.population", 0)
    with pytest.raises(ValueError, match=r"^seed must be an int >= 0, got True\.$"):
        require_int("seed", True, 0)
    with pytest.raises(ValueError, match=r"^stride must be an int >= 1 or None, got 2\.5\.$"):
        require_int("stride", 2.5, none_ok=True)
    with pytest.raises(ValueError, match="got None"):
        require_int("stride", None)


def test_require_number_checks_type_before_range():
    from iap_mjx.configs.env import EnvConfig

    require_number("es.sigma", 0.1, 0, low_open=True)
    require_number("rate", 3, 0, 3, low_open=True)
    with pytest.raises(ValueError, match=r"^es\.sigma must be a number > 0, got 0\.$"):
        require_number("es.sigma", 0, 0, low_open=True)
    with pytest.raises(ValueError, match=r"^rate must be a number in \(0, 3\] \(rad/s\), got 3\.5\.$"):
        require_number("rate", 3.5, 0, 3, low_open=True, unit="rad/s")
    with pytest.raises(ValueError, match=r"^budget must be a finite number >= 0, got inf\.$"):
        require_number("budget", float("inf"), 0, high_open=True)
    for bad in ("abc", True, float("nan"), None):  # a ValueError naming the setting, never a TypeError
        with pytest.raises(ValueError, match="env.max_abs_state must be a number > 0"):
            EnvConfig(max_abs_state=bad)


def test_require_bool_takes_only_true_and_false():
    require_bool("es.antithetic", True)
    require_bool("es.antithetic", False)
    for bad in (1, 0, "true", None):
        with pytest.raises(ValueError, match=rf"^es\.antithetic must be true or false, got {bad!r}\.$"):
            require_bool("es.antithetic", bad)


def test_require_choice_lists_every_valid_value_in_order():
    require_choice("env.solver", "cg", ("newton", "cg"))
    with pytest.raises(ValueError, match=r"^env\.solver must be one of newton, cg, got 'CG'\.$"):
        require_choice("env.solver", "CG", ("newton", "cg"))
    with pytest.raises(ValueError, match=r"^gait must be one of pace, trot, walk, got 1\.$"):
        require_choice("gait", 1, {"walk", "trot", "pace"})  # a set's values sorted
    with pytest.raises(ValueError, match="got True"):  # True == 1, but it is not the choice 1
        require_choice("n", True, (1, 2))
    with pytest.raises(ValueError, match=r"got \['cg'\]"):  # unhashable: refused, not a TypeError
        require_choice("env.solver", ["cg"], ("newton", "cg"))


@pytest.mark.parametrize(
    "override, message",
    [
        ("env.obs_mode=rgb", "env.obs_mode must be one of state, pixels, "),
        ("env.height=-3", "env.height must be an int >= 1, got -3."),
        ("env.dynamic=maybe", "dynamic must be true or false, got 'maybe'."),
        ("es.antithetic=maybe", "es.antithetic must be true or false, got 'maybe'."),
        ("es.optimizer=lbfgs", "es.optimizer must be one of adam, sgd, momentum, got 'lbfgs'."),
        ("es.population_size=3", "es.population_size must be even with antithetic sampling, got 3."),
    ],
)
def test_a_bad_setting_is_named_as_the_command_line_sets_it(override, message):
    """One format for every bad setting, ``<setting> must be <valid>, got <value>.``, naming the
    env's settings by the ``env.<field>`` a user types (not the config class)."""
    from iap_mjx import configs, envs

    with pytest.raises(ValueError) as error:
        config = configs.apply_overrides(configs.get("dcs-cartpole-swingup-quick"), (override,))
        envs.check_spec(config.env)
    assert message in str(error.value)


def _hierarchy(**options):
    shape = {"pixels": (12, 16, 3), "state": (17,)}
    return policies.make("hierarchical", shape, 12, kernel="relu", patch_size=4, top_l=2, **options)


@pytest.mark.parametrize(
    "build, setting, got",
    [
        (lambda: policies.make("attention", (8, 8, 3), 2), "policy.kind", "'attention'"),
        (lambda: policies.ConvNet((16, 16, 3), 2, channels=()), "ConvNet.channels", "()"),
        (lambda: policies.ConvNet((16, 16, 3), 2, strides=(2, 2)), "ConvNet.strides", "(2, 2)"),
        (lambda: pmtg.TGConfig(frequency_range=(2.0, 1.0)), "TGConfig.frequency_range", "(2.0, 1.0)"),
        (lambda: pmtg.TGConfig(intensity_range=(-0.1, 0.5)), "TGConfig.intensity_range", "(-0.1, 0.5)"),
        (lambda: pmtg.TGConfig(ratio_range=(0.0, 1.0)), "TGConfig.ratio_range", "(0.0, 1.0)"),
        (lambda: pmtg.PMTGPolicy(17, 8), "PMTGPolicy.action_size", "8"),
        (lambda: pmtg.PMTGPolicy(17, initial_tg=(1.0, 2.0)), "PMTGPolicy.initial_tg", "(1.0, 2.0)"),
        (lambda: _hierarchy(duration_range=(0, 5)), "HierarchicalPolicy.duration_range", "(0, 5)"),
        (lambda: AttentionConfig(row_normalize=True), "AttentionConfig.row_normalize", "True"),
        (lambda: IAPAttention(AttentionConfig(top_l=30), (8, 8, 3)), "AttentionConfig.top_l", "30"),
        (lambda: IAPAttention(AttentionConfig(), (8, 8)), "IAPAttention.image_shape", "(8, 8)"),
        (lambda: patch_grid(4, 8, 5, 1), "patch_size", "5"),
        (lambda: closed_form_mse("sin", jnp.zeros(3), jnp.zeros(3), m=4), "closed_form_mse's kind", "'sin'"),
        (lambda: CameraConfig(camera_id=-1), "CameraConfig.camera_id", "-1"),
        (lambda: CameraConfig(shading="phong"), "CameraConfig.shading", "'phong'"),
        (lambda: CameraConfig(geom_groups=(7,)), "CameraConfig.geom_groups", "(7,)"),
    ],
)
def test_policy_attention_and_camera_settings_fail_in_the_one_format(build, setting, got):
    """``<setting> must be <valid>, got <value>.`` for the policies', the attention layer's and
    the camera's own checks too (settings named by their class, as Python sets them)."""
    with pytest.raises(ValueError) as error:
        build()
    message = str(error.value)
    assert message.startswith(f"{setting} must be "), message
    assert message.endswith(f", got {got}."), message
