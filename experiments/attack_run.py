"""An attack run on the training front door: hostile and damaged run folders, signals, full and
read-only disks, bad command lines. Each attack is run as a user (or an attacker) would, with
``python -m fastrl.train`` / ``fastrl.evaluate`` in a child process, and judged on two counts:
it ends in a named ``[fastrl] error:`` (no traceback) or a correct continuation, and nothing is
lost (files outside the run folder keep their bytes, the last good checkpoint stays readable,
and the run resumes).

    python -m experiments.attack_run              # every attack (~10 min on 2 cores)
    python -m experiments.attack_run --only SIGTERM "full disk"
    python -m experiments.attack_run --quick --out DIR   # the link and record attacks (CI)

The full-disk and read-only attacks mount a small tmpfs and a read-only bind mount, which needs
root; without it they are reported as not run. Writes ``experiments/results/attack_run.{md,json}``.
"""

from __future__ import annotations

import argparse
import contextlib
import os
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path

from experiments import results

QUICK = ["env=inverted_pendulum", "algo=ppo", "debug=quick", "logger=quiet", "checkpoint.every=1"]
LONG = [*QUICK, "train.total_env_steps=10240", "train.updates_per_chunk=2"]  # 40 chunks
VICTIM = b"a file of the user's, outside the run folder\n"


class Lab:
    """A scratch folder, a saved run to copy, and the child processes' environment."""

    def __init__(self, root: Path):
        self.root = root
        self.env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "FASTRL_XLA_FLAGS_ADDED")}
        self.env["FASTRL_CPU_DEVICES"] = "1"
        self.base = root / "base"
        self.cli(
            "fastrl.train", *QUICK, f"hydra.run.dir={self.base}", "train.stop_after_chunks=2", check=True
        )

    def cli(self, module: str, *args: str, check: bool = False, **kw) -> subprocess.CompletedProcess:
        out = subprocess.run([sys.executable, "-m", module, *args], cwd=self.root, env=self.env,
                             capture_output=True, text=True, timeout=600, **kw)  # fmt: skip
        if check and out.returncode:
            raise RuntimeError(f"{module} {args} exited {out.returncode}:\n{out.stderr[-2000:]}")
        return out

    def copy(self, name: str) -> Path:
        run = self.root / name
        shutil.copytree(self.base, run, symlinks=True)
        return run

    def victim(self, name: str) -> Path:
        path = self.root / f"victim_{name}"
        path.write_bytes(VICTIM)
        return path

    def start(self, run: Path, *extra: str) -> subprocess.Popen:
        cmd = [sys.executable, "-m", "fastrl.train", *LONG, f"hydra.run.dir={run}", *extra]
        return subprocess.Popen(cmd, cwd=self.root, env=self.env, stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)  # fmt: skip


def _wait_for(proc: subprocess.Popen, path: Path) -> None:
    deadline = time.monotonic() + 300
    while not path.exists():
        if proc.poll() is not None or time.monotonic() > deadline:
            raise RuntimeError(f"the run ended before {path} appeared:\n{proc.communicate()[1][-2000:]}")
        time.sleep(0.02)


def _error_line(stderr: str) -> str:
    lines = [line for line in stderr.splitlines() if line.startswith("[fastrl] error:")]
    return lines[0][len("[fastrl] error: ") :][:160] if lines else ""


def _verdict(rc: int, want_rc: int, stderr: str, kept: bool, note: str) -> dict:
    clean = "Traceback" not in stderr
    ok = rc == want_rc and clean and kept
    return {"rc": rc, "expected_rc": want_rc, "no_traceback": clean, "nothing_lost": kept, "ok": ok,
            "said": _error_line(stderr) or note}  # fmt: skip


def _resumes(lab: Lab, run: Path) -> bool:
    out = lab.cli("fastrl.train", f"resume={run}", "train.total_env_steps=1536")
    return out.returncode == 0 and "resumed" in out.stdout


# ----------------------------------------------------------------------------- folder attacks


def link_attack(name: str) -> Callable[[Lab], dict]:
    """``name`` inside a saved run replaced by a link to a file of the user's; then resume."""

    def attack(lab: Lab) -> dict:
        run, victim = lab.copy(f"link_{name.replace('/', '_')}"), lab.victim(name.replace("/", "_"))
        target = run / name
        shutil.rmtree(target) if target.is_dir() else target.unlink(missing_ok=True)
        target.symlink_to(victim)
        out = lab.cli("fastrl.train", f"resume={run}")
        return _verdict(out.returncode, 2, out.stderr, victim.read_bytes() == VICTIM, "")

    return attack


