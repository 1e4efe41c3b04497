"""dm_control's suite task modules, imported without the warning of its OpenGL probe.

Importing ``dm_control.suite`` picks a rendering backend; with ``MUJOCO_GL`` unset it tries GLFW
first, which on a machine without a screen warns ``GLFWError: (65550) X11: The DISPLAY
environment variable is missing``. We use dm_control for its models and task code only (every
image is drawn by our camera), so the warning tells a user nothing they can act on. It is
silenced here, for this import only; ``MUJOCO_GL`` and the process's warning filters are left
as they are.
"""

import warnings

with warnings.catch_warnings():
    warnings.filterwarnings("ignore", message=r".*DISPLAY environment variable is missing")
    from dm_control.suite import ball_in_cup, cartpole, cheetah, finger, reacher, walker

__all__ = ["ball_in_cup", "cartpole", "cheetah", "finger", "reacher", "walker"]
