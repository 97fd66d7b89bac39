#!/usr/bin/env bash
# Create (or update) the peer virtualenv at <repo>/.venv-peers.
#
#   bash experiments/peers/setup_peers.sh        # everything
#   bash experiments/peers/setup_peers.sh sb3    # Stable-Baselines3 only (what CI's quick test needs)
#
# Installs Brax 0.14.x (which pulls jax, mujoco, mujoco-mjx), EnvPool, Gymnasium and NumPy, and
# Stable-Baselines3 with PyTorch's CPU build, with Python 3.11: torch 2.13.0, from PyTorch's CPU
# index where that resolves, else from pip's configured sources (where PyPI's Linux wheel is the
# CUDA build, some 3 GB). Idempotent: re-running reuses the venv and only installs what is missing.
# EnvPool is optional: if no wheel installs for this Python/platform, the script says so and
# carries on (experiments/peers/envpool_ant.py then cannot run).
# JAX is deliberately NOT pinned; the peer scripts shim jax.device_put_replicated (removed from
# newer JAX, still called by Brax 0.14) — see experiments/peers/brax_ant.py.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/../.." && pwd)"
VENV="${PEERS_VENV:-$ROOT/.venv-peers}"
PYTHON="${PEERS_PYTHON:-python3.11}"

if ! command -v "$PYTHON" >/dev/null 2>&1; then
  if [[ -z "${PEERS_PYTHON:-}" ]] && command -v python3 >/dev/null 2>&1; then
    echo "setup_peers: python3.11 not found; using $(python3 --version 2>&1) (EnvPool's wheels may not fit it)" >&2
    PYTHON=python3
  else
    echo "setup_peers: $PYTHON not found; install Python 3.11 first" >&2
    exit 1
  fi
fi

if [[ ! -x "$VENV/bin/python" ]]; then
  echo "setup_peers: creating $VENV with $($PYTHON --version 2>&1)"
  "$PYTHON" -m venv "$VENV"
else
  echo "setup_peers: reusing $VENV ($("$VENV/bin/python" --version 2>&1))"
fi

PIP=("$VENV/bin/python" -m pip --disable-pip-version-check)
"${PIP[@]}" install --quiet --upgrade pip

echo "setup_peers: installing torch (CPU build), stable-baselines3, gymnasium[mujoco]"
if ! "$VENV/bin/python" -c "import torch" 2>/dev/null; then
  # torch 2.13.0's CPU build (2.13.0+cpu sorts above PyPI's CUDA build of 2.13.0)
  CPU_INDEX=()
  if "$VENV/bin/python" -c "import socket; socket.getaddrinfo('download.pytorch.org', 443)" 2>/dev/null; then
    CPU_INDEX=(--extra-index-url https://download.pytorch.org/whl/cpu)
  fi
  "${PIP[@]}" install --quiet "torch==2.13.0" "${CPU_INDEX[@]}"
fi
"${PIP[@]}" install --quiet "stable-baselines3>=2.4,<3" "gymnasium[mujoco]>=1.0"
if [[ "${1:-all}" == "sb3" ]]; then
  "$VENV/bin/python" -c "import importlib.metadata as md; print('  ' + ', '.join(f'{n}=={md.version(n)}' for n in ('torch', 'stable-baselines3', 'gymnasium', 'mujoco')))"
  exit 0
fi

echo "setup_peers: installing brax 0.14.x, gymnasium, numpy"
"${PIP[@]}" install --quiet "brax>=0.14,<0.15" gymnasium numpy

echo "setup_peers: installing envpool (optional)"
if "${PIP[@]}" install --quiet envpool; then
  ENVPOOL_OK=1
else
  ENVPOOL_OK=0
  echo "setup_peers: WARNING: envpool could not be installed for $("$VENV/bin/python" --version 2>&1)" \
       "on $(uname -m); continuing without it (envpool_ant.py will not run)." >&2
fi

echo "setup_peers: installed versions:"
"$VENV/bin/python" - "$ENVPOOL_OK" <<'EOF'
import importlib.metadata as md
import sys

for name in ["brax", "jax", "jaxlib", "mujoco", "mujoco-mjx", "envpool", "gymnasium", "numpy", "torch",
             "stable-baselines3"]:
    try:
        print(f"  {name}=={md.version(name)}")
    except md.PackageNotFoundError:
        print(f"  {name}: not installed")
if sys.argv[1] != "1":
    print("  (envpool unavailable: EnvPool peer benchmarks are skipped)")
EOF
