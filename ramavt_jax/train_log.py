"""Host-side training driver: runs the jitted chunks of :class:`ramavt_jax.train.Trainer`, logs per chunk (JSONL,
optional TensorBoard, tqdm), checkpoints (orbax), evaluates greedily at the end and plots the training curves.

Output folder layout::

    out_dir/config.json          the TrainConfig
    out_dir/metrics.jsonl        one record per chunk
    out_dir/checkpoints/<chunk>/ orbax checkpoints (the last ``keep_checkpoints``)
    out_dir/eval.json            final greedy (and random-agent) evaluation on the train and test target splits
    out_dir/training_curves.png
    out_dir/tb/                  TensorBoard events (config.tensorboard)
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from ramavt_jax import baselines, distributed, evaluate
from ramavt_jax import env as env_lib
from ramavt_jax import targets as targets_lib
from ramavt_jax.checkpoint import CheckpointNotFoundError, CheckpointStore, has_checkpoint
from ramavt_jax.train import ChunkMetrics, TrainConfig, Trainer, TrainingDivergedError, greedy_policy

__all__ = ["run", "RunSummary", "aggregate", "plot_curves", "evaluate_policy", "read_metrics"]


# ============================================================================================ metrics
def aggregate(m: ChunkMetrics, wall_s: float, env_steps: int) -> dict:
    """Per-chunk record from the per-iteration sums of one chunk (host numpy); ``env_steps`` taken in the chunk."""
    m = jax.tree.map(np.asarray, m)
    episodes = int(m.episodes.sum())
    updates = int(m.updates.sum())

    def ratio(a, b):
        return float(a) / b if b else float("nan")

    return {
        "env_steps": int(m.env_steps[-1]),
        "episodes": episodes,
        "episode_length": ratio(m.episode_length_sum.sum(), episodes),
        "episode_return": ratio(m.episode_return_sum.sum(), episodes),
        "updates": updates,
        "loss": ratio(m.loss_sum.sum(), updates),
        "q_mean": ratio(m.q_sum.sum(), updates),
        "grad_norm": ratio(m.grad_norm_sum.sum(), updates),
        "epsilon": float(m.epsilon[-1]),
        "wall_s": wall_s,
        "env_steps_per_s": env_steps / wall_s,
        "updates_per_s": updates / wall_s,
    }


def _diverged(record: dict) -> bool:
    return record["updates"] > 0 and not (math.isfinite(record["loss"]) and math.isfinite(record["q_mean"]))


def read_metrics(path) -> list[dict]:
    path = Path(path)
    if not path.exists():
        return []
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def plot_curves(records: list[dict], path, title: str = "") -> None:
    """training_curves.png: episode length / return of completed training episodes, loss, mean Q, epsilon."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    x = np.array([r["env_steps"] for r in records], float)
    keys = [("episode_length", "episode length (training episodes)"), ("episode_return", "episode return"),
            ("loss", "TD loss"), ("q_mean", "mean Q (taken)"), ("epsilon", "epsilon")]
    fig, axes = plt.subplots(1, len(keys), figsize=(4 * len(keys), 3.2))
    for ax, (k, label) in zip(axes, keys):
        ax.plot(x, [r.get(k, np.nan) for r in records], marker=".", lw=1)
        ax.set_xlabel("env steps")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# ============================================================================================ evaluation
def evaluate_policy(config: TrainConfig, policy: baselines.Policy, key: jax.Array, targets: tuple[str, ...],
                    num_episodes: int, max_steps: int) -> dict:
    """Episodes with the evaluation settings (dist_weight 1, lost_patience 20) on ``targets``; returns a Summary dict."""
    overrides = {k: v for k, v in dict(config.env_params).items() if k not in ("dist_weight", "lost_patience")}
    tracking_env = env_lib.TrackingEnv(dataclasses.replace(config.env, targets=tuple(targets)))
    params = tracking_env.eval_params(**overrides, max_steps=max_steps)
    stats, _ = evaluate.run_episodes(tracking_env, policy, params, key, num_episodes, num_steps=max_steps)
    return evaluate.summarise(stats).as_dict()


