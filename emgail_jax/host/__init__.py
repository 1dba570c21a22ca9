"""The host side: what runs the method and keeps it on disk.

JAX's process set-up, the problem a run solves (env, demonstrations, ERD's references), the
multi-seed runner that compiles the update and shards the seeds over devices, run directories
(``summary.json``), checkpoints, metric logs, demonstration files and saved runs. It imports
the method (:mod:`emgail_jax.method`), never the command lines above it.
"""
