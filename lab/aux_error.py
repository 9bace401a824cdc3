"""Seeing or steering: a trained run's tracking error beside its own estimate of that error (the auxiliary head,
NetworkConfig.aux_outputs = 3, fitted in training to the true tracking error), per camera axis, per target.

If the head's estimate is far better than the tracking (estimate error std << tracking error std, correlation near
1), the agent knows where the target is and fails to act on it; if they are alike (correlation near 0), what it
holds of the target's position is no better than its tracking.

The head was fitted in training, by gradient steps, alongside everything else. Two linear probes fitted after the
fact (ridge regression on the even episodes of each target, scored on the odd ones) bound what a linear read-out
can get: from the LSTM output (the agent's memory, what the head reads) and from the encoder's output for the
current frame alone. A probe far above the head means the head is under-fitted; a memory probe above the frame
probe means the memory adds what one frame does not show.

    python lab/aux_error.py runs/quick_now/seed_0 --targets val --episodes 8

The episodes fly the run's own env (its camera, dynamics and training overrides that also hold in evaluation) with
the evaluation's rules. Steps before --skip (the approach) and after the episode ended are left out; the steps of
up to lost_patience with the target out of view before a loss count. Errors are in metres divided by the target's
stand-off scale k (plain metres for the catalogue's sizes).
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from ramavt_jax import env as env_lib
from ramavt_jax import targets as targets_lib
from ramavt_jax.evaluation import rollouts, runs
from ramavt_jax.network import Encoder, RecurrentState, initial_state, make_network, record_action

RIDGE = 1e-2  # ridge penalty on standardised features: small against the thousands of samples per target


class Carry(NamedTuple):
    obs: jax.Array  # [H, W, C]
    state: env_lib.EnvState
    net_state: RecurrentState  # batch of one
    first: jax.Array  # [] bool
    alive: jax.Array  # [] bool: the episode has not ended before this step


class Step(NamedTuple):
    truth: jax.Array  # [3] target centre minus desired point, camera frame, metres / k
    estimate: jax.Array  # [3] the auxiliary head's estimate of it, same units
    memory: jax.Array  # [lstm] the LSTM output after this step's obs (what the head reads)
    frame: jax.Array  # [F] the encoder's output for this step's obs alone
    alive: jax.Array  # [] bool


class Rollout(NamedTuple):
    env: env_lib.TrackingEnv  # the run's env over the targets asked for
    params: env_lib.EnvParams  # its evaluation params (pin a target with env.pinned)
    run: Callable  # (params, network params, key) -> Step arrays [episodes, steps(, 3)], compiled once


def make_rollout(run: runs.LoadedRun, targets: tuple[str, ...], episodes: int, steps: int) -> Rollout:
    """Greedy episodes of the run's network on its own env over ``targets``, one compiled program for all of them
    (the target is chosen by the params). ``truth`` is taken from the state that rendered the observation the network
    acts on, as the auxiliary label is in training."""
    cfg = run.config
    env = env_lib.TrackingEnv(dataclasses.replace(cfg.env, targets=tuple(targets)))
    net = make_network(cfg.network)
    encoder_only = lambda module, method: isinstance(module, Encoder) and method == "__call__"  # noqa: E731

    def episode(params: env_lib.EnvParams, net_params, k: jax.Array) -> Step:
        k_reset, k_steps = jax.random.split(k)
        obs, state = env.reset(k_reset, params)
        start = Carry(
            obs, state, initial_state(cfg.network, 1, tuple(cfg.env.obs_shape)), jnp.ones((), bool), jnp.ones((), bool)
        )

        def body(c: Carry, k_step):
            (q, net_state), sown = net.apply(
                {"params": net_params},
                c.obs[None, None],
                c.first[None, None],
                c.net_state,
                mutable=["intermediates"],
                capture_intermediates=encoder_only,
            )
            step = Step(
                truth=env_lib.relative_position(c.state) / c.state.scale - params.desired_pos,
                estimate=sown["intermediates"]["aux"][0][0, 0, :3] * params.desired_pos[2],  # the error part
                memory=net_state.h[-1, 0],
                frame=sown["intermediates"]["encoder"]["__call__"][0][0],
                alive=c.alive,
            )
            action = jnp.argmax(q[0, 0]).astype(jnp.int32)
            obs, state, _, terminated, truncated, _ = env.step_env(k_step, c.state, action, params)
            return Carry(
                obs,
                state,
                record_action(net_state, action[None]),
                jnp.zeros((), bool),
                c.alive & ~(terminated | truncated),
            ), step

        return jax.lax.scan(body, start, jax.random.split(k_steps, steps))[1]

    def run_all(params, net_params, key):
        return jax.vmap(episode, in_axes=(None, None, 0))(params, net_params, jax.random.split(key, episodes))

    return Rollout(env, env.eval_params(**rollouts.run_env_overrides(cfg.env_params)), jax.jit(run_all))


def probe_correlation(features: np.ndarray, truth: np.ndarray, fit: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """One ridge regression from features [n, F] to truth [n, 3], fitted on the rows where ``fit`` [n] is True;
    the correlation of its prediction with the truth on the other rows of each group (groups [n] int in [0, G)),
    per axis: [G, 3]."""
    mean, std = features[fit].mean(0), features[fit].std(0) + 1e-6
    x = np.concatenate([(features - mean) / std, np.ones((len(features), 1))], axis=1)
    gram = x[fit].T @ x[fit] + RIDGE * fit.sum() * np.eye(x.shape[1])
    predicted = x @ np.linalg.solve(gram, x[fit].T @ truth[fit])
    held = [~fit & (groups == g) for g in range(groups.max() + 1)]
    return np.array([[np.corrcoef(predicted[h, i], truth[h, i])[0, 1] for i in range(truth.shape[1])] for h in held])


class TargetSteps(NamedTuple):
    """One target's steps that count (alive, after --skip), flattened over episodes: [n, ...]."""

    truth: np.ndarray  # [n, 3]
    estimate: np.ndarray  # [n, 3]
    memory: np.ndarray  # [n, lstm]
    frame: np.ndarray  # [n, F]
    fit: np.ndarray  # [n] bool: from an even episode (the probes are fitted on these rows)


