"""A rollout as one self-contained HTML file: WebGL playback with no network access.

The page embeds the scene (``scene.build_scene``) as JSON and fastrl's own renderer
(``viewer.js``, package data); nothing is fetched when it opens. Controls: play/pause (space),
speed, a frame slider (arrow keys step), orbit (drag), pan (right- or shift-drag), zoom (wheel)
and a follow camera that tracks the root body. Any JavaScript error is written into
``<pre id="errors">`` and the shown frame into ``<span id="frame">``, so a headless browser can
check the page with ``--dump-dom``.
"""

from __future__ import annotations

import html
import shutil
from collections.abc import Callable
from pathlib import Path

import jax
import numpy as np

from fastrl.agents.evaluation import make_rollout
from fastrl.tools.viewer.scene import build_scene, scene_json

JS_PATH = Path(__file__).with_name("viewer.js")
# Env steps in a run's viewer rollout: a short clip keeps each file well under a megabyte.
RUN_STEPS = 300

_RECORDER = """
(function () {
  // Record every error in the page, so a headless browser's DOM dump shows them.
  var box = document.getElementById("errors");
  function record(msg) {
    box.textContent += msg + "\\n";
    box.style.display = "block";
    document.body.dataset.status = "error";
  }
  window.onerror = function (msg, src, line, col, err) {
    record((err && err.stack) || msg + " (line " + line + ")");
  };
  window.addEventListener("unhandledrejection", function (e) { record("unhandled rejection: " + e.reason); });
  var original = console.error;
  console.error = function () {
    record(Array.prototype.map.call(arguments, String).join(" "));
    original.apply(console, arguments);
  };
})();
"""

_STYLE = """
html, body { margin: 0; height: 100%; overflow: hidden; font: 13px system-ui, sans-serif; }
body { display: flex; flex-direction: column; background: #e0e8f2; }
#bar { display: flex; gap: 8px; align-items: center; padding: 5px 8px; background: #2b3340; color: #eee; }
#bar button { width: 56px; }
#bar label { white-space: nowrap; }
#slider { flex: 1; min-width: 80px; }
#counter { font-variant-numeric: tabular-nums; white-space: nowrap; }
#overflow { color: #c00; white-space: nowrap; }
#title { opacity: 0.8; white-space: nowrap; overflow: hidden; text-overflow: ellipsis; max-width: 30%; }
#view { flex: 1; width: 100%; min-height: 0; display: block; touch-action: none; }
#help { position: absolute; bottom: 4px; left: 8px; color: #556; font-size: 11px; pointer-events: none; }
#errors { display: none; position: absolute; top: 40px; left: 8px; right: 8px; margin: 0; padding: 6px;
          background: #fee; color: #900; white-space: pre-wrap; }
"""

_BODY = """
<div id="bar">
  <button id="play" title="space">Pause</button>
  <select id="speed" title="playback speed">
    <option value="0.25">0.25x</option><option value="0.5">0.5x</option>
    <option value="1" selected>1x</option><option value="2">2x</option><option value="4">4x</option>
  </select>
  <input id="slider" type="range" min="0" max="0" value="0" step="1" title="frame (arrow keys step)">
  <span id="counter">frame <span id="frame">0</span> / <span id="nframe">0</span>
    &middot; <span id="time">0.00 s</span></span>
  <label><input id="follow" type="checkbox" checked> follow</label>
  <span id="overflow" title="contacts the scene's fixed budgets dropped in this step"></span>
  <span id="title"></span>
</div>
<canvas id="view"></canvas>
<div id="help">drag: orbit &middot; right/shift-drag: pan &middot; wheel: zoom &middot;
  space: play/pause</div>
<pre id="errors"></pre>
"""


def page(scene: dict) -> str:
    """The HTML text of a scene: controls, the embedded scene JSON and the renderer."""
    title = html.escape(scene["title"])
    js = JS_PATH.read_text(encoding="utf-8")
    return (
        f'<!DOCTYPE html>\n<html lang="en">\n<head>\n<meta charset="utf-8">\n<title>{title}</title>\n'
        f'<meta name="viewport" content="width=device-width, initial-scale=1">\n'
        f"<style>{_STYLE}</style>\n</head>\n"
        f'<body data-status="loading">{_BODY}<script>{_RECORDER}</script>\n'
        f'<script id="scene" type="application/json">{scene_json(scene)}</script>\n'
        f"<script>\n{js}</script>\n</body>\n</html>\n"
    )


def write_html(
    env,
    qpos: np.ndarray,
    path: str | Path,
    title: str = "",
    asset: str | Path | None = None,
    markers: np.ndarray | None = None,
    overflow: np.ndarray | None = None,
) -> Path:
    """Writes a self-contained HTML viewer of a trajectory of ``env``.

    Args:
      env: the fastrl env the trajectory belongs to.
      qpos: (T, nq) positions per frame, one frame per env step (``env.dt`` apart).
      path: the ``.html`` file to write (parent folders are created).
      title: a line shown in the page's control bar (default: the env's name).
      asset: the env's MJCF file, if it was built with a non-default ``asset=``.
      markers: (T, M, 3) goal positions per frame, drawn as red spheres (``env.markers``).
      overflow: (T,) contacts the scene's budgets dropped per frame (the env's
        ``contact_overflow`` metric), shown in the control bar where above 0.
    Returns:
      The path written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(page(build_scene(env, qpos, title, asset, markers, overflow)), encoding="utf-8")
    return path


def make_run_writer(env, act: Callable, title: str = "", batched: bool = False, steps: int = RUN_STEPS):
    """A writer of a training run's viewer pages, its rollout compiled once for the whole run.

    Args:
      env: the run's env.
      act: the learner's deterministic ``act(params, obs)`` of ONE agent.
      title: the page title's prefix (the chunk is appended).
      batched: the params given to ``write`` have a leading agent axis; agent 0 is shown.
      steps: env steps of the rollout (at most the env's episode length).
    Returns:
      ``write(run_dir, chunk, params, key) -> Path`` that writes
      ``run_dir/viewer/chunk_<chunk>.html`` and copies it to ``run_dir/viewer.html``.
    """
    rollout = jax.jit(make_rollout(env, act, steps))

    def write(run_dir: str | Path, chunk: int, params, key: jax.Array) -> Path:
        if batched:
            params = jax.tree.map(lambda x: x[0], params)
        qpos, alive, marks, dropped = jax.device_get(rollout(params, key))
        out = Path(run_dir) / "viewer" / f"chunk_{chunk:06d}.html"
        name = f"{title or env.name}, chunk {chunk}"
        path = write_html(env, qpos[alive], out, name, markers=marks[alive], overflow=dropped[alive])
        shutil.copyfile(path, Path(run_dir) / "viewer.html")
        return path

    return write
