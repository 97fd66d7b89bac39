"""Opening viewer pages in headless Chromium: the DOM after playback, and screenshots.

The tests use it to check a page in a real browser, and the README's screenshot is made with it
(``python -m fastrl.tools.viewer.chromium page.html shot.png``). WebGL runs without a GPU through
SwiftShader. Chromium comes from the system (Debian: ``apt-get install chromium``).
"""

from __future__ import annotations

import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

NAMES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")
FLAGS = (
    "--headless",
    "--no-sandbox",  # CI runs as root
    "--disable-gpu",
    "--use-angle=swiftshader",  # WebGL in software
    "--enable-unsafe-swiftshader",
    "--mute-audio",
    "--hide-scrollbars",
)


def find_chromium() -> str | None:
    """The path of a Chromium (or Chrome) executable on PATH, or None."""
    return next((p for p in map(shutil.which, NAMES) if p), None)


def _run(page: str | Path, args: list[str], budget_ms: int, size: tuple[int, int], fragment: str = ""):
    exe = find_chromium()
    if exe is None:
        raise FileNotFoundError(f"no Chromium found (looked for {', '.join(NAMES)} on PATH)")
    with tempfile.TemporaryDirectory() as profile:
        cmd = [exe, *FLAGS, f"--user-data-dir={profile}", "--enable-logging=stderr", "--v=0",
               f"--virtual-time-budget={budget_ms}", f"--window-size={size[0]},{size[1]}", *args,
               Path(page).absolute().as_uri() + fragment]  # fmt: skip
        return subprocess.run(cmd, capture_output=True, text=True, timeout=120)


def dump_dom(
    page: str | Path, budget_ms: int = 3000, size: tuple[int, int] = (800, 600), frame: int | None = None
):
    """(DOM, console lines): the page's HTML after ``budget_ms`` of virtual time (paused at
    ``frame`` if given), and the browser's console messages (``INFO:CONSOLE`` lines of its log)."""
    r = _run(page, ["--dump-dom"], budget_ms, size, "" if frame is None else f"#frame={frame}")
    console = [line for line in r.stderr.splitlines() if ":CONSOLE" in line]
    return r.stdout, console


def screenshot(
    page: str | Path,
    png: str | Path,
    budget_ms: int = 1500,
    size: tuple[int, int] = (800, 600),
    frame: int | None = None,
) -> Path:
    """Saves a PNG of the page after ``budget_ms`` of virtual time (paused at ``frame`` if
    given); returns its path."""
    png = Path(png).absolute()
    r = _run(page, [f"--screenshot={png}"], budget_ms, size, "" if frame is None else f"#frame={frame}")
    if not png.exists():
        raise RuntimeError(f"chromium wrote no screenshot (exit status {r.returncode}): {r.stderr[-2000:]}")
    return png


if __name__ == "__main__":
    if len(sys.argv) not in (3, 5, 6):
        sys.exit("usage: python -m fastrl.tools.viewer.chromium PAGE.html OUT.png [WIDTH HEIGHT [FRAME]]")
    wh = (int(sys.argv[3]), int(sys.argv[4])) if len(sys.argv) >= 5 else (800, 600)
    print(
        screenshot(sys.argv[1], sys.argv[2], size=wh, frame=int(sys.argv[5]) if len(sys.argv) == 6 else None)
    )
