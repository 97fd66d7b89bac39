"""The rollout viewer: poses against MuJoCo, the page in headless Chromium, videos, the run hooks."""

import json
import re

import mujoco
import numpy as np
import pytest
from PIL import Image

from fastrl import envs
from fastrl.tools import evaluate, viewer
from fastrl.tools.viewer import chromium, scene, video


def ant_trajectory(env, frames: int = 40) -> np.ndarray:
    """(frames, nq) Ant positions without any physics: the torso walks along +x and turns a little
    while the hips and ankles swing, so every body moves (no compile of the env's step)."""
    t = np.arange(frames)[:, None]
    qpos = np.tile(np.asarray(env.model.qpos0), (frames, 1))
    qpos[:, 0:1] = 0.03 * t
    qpos[:, 2] = 0.6
    yaw = 0.01 * t[:, 0]
    qpos[:, 3:7] = np.stack([np.cos(yaw / 2), 0 * yaw, 0 * yaw, np.sin(yaw / 2)], axis=1)
    qpos[:, 7:] += 0.4 * np.sin(0.3 * t + np.arange(env.model.nq - 7))
    return qpos


@pytest.fixture(scope="module")
def ant():
    return envs.make("ant")


@pytest.fixture(scope="module")
def ant_page(ant, tmp_path_factory):
    path = tmp_path_factory.mktemp("viewer") / "ant.html"
    return viewer.write_html(ant, ant_trajectory(ant), path, title="ant test")


def test_poses_match_mujoco_kinematics(ant):
    qpos = ant_trajectory(ant, 5)
    xpos, xquat, _ = scene.body_poses(ant.model, qpos)
    m = mujoco.MjModel.from_xml_path(str(scene.asset_path(ant)))
    d = mujoco.MjData(m)
    for q, p, r in zip(qpos, xpos, xquat, strict=True):
        d.qpos[:] = q
        mujoco.mj_kinematics(m, d)
        np.testing.assert_allclose(p, d.xpos, atol=1e-5)
        np.testing.assert_allclose(np.abs(np.sum(r * d.xquat, axis=1)), 1.0, atol=1e-5)  # q ~ -q


def test_page_is_self_contained_and_embeds_the_scene(ant, ant_page):
    text = ant_page.read_text()
    assert "://" not in text and "src=" not in text, "the page must not fetch anything"
    data = json.loads(re.search(r'<script id="scene" type="application/json">(.*?)</script>', text, re.S)[1])
    assert data["nframe"] == 40 and len(data["frames"]) == 40 * ant.model.nbody * 7
    assert {g["type"] for g in data["geoms"]} == {0, 2, 3}  # the floor, the torso, capsule limbs
    assert len(data["geoms"]) == ant.model.ngeom and data["root"] == 1
    assert all(len(repr(x)) <= 8 for x in data["frames"][:500]), "floats are rounded to 4 decimals"


