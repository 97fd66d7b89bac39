"""Renders a qpos trajectory with MuJoCo's renderer into a GIF or MP4 (a child process).

``fastrl.tools.viewer.video`` runs this file as a script with ``MUJOCO_GL`` set to the OpenGL backend
to try. A backend is chosen once per process (PyOpenGL binds its platform at import), hence a
process per attempt; the script imports only mujoco, numpy and the encoder, so an attempt
costs a fraction of a second. Exit status: 0 written, 3 the OpenGL backend failed (the parent
tries the next one), anything else another error (message on stderr).
"""

import argparse
import sys

import numpy as np

GL_FAILED = 3

try:
    import mujoco
except Exception as e:  # noqa: BLE001 - MuJoCo checks MUJOCO_GL when imported
    print(f"{type(e).__name__}: {e}".splitlines()[0], file=sys.stderr)
    sys.exit(GL_FAILED)


def _camera(m: mujoco.MjModel, d: mujoco.MjData, root: int) -> mujoco.MjvCamera:
    """A camera tracking ``root`` from the front-left, far enough to see every non-plane geom."""
    mujoco.mj_forward(m, d)
    solid = m.geom_type != mujoco.mjtGeom.mjGEOM_PLANE
    reach = np.linalg.norm(d.geom_xpos[solid] - d.xpos[root], axis=1) + m.geom_rbound[solid]
    cam = mujoco.MjvCamera()
    cam.type = mujoco.mjtCamera.mjCAMERA_TRACKING if root > 0 else mujoco.mjtCamera.mjCAMERA_FREE
    cam.trackbodyid = root
    cam.lookat[:] = d.xpos[root]
    cam.distance = 3.2 * max(float(reach.max()) if solid.any() else 1.0, 0.1)
    cam.azimuth, cam.elevation = 110.0, -22.0
    return cam


def _frames(m: mujoco.MjModel, qpos: np.ndarray, width: int, height: int, root: int):
    """Yields (height, width, 3) uint8 images; the first one proves the backend works."""
    m.vis.global_.offwidth = max(m.vis.global_.offwidth, width)
    m.vis.global_.offheight = max(m.vis.global_.offheight, height)
    d = mujoco.MjData(m)
    d.qpos[:] = qpos[0]
    cam = _camera(m, d, root)
    with mujoco.Renderer(m, height, width) as renderer:
        for q in qpos:
            d.qpos[:] = q
            mujoco.mj_forward(m, d)
            renderer.update_scene(d, camera=cam)
            yield renderer.render().copy()


def _write(images: list, out: str, fps: float) -> None:
    if out.lower().endswith(".gif"):
        from PIL import Image

        pics = [Image.fromarray(a) for a in images]
        ms = max(20, round(1000 / fps))  # browsers play GIF delays under 20 ms slower, not faster
        pics[0].save(out, save_all=True, append_images=pics[1:], duration=ms, loop=0)
    else:
        import imageio.v2 as imageio

        with imageio.get_writer(out, fps=fps, macro_block_size=1) as w:
            for a in images:
                w.append_data(a)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("--xml", required=True)
    p.add_argument("--qpos", required=True, help=".npy file of (T, nq) positions")
    p.add_argument("--out", required=True)
    p.add_argument("--fps", type=float, required=True)
    p.add_argument("--width", type=int, default=480)
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--root", type=int, default=1, help="body the camera tracks")
    args = p.parse_args()
    m = mujoco.MjModel.from_xml_path(args.xml)
    frames = _frames(m, np.load(args.qpos), args.width, args.height, args.root)
    try:
        images = [next(frames)]
    except Exception as e:  # noqa: BLE001 - any failure to get a first image is the backend's
        print(f"{type(e).__name__}: {e}".splitlines()[0], file=sys.stderr)
        return GL_FAILED
    images.extend(frames)
    _write(images, args.out, args.fps)
    return 0


if __name__ == "__main__":
    sys.exit(main())