def record_attack(text: str) -> Callable[[Lab], dict]:
    """The run's recorded command line (``.hydra/overrides.yaml``) replaced by ``text``."""

    def attack(lab: Lab) -> dict:
        run = lab.copy(f"record_{abs(hash(text))}")
        (run / ".hydra" / "overrides.yaml").write_text(text)
        out = lab.cli("fastrl.train", f"resume={run}")
        return _verdict(out.returncode, 2, out.stderr, not (lab.root / "pwned").exists(), "")

    return attack


def damage_attack(path: str, damage: Callable[[bytes], bytes], module: str, want_rc: int = 0) -> Callable:
    """``path`` of a saved run damaged, then ``module`` (train: resume; evaluate) run on it."""

    def attack(lab: Lab) -> dict:
        run = lab.copy(f"damage_{path.replace('/', '_')}_{module}_{abs(hash(damage))}")
        (run / path).write_bytes(damage((run / path).read_bytes()))
        args = [f"resume={run}", "train.total_env_steps=1536"] if module == "fastrl.train" else [str(run)]
        out = lab.cli(module, *args)
        note = "continued: " + (out.stderr.strip().splitlines() or ["(nothing said)"])[0][:120]
        return _verdict(out.returncode, want_rc, out.stderr, True, note)

    return attack


def bad_value(*args: str) -> Callable[[Lab], dict]:
    def attack(lab: Lab) -> dict:
        out = lab.cli("fastrl.train", *QUICK, f"hydra.run.dir={lab.root / 'bad'}", *args)
        return _verdict(out.returncode, 2, out.stderr, not (lab.root / "bad").exists(), "")

    return attack


# ----------------------------------------------------------------------------- signals and disks


def signal_attack(signum: int, twice: bool = False) -> Callable[[Lab], dict]:
    """``signum`` sent once a run has saved its first checkpoint (twice: again at once)."""

    def attack(lab: Lab) -> dict:
        run = lab.root / f"signal_{signum}_{twice}"
        proc = lab.start(run)
        _wait_for(proc, run / "checkpoints" / "1")
        proc.send_signal(signum)
        if twice:
            time.sleep(0.01)
            proc.send_signal(signum)
        out, err = proc.communicate(timeout=300)
        want = 128 + (signal.SIGINT if twice else signum)
        note = "resume command printed" if "continue with" in out else "stopped at once"
        return _verdict(proc.returncode, want, err, _resumes(lab, run), note)

    return attack


def kill9(lab: Lab) -> dict:
    """SIGKILL mid-run (nothing can be caught): the resume tidies partial saves and continues."""
    run = lab.root / "kill9"
    proc = lab.start(run)
    _wait_for(proc, run / "checkpoints" / "2")
    proc.kill()
    proc.communicate()
    resumed = _resumes(lab, run) and not list((run / "checkpoints").glob("*tmp*"))
    return _verdict(0, 0, "", resumed, "resumed from the last complete checkpoint")


def file_size_limit(lab: Lab) -> dict:
    """Every write that grows a file fails mid-run (RLIMIT_FSIZE=0: a full disk without root)."""
    run = lab.root / "fsize"
    proc = lab.start(run)
    _wait_for(proc, run / "checkpoints" / "3")
    resource.prlimit(proc.pid, resource.RLIMIT_FSIZE, (0, 0))
    _, err = proc.communicate(timeout=300)
    return _verdict(proc.returncode, 74, err, _resumes(lab, run), "")


@contextlib.contextmanager
def _tmpfs(lab: Lab, name: str, size: str = "8m") -> Iterator[Path | None]:
    """A fresh tmpfs at ``lab.root/name`` for one attack (None where mounting needs root),
    unmounted afterwards."""
    mnt = lab.root / name
    mnt.mkdir()
    ok = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(mnt)], capture_output=True
    )
    if ok.returncode != 0:
        yield None
        return
    try:
        yield mnt
    finally:
        subprocess.run(["umount", "-l", str(mnt)])


def full_disk(lab: Lab) -> dict:
    """A real full disk (a tmpfs filled by another file) once the run has saved."""
    with _tmpfs(lab, "full") as mnt:
        if mnt is None:
            return {"ok": None, "said": "not run: mounting a tmpfs needs root"}
        run = mnt / "r"
        proc = lab.start(run, "logger=default")
        _wait_for(proc, run / "checkpoints" / "3")
        subprocess.run(f"dd if=/dev/zero of={mnt}/filler bs=64k", shell=True, capture_output=True)
        _, err = proc.communicate(timeout=300)
        (mnt / "filler").unlink()
        lines = len(err.strip().splitlines())
        return _verdict(proc.returncode, 74, err, _resumes(lab, run), "") | {"stderr_lines": lines}


