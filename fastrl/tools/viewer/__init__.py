"""Watching policies: a self-contained HTML/WebGL rollout viewer, and videos via MuJoCo.

``write_html(env, qpos, "out.html")`` writes a page that plays a trajectory in 3D with no network
access; ``render_video(env, qpos, "out.gif")`` renders it with ``mujoco.Renderer`` (EGL or
OSMesa). ``python -m fastrl.evaluate RUN_DIR --html out.html --video out.gif`` does both for a
trained run, and ``logger.viewer_every=N`` makes the training runner write a page every N chunks.
"""

from fastrl.tools.viewer.html import make_run_writer, page, write_html
from fastrl.tools.viewer.scene import body_poses, build_scene
from fastrl.tools.viewer.video import VIDEO_FORMATS, VideoError, render_video

__all__ = [
    "VIDEO_FORMATS",
    "VideoError",
    "body_poses",
    "build_scene",
    "make_run_writer",
    "page",
    "render_video",
    "write_html",
]
