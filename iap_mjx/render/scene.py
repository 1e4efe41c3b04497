"""Static scene tables for the ray-cast camera, read once from a ``mujoco.MjModel``.

Everything here is a constant of the model (geom types, sizes, colours, visibility, lights,
floor texture, sky colours); it is computed in numpy at construction time so the compiled
renderer only sees the per-state poses (``geom_xpos``/``geom_xmat``/``cam_xpos``/``cam_xmat``).
"""

from __future__ import annotations

import dataclasses
import hashlib

import mujoco
import numpy as np

# MuJoCo geom type codes (mjtGeom).
PLANE = int(mujoco.mjtGeom.mjGEOM_PLANE)
SPHERE = int(mujoco.mjtGeom.mjGEOM_SPHERE)
CAPSULE = int(mujoco.mjtGeom.mjGEOM_CAPSULE)
ELLIPSOID = int(mujoco.mjtGeom.mjGEOM_ELLIPSOID)
CYLINDER = int(mujoco.mjtGeom.mjGEOM_CYLINDER)
BOX = int(mujoco.mjtGeom.mjGEOM_BOX)
SUPPORTED_TYPES = (PLANE, SPHERE, CAPSULE, ELLIPSOID, CYLINDER, BOX)

# MuJoCo's light modes (mjtCamLight), as ``Scene.light_mode`` holds them.
LIGHT_FIXED = int(mujoco.mjtCamLight.mjCAMLIGHT_FIXED)  # placed in its body's frame
LIGHT_TRACKCOM = int(mujoco.mjtCamLight.mjCAMLIGHT_TRACKCOM)  # follows its subtree's centre of mass
LIGHT_TARGETBODY = int(mujoco.mjtCamLight.mjCAMLIGHT_TARGETBODY)  # fixed, aimed at a body
LIGHT_TARGETBODYCOM = int(mujoco.mjtCamLight.mjCAMLIGHT_TARGETBODYCOM)  # fixed, aimed at its subtree's COM

_DEFAULT_GEOM_RGBA = np.array([0.5, 0.5, 0.5, 1.0], np.float32)