def target_steps(steps: Step, skip: int) -> TargetSteps:
    keep = steps.alive[:, skip:]
    even = np.broadcast_to((np.arange(len(keep)) % 2 == 0)[:, None], keep.shape)
    flat = lambda x: x[:, skip:][keep]  # noqa: E731
    return TargetSteps(flat(steps.truth), flat(steps.estimate), flat(steps.memory), flat(steps.frame), even[keep])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("run", help="a training run folder whose network has the auxiliary head")
    ap.add_argument("--targets", default="val", help="a split of targets_lib.split: val (default), test, ...")
    ap.add_argument(
        "--episodes",
        type=int,
        default=8,
        help="episodes per target (at least 2: the probes are fitted on the even ones and scored on the odd ones)",
    )
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--skip", type=int, default=100, help="steps of each episode left out (the approach)")
    ap.add_argument("--seed", type=int, default=5)
    args = ap.parse_args()
    if args.episodes < 2:
        raise SystemExit(
            f"--episodes must be at least 2 (the probes need episodes to fit and to score), got {args.episodes}"
        )
    run = runs.load_policy(args.run)
    if not run.config.network.aux_outputs:
        raise SystemExit(f"{args.run}: its network has no auxiliary head (NetworkConfig.aux_outputs = 0)")
    names = targets_lib.split(args.targets)
    rollout = make_rollout(run, names, args.episodes, args.steps)
    per_target = []
    for index in range(len(names)):
        pinned = rollout.env.pinned(rollout.params, index)
        steps = jax.tree.map(np.asarray, rollout.run(pinned, run.params, jax.random.PRNGKey(args.seed)))
        per_target.append(target_steps(steps, args.skip))
    every = TargetSteps(*(np.concatenate(x) for x in zip(*per_target)))
    groups = np.concatenate([np.full(len(t.fit), i) for i, t in enumerate(per_target)])
    print(
        f"{'target':15s} tracking error std x/y/z (m)   estimate error std x/y/z (m)   corr(est, e) x/y/z"
        f"      mean |e|  mean |est - e|"
    )
    for name, t in zip(names, per_target):
        miss = t.estimate - t.truth
        corr = [np.corrcoef(t.estimate[:, i], t.truth[:, i])[0, 1] for i in range(3)]
        print(
            f"{name:15s} {str(np.round(t.truth.std(0), 3)):30s} {str(np.round(miss.std(0), 3)):30s} "
            f"{str(np.round(corr, 2)):24s}"
            f"{np.linalg.norm(t.truth, axis=1).mean():8.3f}  {np.linalg.norm(miss, axis=1).mean():.3f}"
        )
    # One read-out for every target (as the head is), and one per target (the target's identity given).
    probes = {}
    for source in ("memory", "frame"):
        features = getattr(every, source)
        probes[source, "one"] = probe_correlation(features, every.truth, every.fit, groups)
        probes[source, "per target"] = np.concatenate(
            [probe_correlation(getattr(t, source), t.truth, t.fit, np.zeros(len(t.fit), int)) for t in per_target]
        )
    print(
        f"\nlinear probes, correlation with e x/y/z on the odd episodes\n{'target':15s} "
        + "".join(f"{f'{source}, {kind}':24s}" for source, kind in probes)
    )
    for index, name in enumerate(names):
        print(f"{name:15s} " + "".join(f"{str(np.round(c[index], 2)):24s}" for c in probes.values()))


if __name__ == "__main__":
    main()
