"""Videos of a rollout rendered by MuJoCo's own renderer (``mujoco.Renderer``), headless.

Rendering needs an OpenGL backend: EGL or OSMesa on a machine without a display. Each backend
is tried in a child process (``_mjrender.py``), since PyOpenGL binds one platform per process;
when none works, ``VideoError`` says which were tried, why each failed and how to get one.
"""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from fastrl.tools.viewer.scene import asset_path, load_mj_model, root_body

VIDEO_FORMATS = (".gif", ".mp4")
# Headless backends, in the order tried when MUJOCO_GL is not set.
BACKENDS = ("egl", "osmesa")
WORKER = Path(__file__).with_name("_mjrender.py")
GL_FAILED = 3  # the worker's exit status when its OpenGL backend fails
# GIF frame delays come in 10 ms units and browsers slow down delays under 20 ms: GIFs of fast
# envs skip frames so that each lasts at least this long.
GIF_MIN_FRAME_S = 0.02

INSTALL_HINT = (
    "MuJoCo renders headless through EGL or OSMesa. On Debian/Ubuntu: "
    "`apt-get install -y libegl1 libegl-mesa0` (EGL, works without a GPU through Mesa) or "
    "`apt-get install -y libosmesa6` (OSMesa); then retry, or set MUJOCO_GL to the backend "
    "that works. The HTML viewer (--html) needs no OpenGL on this machine."
)


class VideoError(RuntimeError):
    """A video could not be written; the message says why and what to do."""


def check_format(path: str | Path) -> str:
    """The lower-case suffix of ``path`` if fastrl can write that format, else ``VideoError``."""
    suffix = Path(path).suffix.lower()
    if suffix not in VIDEO_FORMATS:
        raise VideoError(
            f"{path}: unsupported video format {suffix!r}; use one of {', '.join(VIDEO_FORMATS)}"
        )
    if suffix == ".mp4" and not (
        importlib.util.find_spec("imageio") and importlib.util.find_spec("imageio_ffmpeg")
    ):
        raise VideoError(
            f"{path}: writing .mp4 needs imageio-ffmpeg (pip install imageio-ffmpeg); .gif needs nothing"
        )
    return suffix


def render_video(
    env,
    qpos: np.ndarray,
    path: str | Path,
    width: int = 480,
    height: int = 360,
    backends: tuple[str, ...] | None = None,
    asset: str | Path | None = None,
) -> Path:
    """Renders a trajectory of ``env`` with MuJoCo into a GIF or MP4 (chosen by the suffix).

    Args:
      env: the fastrl env the trajectory belongs to (its MJCF file is rendered).
      qpos: (T, nq) positions, one frame per env step.
      path: ``.gif`` or ``.mp4`` file to write.
      width, height: image size in pixels.
      backends: MUJOCO_GL values to try in order (default: $MUJOCO_GL if set, else egl, osmesa).
      asset: the env's MJCF file, if it was built with a non-default ``asset=``.
    Returns:
      The path written.
    Raises:
      VideoError: unsupported format, or no OpenGL backend works (the message names them).
    """
    path = Path(path)
    suffix = check_format(path)
    qpos = np.asarray(qpos, np.float64)
    root = root_body(load_mj_model(env, asset))
    stride = max(1, math.ceil(GIF_MIN_FRAME_S / env.dt - 1e-9)) if suffix == ".gif" else 1
    fps = 1.0 / (env.dt * stride)
    if backends is None:
        backends = (os.environ["MUJOCO_GL"],) if os.environ.get("MUJOCO_GL") else BACKENDS
    path.parent.mkdir(parents=True, exist_ok=True)
    failures = []
    with tempfile.TemporaryDirectory() as tmp:
        np.save(Path(tmp) / "qpos.npy", qpos[::stride])
        cmd = [sys.executable, str(WORKER), "--xml", str(asset_path(env, asset)), "--qpos",
               str(Path(tmp) / "qpos.npy"), "--out", str(path), "--fps", str(fps), "--width",
               str(width), "--height", str(height), "--root", str(root)]  # fmt: skip
        for backend in backends:
            child_env = {**os.environ, "MUJOCO_GL": backend, "PYOPENGL_PLATFORM": backend}
            r = subprocess.run(cmd, env=child_env, capture_output=True, text=True)
            if r.returncode == 0:
                return path
            last = (r.stderr.strip().splitlines() or [f"exit status {r.returncode}"])[-1]
            if r.returncode != GL_FAILED:
                raise VideoError(f"rendering {path} with MUJOCO_GL={backend} failed: {last}")
            failures.append(f"MUJOCO_GL={backend}: {last}")
    raise VideoError(
        f"no OpenGL backend for MuJoCo's renderer worked; tried {'; '.join(failures)}. {INSTALL_HINT}"
    )
