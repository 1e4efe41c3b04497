"""Background videos (``iap_mjx.envs.backgrounds``): the reference's resize, the DAVIS loader on
JPEGs written here, the built-in photographs, and every bad setting."""

from __future__ import annotations

import importlib.metadata
import socket
from pathlib import Path

import jax
import numpy as np
import pytest
from PIL import Image

from iap_mjx.configs import background_sets
from iap_mjx.configs import distraction as dcs
from iap_mjx.envs import backgrounds

EASY = background_sets.DAVIS17_TRAINING_VIDEOS[:4]
FRAME_COUNTS = (3, 5, 2, 4)  # of the four easy videos: padding to 5 is exercised


def _write_davis(video_root: Path, videos=EASY, counts=FRAME_COUNTS, shape=(24, 40)) -> None:
    """Videos of flat frames whose brightness encodes (video, frame), written out of order,
    with files that are not frames beside them."""
    for v, (name, count) in enumerate(zip(videos, counts)):
        folder = video_root / name
        folder.mkdir(parents=True)
        for f in reversed(range(count)):
            pixels = np.full(shape + (3,), 20 + 40 * f, np.uint8)
            pixels[..., 2] = 10 * v
            Image.fromarray(pixels).save(folder / f"{f:05d}.jpg", quality=95)
        (folder / "notes.txt").write_text("not a frame")
        (folder / ".hidden.jpg").write_bytes(b"")


# ---- the reference's resize ---------------------------------------------------------------


def test_resize_is_tensorflows_half_pixel_bilinear_truncated():
    """A ramp [0, 10] resized from 2 to 4 columns: half-pixel centres sample x = -0.25,
    0.25, 0.75, 1.25, i.e. 0, 2.5, 7.5, 10; the uint8 cast truncates (rounding: 3, 8)."""
    image = np.zeros((1, 2, 3), np.uint8)
    image[0, 1] = 10
    out = backgrounds.resize_frame(image, 4)
    assert out.shape == (4, 4, 3) and out.dtype == np.uint8
    np.testing.assert_array_equal(out[:, :, 0], np.tile([0, 2, 7, 10], (4, 1)))


@pytest.mark.parametrize("shape, size", [((37, 53), 16), ((37, 53), 80), ((480, 854), 64)])
def test_resize_matches_jax_linear_resize(shape, size):
    """Against ``jax.image.resize(..., "linear", antialias=False)``, an independent
    formulation of the same half-pixel bilinear map (weights normalised at the edges, where
    TensorFlow clamps), down- and up-sampling, aspect ratio not kept."""
    image = np.random.default_rng(0).integers(0, 256, shape + (3,), dtype=np.uint8)
    expected = np.asarray(jax.image.resize(image.astype(np.float32), (size, size, 3), "linear", antialias=False))
    ours = backgrounds._sample_window(image.astype(np.float32), 0.0, 0.0, shape[0], shape[1], size)
    np.testing.assert_allclose(ours, expected, atol=2e-3)
    truncated = backgrounds.resize_frame(image, size)
    clear = np.abs(expected - np.round(expected)) > 2e-3  # away from integers, truncation is unambiguous
    np.testing.assert_array_equal(truncated[clear], np.floor(expected[clear]).astype(np.uint8))


def test_a_frame_of_the_texture_size_is_kept():
    image = np.random.default_rng(1).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    assert backgrounds.resize_frame(image, 16) is image


# ---- DAVIS --------------------------------------------------------------------------------


@pytest.mark.parametrize("layout", ["JPEGImages/480p", "."])
def test_davis_loader_reads_both_layouts(tmp_path, layout):
    _write_davis(tmp_path / layout)
    (tmp_path / layout / "not-a-training-video").mkdir()  # ignored: not in the list
    videos = backgrounds.load("easy", background_dir=tmp_path, size=8)
    assert videos.names == EASY
    assert videos.frames.shape == (4, 5, 8, 8, 3) and videos.frames.dtype == np.uint8
    np.testing.assert_array_equal(videos.lengths, FRAME_COUNTS)
    assert videos.source.startswith("davis:")
    for v, count in enumerate(FRAME_COUNTS):
        red = videos.frames[v, :, :, :, 0].mean(axis=(1, 2))
        # Sorted by name: brightness 20 + 40 f (JPEG keeps flat frames within a few levels).
        np.testing.assert_allclose(red[:count], 20 + 40 * np.arange(count), atol=3)
        # Padding repeats the last real frame.
        for f in range(count, 5):
            np.testing.assert_array_equal(videos.frames[v, f], videos.frames[v, count - 1])
        np.testing.assert_allclose(videos.frames[v, :count, :, :, 2].mean(), 10 * v, atol=3)
    # Each frame is the decoded file through the reference's resize.
    first = tmp_path / layout / EASY[1] / "00002.jpg"
    np.testing.assert_array_equal(
        videos.frames[1, 2], backgrounds.resize_frame(np.asarray(Image.open(first).convert("RGB")), 8)
    )


