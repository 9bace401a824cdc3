"""Pretrained agents shipped inside the package (``ramavt_jax/agents/<name>/``), loadable without a run folder.

An agent folder holds ``config.json`` (the full TrainConfig it was trained with, plus the training command and
what it was trained on), ``params.npz`` (the network parameters its policy acts with, one array per parameter
path) and ``TRAINING.md`` (how to reproduce it). Only the network parameters are stored: about 0.9 MB per network
of the presets in float32. An agent may be an ensemble: the seeds of one training command flying together, each with its own memory,
greedy on their mean Q (greedy.greedy_policy(members=)); its arrays then carry a leading [members] axis and
``config.json``'s info says how many (``members``).

    agent = pretrained.load()                 # the default agent: RAMAVT, depth
    policy = agent.policy                     # a baselines.Policy, acting greedily (evaluate / render it)
    pretrained.export("runs/clip_1152k/seed_0", "ramavt_depth", command="ramavt train --preset quick --seeds 5 ...")
    pretrained.export([f"runs/g/seed_{k}" for k in range(5)], "ramavt_depth", command=..., precision="float16")
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Sequence
from pathlib import Path
from typing import Literal

import jax
import numpy as np

from ramavt_jax.baselines import Policy
from ramavt_jax.evaluation.runs import ensemble_params, load_policy
from ramavt_jax.greedy import greedy_policy
from ramavt_jax.network import init_params
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import files

__all__ = [
    "AGENTS_DIR",
    "DEFAULT_AGENT",
    "PretrainedAgent",
    "PretrainedError",
    "available",
    "load",
    "export",
    "load_policy",
]

AGENTS_DIR = Path(__file__).resolve().parent.parent / "agents"
DEFAULT_AGENT = "ramavt_depth"


class PretrainedError(ValueError):
    """A pretrained agent that does not exist or does not fit this code version."""


@dataclasses.dataclass(frozen=True)
class PretrainedAgent:
    name: str
    policy: Policy
    config: TrainConfig
    params: object  # network params; an ensemble's with a leading [members] axis
    info: dict  # training command, targets, budget and measured results recorded at export
    members: int = 0  # 0: one network; M: an ensemble of M networks (greedy.greedy_policy(members=M))


def available(agents_dir: Path = AGENTS_DIR) -> list[str]:
    """Names of the agents shipped with this installation (or found in ``agents_dir``)."""
    return sorted(p.parent.name for p in Path(agents_dir).glob("*/params.npz"))


def _path_key(path) -> str:
    return "/".join(str(getattr(k, "key", k)) for k in path)


def load(name: str = DEFAULT_AGENT, agents_dir: Path = AGENTS_DIR, search: str = "learned") -> PretrainedAgent:
    """Load a shipped agent by name (see :func:`available`); ``search`` is what its policy commands until a frame
    first shows the target (greedy.greedy_policy). Stored arrays of a lower precision are widened to the network's
    dtype."""
    folder = Path(agents_dir) / name
    if not (folder / "params.npz").is_file():
        raise PretrainedError(f"no pretrained agent {name!r}; available: {', '.join(available(agents_dir)) or 'none'}")
    saved = json.loads((folder / "config.json").read_text())
    config = TrainConfig.from_dict(saved["config"])
    info = saved.get("info", {})
    members = int(info.get("members", 0))
    obs_shape = tuple(config.env.obs_shape)
    template = jax.eval_shape(lambda k: init_params(config.network, k, obs_shape)["params"], jax.random.key(0))
    with np.load(folder / "params.npz") as arrays:
        stored = {k: arrays[k] for k in arrays.files}

    def fill(path, like):
        key, shape = _path_key(path), ((members,) if members else ()) + tuple(like.shape)
        if key not in stored or stored[key].shape != shape:
            raise PretrainedError(f"pretrained agent {name!r} does not match this code's network at {key!r}")
        return jax.numpy.asarray(stored[key], like.dtype)

    params = jax.tree_util.tree_map_with_path(fill, template)
    policy = greedy_policy(config.network, params, obs_shape, name=f"pretrained:{name}", search=search, members=members)
    return PretrainedAgent(name=name, policy=policy, config=config, params=params, info=info, members=members)


def export(
    run_dir,
    name: str,
    command: str,
    info: dict | None = None,
    out_dir: Path = AGENTS_DIR,
    policy_params: str | None = None,
    precision: Literal["float32", "float16"] = "float32",
) -> Path:
    """Copy a run folder's latest network parameters (the set its config's RunConfig.policy_params names, unless
    ``policy_params`` says) and config into an agent folder ``out_dir/name`` (both files replaced together, whole or
    not at all). ``run_dir`` may be a sequence of run folders of one config (the seeds of a sweep): the agent is then
    their ensemble, its arrays stacked [members, ...]. ``precision``: the dtype the arrays are stored in (float16
    halves the file; the agent acts with them widened back, so evaluate what is stored)."""
    if precision not in ("float32", "float16"):
        raise ValueError(f"precision must be 'float32' or 'float16', got {precision!r}")
    many = isinstance(run_dir, Sequence) and not isinstance(run_dir, str)
    if many and len(run_dir) < 2:
        raise ValueError(f"an ensemble needs at least two run folders, got {len(run_dir)}")
    loaded = [load_policy(d, policy_params=policy_params) for d in (run_dir if many else [run_dir])]
    params = ensemble_params(loaded) if many else loaded[0].params
    flat = {_path_key(p): np.asarray(v).astype(precision) for p, v in jax.tree_util.tree_flatten_with_path(params)[0]}
    overflow = [key for key, array in flat.items() if not np.isfinite(array).all()]
    if overflow:
        raise ValueError(f"parameters at {overflow[0]!r} are not finite in {precision}; store them in float32")
    provenance = {"command": command, "run": str(loaded[0].run_dir), "seed": loaded[0].seed, "chunks": loaded[0].step}
    if many:
        provenance.update(
            members=len(loaded), runs=[str(lr.run_dir) for lr in loaded], seeds=[lr.seed for lr in loaded]
        )
    # the caller's notes may not overwrite what load() reads the arrays by
    record = {"config": loaded[0].config.to_dict(), "info": {**(info or {}), **provenance, "precision": precision}}
    text = json.dumps(record, indent=1)
    folder = Path(out_dir) / name
    folder.mkdir(parents=True, exist_ok=True)
    files.replace_files(
        {
            folder / "params.npz": lambda tmp: np.savez_compressed(tmp, **flat),
            folder / "config.json": lambda tmp: tmp.write_text(text),
        }
    )
    return folder
