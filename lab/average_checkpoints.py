"""Checkpoint averaging: the uniform average of a run's policy parameters (the set it acts with,
RunConfig.policy_params; for a run that acts with its tail average, 'averaged', the target net's, which that average
is made of) over the checkpoints of chunks FIRST..LAST, written as a run folder that `ramavt eval --policy checkpoint`
reads. With FIRST = LAST it picks out that one chunk.

    python lab/average_checkpoints.py runs/eps_100k/seed_0 --chunks 13 24 --out runs/avg/eps_100k_13-24/seed_0

The run needs a checkpoint of every chunk in the range (`--run.checkpoint-every-chunks 1 --run.keep-checkpoints N`;
`--run.no-checkpoint-replay` keeps them small, and each is read whole).
The output folder holds the run's config.json and one checkpoint, numbered LAST, whose online and target parameters
(and averaged ones, where the run keeps them) are all the average; its other arrays (optimiser, envs) are the LAST
checkpoint's, and it has no replay, so it can be evaluated but not resumed. A run trained with
`--run.policy-average-from S` keeps such a mean of its chunks after S itself (RunConfig.policy_params='averaged').
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp

from ramavt_jax.train import Trainer
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import run_folder as folders
from ramavt_jax.training.checkpoint import CheckpointStore


def average_params(run_dir: Path, first: int, last: int):
    """(mean policy params over chunks first..last, the last chunk's state without replay, its meta, config)."""
    config = TrainConfig.from_dict(folders.read_config(run_dir)["config"])
    # a tail average's checkpoints hold running means: average what they are means of, the target params
    which = "target" if config.run.policy_params == "averaged" else config.run.policy_params
    store = CheckpointStore(run_dir / folders.CHECKPOINTS, create=False)
    try:
        missing = sorted(set(range(first, last + 1)) - set(store.all_steps()))
        if missing:
            raise SystemExit(
                f"{run_dir}: no checkpoint of chunk(s) {missing}; train with --run.checkpoint-every-chunks 1"
            )
        like = jax.eval_shape(Trainer(config).init, jax.ShapeDtypeStruct((2,), jnp.uint32))
        if not config.run.checkpoint_replay:
            like = like.replace(replay=None)
        total = None
        for step in range(first, last + 1):  # whole states (no replay: a few MB each), one orbax handler throughout
            state, meta = store.restore(like, step)
            params, state = state.learner.policy_params(which), state.replace(replay=None)
            total = params if total is None else jax.tree.map(jnp.add, total, params)
        mean = jax.tree.map(lambda x: x / (last - first + 1), total)
    finally:
        store.close()
    return mean, state, meta, config


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--chunks", type=int, nargs=2, required=True, metavar=("FIRST", "LAST"))
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args(argv)
    first, last = args.chunks
    if not 1 <= first <= last:
        raise SystemExit(f"--chunks {first} {last}: need 1 <= FIRST <= LAST")
    if args.out.exists():
        raise SystemExit(f"--out {args.out} exists: name a new folder (it is never overwritten)")
    mean, state, meta, config = average_params(args.run, first, last)
    averaged = None if state.learner.averaged_params is None else mean
    state = state.replace(learner=state.learner.replace(params=mean, target_params=mean, averaged_params=averaged))
    # restore() leaves empty arrays, and leaves the checkpoint predates (checkpoint.ADDED_LEAVES), as the template's
    # shape structs: make them arrays again to save them (zeros; only the params of this state are ever read)
    state = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype) if isinstance(x, jax.ShapeDtypeStruct) else x, state)
    args.out.mkdir(parents=True)
    saved = folders.read_config(args.run)
    saved["config"]["run"]["checkpoint_replay"] = False  # the state written has no replay
    (args.out / folders.CONFIG_FILE).write_text(json.dumps(saved, indent=1))
    store = CheckpointStore(args.out / folders.CHECKPOINTS)
    try:
        meta = dict(meta, averaged_from=str(args.run), averaged_chunks=[first, last])
        store.save(last, state, meta)
    finally:
        store.close()
    print(f"{args.out}: the mean of chunks {first}-{last} of {args.run}")


if __name__ == "__main__":
    main()
