"""The ray-cast RGB-D camera: MJX state -> pixels.

``Camera(mj_model, camera_id=0, height=100, width=100)`` builds a renderer whose pure
``render(data) -> (rgb, depth)`` runs under ``jit``/``vmap``; see ``camera.Camera`` for the
pixel, depth and background conventions.
"""

from iap_mjx import _mjx  # noqa: F401  (imports mujoco.mjx first, quietly)
from iap_mjx.render.camera import Camera, CameraConfig
from iap_mjx.render.scene import Scene, build_scene

__all__ = ["Camera", "CameraConfig", "Scene", "build_scene"]