def final_evaluation(config: TrainConfig, params: Any, key: jax.Array) -> dict:
    policy = greedy_policy(config.network, params, tuple(config.env.obs_shape))
    splits = {"train": tuple(config.env.targets), "test": targets_lib.TEST_TARGETS}
    out = {}
    for i, (split, names) in enumerate(splits.items()):
        for j, (name, pol) in enumerate((("greedy", policy), ("random", baselines.random_policy()))):
            k = jax.random.fold_in(key, 2 * i + j)
            out.setdefault(split, {})[name] = evaluate_policy(config, pol, k, names, config.eval_episodes,
                                                              config.eval_max_steps)
    return out


# ============================================================================================ driver
class RunSummary(dict):
    """The JSON-friendly summary of a run; the final RunnerState (params, replay, ...) is ``.state`` (with a leading
    [seeds] axis when several seeds were trained together)."""

    state: Any = None


@dataclasses.dataclass
class _Program:
    trainer: Trainer
    init: Any  # key [2] (or [S, 2]) -> RunnerState
    chunk: Any  # AOT-compiled: RunnerState -> (RunnerState, ChunkMetrics)
    compile_s: float
    shardings: Any  # RunnerState pytree of NamedSharding, or None (one device)
    memory: dict  # bytes: state per seed, replay per seed, XLA temp of the chunk


_COMPILED: dict = {}  # (config, seeds, mesh, env id) -> _Program; repeated runs, resumes and tests compile once


def _tree_bytes(tree) -> int:
    return int(sum(np.prod(x.shape) * np.dtype(x.dtype).itemsize for x in jax.tree.leaves(tree)))


def _compiled(config: TrainConfig, tracking_env, num_seeds: int = 1, mesh=None) -> _Program:
    """Trainer, jitted init and AOT-compiled chunk for a config: one program for ``num_seeds`` seeds (vmapped when
    > 1), with the envs and replay split over ``mesh`` when given. Cached per (config, seeds, mesh)."""
    host_only = dict(total_env_steps=config.env_steps_per_chunk, eval_episodes=0, eval_max_steps=1,
                     checkpoint_every_chunks=0, checkpoint_replay=True, keep_checkpoints=1, tensorboard=False)
    # host-only fields do not change the compiled chunk (learning_starts does; it is kept in the key separately
    # because the shortened total_env_steps would fail validation with it)
    key = (dataclasses.replace(config, learning_starts=0, **host_only), config.learning_starts, num_seeds, mesh,
           id(tracking_env))
    if key not in _COMPILED:
        distributed.check_seeds_divisible(num_seeds, mesh)
        # several seeds: the seed axis is split over the devices and each seed's program runs whole on one device
        trainer = Trainer(config, tracking_env, mesh if num_seeds == 1 else None)
        init_fn, chunk_fn = trainer.init, trainer.chunk
        key_shape = (2,)
        if num_seeds > 1:
            init_fn, chunk_fn, key_shape = jax.vmap(init_fn), jax.vmap(chunk_fn), (num_seeds, 2)
        t0 = time.time()
        abstract = jax.eval_shape(init_fn, jax.ShapeDtypeStruct(key_shape, np.uint32))
        if mesh is None:
            shardings = None
            init = jax.jit(init_fn)
            chunk = jax.jit(chunk_fn, donate_argnums=0)
        else:
            shardings = distributed.runner_shardings(abstract, mesh, seed_axis=num_seeds > 1)
            rep = distributed.replicated(mesh)
            init = jax.jit(init_fn, in_shardings=rep, out_shardings=shardings)
            chunk = jax.jit(chunk_fn, in_shardings=(shardings,), out_shardings=(shardings, rep), donate_argnums=0)
        compiled = chunk.lower(abstract).compile()
        try:
            temp = int(compiled.memory_analysis().temp_size_in_bytes)
        except Exception:  # noqa: BLE001 (not every backend reports it)
            temp = -1
        memory = {"state_bytes_per_seed": _tree_bytes(abstract) // num_seeds,
                  "replay_bytes_per_seed": _tree_bytes(abstract.replay) // num_seeds,
                  "chunk_temp_bytes": temp}
        if len(_COMPILED) >= 4:
            _COMPILED.pop(next(iter(_COMPILED)))
        _COMPILED[key] = _Program(trainer, init, compiled, time.time() - t0, shardings, memory)
    return _COMPILED[key]


