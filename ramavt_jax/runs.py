"""Trained run folders (written by ``ramavt train``): rebuild the TrainConfig from ``config.json`` and load the
greedy policy from the latest (or a given) checkpoint, reading only the online network's parameters."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import jax
import jax.numpy as jnp

from ramavt_jax.baselines import Policy

__all__ = ["LoadedRun", "load_policy"]


def _from_dict(cls, data: dict):
    """Rebuild a (nested) frozen config dataclass from its to_dict() form: lists become tuples."""
    import typing

    hints = typing.get_type_hints(cls)
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in data:
            continue
        value = data[f.name]
        sub = hints.get(f.name)
        default = f.default if f.default is not dataclasses.MISSING else None
        target = sub if dataclasses.is_dataclass(sub) else (type(default) if dataclasses.is_dataclass(default) else None)
        if f.name == "augment_config" and isinstance(value, dict):
            from ramavt_jax import augment

            target = augment.AugmentConfig
        if target is not None and isinstance(value, dict):
            value = _from_dict(target, value)
        else:
            value = _tuplify(value)
        kwargs[f.name] = value
    return cls(**kwargs)


def _tuplify(x):
    return tuple(_tuplify(v) for v in x) if isinstance(x, list) else x


@dataclasses.dataclass(frozen=True)
class LoadedRun:
    policy: Policy
    config: object  # train.TrainConfig
    params: object  # network params
    run_dir: str
    seed: int
    step: int  # checkpoint step (chunks completed)
    meta: dict


def load_policy(run_dir, step: int | None = None, name: str | None = None) -> LoadedRun:
    """The greedy policy of a training run folder written by ``train.run`` (config.json + checkpoints/).

    Only the online network parameters are read from the checkpoint (not the replay buffer)."""
    import json

    import orbax.checkpoint as ocp

    from ramavt_jax import train
    from ramavt_jax.checkpoint import CheckpointStore

    run_dir = Path(run_dir)
    cfg_file = run_dir / "config.json"
    if not cfg_file.is_file():
        raise FileNotFoundError(f"{cfg_file} not found: --run must name a folder written by `ramavt train` "
                                f"(config.json, checkpoints/)")
    saved = json.loads(cfg_file.read_text())
    config = _from_dict(train.TrainConfig, saved["config"])
    store = CheckpointStore(run_dir / "checkpoints", create=False)
    step = store.latest_step() if step is None else int(step)
    trainer = train.Trainer(config)
    like = jax.eval_shape(trainer.init, jax.ShapeDtypeStruct((2,), jnp.uint32))
    if not config.checkpoint_replay:
        like = like.replace(replay=None)
    leaves, treedef = jax.tree.flatten(like)
    meta = store.read_meta(step)
    if meta.get("_num_leaves") != len(leaves):
        raise ValueError(f"checkpoint {step} in {run_dir} holds {meta.get('_num_leaves')} arrays, this code expects "
                         f"{len(leaves)}: it was written by another code version")
    index_tree = jax.tree.unflatten(treedef, list(range(len(leaves))))
    wanted = jax.tree.leaves(index_tree.learner.params)
    abstract = {f"{i:05d}": jax.ShapeDtypeStruct(leaves[i].shape, leaves[i].dtype) for i in wanted}
    restored = store.manager.restore(
        int(step), args=ocp.args.Composite(state=ocp.args.PyTreeRestore(abstract, partial_restore=True)))["state"]
    params_like = like.learner.params
    _, p_def = jax.tree.flatten(params_like)
    params = jax.tree.unflatten(p_def, [jnp.asarray(restored[f"{i:05d}"]) for i in wanted])
    store.close()
    label = name or run_dir.name
    policy = train.greedy_policy(config.network, params, tuple(config.env.obs_shape), name=label)
    meta = {k: v for k, v in meta.items() if k not in ("_num_leaves", "config")}
    return LoadedRun(policy=policy, config=config, params=params, run_dir=str(run_dir),
                     seed=int(saved.get("seed", -1)), step=int(step), meta=meta)
