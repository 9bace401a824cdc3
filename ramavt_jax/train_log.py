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

from ramavt_jax import baselines, evaluate
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
    """The JSON-friendly summary of a run; the final RunnerState (params, replay, ...) is ``.state``."""

    state: Any = None


_COMPILED: dict = {}  # (config, env id) -> (trainer, init, compiled chunk, compile seconds); a run's pieces are reused


def _compiled(config: TrainConfig, tracking_env) -> tuple:
    """Trainer, jitted init and AOT-compiled chunk for a config (cached: repeated runs, resumes and tests
    in one process compile once)."""
    host_only = dict(total_env_steps=config.env_steps_per_chunk, eval_episodes=0, eval_max_steps=1,
                     checkpoint_every_chunks=0, checkpoint_replay=True, keep_checkpoints=1, tensorboard=False)
    # host-only fields do not change the compiled chunk (learning_starts does; it is kept in the key separately
    # because the shortened total_env_steps would fail validation with it)
    key = (dataclasses.replace(config, learning_starts=0, **host_only), config.learning_starts, id(tracking_env))
    if key not in _COMPILED:
        trainer = Trainer(config, tracking_env)
        init = jax.jit(trainer.init)
        t0 = time.time()
        abstract = jax.eval_shape(init, jax.ShapeDtypeStruct((2,), np.uint32))
        compiled = jax.jit(trainer.chunk, donate_argnums=0).lower(abstract).compile()
        if len(_COMPILED) >= 4:
            _COMPILED.pop(next(iter(_COMPILED)))
        _COMPILED[key] = (trainer, init, compiled, time.time() - t0)
    return _COMPILED[key]


def _finite_params(state) -> bool:
    return all(bool(np.isfinite(np.asarray(x)).all()) for x in jax.tree.leaves(state.learner.params))


def _resolve_resume(resume, ckpt_dir: Path) -> Path | None:
    """True: the run folder's checkpoints if any; False: fresh; a path: that checkpoint folder (must exist)."""
    if resume is True:
        return ckpt_dir if has_checkpoint(ckpt_dir) else None
    if resume is False or resume is None:
        return None
    path = Path(resume)
    for cand in (path, path / "checkpoints"):
        if has_checkpoint(cand):
            return cand
    raise CheckpointNotFoundError(f"resume={str(resume)!r}: no checkpoint there (looked in {path} and "
                                  f"{path / 'checkpoints'}); pass resume=False to start a fresh run")