def _finite_params(state) -> bool:
    return all(bool(np.isfinite(np.asarray(x)).all()) for x in jax.tree.leaves(distributed.local_copy(
        state.learner.params)))


def _resolve_resume(resume, ckpt_dir: Path, subdir: str | None = None) -> Path | None:
    """True: the run folder's checkpoints if any; False: fresh; a path: that checkpoint folder (must exist; for
    several seeds its ``seed_<k>`` sub-folders)."""
    if resume is True:
        return ckpt_dir if has_checkpoint(ckpt_dir) else None
    if resume is False or resume is None:
        return None
    path = Path(resume) / subdir if subdir else Path(resume)
    for cand in (path, path / "checkpoints"):
        if has_checkpoint(cand):
            return cand
    raise CheckpointNotFoundError(f"resume={str(resume)!r}: no checkpoint there (looked in {path} and "
                                  f"{path / 'checkpoints'}); pass resume=False to start a fresh run")


def _host_int(x) -> int:
    """A counter of the (possibly sharded, possibly [seeds]-stacked) state as a host int (seeds share it: first)."""
    return int(np.asarray(distributed.local_copy(x)).reshape(-1)[0])


def _seed_slice(tree, k: int, num_seeds: int):
    return tree if num_seeds == 1 else jax.tree.map(lambda x: x[k], tree)


