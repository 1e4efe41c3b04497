"""The first import of ``mujoco.mjx``, without the two lines its optional Warp backend prints.

``mujoco.mjx.warp`` ``print``s ``Failed to import warp: ...`` and ``Failed to import
mujoco_warp: ...`` to stdout whenever NVIDIA's Warp package is absent, which on our CPU-only
installs it always is (Warp is a GPU backend we do not use). A user cannot act on them, and
they land on stdout, where our commands print their JSON results. So the packages that use
MJX (``render``, ``envs``) import it here first, with stdout captured: those two lines go to
the debug log, anything else MJX prints is passed through unchanged.
"""

from __future__ import annotations

import contextlib
import io
import logging
import sys

logger = logging.getLogger(__name__)

_WARP_LINES = ("Failed to import warp:", "Failed to import mujoco_warp:")


def _import_mjx_quietly() -> None:
    """Imports ``mujoco.mjx`` with stdout captured: Warp's lines to the debug log, the rest
    back to stdout."""
    captured = io.StringIO()
    with contextlib.redirect_stdout(captured):
        from mujoco import mjx  # noqa: F401
    for line in captured.getvalue().splitlines(keepends=True):
        if line.startswith(_WARP_LINES):
            logger.debug("mujoco.mjx: %s", line.rstrip())
        else:
            sys.stdout.write(line)


if "mujoco.mjx" not in sys.modules:
    _import_mjx_quietly()
