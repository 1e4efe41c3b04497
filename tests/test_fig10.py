"""``iap-mjx reproduce fig10``: runs that cannot show selected patches fail before anything
compiles; each run's strip is the course seen from the camera that follows the robot with its
camera inset, scaled up with the high level's patches in red, named by its patch size and
stride, and the section shows both. The episode itself is
``viz.recording.record_episode``'s (tested in test_video.py; the quadruped's compiles for minutes), so
here it is a hand-made record drawn by the real strip code."""

from __future__ import annotations

import shutil
import types

import jax
import mujoco
import numpy as np
import pytest
from fake_runs import fake_run
from mujoco import mjx
from PIL import Image

from iap_mjx import cli, configs
from iap_mjx.configs.training import EVAL_SEED
from iap_mjx.es import checkpoint
from iap_mjx.paper import fig10, table2
from iap_mjx.viz import drawing, recording, video

STEPS = 1000  # quadruped-walls' episode
SMALL = [(row, col) for row in (6, 16) for col in (2, 8, 14, 20, 26)]  # far enough apart that no rings overlap


def _run(out, preset, overrides=()):
    config = configs.apply_overrides(configs.get(preset), ("run.iterations=2", *overrides))
    fake_run(out / f"{preset}-{'-'.join(overrides) or 'own'}", config, 2, [1.0, 2.0])
    return out / f"{preset}-{'-'.join(overrides) or 'own'}"


def scene_pose(env):
    """The scene camera's poses (``recording.state_camera``) of the course at its model's own
    state, as a recorded episode keeps them at each step."""
    data = mujoco.MjData(env.mj_model)
    mujoco.mj_forward(env.mj_model, data)
    return {
        name: np.asarray(value)
        for name, value in recording.state_camera(env).poses(mjx.put_data(env.mj_model, data)).items()
    }


@pytest.fixture
def episodes(monkeypatch):
    """Recorded episode keys; a black episode whose high level selects the same patches at
    every step (a patch-1 run: :data:`SMALL`; the patch-4 run: 9, its (row 1, col 1)), 0.01
    reward a step."""
    keys = []

    def load_run(run_dir, *, env=None, policy=None):
        assert env is not None and policy is not None  # the ones fig10's check built, not built again
        config = configs.TrainConfig.from_dict(checkpoint.load_config(run_dir))
        return types.SimpleNamespace(config=config, env=env, policy=policy, params="params", obs_stats=None)

    def record_episode(env, policy, params, key, *, steps, obs_stats=None, program=None):
        assert params == "params" and steps == STEPS
        keys.append(np.asarray(key).tolist())
        small = policy.layer.config.patch_size == 1
        first = np.array([32 * row + col for row, col in SMALL]) if small else np.full(10, 9)
        return {
            "frames": np.zeros((steps, 24, 32, 3), np.float32),
            "indices": np.tile(first, (steps, 1)),
            "scene": {name: np.repeat(pose[None], steps, axis=0) for name, pose in scene_pose(env).items()},
            "rewards": np.full(steps, 0.01),
            "alive": np.ones(steps, bool),  # as the real record: an episode that lasts every step
        }

    from iap_mjx import es

    monkeypatch.setattr(es, "load_run", load_run)
    monkeypatch.setattr(recording, "record_episode", record_episode)
    return keys


