"""Held-out return against training wall time: every checkpoint of a run (or of several runs, e.g. the seeds of a
sweep) flies the same episodes, greedily, beside the depth tracker and the mpc ceiling flown once.

The episodes are those of ``ramavt eval --targets T --episodes N --seed S --max-steps M`` without perturbation (the
setting 'none'; ``tables.episode_key``), so a checkpoint's AER here equals that command's AER for the same
checkpoint. A run's checkpoints share one compiled episode runner: the network's parameters are an input of the
program (``greedy.GreedyPolicyOf``), not constants baked into it.

A run keeps every chunk's parameters when trained with ``--run.checkpoint-every-chunks 1 --run.keep-checkpoints K``
(K >= its chunks; ``--run.no-checkpoint-replay`` keeps each checkpoint small).
"""

from __future__ import annotations

import dataclasses
import math
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax

from ramavt_jax import baselines as baselines_lib
from ramavt_jax import env as env_lib
from ramavt_jax import render
from ramavt_jax.evaluation import rollouts, tables
from ramavt_jax.evaluation.runs import load_policy, row_name
from ramavt_jax.greedy import GreedyPolicyOf
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import run_folder as folders
from ramavt_jax.training.checkpoint import CheckpointNotFoundError, CheckpointStore, has_checkpoint

__all__ = [
    "CurveEpisodes",
    "BASELINES",
    "checkpoint_steps",
    "chosen_steps",
    "training_clock",
    "evaluate_checkpoint",
    "evaluate_baselines",
    "first_above",
    "run_curve",
    "learning_curves",
]

DEPTH, CEILING = "depth", "mpc"
BASELINES = {DEPTH: "depth tracker", CEILING: "mpc ceiling (true state)"}
SETTING = "none"  # no perturbation: Table I's episodes


@dataclasses.dataclass(frozen=True)
class CurveEpisodes:
    """The episodes every checkpoint and baseline flies: ``episodes`` per target of ``targets`` (catalogue names or
    MJCF files, each maybe resized: NAME@<radius>m), at most ``max_steps`` steps, drawn from ``seed`` as
    ``ramavt eval --seed`` draws them."""

    targets: tuple[str, ...]
    episodes: int
    max_steps: int = 1000
    seed: int = 0

    def as_dict(self) -> dict:
        return {
            "targets": list(self.targets),
            "episodes_per_target": self.episodes,
            "max_steps": self.max_steps,
            "seed": self.seed,
            "setting": SETTING,
        }


def _evaluate(tracking_env, policy, overrides: dict, ep: CurveEpisodes, policy_params=None) -> dict:
    """{'overall', 'per_target'} Summary dicts of one policy on ``ep`` (tables.evaluate_setting, setting 'none')."""
    return tables.evaluate_setting(
        tracking_env,
        policy,
        overrides,
        ep.episodes,
        ep.max_steps,
        jax.random.PRNGKey(ep.seed),
        SETTING,
        rollouts.PERTURBATION_VALUES,
        policy_params,
    )


def _point(res: dict) -> dict:
    """The curve's columns of one evaluation: AER with its 95 % bootstrap interval (episodes resampled within each
    target), AEL, lost fraction, and AER / AEL per target."""
    o = res["overall"]
    return {
        "aer": o["return_mean"],
        "aer_ci_low": o["return_ci_low"],
        "aer_ci_high": o["return_ci_high"],
        "ael": o["length_mean"],
        "lost_fraction": o["lost_fraction"],
        "per_target": {t: {"aer": s["return_mean"], "ael": s["length_mean"]} for t, s in res["per_target"].items()},
    }


# ============================================================================================ a run's checkpoints
def checkpoint_steps(run_dir: str | Path) -> list[int]:
    """The checkpoint steps (chunks completed) of a run folder, oldest first. Raises CheckpointNotFoundError (one
    line, naming the flags that keep checkpoints) for a folder without any."""
    ckpt = Path(run_dir) / folders.CHECKPOINTS
    if not has_checkpoint(ckpt):
        raise CheckpointNotFoundError(
            f"{run_dir} has no checkpoints (nothing in {ckpt}); train it with --run.checkpoint-every-chunks 1 "
            f"--run.keep-checkpoints K to keep one per chunk"
        )
    store = CheckpointStore(ckpt, create=False)
    try:
        return sorted(store.all_steps())
    finally:
        store.close()


