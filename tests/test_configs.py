"""Configs: validation names the field, overrides parse and coerce, presets round-trip."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys

import pytest

import iap_mjx
from iap_mjx import configs
from iap_mjx.configs import EnvConfig, ESConfig, PolicySpec, RunConfig, TrainConfig, apply_overrides
from iap_mjx.configs.distraction import DistractionConfig
from iap_mjx.configs.env import DISTRACTION_FIELDS, DISTRACTION_SETTINGS, QuadrupedConfig


@pytest.mark.parametrize("name", configs.names())
def test_every_preset_builds_hashes_and_round_trips_through_json(name):
    config = configs.get(name)
    hash(config)
    again = TrainConfig.from_dict(json.loads(json.dumps(config.to_dict())))
    assert again == config
    assert configs.describe(name)


def test_unknown_preset_lists_the_valid_ones():
    with pytest.raises(ValueError) as error:
        configs.get("no-such-preset")
    for name in configs.names():
        assert name in str(error.value)


@pytest.mark.parametrize(
    "make, field",
    [
        (lambda: ESConfig(population_size=7), "es.population_size"),
        (lambda: ESConfig(sigma=0.0), "es.sigma"),
        (lambda: ESConfig(optimizer="adamw"), "es.optimizer"),
        (lambda: ESConfig(shaping="ranks"), "es.shaping"),
        (lambda: ESConfig(strategy="NotAnES"), "es.strategy"),
        (lambda: ESConfig(n_episodes=0), "es.n_episodes"),
        (lambda: ESConfig(shared_episodes=1), "es.shared_episodes"),
        (lambda: ESConfig(sigma_schedule="cosine"), "es.sigma_schedule"),
        (lambda: RunConfig(iterations=-1), "run.iterations"),
        (lambda: RunConfig(iterations_per_call=4, checkpoint_every=10), "run.checkpoint_every"),
        (lambda: RunConfig(eval_episodes=-1), "run.eval_episodes"),
        (lambda: RunConfig(chunk_size=0), "run.chunk_size"),
        (lambda: PolicySpec(kind="transformer"), "policy.kind"),
        (lambda: PolicySpec(options=(("hidden_sizes", [8]),)), "policy.options"),
    ],
)
def test_invalid_values_fail_naming_the_field(make, field):
    with pytest.raises(ValueError, match=field.replace(".", r"\.")):
        make()


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda: EnvConfig(episode_length=True), r"env\.episode_length must be an int >= 1 or None, got True"),
        (lambda: EnvConfig(camera_id=False), r"env\.camera_id must be an int >= 0, got False"),
        (
            lambda: EnvConfig(frame_stack=2, height=64),
            r"env: height=64, frame_stack=2 set the camera of a pixel obs_mode, but obs_mode is 'state'",
        ),
        (lambda: QuadrupedConfig(action_repeat=2), r"env\.action_repeat must be 1 .*, got 2"),
    ],
)
def test_bad_env_settings_are_refused_naming_them(make, message):
    with pytest.raises(ValueError, match=message):
        make()
    assert QuadrupedConfig(action_repeat=1).action_repeat == 1


def test_cmaes_needs_no_even_population():
    assert ESConfig(strategy="CMA_ES", population_size=7, antithetic=False).population_size == 7


def test_overrides_parse_coerce_and_route():
    base = configs.get("cheetah-run-state-mlp")
    config = apply_overrides(
        base,
        [
            "iterations=5",
            "es.sigma=1",
            "es.antithetic=true",
            "policy.hidden_sizes=64,64",
            "es.optimizer=sgd",
            "env.episode_length=100",
            "run.seed=3",
            "policy.activation='relu'",
        ],
    )
    assert config.run.iterations == 5 and config.run.seed == 3
    assert config.es.sigma == 1.0 and isinstance(config.es.sigma, float)
    assert config.es.optimizer == "sgd"
    assert dict(config.policy.options) == {"hidden_sizes": (64, 64), "activation": "relu"}
    assert dict(config.env.overrides) == {"episode_length": 100}
    assert base == configs.get("cheetah-run-state-mlp")  # presets are fresh values
    hash(config)


@pytest.mark.parametrize(
    "override, message",
    [
        ("es.sigma=-1", r"es\.sigma"),
        ("nope=1", "not a config field"),
        ("run.nope=1", "run has no field 'nope'"),
        ("bogus.x=1", "unknown section"),
        ("es.population_size", "key=value"),
        ("es.population_size=33", r"es\.population_size"),
        ("es.sigma_final=0.05", r"es\.sigma_final is the end of a sigma_schedule"),
    ],
)
def test_bad_overrides_fail_with_the_field(override, message):
    with pytest.raises(ValueError, match=message):
        apply_overrides(configs.get("cheetah-run-state"), [override])


@pytest.mark.parametrize(
    "overrides",
    [
        ("es.population_size=33", "es.antithetic=false"),
        ("es.sigma_final=0.05", "es.sigma_schedule=linear"),
        ("policy.top_l=5", "policy.patch_size=2", "env.height=64"),
    ],
)
def test_overrides_that_depend_on_each_other_apply_in_either_order(overrides):
    """Each section is validated once with all its overrides: one valid only beside another
    does not fail for coming first."""
    base = configs.get("cheetah-run-pixels")
    forward = apply_overrides(base, overrides)
    assert forward == apply_overrides(base, overrides[::-1]) != base


def test_an_override_given_twice_keeps_its_last_value():
    base = configs.get("cheetah-run-pixels")
    config = apply_overrides(base, ["es.sigma=0.2", "policy.top_l=5", "es.sigma=0.1", "policy.top_l=7"])
    assert config.es.sigma == 0.1 and dict(config.policy.options)["top_l"] == 7


@pytest.mark.parametrize(
    "override, path",
    [
        ("iterations=5", "run.iterations"),
        ("es.sigma = 1", "es.sigma"),
        ("policy.patch_size=2", "policy.patch_size"),
        ("env.distraction=none", "env.distraction"),
    ],
)
def test_override_path_names_the_setting_an_override_sets(override, path):
    assert configs.override_path(override) == path


def test_quadruped_solver_defaults_are_the_robot_models():
    """The config repeats the A1 model's solver settings as literals (configs import no JAX):
    they must stay equal, or a default run would not use the MJCF's solver."""
    from iap_mjx.robots import a1

    config = QuadrupedConfig()
    assert (config.solver, config.solver_iterations, config.ls_iterations) == (
        a1.SOLVER,
        a1.ITERATIONS,
        a1.LS_ITERATIONS,
    )


