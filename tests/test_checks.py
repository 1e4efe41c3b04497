"""The shared setting checks: ``bool`` is never an int, and the error names the setting."""

import pytest

from iap_mjx.checks import is_int, is_number, require_bool, require_choice, require_int, require_number


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
        envs.check(config.env.name, **dict(config.env.overrides))
    assert message in str(error.value)
