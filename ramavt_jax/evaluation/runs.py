"""Trained run folders (written by ``ramavt train``): rebuild the TrainConfig from ``config.json`` and load the
greedy policy from the latest (or a given) checkpoint, reading only the online network's parameters."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from pathlib import Path

import jax
import jax.numpy as jnp

from ramavt_jax.baselines import Policy
from ramavt_jax.greedy import greedy_policy, stack_params
from ramavt_jax.train import Trainer
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import run_folder as folders
from ramavt_jax.training.checkpoint import CheckpointStore

__all__ = ["LoadedRun", "ensemble_params", "load_policy", "row_name"]


def row_name(run_dir: str | Path) -> str:
    """The name of a run folder in tables and legends: its folder name, with the sweep for a ``seed_<k>`` folder."""
    path = Path(run_dir)
    return f"{path.resolve().parent.name}/{path.name}" if folders.is_seed_dir(path) else path.name


@dataclasses.dataclass(frozen=True)
class LoadedRun:
    policy: Policy
    config: TrainConfig
    params: object  # network params
    run_dir: str
    seed: int
    step: int  # checkpoint step (chunks completed)
    meta: dict


def check_policy_params(run_dir, policy_params: str | None, config: TrainConfig | None = None) -> None:
    """Refuse (ValueError, one line) ``policy_params='averaged'`` for a run folder that keeps no tail average;
    ``config``: the run's, when already read."""
    if policy_params != "averaged":
        return
    if config is None:
        config = TrainConfig.from_dict(folders.read_config(Path(run_dir))["config"])
    if config.run.policy_average_from is None:
        raise ValueError(
            f"{run_dir} keeps no averaged params: policy_params='averaged' needs a run trained with "
            f"--run.policy-average-from S (or use the 'target' params)"
        )


def load_policy(
    run_dir,
    step: int | None = None,
    name: str | None = None,
    policy_params: str | None = None,
    log=print,
    search: str = "learned",
) -> LoadedRun:
    """The greedy policy of a training run folder written by ``ramavt train`` (config.json + checkpoints/).

    One network parameter set is read from the checkpoint (not the replay buffer): the online net's, the target
    net's or their tail average ('online' | 'target' | 'averaged'), as ``policy_params`` says, by default as the
    run's config (RunConfig.policy_params) says (check_policy_params refuses a set the run does not keep). The
    returned config records the set that was read. Without ``step``, a damaged newest checkpoint is skipped (reported through
    ``log`` in one line, left on disk) for the newest that loads. An incomplete config.json is refused
    (RunFolderError naming the missing field), and so is a config.json that no longer fits the checkpoints (an
    edited network, resolution or observation mode: CheckpointError, in the words ``ramavt train`` uses, before
    any array is read). ``search``: what the policy commands before the target is first in view
    (greedy.greedy_policy)."""
    run_dir = Path(run_dir)
    cfg_file = run_dir / folders.CONFIG_FILE
    if not cfg_file.is_file():
        raise FileNotFoundError(
            f"{cfg_file} not found: --run must name a folder written by `ramavt train` (config.json, checkpoints/)"
        )
    saved = folders.read_config(run_dir)
    config = TrainConfig.from_dict(saved["config"])
    check_policy_params(run_dir, policy_params, config)
    if policy_params is not None:
        config = config.override(policy_params=policy_params)
    store = CheckpointStore(run_dir / folders.CHECKPOINTS, create=False)
    like = jax.eval_shape(Trainer(config).init, jax.ShapeDtypeStruct((2,), jnp.uint32))
    if not config.run.checkpoint_replay:
        like = like.replace(replay=None)
    pick = lambda s: s.learner.policy_params(config.run.policy_params)  # noqa: E731
    read_with = saved["config"]  # a checkpoint that does not fit it is refused in one line, naming the fields
    try:
        if step is None:  # the newest step that loads, as a resumed training run uses (a damaged one is skipped)
            params, meta, step = store.restore_subtree_newest_loadable(like, pick, log, read_with)
        else:
            step = int(step)
            params, meta = store.restore_subtree(like, pick, step, read_with), store.read_meta(step)
    finally:
        store.close()
    params = jax.tree.map(jnp.asarray, params)
    policy = greedy_policy(
        config.network,
        params,
        tuple(config.env.obs_shape),
        name=name or run_dir.name,
        search=search,
    )
    meta = {k: v for k, v in meta.items() if k not in ("_num_leaves", "_leaf_paths", "config")}
    return LoadedRun(
        policy=policy,
        config=config,
        params=params,
        run_dir=str(run_dir),
        seed=int(saved.get("seed", -1)),
        step=int(step),
        meta=meta,
    )


def ensemble_params(loaded: Sequence[LoadedRun]) -> object:
    """The parameter sets of runs flying as one ensemble (greedy.greedy_policy(members=len(loaded))), stacked on a
    leading axis [members, ...]. Their network, env, env settings and parameter set must agree: ValueError (one
    line) names the first run that differs."""
    shared = lambda c: (c.network, c.env, c.env_params, c.run.policy_params)  # noqa: E731
    for lr in loaded[1:]:
        if shared(lr.config) != shared(loaded[0].config):
            raise ValueError(
                f"{lr.run_dir} has another network, env, env settings or parameter set than {loaded[0].run_dir}; "
                f"an ensemble's runs share one config"
            )
    return stack_params([lr.params for lr in loaded])