def test_runs_that_show_no_patches_fail_before_anything_compiles(tmp_path, capsys):
    blind = _run(tmp_path, "quadruped-walls-blind")
    with pytest.raises(ValueError, match="selects no patches"):
        fig10.reproduce_fig10(tmp_path / "out", run_dirs=(blind,))
    with pytest.raises(ValueError, match="no checkpoint"):
        fig10.reproduce_fig10(tmp_path / "out")  # the default runs: none in out
    small = _run(tmp_path, "quadruped-walls-iap", table2.setting_overrides(1, 1))
    with pytest.raises(ValueError, match="distinct run directories"):
        fig10.reproduce_fig10(tmp_path / "out", run_dirs=(small, small))
    again = tmp_path / "again"
    shutil.copytree(small, again)
    with pytest.raises(ValueError, match="same patch size and stride"):
        fig10.reproduce_fig10(tmp_path / "out", run_dirs=(small, again))
    with pytest.raises(ValueError, match="frames"):
        fig10.reproduce_fig10(tmp_path / "out", run_dirs=(small,), frames=0)
    assert not (tmp_path / "out").exists()
    assert cli.main(["reproduce", "fig10", "--run-dirs", str(blind), "--out", str(tmp_path / "out")]) == 2
    assert "selects no patches" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_:  # fig10 draws the runs as trained: no overrides
        cli.main(["reproduce", "fig10", "env.n_walls=2", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert exit_.value.code == 2 and "iap-mjx reproduce fig10: error: unrecognized arguments: env.n_walls=2" in err


def test_strips_show_the_scene_with_the_camera_scaled_and_the_selected_patches_inset(tmp_path, episodes):
    small = _run(tmp_path, "quadruped-walls-iap", table2.setting_overrides(1, 1))
    large = _run(tmp_path, "quadruped-walls-iap")
    results = tmp_path / "RESULTS.md"
    markdown = fig10.reproduce_fig10(tmp_path, run_dirs=(small, large), frames=3, results=results)
    unseen = np.asarray(jax.random.PRNGKey(EVAL_SEED)).tolist()
    assert episodes == [unseen] * 2  # a course not seen in training, the same for both
    (height, width), margin = recording.SCENE_VIDEO_SIZE, drawing.INSET_MARGIN
    view_h, view_w = (
        16 + 24 * video.STRIP_SCENE_SCALE,
        32 * video.STRIP_SCENE_SCALE,
    )  # the camera, scaled, under its caption
    top, left = margin, width - margin - view_w  # the view's corner in each tile: top right
    env = fig10.check((small,))[small][1]
    # the strip's three frames of one pose, rendered by the same program (a batch of 3)
    scene = recording.render_scene(
        env, {name: np.repeat(pose[None], 3, axis=0) for name, pose in scene_pose(env).items()}
    )[0]
    assert scene.std() > 10  # a picture of the course, not a blank
    tiles = {}
    for name in ("fig10-p1-s1.png", "fig10-p4-s4.png"):
        image = np.asarray(Image.open(tmp_path / name).convert("RGB"))
        assert image.shape == (height, 3 * width + 2 * 4, 3)  # 3 tiles, 2 white gaps
        first = image[:, :width]
        outside = np.ones((height, width), bool)
        outside[top - 2 : top + view_h + 2, left - 2 : left + view_w + 2] = False
        np.testing.assert_array_equal(first[outside], scene[outside])  # the course around the inset
        ring = first[top - 2 : top + view_h + 2, left - 2 : left + view_w + 2].copy()
        ring[2:-2, 2:-2] = 255
        assert (ring == 255).all()  # the inset's white frame
        tiles[name] = first[top + 16 : top + view_h, left : left + view_w]
    red = np.array(drawing.RED)
    patch = 4 * video.STRIP_SCENE_SCALE
    large_tile = tiles["fig10-p4-s4.png"]
    assert (large_tile[patch, patch] == red).all() and (large_tile[2 * patch - 1, 2 * patch - 1] == red).all()
    assert (large_tile[patch + 1, patch + 1] == 255).all()  # a white line inside the red one
    assert (large_tile[patch + 2, patch + 2] == 0).all()  # inside the outline: the camera's black
    small_tile, scale = tiles["fig10-p1-s1.png"], video.STRIP_SCENE_SCALE
    for row, col in SMALL:  # each 1-pixel patch a scale-pixel square outlined, ringed red inside white
        top, left, centre = row * scale, col * scale, (row * scale + scale // 2, col * scale + scale // 2)
        assert (small_tile[top, left] == red).all() and (small_tile[centre] == 0).all()
        assert (small_tile[centre[0], centre[1] + drawing.MARK_RADIUS - 1] == red).all()
        assert (small_tile[centre[0], centre[1] + drawing.MARK_RADIUS + 1] == 255).all()
    assert (small_tile[11 * scale : 14 * scale] == 0).all()  # between the two rows: nothing selected
    assert markdown.splitlines()[0] == (
        f"Patch size 1, stride 1 (L = 768 patches, top 10 selected): `{small}`, episode return 10.00."
    )
    assert "![fig10-p4-s4](experiments/fig10/fig10-p4-s4.png)" in markdown and "(L = 48 patches" in markdown
    text = results.read_text()
    assert "<!-- BEGIN fig10 -->" in text and markdown in text
    assert f"`iap-mjx reproduce fig10 --run-dirs {small},{large} --frames 3" in text
