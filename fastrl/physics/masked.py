"""A per-element function evaluated only where a mask is set, paying for those elements only.

Collision tests run one per candidate pair (``jax.vmap`` over pairs), and a batch of
environments vmaps that again. A branch-free program would run an expensive test (GJK, EPA, face
clipping) on every candidate of every environment, although a few touch: ``lax.cond`` on "any
pair needs it" does not help, since under ``vmap`` it becomes a ``select`` that runs both sides.

``masked_map`` runs the test on the elements whose mask is set and gives the others a fixed
``empty`` result, with the same values either way (to rounding: XLA may fuse a gathered chunk
differently, a unit in the last place apart):

- for one environment, all elements under one ``lax.cond`` (skipped when none is set);
- under ``vmap`` over environments (``jax.custom_batching.custom_vmap``), the set (environment,
  element) entries of the whole batch are gathered and evaluated in chunks, a ``while_loop`` that
  stops after the last set entry, and scattered back: the batch pays for the entries it sets,
  not for every candidate of every environment;
- differentiated, the whole-batch ``where`` form (``jax.custom_jvp``), whose derivative is the
  same; forward- and reverse-mode both work through it.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

# Entries per pass of a batch's loop. Small chunks win for GJK and EPA: a chunk runs until its
# slowest entry converges, and a pass costs little beside its entries. Franka Panda's full-collision
# scene at batch 128, random joint angles (10 pairs per env reach GJK), its four face-clipped
# groups' GJK and EPA, us/env: chunks of 16 entries 270, 32 330, 128 580, a sixteenth of the
# batch's entries (at least 64) 850.
CHUNK = 16


def chunk_size(entries: int) -> int:
    """Entries evaluated per pass of the batch's loop, for a batch of ``entries`` (envs x elements)."""
    return min(entries, CHUNK)


def masked_map(fn, mask: jax.Array, args: tuple, axes: tuple, empty):
    """``vmap(fn, axes)(*args)`` where ``mask`` is set and ``empty`` elsewhere, evaluating ``fn`` on
    the set elements only (module docstring).

    Args:
      fn: a function of one element's ``args``.
      mask: (n,) bool, the elements to evaluate.
      args: ``fn``'s arguments: pytrees whose leaves have the element axis first where ``axes``
        is 0, or are shared by every element where it is None.
      axes: per argument, 0 or None (``jax.vmap``'s ``in_axes``).
      empty: the result of an element not evaluated: a pytree like one element's ``fn`` output.

    Returns:
      ``fn``'s outputs with a leading (n,) axis.
    """
    n = mask.shape[0]
    full = lambda: jax.tree.map(lambda e: jnp.broadcast_to(e, (n,) + jnp.shape(e)), empty)  # noqa: E731

    def plain(mask, args):
        out = jax.vmap(fn, axes)(*args)
        pick = lambda o, e: jnp.where(mask.reshape((n,) + (1,) * (o.ndim - 1)), o, e)  # noqa: E731
        return jax.tree.map(pick, out, full())

    def one(mask, args):  # one environment: the elements under one cond
        return jax.lax.cond(jnp.any(mask), lambda a: plain(mask, a), lambda a: full(), args)

    def batched(size: int, in_batched, mask, args):
        mask_batched, args_batched = in_batched
        mask = mask if mask_batched else jnp.broadcast_to(mask, (size, n))
        return _chunked(fn, mask, args, axes, args_batched, empty), jax.tree.map(lambda _: True, empty)

    skipping = jax.custom_batching.custom_vmap(one)
    skipping.def_vmap(batched)
    differentiable = jax.custom_jvp(skipping)
    differentiable.defjvp(lambda primals, tangents: jax.jvp(plain, primals, tangents))
    return differentiable(mask, args)


def _chunked(fn, mask: jax.Array, args: tuple, axes: tuple, batched: tuple, empty):
    """``masked_map`` over a batch: ``mask`` (B, n); each argument's leaves have the batch axis
    first where ``batched`` says so, then the element axis where ``axes`` is 0. Returns the
    outputs with leading (B, n) axes."""
    size, n = mask.shape
    entries = size * n
    chunk = chunk_size(entries)
    passes = -(-entries // chunk)
    flat = mask.reshape(entries)
    count = jnp.sum(flat)
    # the set entries first, in order; the rest point past the end (dropped when scattered)
    order = jnp.nonzero(flat, size=passes * chunk, fill_value=entries)[0]

    def take(sel):
        """The arguments of the entries ``sel`` (chunk,), and their vmap axes."""
        safe = jnp.minimum(sel, entries - 1)
        env, elem = safe // n, safe % n
        out, in_axes = [], []
        for arg, axis, flags in zip(args, axes, batched, strict=True):
            leaves, tree = jax.tree.flatten(arg)
            picked, leaf_axes = [], []
            for leaf, b in zip(leaves, jax.tree.leaves(flags), strict=True):
                if axis == 0:
                    picked.append(leaf[env, elem] if b else leaf[elem])
                else:
                    picked.append(leaf[env] if b else leaf)
                leaf_axes.append(0 if (axis == 0 or b) else None)
            out.append(jax.tree.unflatten(tree, picked))
            in_axes.append(jax.tree.unflatten(tree, leaf_axes))
        return tuple(out), tuple(in_axes)

    def body(state):
        i, buffers = state
        sel = jax.lax.dynamic_slice(order, (i * chunk,), (chunk,))
        chunk_args, in_axes = take(sel)
        out = jax.vmap(fn, in_axes)(*chunk_args)
        put = lambda buf, o: buf.at[sel].set(o, mode="drop")  # noqa: E731
        return i + 1, jax.tree.map(put, buffers, out)

    start = jax.tree.map(lambda e: jnp.broadcast_to(e, (entries,) + jnp.shape(e)), empty)
    _, buffers = jax.lax.while_loop(lambda s: s[0] * chunk < count, body, (jnp.zeros((), jnp.int32), start))
    return jax.tree.map(lambda b: b.reshape((size, n) + b.shape[1:]), buffers)