def run(config: TrainConfig, out_dir, seed: int = 0, resume=True, progress: bool = True,
        max_chunks: int | None = None, evaluate_at_end: bool = True, tracking_env=None) -> dict:
    """Train ``config`` into ``out_dir``; returns a :class:`RunSummary` (a JSON-friendly dict: counters, timings,
    the last metrics record, eval results) whose ``.state`` is the final RunnerState.

    resume: True resumes from ``out_dir/checkpoints`` when present; False starts fresh (existing checkpoints are
      overwritten as the run proceeds); a path resumes from that checkpoint folder (error if none is there).
    max_chunks: stop after this many chunks in this call (a checkpoint is saved), e.g. to split a run.
    Raises TrainingDivergedError on a NaN/inf loss (the last good checkpoint is kept); Ctrl-C saves a checkpoint
    of the last completed chunk and re-raises KeyboardInterrupt.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    ckpt_dir = out / "checkpoints"
    source = _resolve_resume(resume, ckpt_dir)
    if progress:
        print(f"compiling the training chunk ({config.network.variant}, {config.env.obs_shape}) ...", flush=True)
    _, init, compiled, compile_s = _compiled(config, tracking_env)
    state = init(jax.random.PRNGKey(seed))
    (out / "config.json").write_text(json.dumps({"seed": seed, "config": config.to_dict()}, indent=1, default=str))

    if source is not None:
        like = state if config.checkpoint_replay else state.replace(replay=None)
        loaded, meta = CheckpointStore(source, create=False).restore(like)
        if meta.get("config") != json.loads(json.dumps(config.to_dict(), default=str)):
            raise ValueError(f"the checkpoint in {source} was written with a different TrainConfig; resume it with "
                             f"the same config (see its config.json) or pass resume=False")
        state = loaded if config.checkpoint_replay else loaded.replace(replay=state.replay)
    start = int(state.chunk)
    metrics_path = out / "metrics.jsonl"
    records = [r for r in read_metrics(metrics_path) if r["chunk"] <= start] if source is not None else []
    metrics_path.write_text("".join(json.dumps(r) + "\n" for r in records))

    store = CheckpointStore(ckpt_dir, keep=config.keep_checkpoints)
    writer = None
    if config.tensorboard:
        from tensorboardX import SummaryWriter

        writer = SummaryWriter(str(out / "tb"))

    def save(st):
        meta = {"config": config.to_dict(), "seed": seed, "chunk": int(st.chunk), "env_steps": int(st.env_steps),
                "updates": int(st.learner.updates)}
        saved = st if config.checkpoint_replay else st.replace(replay=None)
        store.save(int(st.chunk), saved, json.loads(json.dumps(meta, default=str)))
        return int(st.chunk)

    end = config.num_chunks if max_chunks is None else min(config.num_chunks, start + max_chunks)
    last_saved = start if source is not None else None
    bar = None
    if progress:
        from tqdm.auto import tqdm

        bar = tqdm(total=config.total_env_steps, initial=start * config.env_steps_per_chunk, unit="step",
                   unit_scale=True, dynamic_ncols=True, desc="train")
    train_t0 = time.time()
    try:
        for _ in range(start, end):
            t = time.time()
            state, m = compiled(state)
            m = jax.device_get(m)
            record = {"chunk": int(state.chunk), **aggregate(m, time.time() - t, config.env_steps_per_chunk)}
            record["trained_frames_per_s"] = record["updates_per_s"] * config.batch_size * config.train_len
            record["compile_s"] = compile_s
            if _diverged(record):
                where = (f"the last good checkpoint is chunk {last_saved} in {ckpt_dir}" if last_saved is not None
                         else "no checkpoint was saved yet")
                raise TrainingDivergedError(
                    f"training diverged at chunk {record['chunk']} (env step {record['env_steps']}, gradient step "
                    f"{int(state.learner.updates)}): loss={record['loss']}, mean Q={record['q_mean']}. The diverged "
                    f"state was NOT saved; {where}. Try a lower lr (now {config.lr}), gradient clipping "
                    f"(max_grad_norm) or a smaller reward_scale.")
            records.append(record)
            with metrics_path.open("a") as f:
                f.write(json.dumps(record) + "\n")
            if writer is not None:
                for k, v in record.items():
                    if isinstance(v, (int, float)) and math.isfinite(v):
                        writer.add_scalar(f"train/{k}", v, record["env_steps"])
            if bar is not None:
                bar.update(config.env_steps_per_chunk)
                bar.set_postfix(ep_len=f"{record['episode_length']:.0f}", loss=f"{record['loss']:.3g}",
                                eps=f"{record['epsilon']:.2f}")
            if config.checkpoint_every_chunks and record["chunk"] % config.checkpoint_every_chunks == 0:
                last_saved = save(state)
    except KeyboardInterrupt:
        if bar is not None:
            bar.close()
        leaves = jax.tree.leaves(state)
        if any(getattr(x, "is_deleted", lambda: False)() for x in leaves):
            print(f"\ninterrupted while a chunk was dispatched; last checkpoint: chunk {last_saved} in {ckpt_dir}")
        else:
            jax.block_until_ready(state)  # the chunk in flight finishes (XLA cannot cancel it)
            if _finite_params(state) and int(state.chunk) != last_saved:
                last_saved = save(state)
            print(f"\ninterrupted: checkpoint of chunk {last_saved} saved in {ckpt_dir}; run again to resume")
        raise
    finally:
        if writer is not None:
            writer.close()
    if bar is not None:
        bar.close()
    train_s = time.time() - train_t0
    if int(state.chunk) != last_saved:
        last_saved = save(state)
    store.close()

    summary = {"chunks_done": int(state.chunk), "num_chunks": config.num_chunks, "env_steps": int(state.env_steps),
               "updates": int(state.learner.updates), "train_wall_s": train_s, "compile_s": compile_s,
               "last": records[-1] if records else None, "out_dir": str(out)}
    if records:
        plot_curves(records, out / "training_curves.png", title=f"{config.network.variant} seed {seed}")
    finished = int(state.chunk) >= config.num_chunks
    if finished and evaluate_at_end and config.eval_episodes > 0:
        t = time.time()
        results = final_evaluation(config, state.learner.params, jax.random.PRNGKey(seed + 10_000))
        results["eval_wall_s"] = time.time() - t
        (out / "eval.json").write_text(json.dumps(results, indent=1))
        summary["eval"] = results
    summary = RunSummary(summary)
    summary.state = state
    return summary
