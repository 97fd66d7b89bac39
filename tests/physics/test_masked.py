"""``masked.masked_map``: the same values as evaluating every element, under every transformation."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from fastrl.physics import masked

N = 40
W = jnp.arange(N * 3, dtype=jnp.float32).reshape(N, 3)
EMPTY = {"a": jnp.float32(9.0), "b": jnp.zeros(2, jnp.float32)}


def _fn(x, w, s):
    return {"a": jnp.sin(x) * s + w.sum(), "b": jnp.stack([x, 2 * x])}


def _masked(x, mask, s):
    return masked.masked_map(_fn, mask, (x, W, s), (0, 0, None), EMPTY)


def _everywhere(x, mask, s):
    """Every element evaluated, then the unset ones replaced: what ``masked_map`` must equal."""
    out = jax.vmap(_fn, (0, 0, None))(x, W, s)
    return {"a": jnp.where(mask, out["a"], 9.0), "b": jnp.where(mask[:, None], out["b"], 0.0)}


def _batch(size, share, seed=0):
    k = jax.random.split(jax.random.PRNGKey(seed), 3)
    x = jax.random.normal(k[0], (size, N))
    return x, jax.random.uniform(k[1], (size, N)) < share, jax.random.normal(k[2], (size,))


@pytest.mark.parametrize("share", [0.0, 0.1, 1.0])
def test_a_batch_gets_the_values_of_evaluating_every_element(share):
    """Under ``vmap`` the set entries are gathered in chunks (several here), and the result
    equals the where-form's, none, some or all set (to rounding:
    XLA may compile the gathered chunk with other fusions, a unit in the last place apart)."""
    x, mask, s = _batch(100, share)
    assert masked.chunk_size(100 * N) < int(mask.sum()) or share < 1
    got = jax.jit(jax.vmap(_masked))(x, mask, s)
    want = jax.jit(jax.vmap(_everywhere))(x, mask, s)
    for key in want:
        np.testing.assert_allclose(got[key], want[key], rtol=3e-7)


def test_one_environment_and_nested_batches_agree():
    x, mask, s = _batch(24, 0.2)
    want = jax.jit(jax.vmap(_everywhere))(x, mask, s)
    one = jax.jit(_masked)(x[3], mask[3], s[3])
    np.testing.assert_allclose(one["a"], want["a"][3], rtol=3e-7)
    nested = jax.jit(jax.vmap(jax.vmap(_masked)))(*(a.reshape(4, 6, *a.shape[1:]) for a in (x, mask, s)))
    np.testing.assert_allclose(nested["b"].reshape(24, N, 2), want["b"], rtol=3e-7)


def test_derivatives_are_those_of_the_where_form():
    """``jax.grad`` and ``jax.jvp`` through a batch: the set elements' derivative, zero elsewhere."""
    x, mask, s = _batch(16, 0.3)
    loss = lambda f: lambda x: jnp.sum(jax.vmap(f)(x, mask, s)["a"] ** 2)  # noqa: E731
    np.testing.assert_allclose(jax.grad(loss(_masked))(x), jax.grad(loss(_everywhere))(x), rtol=1e-6)
    tangent = jax.jvp(lambda x: jax.vmap(_masked)(x, mask, s)["a"], (x,), (jnp.ones_like(x),))[1]
    np.testing.assert_allclose(tangent, jnp.where(mask, jnp.cos(x) * s[:, None], 0.0), rtol=1e-6)


def test_a_batch_evaluates_only_its_set_entries_in_whole_chunks():
    """A function that records each element it is called on: a batch with 5% of its entries set
    calls it for those rounded up to whole chunks, not for all 4,000 entries."""
    x, mask, _ = _batch(100, 0.05)
    calls = []

    def fn(v):
        jax.debug.callback(lambda v: calls.append(1), v)
        return v

    out = jax.jit(jax.vmap(lambda x, m: masked.masked_map(fn, m, (x,), (0,), jnp.float32(0))))(x, mask)
    np.testing.assert_array_equal(out, jnp.where(mask, x, 0.0))
    chunk = masked.chunk_size(100 * N)
    assert len(calls) == -(-int(mask.sum()) // chunk) * chunk < 100 * N
