"""The end-of-training evaluation of a run folder: the greedy policy, a random agent and the mpc ceiling (true-state
receding-horizon control, baselines.mpc_policy) on the training, the validation and the held-out (test) targets, with
the evaluation settings (``env.eval_params``), written to ``eval.json``. Choose among runs by the validation split;
the test split is for the final numbers. The ceiling flies the greedy policy's episodes, so the greedy entry's
'ceiling_fraction' (its AER / the ceiling's) compares like with like."""

from __future__ import annotations

import dataclasses
import time
import zlib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp

from ramavt_jax import baselines
from ramavt_jax import env as env_lib
from ramavt_jax import targets as targets_lib
from ramavt_jax.evaluation import rollouts
from ramavt_jax.greedy import greedy_policy
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import files
from ramavt_jax.training import run_folder as folders

__all__ = ["split_envs", "split_key", "final_evaluation", "evaluate_run"]


def split_key(key: jax.Array, split: str) -> jax.Array:
    """The key of one split's episodes, from the split's name (not its position): a split's key does not change with
    the other splits evaluated beside it, and validation and test episodes never share a key."""
    return jax.random.fold_in(key, zlib.crc32(split.encode()))


def split_envs(
    config: TrainConfig, splits: dict[str, tuple[str, ...]], max_steps: int
) -> tuple[env_lib.TrackingEnv, dict[str, env_lib.EnvParams]]:
    """One env over every split's targets, and per split the evaluation EnvParams that draw only that split's
    targets (uniformly). The target draw is a traced value, so one compiled rollout serves every split."""
    names = tuple(dict.fromkeys(n for split in splits.values() for n in split))
    tracking_env = env_lib.TrackingEnv(dataclasses.replace(config.env, targets=names))
    base = tracking_env.eval_params(**rollouts.run_env_overrides(config.env_params), max_steps=max_steps)
    params = {}
    for split, members in splits.items():
        member = jnp.asarray([n in members for n in names], jnp.float32)
        params[split] = base.replace(target_probs=member / member.sum())
    return tracking_env, params


def final_evaluation(config: TrainConfig, params: Any, key: jax.Array, log: Callable[[str], None] = print) -> dict:
    """{split: {'greedy' | 'random' | 'mpc': Summary dict}} on the run's training targets, the validation and the
    held-out (test) split; one compiled rollout per policy serves every split."""
    splits = {"train": tuple(config.env.targets), "val": targets_lib.VAL_TARGETS, "test": targets_lib.TEST_TARGETS}
    tracking_env, split_params = split_envs(config, splits, config.run.eval_max_steps)
    greedy = greedy_policy(config.network, params, tuple(config.env.obs_shape))
    policies = {"greedy": greedy, "random": baselines.random_policy(), "mpc": baselines.mpc_policy(tracking_env.config)}
    key_index = {"greedy": 0, "random": 1, "mpc": 0}  # the ceiling flies the greedy policy's episodes
    out = {}
    for split, names in splits.items():
        for name, policy in policies.items():
            t = time.time()
            k = jax.random.fold_in(split_key(key, split), key_index[name])
            stats, _ = rollouts.run_episodes(
                tracking_env,
                policy,
                split_params[split],
                k,
                config.run.eval_episodes,
                num_steps=config.run.eval_max_steps,
            )
            out.setdefault(split, {})[name] = res = rollouts.summarise(stats).as_dict()
            log(
                f"final evaluation: {name:<6} on {split:<5} targets ({len(names)}): mean episode length "
                f"{res['length_mean']:.0f}, return {res['return_mean']:.1f} ({time.time() - t:.0f} s)"
            )
        ceiling = out[split]["mpc"]["return_mean"]
        greedy = out[split]["greedy"]
        greedy["ceiling_fraction"] = greedy["return_mean"] / ceiling if ceiling > 0 else None
    return out


def evaluate_run(
    config: TrainConfig, run_dir: str | Path, seed: int, params: Any, log: Callable[[str], None] = print
) -> dict:
    """Evaluate a finished run's params (the set ``config.run.policy_params`` names; key: seed + 10,000) and write
    ``run_dir/eval.json`` (whole or not at all: a full disk leaves the earlier one); returns the results."""
    t = time.time()
    log(
        f"final evaluation of {run_dir} ({config.run.policy_params} params): {config.run.eval_episodes} episodes per "
        f"split and policy, up to {config.run.eval_max_steps} steps ..."
    )
    results = final_evaluation(config, params, jax.random.PRNGKey(seed + 10_000), log)
    results["policy_params"] = config.run.policy_params
    results["eval_wall_s"] = time.time() - t
    files.write_atomic(Path(run_dir) / folders.EVAL_FILE, files.dumps(results, indent=1))
    return results