@dataclasses.dataclass(frozen=True, eq=False)
class Scene:
    """The static part of a model that the renderer needs (numpy arrays, never traced).

    Attributes:
      geom_ids: ``(G,)`` int, the MuJoCo ids of the rendered geoms (visible group, alpha > 0,
        supported type), in model order.
      geom_type: ``(G,)`` int, mjtGeom codes.
      geom_size: ``(G, 3)`` float32, MuJoCo sizes (plane size 0 = infinite in that direction).
      geom_rgb: ``(G, 3)`` float32, the colour MuJoCo's renderer uses (material colour when the
        geom keeps the default rgba, as ``mjv`` does).
      geom_alpha: ``(G,)`` float32 in (0, 1], the opacity from the same rgba (geoms of alpha 0
        are not drawn at all, as MuJoCo's renderer shows them; ``mj_ray`` differs when the
        geom's and its material's alpha disagree: it tests the material's alone); a partly
        transparent geom is drawn over the sky behind it (not over the geoms behind it).
      checker: ``(G,)`` bool, geom is a plane with a 2-D texture drawn as a 2x2 checker.
      checker_rgb: ``(G, 2, 3)`` float32, the two checker colours (texture quadrant centres,
        times the material colour): square ``(i, j)`` of the checker (``i = floor(x *
        checker_scale[0] + checker_offset[0])``, ``j`` likewise along y) shows the first
        when ``i + j`` is even, the second when it is odd.
      checker_texture: ``(G, 2, 3)`` float32, the texture's two colours alone (MuJoCo
        multiplies them by the geom's colour, so a changed colour tints the checker).
      checker_scale: ``(G, 2)`` float32, checker squares per unit length along local x, y.
      checker_offset: ``(G, 2)`` float32 in [0, 2), where the texture's origin falls, in
        squares from the plane's centre along x, y, modulo the pattern's two squares (it
        shifts the checker's phase).
      light_mode: ``(L,)`` int, mjtCamLight as ``mj_camlight`` reads it: 0 fixed to
        ``light_bodyid`` (position and direction in the body frame), 1 tracking the body's
        position, 2 tracking its subtree's centre of mass (both keep ``light_offset`` and
        ``light_dirs`` in the world frame), 3 and 4 placed as 0 and aimed at
        ``light_targetbodyid`` or its subtree's centre of mass (a target mode without a
        target body is 0).
      light_bodyid: ``(L,)`` int.
      light_targetbodyid: ``(L,)`` int, the body modes 3 and 4 aim at (0 for other modes).
      light_offset: ``(L, 3)`` float32, position in the body frame (modes 0, 3, 4) or offset
        in the world frame from the body (mode 1) or subtree centre of mass (mode 2).
      light_dirs: ``(L, 3)`` float32, direction the light shines (body frame for mode 0;
        unused by modes 3 and 4).
      light_directional: ``(L,)`` bool; other lights are spot lights with
        ``light_cos_cutoff`` ``(L,)`` and ``light_exponent`` ``(L,)`` (a point light has a
        cutoff of 180 degrees). Attenuation is ignored.
      light_diffuse: ``(L, 3)`` float32.
      ambient: ``(3,)`` float32, headlight plus model-light ambient.
      headlight_diffuse: ``(3,)`` float32 (zero if the headlight is off).
      sky_mid, sky_slope: ``(3,)`` float32, sky colour ``mid + slope * z`` for a world ray
        direction with unit ``z`` (fitted to the model's skybox texture; flat if it has none).
      zfar: the far clip plane of MuJoCo's renderer in metres (``vis.map.zfar`` times extent).
    """

    geom_ids: np.ndarray
    geom_type: np.ndarray
    geom_size: np.ndarray
    geom_rgb: np.ndarray
    geom_alpha: np.ndarray
    checker: np.ndarray
    checker_rgb: np.ndarray
    checker_texture: np.ndarray
    checker_scale: np.ndarray
    checker_offset: np.ndarray
    light_mode: np.ndarray
    light_bodyid: np.ndarray
    light_targetbodyid: np.ndarray
    light_offset: np.ndarray
    light_dirs: np.ndarray
    light_directional: np.ndarray
    light_cos_cutoff: np.ndarray
    light_exponent: np.ndarray
    light_diffuse: np.ndarray
    ambient: np.ndarray
    headlight_diffuse: np.ndarray
    sky_mid: np.ndarray
    sky_slope: np.ndarray
    zfar: float

    @property
    def has_aimed_lights(self) -> bool:
        """Whether a light aims at a target body (modes 3 and 4): the camera then reads the
        targets' poses too."""
        return bool(np.any(self.light_mode >= LIGHT_TARGETBODY))

    def digest(self) -> str:
        """A content hash, so equal scenes give equal (hashable) cameras."""
        h = hashlib.sha1()
        for field in dataclasses.fields(self):
            value = getattr(self, field.name)
            h.update(field.name.encode())
            h.update(np.ascontiguousarray(np.asarray(value)).tobytes())
        return h.hexdigest()


def _geom_colour(m: mujoco.MjModel, geom: int) -> np.ndarray:
    """``(4,)`` float32, the rgba MuJoCo's renderer draws ``geom`` with: its material's if it
    has one and keeps the default rgba (compared exactly, as ``mjv`` does), else its own."""
    rgba = np.asarray(m.geom_rgba[geom], np.float32)
    matid = int(m.geom_matid[geom])
    if matid >= 0 and np.array_equal(rgba, _DEFAULT_GEOM_RGBA):
        rgba = np.asarray(m.mat_rgba[matid], np.float32)
    return rgba


def _texture_rgb(m: mujoco.MjModel, tex: int) -> np.ndarray:
    """``(height, width, 3)`` float32 texture in [0, 1]."""
    adr, h, w = int(m.tex_adr[tex]), int(m.tex_height[tex]), int(m.tex_width[tex])
    c = int(m.tex_nchannel[tex])
    data = np.asarray(m.tex_data[adr : adr + h * w * c], np.float32).reshape(h, w, c) / 255.0
    return data[..., :3] if c >= 3 else np.repeat(data[..., :1], 3, axis=-1)