def test_the_strategy_and_policy_names_are_evosaxs_and_the_policy_tables():
    """Configs list evosax's strategies and the policy kinds as literals (importing evosax or
    the policies loads JAX): they must stay equal, or a valid name would be refused."""
    from evosax.algorithms import distribution_based_algorithms

    from iap_mjx import policies
    from iap_mjx.configs.training import EVOSAX_STRATEGIES, POLICY_KINDS
    from iap_mjx.es.strategy import usable_evosax_algorithm

    usable = [name for name, algorithm in distribution_based_algorithms.items() if usable_evosax_algorithm(algorithm)]
    assert sorted(EVOSAX_STRATEGIES) == sorted(usable)
    assert {"SV_CMA_ES", "SV_Open_ES"} <= set(distribution_based_algorithms) - set(usable)
    assert sorted(POLICY_KINDS) == policies.names()


def test_importing_the_configs_and_building_the_presets_loads_no_jax():
    """A notebook may build a config before ``runtime.setup()``, which must run before JAX starts;
    the package's one-call entry points load it on first use."""
    code = (
        "import sys, iap_mjx; from iap_mjx import configs; configs.get('dcs-cartpole-swingup'); "
        "print('jax' in sys.modules); from iap_mjx import es; "
        "print(iap_mjx.train is es.train, iap_mjx.load_run is es.load_run, iap_mjx.evaluate_run is es.evaluate_run)"
    )
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.split() == ["False", "True", "True", "True"]
    with pytest.raises(AttributeError, match="no attribute 'trian'"):
        iap_mjx.trian


def test_configs_are_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        configs.get("cheetah-run-state").run.iterations = 3


def test_none_is_a_string_setting_and_None_or_null_is_None():
    assert configs.parse_value("none") == "none"  # e.g. the attention's scaling=none
    assert configs.parse_value("None") is None and configs.parse_value("null") is None
    config = apply_overrides(configs.get("cheetah-run-pixels"), ["policy.scaling=none", "env.episode_length=None"])
    assert dict(config.policy.options)["scaling"] == "none"
    assert dict(config.env.overrides)["episode_length"] is None


def test_env_config_distraction_fields_are_distraction_configs():
    """``EnvConfig``'s distraction fields set ``DistractionConfig``'s, every one of them, by
    ``DISTRACTION_FIELDS``; left at their defaults they give ``DistractionConfig``'s."""
    env_fields = {field.name: field.default for field in dataclasses.fields(EnvConfig)}
    assert set(DISTRACTION_FIELDS) <= set(env_fields)
    assert sorted(DISTRACTION_FIELDS.values()) == sorted(f.name for f in dataclasses.fields(DistractionConfig))
    assert all(env_fields[name] in (None, False) for name in DISTRACTION_SETTINGS)
    config = EnvConfig(obs_mode="pixels", distraction="hard")
    assert config.distraction_config() == DistractionConfig(difficulty="hard")


def test_distraction_settings_are_validated_without_the_envs():
    """Configs sit below the envs: importing them and validating a distraction (its background
    set included) in a fresh interpreter loads no ``iap_mjx.envs``, ``iap_mjx.es`` or MuJoCo."""
    code = (
        "import sys; from iap_mjx.configs import EnvConfig; "
        "EnvConfig(obs_mode='pixels', distraction='medium').distraction_config(); "
        "print(' '.join(m for m in sys.modules if m.split('.')[0] in ('mujoco', 'orbax') "
        "or m.startswith(('iap_mjx.envs', 'iap_mjx.es'))))"
    )
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert loaded.split() == []