def test_davis_levels_take_the_first_videos_of_the_training_list(tmp_path):
    medium = background_sets.DAVIS17_TRAINING_VIDEOS[:8]
    _write_davis(tmp_path, medium, (1,) * 8, shape=(6, 6))
    assert backgrounds.load("medium", tmp_path, size=4).names == medium
    assert backgrounds.load("easy", tmp_path, size=4).names == medium[:4]
    assert len(background_sets.DAVIS17_TRAINING_VIDEOS) == 60
    assert len(set(background_sets.DAVIS17_TRAINING_VIDEOS)) == 60
    with pytest.raises(ValueError, match="lacks 52 of the 60") as error:
        dcs.check_backgrounds("hard", tmp_path)
    assert "'walking'" in str(error.value) and "'bear'" not in str(error.value).split("missing")[1].split("]")[0]


def test_davis_validation_videos_are_the_references_held_out_list(tmp_path):
    """``videos="val"`` reads the reference's DAVIS17_VALIDATION_VIDEOS (its 30 names as
    distracting_control/background.py lists them; a level takes the first N), none of them a
    training video, and names the validation videos it misses."""
    val = background_sets.DAVIS17_VALIDATION_VIDEOS
    assert len(val) == 30 and len(set(val)) == 30 and not set(val) & set(background_sets.DAVIS17_TRAINING_VIDEOS)
    assert (val[0], val[9], val[-1]) == ("bike-packing", "dog", "soapbox")
    _write_davis(tmp_path, val[:8], (1,) * 8, shape=(6, 6))
    held_out = backgrounds.load("medium", tmp_path, size=4, videos="val")
    assert held_out.names == val[:8] and held_out.source.endswith(":val")
    with pytest.raises(ValueError, match="lacks 8 of the 8 DAVIS-2017 training"):
        dcs.check_backgrounds("medium", tmp_path)  # the training videos are not there
    with pytest.raises(ValueError, match="lacks 22 of the 30 DAVIS-2017 validation") as error:
        dcs.check_backgrounds("hard", tmp_path, videos="val")
    assert "'soapbox'" in str(error.value)
    with pytest.raises(ValueError, match="background_videos = 'test': valid train, val"):
        dcs.check_backgrounds("medium", videos="test")


def test_missing_videos_are_all_named(tmp_path):
    _write_davis(tmp_path, EASY[:2], FRAME_COUNTS[:2])
    with pytest.raises(ValueError, match="background_dir") as error:
        backgrounds.load("easy", tmp_path, size=8)
    message = str(error.value)
    assert f"missing {list(EASY[2:])}" in message and "JPEGImages/480p" in message


@pytest.mark.parametrize("make", ["nothing", "file"])
def test_a_background_dir_that_is_not_a_directory(tmp_path, make):
    path = tmp_path / "davis"
    if make == "file":
        path.write_text("")
    for call in (dcs.check_backgrounds, backgrounds.load):
        with pytest.raises(ValueError, match="background_dir .*does not exist.*None for the built-in"):
            call("easy", path)


def test_a_video_without_frames(tmp_path):
    _write_davis(tmp_path)
    for frame in (tmp_path / EASY[2]).glob("*.jpg"):
        frame.unlink()
    with pytest.raises(ValueError, match=f"background_dir: video '{EASY[2]}' .*holds no frames"):
        dcs.check_backgrounds("easy", tmp_path)


def test_a_frame_that_does_not_decode_is_named(tmp_path):
    _write_davis(tmp_path)
    broken = tmp_path / EASY[3] / "00001.jpg"
    broken.write_bytes(b"not a jpeg")
    dcs.check_backgrounds("easy", tmp_path)  # check does not decode
    with pytest.raises(ValueError, match="background_dir: cannot decode frame") as error:
        backgrounds.load("easy", tmp_path, size=8)
    assert str(broken) in str(error.value)


# ---- settings -----------------------------------------------------------------------------


def test_unknown_difficulty_lists_the_valid_ones(tmp_path):
    for call in (dcs.check_backgrounds, backgrounds.load, dcs.num_videos):
        with pytest.raises(ValueError, match="difficulty 'extreme'; valid: easy, medium, hard"):
            call("extreme")
    _write_davis(tmp_path)
    with pytest.raises(ValueError, match="difficulty"):
        backgrounds.load_davis(tmp_path, "Medium")


@pytest.mark.parametrize("setting", [dict(size=0), dict(num_frames=0), dict(size=2.5), dict(num_frames=True)])
def test_bad_sizes_are_named(setting):
    (name,) = setting
    setting_name = {"size": "env.background_size", "num_frames": "env.background_frames"}[name]
    with pytest.raises(ValueError, match=rf"background {name} \(the setting {setting_name}\) must be an int >= 1"):
        backgrounds.load("easy", **setting)


