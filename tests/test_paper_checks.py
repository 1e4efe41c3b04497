"""Every report refuses, before anything compiles, a setting that would leave it nothing to
read (no evaluation episodes) or that it sets itself per run (what it sweeps)."""

import pytest

from iap_mjx.paper import fig1_fig6, fig7, fig8, fig11, gates, table1, table2
from iap_mjx.paper.report_runs import check_evaluated, check_not_swept

NO_EVALUATION = ("run.eval_episodes=0",)

CHECKS = {
    "fig1": lambda overrides: fig1_fig6.check("fig1", overrides),
    "fig6": lambda overrides: fig1_fig6.check("fig6", overrides),
    "fig7": lambda overrides: fig7.check(overrides),
    "fig8": lambda overrides: fig8.check(overrides),
    "fig11": lambda overrides: fig11.check(overrides),
    "gates": lambda overrides: gates.check(overrides),
    "table1": lambda overrides: table1.check(("cartpole-swingup",), overrides),
    "table2": lambda overrides: table2.check(((4, 4), (2, 2)), overrides, 0),
}


@pytest.mark.parametrize("report", sorted(CHECKS))
def test_every_report_refuses_a_run_without_evaluation(report):
    CHECKS[report](())  # the report's own settings pass
    with pytest.raises(ValueError, match=f"^{report} reads the evaluation return: run.eval_episodes must be >= 1$"):
        CHECKS[report](NO_EVALUATION)


@pytest.mark.parametrize(
    ("report", "override"),
    [("fig7", "policy.d_qk=4"), ("fig8", "policy.kernel=relu"), ("table2", "policy.stride=2")],
)
def test_sweeps_refuse_an_override_of_what_they_vary(report, override):
    with pytest.raises(ValueError, match=f"^{report} sets .*; remove {override}$"):
        CHECKS[report](("es.sigma=0.1", override))


@pytest.mark.parametrize("override", ["run.seed=1", "seed=1"])
@pytest.mark.parametrize("report", sorted(CHECKS))
def test_every_report_refuses_a_seed_override_which_its_own_seeds_would_replace(report, override):
    with pytest.raises(ValueError, match=f"^{report} sets each run's seed itself .*; remove {override}$"):
        CHECKS[report](("es.sigma=0.1", override))


@pytest.mark.parametrize("figure", ["fig1", "fig6"])
def test_fig1_and_fig6_refuse_a_seed_override_before_writing_anything(figure, tmp_path, monkeypatch):
    import iap_mjx.es

    def trains(config, **kwargs):
        raise AssertionError(f"{figure} trained with seed=1")

    monkeypatch.setattr(iap_mjx.es, "train", trains)  # nothing may start
    out = tmp_path / "out"
    with pytest.raises(ValueError, match=f"^{figure} sets each run's seed itself .*; remove seed=1$"):
        fig1_fig6.reproduce_fig1_fig6(figure, out, overrides=("seed=1",))
    assert not out.exists()


def test_check_not_swept_names_every_swept_override_and_nothing_else():
    swept = ("policy.patch_size", "policy.stride")
    check_not_swept("t", ("es.sigma=0.1", "policy.patch_size_extra=1"), swept, "x")  # no swept key
    with pytest.raises(ValueError, match=r"^t sets the sizes; remove policy.patch_size=2, policy.stride = 1$"):
        check_not_swept("t", ("policy.patch_size=2", "es.sigma=0.1", "policy.stride = 1"), swept, "the sizes")
    with pytest.raises(ValueError, match=r"^t sets the seed; remove seed=2$"):  # a key without its section
        check_not_swept("t", ("iterations=3", "seed=2"), ("run.seed",), "the seed")


def test_check_evaluated_reads_every_config():
    from iap_mjx import configs

    good = configs.get("cartpole-swingup-pixels")
    bad = configs.apply_overrides(good, NO_EVALUATION)
    check_evaluated("t", [good, good])
    with pytest.raises(ValueError, match="^t reads"):
        check_evaluated("t", iter([good, bad]))  # the last one counts too, from a generator