def run(config: TrainConfig, out_dir, seed: int = 0, resume=True, progress: bool = True,
        max_chunks: int | None = None, evaluate_at_end: bool = True, tracking_env=None, num_seeds: int = 1,
        num_devices: int | None = None) -> dict:
    """Train ``config`` into ``out_dir``; returns a :class:`RunSummary` (a JSON-friendly dict: counters, timings,
    memory, the last metrics record, eval results) whose ``.state`` is the final RunnerState.

    num_seeds: > 1 trains seeds ``seed .. seed + num_seeds - 1`` as ONE jitted program (vmap over seeds, each
      with its own envs and replay) into ``out_dir/seed_<k>/`` (each folder is a complete single-seed run folder:
      config, metrics, checkpoints, eval). The summary's ``seeds`` lists the per-seed summaries.
    num_devices: devices to split the envs and replay over (default: all visible, every process's in a
      multi-host run); 1 = the plain single-device program.
    resume: True resumes from the run folder's checkpoints when present; False starts fresh (existing checkpoints
      are overwritten as the run proceeds); a path resumes from that checkpoint folder (error if none is there).
    max_chunks: stop after this many chunks in this call (a checkpoint is saved), e.g. to split a run.
    Raises TrainingDivergedError on a NaN/inf loss (the last good checkpoint is kept); Ctrl-C saves a checkpoint
    of the last completed chunk and re-raises KeyboardInterrupt. In a multi-host run only process 0 writes logs,
    plots and evaluations; every process takes part in checkpointing.
    """
    if isinstance(num_seeds, bool) or not isinstance(num_seeds, int) or num_seeds < 1:
        raise ValueError(f"num_seeds must be an int >= 1, got {num_seeds!r}")
    out = Path(out_dir)
    seeds = [seed + k for k in range(num_seeds)]
    dirs = [out] if num_seeds == 1 else [out / f"seed_{s}" for s in seeds]
    primary = distributed.is_primary()
    for d in dirs:
        d.mkdir(parents=True, exist_ok=True)
    sources = [_resolve_resume(resume, d / "checkpoints", None if num_seeds == 1 else d.name) for d in dirs]
    if any(s is None for s in sources) and any(s is not None for s in sources):
        raise CheckpointNotFoundError(f"only some seed folders in {out} have checkpoints "
                                      f"({[str(s) for s in sources]}); resume them together or pass resume=False")
    resuming = sources[0] is not None
    mesh = distributed.make_mesh(num_devices)
    if progress and primary:
        where = "1 device" if mesh is None else f"{mesh.devices.size} devices"
        print(f"compiling the training chunk ({config.network.variant}, {config.env.obs_shape}, "
              f"{num_seeds} seed(s), {where}) ...", flush=True)
    prog = _compiled(config, tracking_env, num_seeds, mesh)
    keys = np.stack([np.asarray(jax.random.PRNGKey(s)) for s in seeds]) if num_seeds > 1 else jax.random.PRNGKey(seed)
    state = prog.init(keys)
    if primary:
        for s, d in zip(seeds, dirs):
            (d / "config.json").write_text(json.dumps({"seed": s, "config": config.to_dict()}, indent=1, default=str))
    config_json = json.loads(json.dumps(config.to_dict(), default=str))

    if resuming:
        loaded = []
        for k, src in enumerate(sources):
            like = _seed_slice(state, k, num_seeds)
            like = like if config.checkpoint_replay else like.replace(replay=None)
            st, meta = CheckpointStore(src, create=False).restore(like)
            if meta.get("config") != config_json:
                raise ValueError(f"the checkpoint in {src} was written with a different TrainConfig; resume it with "
                                 f"the same config (see its config.json) or pass resume=False")
            loaded.append(st)
        if len({_host_int(st.chunk) for st in loaded}) > 1:
            raise ValueError(f"the seed folders in {out} were checkpointed at different chunks; resume=False")
        if num_seeds > 1:
            loaded = [jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *loaded)]
        restored = loaded[0]
        if not config.checkpoint_replay:
            restored = restored.replace(replay=state.replay)
        state = restored if prog.shardings is None else jax.device_put(restored, prog.shardings)
    start = _host_int(state.chunk)
    metrics_paths = [d / "metrics.jsonl" for d in dirs]
    records = [[r for r in read_metrics(p) if r["chunk"] <= start] if resuming else [] for p in metrics_paths]
    if primary:
        for p, recs in zip(metrics_paths, records):
            p.write_text("".join(json.dumps(r) + "\n" for r in recs))

    stores = [CheckpointStore(d / "checkpoints", keep=config.keep_checkpoints) for d in dirs]
    writers = [None] * num_seeds
    if config.tensorboard and primary:
        from tensorboardX import SummaryWriter

        writers = [SummaryWriter(str(d / "tb")) for d in dirs]

    def save(st, chunk: int) -> int:
        for k, (s, store) in enumerate(zip(seeds, stores)):
            one = _seed_slice(st, k, num_seeds)
            meta = {"config": config_json, "seed": s, "chunk": chunk, "env_steps": _host_int(one.env_steps),
                    "updates": _host_int(one.learner.updates)}
            store.save(chunk, one if config.checkpoint_replay else one.replace(replay=None), meta)
        return chunk

    end = config.num_chunks if max_chunks is None else min(config.num_chunks, start + max_chunks)
    last_saved = start if resuming else None
    bar = None
    if progress and primary:
        from tqdm.auto import tqdm

        bar = tqdm(total=config.total_env_steps * num_seeds, initial=start * config.env_steps_per_chunk * num_seeds,
                   unit="step", unit_scale=True, dynamic_ncols=True, desc="train")
    train_t0 = time.time()
    chunk_no = start  # host mirror of state.chunk (each compiled chunk adds one): no device read per chunk
    try:
        for _ in range(start, end):
            t = time.time()
            state, m = prog.chunk(state)
            m = distributed.local_copy(m)  # the one host sync per chunk
            wall = time.time() - t
            chunk_no += 1
            for k in range(num_seeds):
                record = {"chunk": chunk_no, **aggregate(_seed_slice(m, k, num_seeds), wall,
                                                         config.env_steps_per_chunk)}
                record["trained_frames_per_s"] = record["updates_per_s"] * config.batch_size * config.train_len
                record["compile_s"] = prog.compile_s
                if num_seeds > 1:
                    record["seeds_in_program"] = num_seeds
                if _diverged(record):
                    where = (f"the last good checkpoint is chunk {last_saved} in {dirs[k] / 'checkpoints'}"
                             if last_saved is not None else "no checkpoint was saved yet")
                    raise TrainingDivergedError(
                        f"training diverged at chunk {record['chunk']} (seed {seeds[k]}, env step "
                        f"{record['env_steps']}): loss={record['loss']}, mean Q={record['q_mean']}. The diverged "
                        f"state was NOT saved; {where}. Try a lower lr (now {config.lr}), gradient clipping "
                        f"(max_grad_norm) or a smaller reward_scale.")
                records[k].append(record)
                if primary:
                    with metrics_paths[k].open("a") as f:
                        f.write(json.dumps(record) + "\n")
                if writers[k] is not None:
                    for name, v in record.items():
                        if isinstance(v, (int, float)) and math.isfinite(v):
                            writers[k].add_scalar(f"train/{name}", v, record["env_steps"])
            if bar is not None:
                bar.update(config.env_steps_per_chunk * num_seeds)
                r = records[0][-1]
                bar.set_postfix(ep_len=f"{r['episode_length']:.0f}", loss=f"{r['loss']:.3g}", eps=f"{r['epsilon']:.2f}")
            if config.checkpoint_every_chunks and chunk_no % config.checkpoint_every_chunks == 0:
                last_saved = save(state, chunk_no)
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        leaves = jax.tree.leaves(state)
        if any(getattr(x, "is_deleted", lambda: False)() for x in leaves):
            print(f"\ninterrupted while a chunk was dispatched; last checkpoint: chunk {last_saved} in {out}")
        else:
            jax.block_until_ready(state)  # the chunk in flight finishes (XLA cannot cancel it)
            chunk_no = _host_int(state.chunk)  # may be one ahead of the host mirror (interrupted before logging)
            if _finite_params(state) and chunk_no != last_saved:
                last_saved = save(state, chunk_no)
            print(f"\ninterrupted: checkpoint of chunk {last_saved} saved under {out}; run again to resume")
        raise
    finally:
        for w in writers:
            if w is not None:
                w.close()
    if bar is not None:
        bar.close()
    train_s = time.time() - train_t0
    if chunk_no != last_saved:
        last_saved = save(state, chunk_no)
    for store in stores:
        store.close()

    finished = chunk_no >= config.num_chunks
    per_seed = []
    for k, (s, d) in enumerate(zip(seeds, dirs)):
        one = {"seed": s, "chunks_done": chunk_no, "num_chunks": config.num_chunks,
               "env_steps": _host_int(_seed_slice(state.env_steps, k, num_seeds)),
               "updates": _host_int(_seed_slice(state.learner.updates, k, num_seeds)),
               "train_wall_s": train_s, "compile_s": prog.compile_s, "last": records[k][-1] if records[k] else None,
               "out_dir": str(d)}
        if primary and records[k]:
            plot_curves(records[k], d / "training_curves.png", title=f"{config.network.variant} seed {s}")
        if primary and finished and evaluate_at_end and config.eval_episodes > 0:
            t = time.time()
            params = distributed.local_copy(_seed_slice(state.learner.params, k, num_seeds))
            results = final_evaluation(config, params, jax.random.PRNGKey(s + 10_000))
            results["eval_wall_s"] = time.time() - t
            (d / "eval.json").write_text(json.dumps(results, indent=1))
            one["eval"] = results
        per_seed.append(one)
    if num_seeds == 1:
        summary = per_seed[0]
    else:
        summary = {k: v for k, v in per_seed[0].items() if k in ("chunks_done", "num_chunks", "train_wall_s",
                                                                 "compile_s")}
        summary.update(out_dir=str(out), seeds=per_seed)
    summary.update(memory=prog.memory, devices=1 if mesh is None else int(mesh.devices.size),
                   processes=jax.process_count())
    summary = RunSummary(summary)
    summary.state = state
    return summary