@pytest.mark.skipif(chromium.find_chromium() is None, reason="no chromium on PATH (apt-get install chromium)")
def test_page_plays_in_headless_chromium(ant_page, tmp_path):
    dom, console = chromium.dump_dom(ant_page, budget_ms=3000)
    errors = re.search(r'<pre id="errors"[^>]*>(.*?)</pre>', dom, re.S)[1]
    assert errors == "", f"the page recorded errors: {errors}"
    assert not [line for line in console if "Uncaught" in line or "rror" in line], console
    assert re.search(r'<body[^>]*data-status="running"', dom), dom[:500]
    frame = int(re.search(r'<span id="frame">(\d+)</span>', dom)[1])
    assert frame > 0, "the frame counter did not advance"

    png = chromium.screenshot(ant_page, tmp_path / "ant.png", size=(640, 480))
    img = np.asarray(Image.open(png).convert("RGB"), np.int32)
    h, w, _ = img.shape
    centre = img[h // 4 : 3 * h // 4, w // 4 : 3 * w // 4]
    # The Ant is brown (rgba 0.8 0.6 0.4); the sky is blue-grey and the floor green-grey.
    body = (centre[..., 0] - centre[..., 2]) > 40
    assert body.mean() > 0.03, f"only {body.mean():.1%} of the centre shows the Ant"


def test_video_writes_a_gif_or_says_why_not(tmp_path):
    env = envs.make("inverted_pendulum")
    qpos = np.zeros((6, env.model.nq))
    qpos[:, 0] = np.linspace(-0.5, 0.5, 6)
    qpos[:, 1] = np.linspace(-0.5, 0.5, 6)
    out = tmp_path / "pendulum.gif"
    try:
        viewer.render_video(env, qpos, out, width=96, height=72)
    except viewer.VideoError as e:  # no EGL/OSMesa on this machine: the message must say so
        assert "tried MUJOCO_GL=" in str(e) and "apt-get install" in str(e)
        pytest.skip(f"no OpenGL backend for MuJoCo here: {e}")
    gif = Image.open(out)
    assert gif.size == (96, 72) and gif.n_frames == 6
    first, last = np.asarray(gif.convert("RGB")), None
    gif.seek(5)
    last = np.asarray(gif.convert("RGB"))
    assert first.std() > 5 and np.abs(first.astype(int) - last).mean() > 0.5, "frames look empty or equal"


def test_video_errors_are_clear(tmp_path):
    env = envs.make("inverted_pendulum")
    qpos = np.zeros((2, env.model.nq))
    with pytest.raises(viewer.VideoError, match="unsupported video format '.avi'"):
        viewer.render_video(env, qpos, tmp_path / "x.avi")
    with pytest.raises(viewer.VideoError, match="tried MUJOCO_GL=nogl: .*apt-get install -y libosmesa6"):
        viewer.render_video(env, qpos, tmp_path / "x.gif", backends=("nogl",))
    assert video.VIDEO_FORMATS == (".gif", ".mp4")


def test_training_run_writes_viewer_pages_and_evaluate_cli(tmp_path, capsys):
    from fastrl.cli.train import run
    from tests.train.test_front_door import QUICK, compose_cfg

    run_dir = tmp_path / "run"
    out = run(compose_cfg([*QUICK, f"run_dir={run_dir}", "logger.viewer_every=2"]))
    pages = sorted(p.name for p in (run_dir / "viewer").iterdir())
    chunks = out["chunks"]
    assert pages == [f"chunk_{c:06d}.html" for c in range(2, chunks + 1) if c % 2 == 0 or c == chunks]
    assert (run_dir / "viewer.html").read_text() == (run_dir / "viewer" / pages[-1]).read_text()

    html, npz = tmp_path / "eval.html", tmp_path / "ep.npz"
    args = [str(run_dir), "--episodes", "2", "--steps", "10", "--html", str(html), "--export", str(npz)]
    assert evaluate.run(args) == 0
    frames = len(np.load(npz)["qpos"])
    assert 1 <= frames <= 11 and f'"nframe":{frames},' in html.read_text()
    assert "wrote" in capsys.readouterr().out
    assert evaluate.run([str(run_dir), "--episodes", "2", "--video", str(tmp_path / "x.avi")]) == 2
    assert "unsupported video format" in capsys.readouterr().err


def test_goal_markers_are_embedded_and_drawn(tmp_path):
    arm = envs.make("arm_reach")
    qpos = np.tile(np.asarray(arm.model.qpos0), (6, 1))
    marks = np.tile([[[0.4, 0.1, 0.3]]], (6, 1, 1))
    data = scene.build_scene(arm, qpos, markers=marks)
    assert data["nmarker"] == 1 and data["markers"][:3] == [0.4, 0.1, 0.3] and len(data["markers"]) == 18
    assert scene.build_scene(arm, qpos)["nmarker"] == 0
    with pytest.raises(ValueError, match="markers has shape"):
        scene.build_scene(arm, qpos, markers=marks[:3])
    if chromium.find_chromium() is None:
        pytest.skip("no chromium on PATH (apt-get install chromium)")
    # Opened paused at frame 3: a playing 6-frame loop shows frame 0 one sixth of the time.
    dom, _ = chromium.dump_dom(
        viewer.write_html(arm, qpos, tmp_path / "arm.html", markers=marks), budget_ms=2000, frame=3
    )
    assert re.search(r'<pre id="errors"[^>]*>(.*?)</pre>', dom, re.S)[1] == ""
    assert int(re.search(r'<span id="frame">(\d+)</span>', dom)[1]) == 3, "the marked frame was not drawn"


def test_dropped_contacts_show_in_the_bar(tmp_path):
    """Frames where the scene's contact budgets dropped contacts say so in the control bar."""
    arm = envs.make("arm_reach")
    qpos = np.tile(np.asarray(arm.model.qpos0), (6, 1))
    dropped = np.array([0, 0, 0, 2, 0, 0])
    assert scene.build_scene(arm, qpos, overflow=dropped)["overflow"] == [0, 0, 0, 2, 0, 0]
    assert scene.build_scene(arm, qpos)["overflow"] == []
    with pytest.raises(ValueError, match="overflow has shape"):
        scene.build_scene(arm, qpos, overflow=dropped[:3])
    if chromium.find_chromium() is None:
        pytest.skip("no chromium on PATH (apt-get install chromium)")
    page = viewer.write_html(arm, qpos, tmp_path / "arm.html", overflow=dropped)
    shown = lambda frame: re.search(  # noqa: E731
        r'<span id="overflow"[^>]*>(.*?)</span>', chromium.dump_dom(page, budget_ms=2000, frame=frame)[0]
    )[1]
    assert shown(3) == "contacts dropped: 2"
    assert shown(1) == ""