def read_only(lab: Lab) -> dict:
    """The checkpoints folder made read-only (a bind mount) while the run goes."""
    with _tmpfs(lab, "ro") as mnt:
        if mnt is None:
            return {"ok": None, "said": "not run: mounting needs root"}
        run = mnt / "r"
        proc = lab.start(run)
        _wait_for(proc, run / "checkpoints" / "3")
        ckpts = str(run / "checkpoints")
        subprocess.run(["mount", "--bind", ckpts, ckpts], check=True)
        subprocess.run(["mount", "-o", "remount,ro,bind", ckpts], check=True)
        t = time.monotonic()
        _, err = proc.communicate(timeout=300)
        seconds = time.monotonic() - t
        subprocess.run(["umount", ckpts])
        return _verdict(proc.returncode, 74, err, _resumes(lab, run), "") | {"exit_s": round(seconds, 1)}


# ----------------------------------------------------------------------------- models users bring

_CHAIN = """
import numpy as np
from fastrl import physics
body = ""
for i in reversed(range(200)):
    body = (f'<body pos="0 0 {-0.1 if i else 0}"><joint name="j{i}" axis="0 1 0" damping="0.01"/>'
            f'<geom type="capsule" fromto="0 0 0 0 0 -0.1" size="0.01"/>{body}</body>')
flag = "" if CONTACTS else '<option><flag contact="disable"/></option>'
model = physics.load_mjcf(f'<mujoco>{flag}<worldbody><body pos="0 0 25">{body}</body></worldbody></mujoco>')
d = physics.make_data(model, qpos=np.full(model.nq, 0.05))
for _ in range(5):
    d = physics.step(model, d)
assert np.isfinite(np.asarray(d.qvel)).all() and not bool(d.diverged)
print("200-deep chain, float32: 5 steps finite")
"""

_SPHERES = """
import time
from fastrl import physics
geoms = "".join(f'<geom type="sphere" size="0.1" pos="{i % 100} {i // 100} 0.1"/>' for i in range(10000))
xml = f'<mujoco><worldbody>{geoms}<body pos="0 0 2"><freejoint/><geom size=".2"/></body></worldbody></mujoco>'
t = time.perf_counter()
physics.load_mjcf(xml)
seconds = time.perf_counter() - t
assert seconds < 5, seconds
print(f"10,000 static spheres loaded in {seconds:.1f} s")
"""

_ACTIVATION = """
import numpy as np
from fastrl import physics
xml = (
    '<mujoco><option noslip_iterations="10"/><worldbody><geom type="plane" size="2 2 .1"/>'
    '<body pos="0 0 .1" euler="0 10 0"><freejoint/><geom type="box" size=".1 .1 .1"/></body>'
    '<body pos="0 0 1"><joint name="h" axis="0 1 0"/><geom type="capsule" fromto="0 0 0 .3 0 0" size=".03"/>'
    '</body></worldbody><actuator><position joint="h" kp="10" timeconst=".05"/>'
    '<intvelocity joint="h" kp="5" actrange="-1 1"/><general joint="h" dyntype="filter" dynprm=".1"/>'
    '</actuator></mujoco>'
)
model = physics.load_mjcf(xml)
d = physics.make_data(model)
d = d.replace(ctrl=np.full(model.nu, 0.5, np.float32))
for _ in range(20):
    d = physics.step(model, d)
assert np.isfinite(np.asarray(d.qpos)).all() and np.abs(np.asarray(d.act)).max() > 0
print("filterexact, integrator and filter actuators with noslip: 20 steps finite, act moving")
"""


def model_attack(code: str, refused: str | None = None) -> Callable[[Lab], dict]:
    """A model a user brings, loaded and stepped in a child process: it runs, or (``refused``)
    is refused by name."""

    def attack(lab: Lab) -> dict:
        out = subprocess.run([sys.executable, "-c", code], cwd=lab.root, env=lab.env, capture_output=True,
                             text=True, timeout=900)  # fmt: skip
        if refused is not None:
            ok = out.returncode == 1 and refused in out.stderr
            said = next((x for x in out.stderr.splitlines() if f"{refused}:" in x), out.stderr[-200:])
            return {"rc": out.returncode, "expected_rc": 1, "ok": ok, "said": said[:200]}
        return _verdict(out.returncode, 0, out.stderr, True, out.stdout.strip()[-160:])

    return attack