def training_clock(run_dir: str | Path) -> dict[int, dict]:
    """{chunk: {'env_steps', 'wall_s'}} from a run's metrics.jsonl. ``wall_s``: seconds of ``ramavt train`` up to the
    end of that chunk, from the start of its process: the records' ``since_start_s`` (imports, compiling, building the
    state, the chunks, checkpoints and metrics lines before it). A resumed run's process (another ``started_at``)
    starts its own clock; its seconds are added to the earlier processes' totals.

    Records written before ``since_start_s`` existed count the compile (``compile_s``, added once per process: a
    record whose ``compile_s`` differs from the one before comes from a resumed process) plus the chunks' own
    ``wall_s``; that clock leaves out the rest of the start-up and the checkpoints, and runs behind the wall's."""
    records = folders.read_metrics(Path(run_dir) / folders.METRICS_FILE)
    clock, total, compile_s = {}, 0.0, None
    process, process_base = None, 0.0  # the current process's started_at; the total before it
    for r in records:
        since = _finite(r.get("since_start_s"))
        if since is not None:
            if r.get("started_at") != process:  # the first record of a process
                process, process_base = r.get("started_at"), total
            total = process_base + since
        else:
            c = _finite(r.get("compile_s"))
            if c != compile_s:  # a new process (the first, or a resume) compiled before its chunks
                compile_s = c
                total += c or 0.0
            total += float(r["wall_s"])
            process = None
        clock[int(r["chunk"])] = {"env_steps": int(r["env_steps"]), "wall_s": total}
    return clock


def _finite(x) -> float | None:
    return float(x) if isinstance(x, (int, float)) and math.isfinite(x) else None


def evaluate_checkpoint(run_dir: str | Path, step: int, ep: CurveEpisodes, policy_params: str | None = None) -> dict:
    """One checkpoint's greedy policy on ``ep`` (with the run's own parameter set unless ``policy_params`` names
    'online', 'target' or 'averaged'): :func:`_point`'s columns plus 'step' and 'env_steps' from the checkpoint."""
    lr = load_policy(run_dir, step=step, policy_params=policy_params, log=lambda msg: None)
    cfg = lr.config
    tracking_env = tables.suite_env(cfg.env, ep.targets, rollouts.PERTURBATION_VALUES)
    # one compile for every checkpoint of a network
    policy = GreedyPolicyOf(cfg.network, tuple(cfg.env.obs_shape))
    res = _evaluate(tracking_env, policy, rollouts.run_env_overrides(cfg.env_params), ep, lr.params)
    return {"step": lr.step, "env_steps": lr.meta.get("env_steps"), **_point(res)}


def chosen_steps(run_dir: str | Path, chunks: Sequence[int] = ()) -> list[int]:
    """The run's checkpoint steps among ``chunks`` (all of them when empty), oldest first. Raises
    CheckpointNotFoundError (one line) naming the asked-for chunks the run has no checkpoint of."""
    steps = checkpoint_steps(run_dir)
    if not chunks:
        return steps
    missing = sorted(set(chunks) - set(steps))
    if missing:
        raise CheckpointNotFoundError(f"{run_dir} has no checkpoint of chunk(s) {missing}; it has {steps}")
    return sorted(set(chunks))


def first_above(points: Sequence[dict], level: float) -> dict | None:
    """The first point (oldest step) whose AER exceeds ``level``: {'step', 'env_steps', 'wall_s', 'aer'}; None when
    no point does."""
    for p in points:
        if p["aer"] > level:
            return {k: p.get(k) for k in ("step", "env_steps", "wall_s", "aer")}
    return None


def run_curve(
    run_dir: str | Path,
    ep: CurveEpisodes,
    policy_params: str | None = None,
    baselines: dict | None = None,
    progress: bool = False,
    chunks: Sequence[int] = (),
) -> dict:
    """Every checkpoint of one run on ``ep``, oldest first: {'run_dir', 'name', 'seed', 'policy_params', 'points':
    [{'step', 'env_steps', 'wall_s', 'aer', 'aer_ci_low', 'aer_ci_high', 'ael', 'lost_fraction', 'per_target'}],
    'above_depth'}. ``wall_s`` is :func:`training_clock`'s (None for a step without a metrics record). With
    ``baselines`` (:func:`evaluate_baselines`' result) each point gets 'ceiling_fraction' (AER / the ceiling's,
    None for a non-positive ceiling) and 'above_depth' is the first point above the depth tracker's AER.
    ``chunks``: only these checkpoint steps (:func:`chosen_steps`); empty = all."""
    steps = chosen_steps(run_dir, chunks)
    clock = training_clock(run_dir)
    seed, config = _saved_config(run_dir)
    points = []
    for step in _progress(steps, row_name(run_dir), progress):
        points.append(
            {**evaluate_checkpoint(run_dir, step, ep, policy_params), "wall_s": clock.get(step, {}).get("wall_s")}
        )
    out = {
        "run_dir": str(run_dir),
        "name": row_name(run_dir),
        "seed": seed,
        "policy_params": policy_params or config.run.policy_params,
        "points": points,
        "above_depth": None,
    }
    baselines = baselines or {}
    if CEILING in baselines:
        top = baselines[CEILING]["aer"]
        for p in points:
            p["ceiling_fraction"] = p["aer"] / top if top > 0 else None  # a fraction of a negative ceiling misleads
    if DEPTH in baselines:
        out["above_depth"] = first_above(points, baselines[DEPTH]["aer"])
    return out


