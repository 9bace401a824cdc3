"""One experiment as a library call: train (``training.driver``), plot each seed's training curves (``figures``),
then evaluate the finished run (``evaluation.final``). ``ramavt train`` parses its flags and calls
:func:`train_and_evaluate`; Python users call it directly::

    from ramavt_jax.experiment import train_and_evaluate
    from ramavt_jax.presets import preset
    summary = train_and_evaluate(preset("smoke"), "runs/smoke")

This module sits above the figures layer and below the command line (contracts in pyproject.toml).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from pathlib import Path

from ramavt_jax import distributed
from ramavt_jax.evaluation.final import evaluate_run
from ramavt_jax.figures.training import plot_run
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import driver, host_state, run_folder

__all__ = ["train_and_evaluate"]


def train_and_evaluate(
    config: TrainConfig,
    out: str | Path,
    seed: int = 0,
    seeds: int = 1,
    resume: bool = True,
    progress: bool = True,
    devices: int = 0,
    log: Callable[[str], None] = print,
    **run_kwargs,
) -> driver.RunSummary:
    """Train into ``out`` (see ``driver.run``), then write each seed folder's ``training_curves.png`` and, when the
    run reached ``total_env_steps`` and ``config.run.eval_episodes > 0``, its ``eval.json``. The folder stays locked
    against a second command until all of it is written. Returns the summary; with ``seeds > 1`` its ``"seeds"``
    list holds one summary per seed folder ``out/seed_<k>``."""
    distributed.make_mesh(devices or None)  # a bad device count fails before the folder is created
    primary = distributed.is_primary()
    with run_folder.lock_folder(out) if primary else contextlib.nullcontext() as lock:
        summary = driver.run(
            config,
            Path(out),
            seed=seed,
            resume=resume,
            progress=progress,
            num_seeds=seeds,
            num_devices=devices or None,
            lock=lock,
            **run_kwargs,
        )
        if not primary:
            return summary
        per_seed = summary.get("seeds", [summary])
        quiet = log if progress else (lambda msg: None)
        for k, one in enumerate(per_seed):
            if one["last"] is not None:
                plot_run(one["out_dir"], title=f"{config.network.variant} seed {one['seed']}")
            if summary["finished"] and config.run.eval_episodes > 0:
                params = host_state.seed_params(summary.state, k, len(per_seed), config.run.policy_params)
                one["eval"] = evaluate_run(config, one["out_dir"], one["seed"], params, quiet)
    return summary
