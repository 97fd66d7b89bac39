"""The runtime: how fastrl's programs meet the machine, below every other layer.

- ``devices``: device meshes, the one axis every split (envs, learners, agent batches) uses.
- ``xla_flags``: the XLA:CPU flags the command lines set before JAX starts a backend.
- ``compile_cache``: JAX's persistent compilation cache and the kept traced training chunk.

Imports nothing from the rest of fastrl. Importing this package imports none of its modules, so
``import fastrl`` (which reads ``xla_flags``) does not import JAX.
"""