def test_videos_validate_their_arrays():
    good = dict(
        frames=np.zeros((2, 3, 4, 4, 3), np.uint8), lengths=np.array([3, 1], np.int32), names=("a", "b"), source="test"
    )
    assert backgrounds.BackgroundVideos(**good).nbytes == 2 * 3 * 4 * 4 * 3
    for bad in (
        dict(frames=np.zeros((2, 3, 4, 4, 3), np.float32)),
        dict(frames=np.zeros((2, 3, 4, 5, 3), np.uint8)),
        dict(lengths=np.array([4, 1], np.int32)),
        dict(lengths=np.array([3, 0], np.int32)),
        dict(lengths=np.array([3, 1])),
        dict(names=("a",)),
    ):
        with pytest.raises(ValueError, match="BackgroundVideos"):
            backgrounds.BackgroundVideos(**{**good, **bad})


# ---- the built-in photographs ---------------------------------------------------------------


def test_photographs_ship_inside_their_wheels():
    """Every photograph, training and held out, is a file of an installed wheel (its RECORD),
    not one that a package fetches on demand."""
    for photo in background_sets.PHOTOGRAPHS + background_sets.VALIDATION_PHOTOGRAPHS:
        distribution = {"skimage": "scikit-image", "matplotlib": "matplotlib"}[photo.package]
        shipped = {str(path) for path in importlib.metadata.files(distribution)}
        folder = "/".join((photo.package,) + background_sets.PACKAGE_DATA[photo.package])
        assert f"{folder}/{photo.filename}" in shipped, photo.filename


def test_held_out_photographs_are_other_pictures():
    """The held-out set shares no file and no picture with the training set: names, files and
    pixels all differ (the pan/zoom videos' first frames are compared too), and each level has
    as many held-out videos as training ones, so a compiled program takes either."""
    train, val = background_sets.PHOTOGRAPHS, background_sets.VALIDATION_PHOTOGRAPHS
    assert not {p.name for p in train} & {p.name for p in val}
    assert not {p.filename for p in train} & {p.filename for p in val}
    for difficulty in dcs.DIFFICULTIES:
        seen = backgrounds.load(difficulty, size=16, num_frames=2)
        held = backgrounds.load(difficulty, size=16, num_frames=2, videos="val")
        assert held.frames.shape == seen.frames.shape and held.source == "builtin:val"
        first = held.frames[:, 0].reshape(len(held.names), -1).astype(int)
        for frame in seen.frames[:, 0].reshape(len(seen.names), -1).astype(int):
            assert np.all(np.abs(first - frame).mean(axis=1) > 5)


def test_builtin_videos_load_without_network(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("the built-in backgrounds tried to use the network")

    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)
    names = tuple(photo.name for photo in background_sets.PHOTOGRAPHS)
    for difficulty, count in (("easy", 4), ("medium", 8), ("hard", 10)):
        videos = backgrounds.load(difficulty, size=16, num_frames=4)
        assert videos.names == names[:count] and videos.source == "builtin"
        assert videos.frames.shape == (count, 4, 16, 16, 3)
        np.testing.assert_array_equal(videos.lengths, [4] * count)
    again = backgrounds.load("hard", size=16, num_frames=4)
    np.testing.assert_array_equal(again.frames, videos.frames)  # deterministic
    # Each video moves: no two of its frames are the same.
    diffs = np.abs(videos.frames[:, 1:].astype(int) - videos.frames[:, :1]).mean(axis=(2, 3, 4))
    assert np.all(diffs > 1.0), diffs


def test_pan_zoom_stays_inside_the_photo_and_moves_smoothly():
    for height, width in ((300, 451), (872, 1000), (512, 512)):
        windows = backgrounds.pan_zoom_windows(height, width, 64, (1.25, 1.6), 0.9)
        top, left, side = windows.T
        assert np.all(top >= 0) and np.all(left >= 0)
        assert np.all(top + side <= height) and np.all(left + side <= width)
        np.testing.assert_allclose(side.max(), min(height, width) / 1.25)
        np.testing.assert_allclose(side.min(), min(height, width) / 1.6, rtol=1e-3)
        # Smooth and periodic: every step, the wrap-around included, moves the window by at
        # most a tenth of its side at 64 frames.
        steps = np.abs(np.diff(np.concatenate([windows, windows[:1]]), axis=0))
        assert np.all(steps <= 0.1 * side.min()[None]), steps.max(0)


def test_every_photograph_is_documented_with_its_licence():
    doc = (Path(__file__).resolve().parent.parent / "docs" / "backgrounds.md").read_text()
    rows = {line.split("|")[2].strip(): line for line in doc.splitlines() if line.startswith("| ") and "`" in line}
    for photo in background_sets.PHOTOGRAPHS + background_sets.VALIDATION_PHOTOGRAPHS:
        assert photo.name in rows, photo.name
        assert f"`{photo.filename}`" in rows[photo.name] and photo.licence in rows[photo.name]
