"""The compiled training program of one config: the Trainer, its AOT-compiled ``init`` and ``chunk``,
vmapped over seeds and/or split over a device mesh, cached in-process so repeated runs and resumes compile once."""

from __future__ import annotations

import dataclasses
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import jax
import numpy as np

from ramavt_jax import distributed
from ramavt_jax.train import Components, Trainer
from ramavt_jax.train_config import RunConfig, TrainConfig
from ramavt_jax.training import memory as memplan

__all__ = ["compiled_program"]


@dataclasses.dataclass
class _Program:
    trainer: Trainer
    init: Any  # AOT-compiled: key [2] (or [S, 2]) -> RunnerState
    chunk: Any  # AOT-compiled: RunnerState -> (RunnerState, ChunkMetrics)
    compile_s: float
    shardings: Any  # RunnerState pytree of NamedSharding, or None (one device)
    memory: dict  # bytes: state per seed, replay per seed, XLA temp of the chunk


# (config, seeds, mesh, env id, NaN hook, components) -> _Program; repeated runs, resumes and tests compile once
_COMPILED: dict = {}
# The initial state's program (the envs' reset with its renderer, the network's init) runs once per run, so on CPU
# it is compiled without LLVM's optimisations, beside the chunk. One-off timings on an idle 2-core VM (quick preset,
# cold cache; benchmarks/RESULTS.md): the two compiled one after the other in 19.4-21.7 s, in parallel in 23.8 s
# (XLA already uses both cores), and in parallel with the init unoptimised in 12.3-16.6 s.
_INIT_COMPILER_OPTIONS = {"cpu": {"xla_backend_optimization_level": 0}}


@dataclasses.dataclass(frozen=True)
class _Staged:
    init: Any  # lowered: key [2] (or [S, 2]) -> RunnerState
    chunk: Any  # jitted (lowered once the state is known to fit): RunnerState -> (RunnerState, ChunkMetrics)
    abstract: Any  # RunnerState of ShapeDtypeStructs: the state's shapes
    shardings: Any  # RunnerState pytree of NamedSharding, or None (one device)


def _staged(trainer: Trainer, num_seeds: int, mesh) -> _Staged:
    """The lowered init and the jitted chunk of one program: vmapped over seeds when > 1, split over ``mesh``."""
    init_fn, chunk_fn, key_shape = trainer.init, trainer.chunk, (2,)
    if num_seeds > 1:
        init_fn, chunk_fn, key_shape = jax.vmap(init_fn), jax.vmap(chunk_fn), (num_seeds, 2)
    key_spec = jax.ShapeDtypeStruct(key_shape, np.uint32)
    if mesh is None:
        init = jax.jit(init_fn).lower(key_spec)
        abstract = init.out_info  # the state's shapes from init's one trace (tracing the env's reset takes seconds)
        return _Staged(init, jax.jit(chunk_fn, donate_argnums=0), abstract, None)
    abstract = jax.eval_shape(init_fn, key_spec)
    shardings = distributed.runner_shardings(abstract, mesh, seed_axis=num_seeds > 1)
    rep = distributed.replicated(mesh)
    init = jax.jit(init_fn, in_shardings=rep, out_shardings=shardings)
    chunk = jax.jit(chunk_fn, in_shardings=(shardings,), out_shardings=(shardings, rep), donate_argnums=0)
    return _Staged(init.lower(key_spec), chunk, abstract, shardings)


def check_state_fits(config: TrainConfig, abstract, num_seeds: int, mesh, chunk_temp: int = 0) -> None:
    """Refuse (MemoryPlanError, one line) a RunnerState (plus ``chunk_temp``, the compiled chunk's working memory
    once known) larger than the memory available, before it is allocated; called before compiling with the state
    alone and after with both. ``abstract``: the state's shapes (of init's output), [seeds]-stacked when
    ``num_seeds`` > 1; with a mesh each device holds its share (on CPU all devices share the host's RAM)."""
    total, replay = memplan.tree_bytes(abstract), memplan.tree_bytes(abstract.replay)
    device = jax.local_devices()[0]
    shares = 1 if mesh is None or device.platform == "cpu" else int(mesh.devices.size)
    working = f" and {memplan.human(chunk_temp)} of working memory" if chunk_temp else ""
    memplan.check_fits(
        total // shares + chunk_temp,
        f"the training state ({num_seeds} seed(s); replay {memplan.human(replay)} for "
        f"replay.capacity_steps={config.replay.capacity_steps}{working})",
        "lower --replay.capacity-steps (or --acting.num-envs, --seeds, --replay.batch-size)",
        device,
    )


def _cache_key(config: TrainConfig) -> TrainConfig:
    """The config with what does not change the compiled chunk set to constants: the run group but its
    iterations_per_chunk and policy_average_from. learning_starts does change it; it is zeroed here (and kept in the
    cache key beside) only because a shortened total_env_steps would fail validation with it."""
    run = RunConfig(
        total_env_steps=config.env_steps_per_chunk,
        iterations_per_chunk=config.run.iterations_per_chunk,
        policy_average_from=config.run.policy_average_from,
    )
    return config.override(run=run, learning_starts=0)


def _compiled(
    config: TrainConfig,
    tracking_env,
    num_seeds: int = 1,
    mesh=None,
    debug_nan_at_update: int = -1,
    components: Components | None = None,
) -> _Program:
    """Trainer, AOT-compiled init and chunk for a config: one program for ``num_seeds`` seeds (vmapped when
    > 1), with the envs and replay split over ``mesh`` when given. Cached per (config, seeds, mesh, components).
    ``debug_nan_at_update``: the Trainer's test hook; ``components``: its extension points (None: the config's)."""
    components = components or Components()
    key = (
        _cache_key(config),
        config.learner.learning_starts,
        num_seeds,
        mesh,
        id(tracking_env),
        debug_nan_at_update,
        components,
    )
    if key not in _COMPILED:
        distributed.check_seeds_divisible(num_seeds, mesh)
        # several seeds: the seed axis is split over the devices and each seed's program runs whole on one device
        trainer = Trainer(
            config, tracking_env, mesh if num_seeds == 1 else None, debug_nan_at_update, **components.kwargs()
        )
        t0 = time.time()
        staged = _staged(trainer, num_seeds, mesh)
        abstract = staged.abstract
        check_state_fits(config, abstract, num_seeds, mesh)
        chunk = staged.chunk.lower(abstract)
        with ThreadPoolExecutor(1) as pool:  # XLA releases the GIL while it compiles
            init_compiling = pool.submit(staged.init.compile, _INIT_COMPILER_OPTIONS.get(jax.default_backend()))
            compiled = chunk.compile()
            init = init_compiling.result()
        try:
            temp = int(compiled.memory_analysis().temp_size_in_bytes)
        except Exception:  # noqa: BLE001 (not every backend reports it)
            temp = -1
        check_state_fits(config, abstract, num_seeds, mesh, max(temp, 0))  # now with the chunk's working memory
        memory = {
            "state_bytes_per_seed": memplan.tree_bytes(abstract) // num_seeds,
            "replay_bytes_per_seed": memplan.tree_bytes(abstract.replay) // num_seeds,
            "chunk_temp_bytes": temp,
        }
        if len(_COMPILED) >= 4:
            _COMPILED.pop(next(iter(_COMPILED)))
        _COMPILED[key] = _Program(trainer, init, compiled, time.time() - t0, staged.shardings, memory)
    return _COMPILED[key]


compiled_program = _compiled