def _progress(steps: list[int], name: str, on: bool):
    """``steps``, under a tqdm bar (one tick per checkpoint) when ``on``."""
    if not on:
        return steps
    from tqdm.auto import tqdm

    return tqdm(steps, desc=name, unit="checkpoint", dynamic_ncols=True)


# ============================================================================================ baselines
def evaluate_baselines(
    names: Sequence[str],
    ep: CurveEpisodes,
    resolution: int = 64,
    dynamics: str = "cw",
    horizon: int = baselines_lib.MPC_HORIZON,
) -> dict[str, dict]:
    """{name: {'label', 'aer', 'aer_ci_low', 'aer_ci_high', 'ael', 'lost_fraction', 'per_target'}} of each baseline
    ('depth', 'mpc', ...) on ``ep``, as ``ramavt eval`` flies them (depth images at ``resolution``, ``dynamics``)."""
    camera = render.CameraConfig(resolution=resolution)
    out = {}
    for name in names:
        config = env_lib.EnvConfig(camera=camera, obs_mode="depth", targets=tuple(ep.targets), dynamics=dynamics)
        tracking_env = tables.suite_env(config, ep.targets, rollouts.PERTURBATION_VALUES)
        policy = baselines_lib.make_policy(name, camera, dynamics, horizon)
        out[name] = {"label": BASELINES.get(name, name), **_point(_evaluate(tracking_env, policy, {}, ep))}
    return out


# ============================================================================================ all together
def learning_curves(
    run_dirs: Sequence[str | Path],
    ep: CurveEpisodes,
    policy_params: str | None = None,
    baselines: Sequence[str] = (DEPTH, CEILING),
    resolution: int = 64,
    horizon: int = baselines_lib.MPC_HORIZON,
    progress: bool = False,
    log: Callable[[str], None] = print,
    chunks: Sequence[int] = (),
) -> dict:
    """The curve of every run in ``run_dirs`` (:func:`run_curve`) and of the ``baselines`` flown once
    (:func:`evaluate_baselines`, with the first run's dynamics): {'episodes', 'baselines', 'runs', 'wall_s'}.
    ``chunks``: only these checkpoints of each run (empty = all).
    JSON-able (write it with training.files.dumps)."""
    t0 = time.time()
    counts = [len(chosen_steps(run_dir, chunks)) for run_dir in run_dirs]  # all there before anything compiles
    dynamics = _saved_config(run_dirs[0])[1].env.dynamics if run_dirs else "cw"
    base = {}
    if baselines:
        log(
            f"flying the baselines ({', '.join(baselines)}) on {len(ep.targets)} target(s) x {ep.episodes} episodes ..."
        )
        base = evaluate_baselines(baselines, ep, resolution, dynamics, horizon)
    runs = []
    for run_dir, count in zip(run_dirs, counts):
        log(f"{run_dir}: {count} checkpoint(s) (one compile per network, the parameters are its input) ...")
        runs.append(run_curve(run_dir, ep, policy_params, base, progress, chunks))
    return {
        "episodes": ep.as_dict(),
        "baselines": base,
        "baseline_settings": {"resolution": resolution, "dynamics": dynamics, "mpc_horizon": horizon},
        "runs": runs,
        "wall_s": time.time() - t0,
    }


def _saved_config(run_dir: str | Path) -> tuple[int, TrainConfig]:
    """(training seed, TrainConfig) of a run folder's config.json."""
    saved = folders.read_config(run_dir)
    return int(saved.get("seed", -1)), TrainConfig.from_dict(saved["config"])
