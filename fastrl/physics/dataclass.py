"""Frozen dataclasses that are JAX pytrees, with static fields decided by annotation.

A field annotated ``np.ndarray``, ``int``, ``float``, ``bool``, ``str`` or ``tuple`` is static: it
lives in the pytree's treedef, so the program is specialised on it at trace time. Every other
field (``jax.Array``, or a nested pytree) is a child: traced under ``jit``, batched under
``vmap``, differentiable. This is how ``Model``
keeps topology (joint types, parent indices) static and physical parameters traced.
"""

from __future__ import annotations

import dataclasses
import typing

import jax
import numpy as np

_T = typing.TypeVar("_T")


class _Frozen:
    """Hashable wrapper for a static field value (numpy arrays hash by dtype, shape and bytes)."""

    __slots__ = ("value", "_key")

    def __init__(self, value):
        self.value = value
        if isinstance(value, np.ndarray):
            self._key = (value.dtype.str, value.shape, value.tobytes())
        else:
            self._key = value

    def __hash__(self):
        return hash(self._key)

    def __eq__(self, other):
        return isinstance(other, _Frozen) and self._key == other._key


_STATIC = (np.ndarray, int, float, bool, str, tuple)
_STATIC_NAMES = {"np.ndarray", "numpy.ndarray", "int", "float", "bool", "str", "tuple"}


def _is_traced(annotation) -> bool:
    if isinstance(annotation, str):
        return annotation.split("[")[0] not in _STATIC_NAMES
    return annotation not in _STATIC


def pytree_dataclass(cls: type[_T]) -> type[_T]:
    """Turns ``cls`` into a frozen dataclass registered as a pytree (see module docstring)."""
    cls = dataclasses.dataclass(frozen=True)(cls)
    fields = dataclasses.fields(cls)
    leaves = tuple(f.name for f in fields if _is_traced(f.type))
    statics = tuple(f.name for f in fields if not _is_traced(f.type))

    def flatten_with_keys(obj):
        children = [(jax.tree_util.GetAttrKey(n), getattr(obj, n)) for n in leaves]
        aux = tuple(_Frozen(getattr(obj, n)) for n in statics)
        return children, aux

    def unflatten(aux, children):
        obj = object.__new__(cls)
        for n, v in zip(leaves, children, strict=True):
            object.__setattr__(obj, n, v)
        for n, v in zip(statics, aux, strict=True):
            object.__setattr__(obj, n, v.value)
        return obj

    jax.tree_util.register_pytree_with_keys(cls, flatten_with_keys, unflatten)
    cls.replace = lambda self, **kw: dataclasses.replace(self, **kw)  # type: ignore[attr-defined]
    return cls
