"""Dense Cholesky factor and solve at a batch of envs: the designs that could serve every device count.

    python -m experiments.dense_factor                  # n = 14, 15, 18, 22, 23 at batch 1024
    python -m experiments.dense_factor --sizes 18 23 --batch 256 --out DIR

The Newton solver factorises a dense Hessian where a scene's dofs form one chain of 14 or more
(``physics.factor.dense_solver``): Leap 22, Panda 15, the Berkeley humanoid 18, the Humanoid 23.
On several CPU devices a program holding LAPACK's batched ``potrf`` deadlocks (jaxlib's batch
map waits on the intra-op pool that every device's program occupies), so on CPU the column-wise
form in XLA's own ops runs on every device count, and the program does not depend on it. This
times the candidates, each ``jax.jit(jax.vmap(f))`` of one factor plus one solve, float32, on
random well-conditioned SPD matrices:

    lapack      ``lax.linalg.cholesky`` and ``cho_solve`` (safe on one CPU device only)
    columns     fastrl's column-wise factor, blocked 2 x 2 above 16 rows, batch-major (as shipped)
    minor       the same column-wise factor with the batch as the minor axis: a ``custom_vmap``
                rule moves the batch last, so each column step is a contiguous vector op over envs
    chunked     batch-minor in chunks of 128 envs under ``lax.map`` (a working set in cache)

Best of 7 repeats of 20 calls, microseconds per env; the relative error against LAPACK. Writes
``dense_factor.{json,md}`` to ``--out`` (``experiments/results/``).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp
import numpy as np
from jax.custom_batching import custom_vmap

from experiments import results
from fastrl.physics import factor

CHUNK = 128


def _lapack(qm, vec):
    c = jax.lax.linalg.cholesky(qm, symmetrize_input=False)
    return jax.scipy.linalg.cho_solve((c, True), vec)


def _columns(qm, vec):
    return factor._dense_cho_solve(factor._dense_cholesky(qm), vec)


def _last(x):
    return jnp.moveaxis(x, 0, -1)


def _cholesky_minor(qm):
    """``factor._column_cholesky`` of (n, n, B) matrices, the batch last."""
    n, trailing, cols = qm.shape[0], qm, []
    for k in range(n):
        pivot = jnp.sqrt(trailing[0, 0])
        below = trailing[1:, 0] / pivot
        cols.append(jnp.concatenate([jnp.zeros((k,) + pivot.shape, qm.dtype), pivot[None], below]))
        trailing = trailing[1:, 1:] - below[:, None] * below[None, :]
    return jnp.stack(cols, axis=1)


def _solve_minor(qm, vec):
    """``factor._dense_cho_solve`` after ``_cholesky_minor``: (n, n, B) and (n, B), the batch last."""
    c = _cholesky_minor(qm)
    r, y = vec, []
    for i in range(qm.shape[0]):
        y.append(r[i] / c[i, i])
        r = r - c[:, i] * y[i]
    r, x = jnp.stack(y), [None] * qm.shape[0]
    for i in reversed(range(qm.shape[0])):
        x[i] = r[i] / c[i, i]
        r = r - c[i] * x[i]
    return jnp.stack(x)


@custom_vmap
def _minor(qm, vec):
    return _columns(qm, vec)


@_minor.def_vmap
def _minor_rule(axis_size, in_batched, qm, vec):
    # column-wise over (n, n, B): every slice of the factor is a vector over the batch
    return jnp.moveaxis(_solve_minor(_last(qm), _last(vec)), -1, 0), True


@custom_vmap
def _chunked(qm, vec):
    return _columns(qm, vec)


@_chunked.def_vmap
def _chunked_rule(axis_size, in_batched, qm, vec):
    def one(args):
        q, v = args
        return jnp.moveaxis(_solve_minor(_last(q), _last(v)), -1, 0)

    split = lambda x: x.reshape((axis_size // CHUNK, CHUNK) + x.shape[1:])  # noqa: E731
    return jax.lax.map(one, (split(qm), split(vec))).reshape(vec.shape), True


DESIGNS = {"lapack": _lapack, "columns": _columns, "minor": _minor, "chunked": _chunked}


def time_one(f, qm, vec, ref) -> tuple[float, float]:
    fn = jax.jit(jax.vmap(f))
    out = fn(qm, vec).block_until_ready()
    err = float(jnp.max(jnp.abs(out - ref)) / jnp.max(jnp.abs(ref)))
    best = float("inf")
    for _ in range(7):
        start = time.perf_counter()
        for _ in range(20):
            out = fn(qm, vec)
        out.block_until_ready()
        best = min(best, (time.perf_counter() - start) / 20)
    return best / qm.shape[0] * 1e6, err


def measure(n: int, batch: int) -> dict:
    rng = np.random.default_rng(n)
    a = rng.normal(size=(batch, n, 3 * n)).astype(np.float32)
    qm = jnp.asarray(a @ a.transpose(0, 2, 1) / n + np.eye(n, dtype=np.float32))
    vec = jnp.asarray(rng.normal(size=(batch, n)).astype(np.float32))
    ref = jax.jit(jax.vmap(_lapack))(qm, vec)
    row = {"n": n, "batch": batch}
    for name, f in DESIGNS.items():
        row[name], row[f"{name}_err"] = time_one(f, qm, vec, ref)
    return row


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sizes", type=int, nargs="+", default=[14, 15, 18, 22, 23])
    p.add_argument("--batch", type=int, default=1024)
    p.add_argument("--out", default=str(results.RESULTS))
    args = p.parse_args()
    if args.batch % CHUNK:
        raise SystemExit(f"--batch must be a multiple of {CHUNK} (the chunked design's chunk)")
    rows = []
    for n in args.sizes:
        rows.append(measure(n, args.batch))
        print(rows[-1], flush=True)
    meta = {"date": results.today(), "machine": results.machine(), "fastrl": results.fastrl_version(),
            "command": results.command(), "devices": jax.device_count()}  # fmt: skip
    header = ["n", "batch", *(f"{d} us/env" for d in DESIGNS), "worst error vs LAPACK"]
    body = [[r["n"], r["batch"], *(f"{r[d]:.2f}" for d in DESIGNS),
             f"{max(r[f'{d}_err'] for d in DESIGNS):.1e}"] for r in rows]  # fmt: skip
    text = "# Dense Cholesky factor and solve: the designs that could serve every device count\n\n"
    text += f"{meta['date']}, {meta['machine']}, {meta['devices']} cpu device(s); "
    text += f"fastrl {meta['fastrl']}.\n\n"
    text += f"Command: `{meta['command']}`. What each design is: the script's docstring.\n\n"
    text += results.table(header, body)
    results.save(args.out, "dense_factor", {"meta": meta, "rows": rows}, text)


if __name__ == "__main__":
    main()