def _truncate(data: bytes) -> bytes:
    return data[:100]


def _half_row(data: bytes) -> bytes:
    return data + b"3.0,4.1,0.0,0"


ATTACKS: dict[str, Callable[[Lab], dict]] = {
    "link config.json.tmp": link_attack("config.json.tmp"),
    "link .lock": link_attack(".lock"),
    "link metrics.csv": link_attack("metrics.csv"),
    "link .hydra/overrides.yaml": link_attack(".hydra/overrides.yaml"),
    "link checkpoints/1": link_attack("checkpoints/1"),
    "record: init_from='$(touch pwned)'": record_attack(
        "- env=inverted_pendulum\n- init_from='$(touch pwned)'\n"
    ),
    "record: invalid YAML": record_attack("- [unclosed\n"),
    "record: an entry with a line break": record_attack('- "seed=0\\ntouch pwned"\n'),
    "record: hydra.run.dir": record_attack("- hydra.run.dir=/etc\n"),
    "metrics.csv: half a last row": damage_attack("metrics.csv", _half_row, "fastrl.train"),
    "config.json truncated": damage_attack("config.json", _truncate, "fastrl.train"),
    "config.json = null": damage_attack("config.json", lambda d: b"null", "fastrl.train"),
    "newest checkpoint's metadata = null (evaluate)": damage_attack(
        "checkpoints/2/meta/metadata", lambda d: b"null", "fastrl.evaluate"
    ),
    "train.total_env_steps=nan": bad_value("train.total_env_steps=nan"),
    "train.total_env_steps=inf": bad_value("train.total_env_steps=inf"),
    "+env.options.asset=/nonexistent.xml": bad_value("+env.options.asset=/nonexistent.xml"),
    "SIGTERM mid-run": signal_attack(signal.SIGTERM),
    "SIGHUP mid-run": signal_attack(signal.SIGHUP),
    "SIGINT twice": signal_attack(signal.SIGINT, twice=True),
    "SIGKILL mid-run, then resume": kill9,
    "file size limit 0 mid-run": file_size_limit,
    "full disk (tmpfs) mid-run": full_disk,
    "checkpoints read-only mid-run": read_only,
    "model: 200-deep hinge chain, float32": model_attack("CONTACTS = False\n" + _CHAIN),
    "model: 200-deep chain with contacts, float32": model_attack(
        "CONTACTS = True\n" + _CHAIN, refused="UnsupportedFeatureError"
    ),
    "model: 10,000 static spheres": model_attack(_SPHERES),
    "model: activation dynamics and noslip": model_attack(_ACTIVATION),
}


def markdown(rows: dict, meta: dict) -> str:
    head = [
        "# Attack run: hostile and damaged run folders, signals, full and read-only disks",
        "",
        f"{meta['date']}, {meta['machine']}; fastrl {meta['fastrl']}. Command: `{meta['command']}`.",
        "",
        "Each attack runs the command line in a child process. ok: the exit status expected, no "
        "traceback, and nothing lost (a file outside the folder keeps its bytes; the run resumes).",
        "",
    ]
    cells = [
        [
            name,
            r.get("rc"),
            r.get("expected_rc"),
            {True: "yes", False: "NO", None: "not run"}[r["ok"]],
            r["said"],
        ]
        for name, r in rows.items()
    ]
    return "\n".join(head) + results.table(["attack", "exit", "expected", "ok", "said"], cells) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--only", nargs="*", help="substrings of the attacks to run")
    parser.add_argument("--quick", action="store_true", help="the link and record attacks only (CI)")
    parser.add_argument("--out", type=Path, default=results.RESULTS)
    args = parser.parse_args()
    if args.quick:
        args.only = ["link ", "record:"]
    chosen = {k: v for k, v in ATTACKS.items() if not args.only or any(o in k for o in args.only)}
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        lab = Lab(Path(tmp))
        for name, attack in chosen.items():
            rows[name] = attack(lab)
            print(f"{'ok ' if rows[name]['ok'] else 'BAD'} {name}: {rows[name]}", flush=True)
    commit = subprocess.run(
        ["git", "rev-parse", "--short", "HEAD"], cwd=results.ROOT, capture_output=True, text=True
    )
    meta = {"date": results.today(), "machine": results.machine(), "fastrl": commit.stdout.strip(),
            "command": results.command()}  # fmt: skip
    stem = "attack_run_quick" if args.quick else "attack_run"
    results.save(args.out, stem, {"meta": meta, "results": rows}, markdown(rows, meta))


if __name__ == "__main__":
    main()
