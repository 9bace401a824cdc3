"""Training throughput: env steps/s, gradient updates/s and trained frames/s per network variant, with the time
split between the environment (physics + rendering), acting (network forward + epsilon-greedy) and learning,
each timed as a separately jitted piece; plus single-env greedy inference Hz.

    python benchmarks/bench_train.py                      # 64x64, all variants -> benchmarks/results_train.json
    python benchmarks/bench_train.py --resolution 256 --num-envs 4 --batch-size 4 --variants ramavt
    python benchmarks/bench_train.py --preset quick        # the quick preset's own small network at 32x32

Timings on shared machines vary (~+-30%): each figure is the median of ``repeats`` timed calls after a warm-up.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import tarfile
import time
from pathlib import Path

import jax
import jax.numpy as jnp

from ramavt_jax import env as env_lib
from ramavt_jax import greedy, presets, train_config
from ramavt_jax import replay as replay_lib
from ramavt_jax import train as T
from ramavt_jax.network import NetworkConfig, count_params
from ramavt_jax.render import CameraConfig
from ramavt_jax.train_config import ActingConfig, LearnerConfig, ReplayConfig, RunConfig

DEFAULT_OUT = Path(__file__).resolve().parent / "results_train.json"  # beside this script, from any directory

VARIANTS = ("ramavt", "drlavt", "origin", "se", "mha")


def machine_info(load_start: tuple, start_time: float) -> dict:
    """The machine, the load average at the start and now, and the wall time since ``start_time``, for a JSON."""
    return {
        "platform": platform.platform(),
        "cpus": os.cpu_count(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "loadavg_start": load_start,
        "loadavg_end": os.getloadavg(),
        "wall_s": time.time() - start_time,
    }


def code_version() -> str:
    """This checkout's commit, with "-dirty" when it has uncommitted changes (the code a JSON's figures measured)."""
    return subprocess.run(
        ["git", "-C", str(Path(__file__).resolve().parents[1]), "describe", "--always", "--dirty", "--abbrev=7"],
        capture_output=True,
        text=True,
    ).stdout.strip()


def export_package(rev: str, where: Path) -> Path:
    """``ramavt_jax`` of git revision ``rev`` extracted into ``where`` (made if needed): ``where / "ramavt_jax"``."""
    archive = subprocess.run(
        ["git", "-C", str(Path(__file__).resolve().parents[1]), "archive", rev, "ramavt_jax"],
        check=True,
        capture_output=True,
    ).stdout
    where.mkdir(parents=True, exist_ok=True)
    tar_path = where / "package.tar"
    tar_path.write_bytes(archive)
    with tarfile.open(tar_path) as tar:
        tar.extractall(where, filter="data")
    return where / "ramavt_jax"


def merge_json(path, key: str, value) -> None:
    """Write ``value`` under ``key`` into the JSON object at ``path``, keeping its other keys."""
    path = Path(path)
    old = json.loads(path.read_text()) if path.exists() else {}
    old[key] = value
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(old, indent=1))


def _median_time(fn, repeats: int) -> float:
    jax.block_until_ready(fn())  # warm-up (compile)
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t)
    return statistics.median(times)


def _filled_replay(trainer: T.Trainer, key: jax.Array):
    """A full replay of random observations / actions with a few episode starts (the learner's speed does not depend
    on the data)."""
    c = trainer.config
    n, steps = c.acting.num_envs, trainer.replay.steps_per_env
    ks = jax.random.split(key, 4)
    ex = trainer._example_transition()
    chunk = replay_lib.Transition(
        obs=jax.random.uniform(ks[0], (n, steps, *trainer.obs_shape)),
        action=jax.random.randint(ks[1], (n, steps), 0, env_lib.NUM_ACTIONS),
        reward=jax.random.normal(ks[2], (n, steps)),
        terminated=jax.random.uniform(ks[3], (n, steps)) < 0.01,
        truncated=jnp.zeros((n, steps), bool),
        is_first=jax.random.uniform(ks[3], (n, steps)) > 0.99,
        recurrent_state=jax.tree.map(lambda x: jnp.zeros((n, steps, *x.shape)), ex.recurrent_state),
        privileged=None if ex.privileged is None else jnp.zeros((n, steps, *ex.privileged.shape)),
        expert_action=None if ex.expert_action is None else jnp.zeros((n, steps), jnp.int32),
    )
    return trainer.replay.add(trainer.replay.init(), chunk)


def bench_variant(
    variant: str,
    resolution: int,
    num_envs: int,
    batch_size: int,
    burn_in: int,
    train_len: int,
    rollout_steps: int,
    repeats: int,
    network: NetworkConfig | None = None,
) -> dict:
    net = network or NetworkConfig(variant=variant)
    env_steps = num_envs * rollout_steps
    # replay ratio 1 when the numbers allow it, else one update per iteration
    ratio = batch_size * train_len / env_steps
    cfg = train_config.TrainConfig(
        env=env_lib.EnvConfig(camera=CameraConfig(resolution=resolution), autoreset="next_step"),
        network=net,
        acting=ActingConfig(num_envs=num_envs, rollout_steps=rollout_steps),
        replay=ReplayConfig(
            capacity_steps=num_envs * max(burn_in + train_len + 1, rollout_steps) * 2,
            burn_in=burn_in,
            train_len=train_len,
            batch_size=batch_size,
        ),
        learner=LearnerConfig(learning_starts=0, replay_ratio=ratio, n_step=min(5, train_len)),
        run=RunConfig(iterations_per_chunk=1, total_env_steps=env_steps, eval_episodes=0),
    )
    tr = T.Trainer(cfg)
    key = jax.random.PRNGKey(0)
    state = jax.jit(tr.init)(key)
    params = state.learner.params
    actor = state.actor

    # environment only: physics + rendering (+ next-step autoreset), random actions
    env_step = jax.jit(jax.vmap(tr.env.step, in_axes=(0, 0, 0, None)))
    keys = jax.random.split(key, num_envs)
    actions = jax.random.randint(key, (num_envs,), 0, env_lib.NUM_ACTIONS)
    t_env = _median_time(lambda: env_step(keys, actor.env_state, actions, tr.env_params), repeats) / num_envs

    # acting network only: forward of all envs, T=1, + argmax
    fwd = jax.jit(lambda p, a: jnp.argmax(tr.q_values(p, a.obs[:, None], a.is_first[:, None], a.net_state)[0], -1))
    t_act = _median_time(lambda: fwd(params, actor), repeats) / num_envs

    # a whole rollout (env + network + epsilon-greedy, in one scan)
    rollout = jax.jit(tr.rollout)
    t_roll = _median_time(lambda: rollout(params, actor, jnp.int32(0), key), repeats) / env_steps

    # learner: one gradient step on a full replay (sample + burn-in + loss + Adam + target update)
    replay_state = _filled_replay(tr, key)
    update = jax.jit(tr.update)
    t_upd = _median_time(lambda: update(state.learner, replay_state, key), repeats)

    # one whole iteration (rollout + replay add + updates_per_iteration updates), as training runs it
    iteration = jax.jit(lambda s: tr.chunk(s)[0])
    full = state.replace(replay=replay_state)
    t_iter = _median_time(lambda: iteration(full), max(2, repeats // 2))

    # single-env greedy inference (batch 1, T=1), acting Hz of a deployed tracker
    policy = greedy.greedy_policy(net, params, tr.obs_shape)
    ps = policy.init(key)
    obs1 = actor.obs[0]
    act1 = jax.jit(policy.act)
    t_one = _median_time(lambda: act1(key, ps, obs1, None, None), repeats * 5)

    trained_frames = batch_size * train_len
    it_updates = cfg.updates_per_iteration
    return {
        "variant": variant,
        "resolution": resolution,
        "obs_shape": list(tr.obs_shape),
        "params": count_params(params),
        "num_envs": num_envs,
        "batch_size": batch_size,
        "burn_in": burn_in,
        "train_len": train_len,
        "rollout_steps": rollout_steps,
        "updates_per_iteration": it_updates,
        "env_only_steps_per_s": 1.0 / t_env,
        "act_forward_steps_per_s": 1.0 / t_act,
        "rollout_env_steps_per_s": 1.0 / t_roll,
        "updates_per_s": 1.0 / t_upd,
        "trained_frames_per_s": trained_frames / t_upd,
        "iteration_s": t_iter,
        "iteration_env_steps_per_s": env_steps / t_iter,
        "iteration_trained_frames_per_s": it_updates * trained_frames / t_iter,
        # per iteration: time spent in env, network acting and learning (separately jitted estimates)
        "split_s": {
            "env": t_env * env_steps,
            "acting_network": t_act * env_steps,
            "rollout_total": t_roll * env_steps,
            "learning": t_upd * it_updates,
        },
        "single_env_greedy_hz": 1.0 / t_one,
    }


def run(
    variants=VARIANTS,
    resolution: int = 64,
    num_envs: int = 64,
    batch_size: int = 32,
    burn_in: int = 10,
    train_len: int = 20,
    rollout_steps: int = 20,
    repeats: int = 5,
    out: str | None = str(DEFAULT_OUT),
    quiet: bool = False,
    preset: str | None = None,
) -> dict:
    """Benchmark each variant (the paper's network at ``resolution``); print a table; write JSON to ``out``
    (None = don't). ``preset``: instead benchmark that training preset's own network and sizes. Returns the results."""
    rows = []
    network = None
    if preset is not None:
        cfg = presets.preset(preset)
        network, variants = cfg.network, (cfg.network.variant,)
        resolution, num_envs, batch_size = cfg.env.camera.resolution, cfg.acting.num_envs, cfg.replay.batch_size
        burn_in, train_len, rollout_steps = cfg.replay.burn_in, cfg.replay.train_len, cfg.acting.rollout_steps
    for v in variants:
        t = time.time()
        row = bench_variant(v, resolution, num_envs, batch_size, burn_in, train_len, rollout_steps, repeats, network)
        row["preset"] = preset
        row["bench_wall_s"] = time.time() - t
        rows.append(row)
        if not quiet:
            print(f"  {v}: done in {row['bench_wall_s']:.0f} s", flush=True)
    results = {
        "machine": {
            "platform": platform.platform(),
            "cpus": os.cpu_count(),
            "jax": jax.__version__,
            "backend": jax.default_backend(),
            "loadavg": os.getloadavg(),
        },
        "settings": dict(
            resolution=resolution,
            num_envs=num_envs,
            batch_size=batch_size,
            burn_in=burn_in,
            train_len=train_len,
            rollout_steps=rollout_steps,
            repeats=repeats,
        ),
        "rows": rows,
    }
    if not quiet:
        print(table(rows))
    if out:
        merge_json(out, f"preset_{preset}" if preset else f"{resolution}x{resolution}", results)
    return results


def table(rows: list[dict]) -> str:
    head = (
        f"{'variant':8} {'res':>4} {'params':>9} {'env/s':>8} {'act/s':>8} {'rollout/s':>9} {'upd/s':>7} "
        f"{'trFr/s':>8} {'iter env/s':>10} {'iter trFr/s':>11} {'env|act|learn s/iter':>22} {'1-env Hz':>9}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        s = r["split_s"]
        split = f"{s['env']:.2f}|{s['acting_network']:.2f}|{s['learning']:.2f}"
        lines.append(
            f"{r['variant']:8} {r['resolution']:>4} {r['params']:>9,} {r['env_only_steps_per_s']:>8.0f} "
            f"{r['act_forward_steps_per_s']:>8.0f} {r['rollout_env_steps_per_s']:>9.0f} {r['updates_per_s']:>7.2f} "
            f"{r['trained_frames_per_s']:>8.0f} {r['iteration_env_steps_per_s']:>10.0f} "
            f"{r['iteration_trained_frames_per_s']:>11.0f} {split:>22} {r['single_env_greedy_hz']:>9.0f}"
        )
    return "\n".join(lines)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    p.add_argument("--resolution", type=int, default=64)
    p.add_argument("--num-envs", type=int, default=64)
    p.add_argument("--batch-size", type=int, default=32)
    p.add_argument("--burn-in", type=int, default=10)
    p.add_argument("--train-len", type=int, default=20)
    p.add_argument("--rollout-steps", type=int, default=20)
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--out", default=str(DEFAULT_OUT))
    p.add_argument(
        "--preset", default=None, choices=sorted(presets.PRESETS), help="benchmark a training preset's network"
    )
    a = p.parse_args(argv)
    run(
        a.variants,
        a.resolution,
        a.num_envs,
        a.batch_size,
        a.burn_in,
        a.train_len,
        a.rollout_steps,
        a.repeats,
        a.out,
        preset=a.preset,
    )


if __name__ == "__main__":
    main()