def _material_rgb_texture(m: mujoco.MjModel, matid: int) -> int:
    """The id of the material's RGB (2-D) texture, or -1."""
    texid = np.asarray(m.mat_texid[matid]).reshape(-1)
    role = int(mujoco.mjtTextureRole.mjTEXROLE_RGB) if texid.size > 1 else 0
    return int(texid[role])


def _sky(m: mujoco.MjModel) -> tuple[np.ndarray, np.ndarray]:
    """Sky gradient ``mid + slope * z`` fitted to the skybox texture (a side face's top and
    bottom rows sit at z = +-1/sqrt(2)); a flat black sky if the model has no skybox."""
    for tex in range(m.ntex):
        if int(m.tex_type[tex]) == int(mujoco.mjtTexture.mjTEXTURE_SKYBOX):
            rgb = _texture_rgb(m, tex)
            face = rgb.shape[1]
            side = rgb[:face]  # first cube face (+x), a side face of a z-up skybox
            centre = slice(face // 4, 3 * face // 4)
            top = side[: max(1, face // 50), centre].reshape(-1, 3).mean(0)
            bottom = side[-max(1, face // 50) :, centre].reshape(-1, 3).mean(0)
            z = 1.0 / np.sqrt(2.0)
            return ((top + bottom) / 2).astype(np.float32), ((top - bottom) / (2 * z)).astype(np.float32)
    return np.zeros(3, np.float32), np.zeros(3, np.float32)


def _checker(
    m: mujoco.MjModel, g: int, rgba: np.ndarray
) -> tuple[bool, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Geom ``g``'s checker, if it is a plane with a 2-D texture: ``(is_checker, colours (2, 3),
    texture (2, 3), squares per unit length (2,), origin offset (2,))``, float32, the two
    squares' colours with and without the geom's ``rgba``; zeros and unit scale otherwise."""
    matid = int(m.geom_matid[g])
    tex = _material_rgb_texture(m, matid) if matid >= 0 else -1
    is_checker = (
        int(m.geom_type[g]) == PLANE and tex >= 0 and int(m.tex_type[tex]) == int(mujoco.mjtTexture.mjTEXTURE_2D)
    )
    if not is_checker:
        zeros = np.zeros((2, 3), np.float32)
        return False, zeros, zeros.copy(), np.ones(2, np.float32), np.zeros(2, np.float32)
    # As measured with mujoco.Renderer (tests/test_render_mujoco.py), per axis: with
    # texuniform (or an infinite size), a 2x2 checker's squares are 1 / texrepeat long
    # and the texture's origin is texrepeat * size squares from the centre; without,
    # texrepeat textures span the plane from its corner (squares size / texrepeat
    # long, the origin texrepeat squares away). The texture's rows run against local
    # y, so the square at the origin shows its bottom-left quadrant.
    img = _texture_rgb(m, tex)
    h, w = img.shape[:2]
    texture = np.stack([img[3 * h // 4, w // 4], img[3 * h // 4, 3 * w // 4]])
    colours = texture * rgba[None, :3]
    repeat = np.asarray(m.mat_texrepeat[matid], np.float32)
    size = np.asarray(m.geom_size[g, :2], np.float32)
    spread = (size > 0) & (not bool(m.mat_texuniform[matid]))
    scale = np.where(spread, repeat / np.where(spread, size, 1.0), repeat)
    offset = np.where(spread, repeat, repeat * size) * np.array([1.0, -1.0], np.float32)
    offset = np.mod(offset, 2.0)  # the pattern repeats every two squares
    return (
        True,
        colours.astype(np.float32),
        texture.astype(np.float32),
        scale.astype(np.float32),
        offset.astype(np.float32),
    )


def _lights(m: mujoco.MjModel) -> dict[str, np.ndarray]:
    """The active lights as :class:`Scene` holds them (its ``light_*`` fields, ``ambient`` and
    ``headlight_diffuse``)."""
    light_active = np.asarray(m.light_active, bool) if m.nlight else np.zeros(0, bool)
    lights = np.flatnonzero(light_active)
    headlight = m.vis.headlight
    ambient = np.asarray(headlight.ambient, np.float32) * float(bool(headlight.active))
    ambient = ambient + np.asarray(m.light_ambient[lights], np.float32).sum(0) if lights.size else ambient
    light_type = np.asarray(m.light_type[lights], np.int32)
    light_mode = np.asarray(m.light_mode[lights], np.int32)
    light_target = np.asarray(m.light_targetbodyid[lights], np.int32)
    aimed = light_mode >= LIGHT_TARGETBODY
    light_mode = np.where(aimed & (light_target < 0), LIGHT_FIXED, light_mode).astype(np.int32)
    in_body_frame = (light_mode == LIGHT_FIXED) | (light_mode >= LIGHT_TARGETBODY)
    spot = light_type == int(mujoco.mjtLightType.mjLIGHT_SPOT)
    return {
        "light_mode": light_mode,
        "light_bodyid": np.asarray(m.light_bodyid[lights], np.int32),
        "light_targetbodyid": np.where(light_mode >= LIGHT_TARGETBODY, light_target, 0).astype(np.int32),
        "light_offset": np.where(
            in_body_frame[:, None],
            m.light_pos[lights],
            np.where((light_mode == LIGHT_TRACKCOM)[:, None], m.light_poscom0[lights], m.light_pos0[lights]),
        )
        .astype(np.float32)
        .reshape(-1, 3),
        "light_dirs": np.where(in_body_frame[:, None], m.light_dir[lights], m.light_dir0[lights])
        .astype(np.float32)
        .reshape(-1, 3),
        "light_directional": light_type == int(mujoco.mjtLightType.mjLIGHT_DIRECTIONAL),
        "light_cos_cutoff": np.where(
            spot, np.cos(np.deg2rad(np.asarray(m.light_cutoff[lights], np.float64))), -1.0
        ).astype(np.float32),
        "light_exponent": np.where(spot, np.asarray(m.light_exponent[lights]), 0.0).astype(np.float32),
        "light_diffuse": np.asarray(m.light_diffuse[lights], np.float32).reshape(-1, 3),
        "ambient": ambient.astype(np.float32),
        "headlight_diffuse": np.asarray(headlight.diffuse, np.float32) * float(bool(headlight.active)),
    }


def build_scene(m: mujoco.MjModel, geom_groups: tuple[int, ...] = (0, 1, 2)) -> Scene:
    """Reads the static scene of ``m``: the geoms MuJoCo's renderer would draw with the given
    visible groups (mjvOption.geomgroup default: 0, 1, 2), their colours and the lights.

    Geoms of unsupported types (meshes, heightfields, SDFs) are skipped.
    """
    ids, types, sizes, rgbs, alphas, checkers = [], [], [], [], [], []
    for g in range(m.ngeom):
        gtype = int(m.geom_type[g])
        if int(m.geom_group[g]) not in geom_groups or gtype not in SUPPORTED_TYPES:
            continue
        rgba = _geom_colour(m, g)
        if rgba[3] == 0.0:
            continue
        ids.append(g)
        types.append(gtype)
        sizes.append(np.asarray(m.geom_size[g], np.float32))
        rgbs.append(rgba[:3])
        alphas.append(min(float(rgba[3]), 1.0))
        checkers.append(_checker(m, g, rgba))
    # one column per Scene field (empty columns for a scene without geoms)
    checker, checker_rgb, checker_texture, checker_scale, checker_offset = list(zip(*checkers)) or [()] * 5
    sky_mid, sky_slope = _sky(m)
    extent = float(m.stat.extent)
    return Scene(
        geom_ids=np.asarray(ids, np.int32),
        geom_type=np.asarray(types, np.int32),
        geom_size=np.asarray(sizes, np.float32).reshape(-1, 3),
        geom_rgb=np.asarray(rgbs, np.float32).reshape(-1, 3),
        geom_alpha=np.asarray(alphas, np.float32).reshape(-1),
        checker=np.asarray(checker, bool),
        checker_rgb=np.asarray(checker_rgb, np.float32).reshape(-1, 2, 3),
        checker_texture=np.asarray(checker_texture, np.float32).reshape(-1, 2, 3),
        checker_scale=np.asarray(checker_scale, np.float32).reshape(-1, 2),
        checker_offset=np.asarray(checker_offset, np.float32).reshape(-1, 2),
        **_lights(m),
        sky_mid=sky_mid,
        sky_slope=sky_slope,
        zfar=float(m.vis.map.zfar) * extent,
    )
