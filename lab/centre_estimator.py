"""Can the agent's network learn where the target's centre of mass is from the images, and does a longer gradient
horizon let it use the target's tumble to find it? A supervised test, no reinforcement learning:

    python lab/centre_estimator.py --windows 20 100 --updates 1500 --out results/val/centre_estimator.json

The `quick` preset's network (its auxiliary head: the tracking error [3]) is fitted by mean squared error to the
true error (imitation.true_tracking_state) on episodes flown by the ceiling told a centre a random 0-1 m off, with a
random action on a fifth of the steps (so that the error to estimate spans the agent's own and more: 0.68 m on
average on the validation episodes), on the training targets. Training is
truncated back-propagation through time over whole episodes: each update takes the next `window` steps of a batch
of episodes, starting from the recurrent state the previous window ended in (held fixed), as acting carries it.
The window (the gradient horizon) is the change between arms; every arm sees the same frames per update
(`--frames-per-update`) and the same number of updates, so the batch is frames / window episodes (80 at 20 steps,
16 at 100), walked through together from their starts (all rows of a batch at the same step). The agent's trainer
uses 20 (with 10 steps of burn-in); a tumble turns about 0.16 rad/s (0.1 s steps), a full turn in about 400 steps.

Evaluation carries the state over whole episodes (the same behaviour, `--eval-targets`: the validation ones) and
reports the estimate's error after the first `--skip` steps, in metres / k (plain metres for catalogue targets):
across the image, along the boresight, and in 3-D. `visible centroid` is the error of the newest frame's visible
surface centroid on the same frames (those with a target pixel: it has no estimate on the others); `desired point`
the error of guessing that the centre is where it should be (an estimate that has learned nothing).
(The diagnostics `--spin-input` and `--velocity-input`, the target's true angular and relative velocity beside the
image features, were retired with the package's true-state input: lab/README.md.)
`lab/centre_precision.py` gives the yardstick: the ceiling told a centre
0.1 m off keeps about 92 % of its return, 0.2 m off about 81 %, 0.3 m off about 70 %.
"""

from __future__ import annotations

import argparse
import ast
import dataclasses
import functools
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import optax
from flax import struct
from tqdm import tqdm

from lab.centre_precision import offset_ceiling
from lab.surface import surface_centroid
from ramavt_jax import baselines, presets
from ramavt_jax import env as env_lib
from ramavt_jax.baselines import Policy
from ramavt_jax.evaluation import rollouts, runs
from ramavt_jax.imitation import true_tracking_state
from ramavt_jax.network import NetworkConfig, initial_state, make_network

LABEL = 3  # the tracking error's entries (stand-off distances), the auxiliary head's outputs
DESIRED = np.array([0.0, 0.0, 5.0])  # m, the desired point of every catalogue target (stand-off scale k = 1)
FRAME_ONLY_WINDOW = 20  # steps per training row of the one-frame estimator (window 0): a batch shape, no memory


@struct.dataclass
class Episodes:
    """Recorded episodes: obs [E, T, H, W, C] float16 (the env's), action [E, T] int32 taken after each obs,
    label [E, T, 3] the true error when the obs was taken, alive [E, T] bool, target [E] the catalogue index."""

    obs: jax.Array
    action: jax.Array
    label: jax.Array
    alive: jax.Array
    target: jax.Array


def behaviour(camera: env_lib.CameraConfig, max_offset: float, random_share: float) -> Policy:
    """The ceiling told a centre off by a fixed vector per episode, of size uniform in [0, max_offset] m * k, with
    a uniformly random action instead of its own on a share ``random_share`` of the steps."""
    return offset_ceiling(baselines.make_policy("mpc", camera), max_offset, True, random_share)


def collect(
    targets: tuple[str, ...],
    per_target: int,
    steps: int,
    key: jax.Array,
    camera: env_lib.CameraConfig,
    max_offset: float = 1.0,
    random_share: float = 0.2,
) -> Episodes:
    """``per_target`` episodes of ``steps`` steps on each of ``targets`` (evaluation rules), flown by behaviour()."""
    tracking_env = env_lib.TrackingEnv(env_lib.EnvConfig(camera=camera, targets=targets))
    policy = behaviour(camera, max_offset, random_share)

    @jax.jit
    def run(params, key):
        k_reset, k_policy, k_loop = jax.random.split(key, 3)
        obs, state = jax.vmap(tracking_env.reset, in_axes=(0, None))(jax.random.split(k_reset, per_target), params)
        pstate = jax.vmap(policy.init)(jax.random.split(k_policy, per_target))

        def body(carry, step_key):
            obs, state, pstate, alive = carry
            k_act, k_env = jax.random.split(step_key)
            action, pstate = jax.vmap(policy.act, in_axes=(0, 0, 0, 0, None))(
                jax.random.split(k_act, per_target), pstate, obs, state, params
            )
            true = jax.vmap(true_tracking_state, in_axes=(0, None))(state, params)
            record = (obs.astype(jnp.float16), action, true[:, :LABEL], alive)
            obs, state, _, terminated, truncated, _ = jax.vmap(tracking_env.step_env, in_axes=(0, 0, 0, None))(
                jax.random.split(k_env, per_target), state, action, params
            )
            return (obs, state, pstate, alive & ~(terminated | truncated)), record

        init = (obs, state, pstate, jnp.ones(per_target, bool))
        _, record = jax.lax.scan(body, init, jax.random.split(k_loop, steps))
        return jax.tree.map(lambda x: jnp.swapaxes(x, 0, 1), record)  # [E, T, ...]

    base = tracking_env.eval_params(max_steps=steps)
    parts = [run(tracking_env.pinned(base, i), jax.random.fold_in(key, i)) for i in range(len(targets))]
    obs, action, label, alive = (jnp.concatenate(x) for x in zip(*parts))
    target = jnp.repeat(jnp.arange(len(targets)), per_target)
    return Episodes(obs=obs, action=action, label=label, alive=alive, target=target)


def _aux_pass(net, params, obs, reset, state, actions):
    """The network over a window: (aux [B, W, 3] float32, the state after it)."""
    (_, new_state), variables = net.apply(
        {"params": params},
        obs.astype(jnp.float32),
        reset,
        state,
        actions=actions,
        mutable=["intermediates"],
    )
    return variables["intermediates"]["aux"][0].astype(jnp.float32), new_state


def _masked_error(aux: jax.Array, label: jax.Array, alive: jax.Array) -> jax.Array:
    """Mean over live steps of the squared error's sum over the 3 entries; aux, label [B, W, 3], alive [B, W]."""
    return jnp.sum(jnp.sum((aux - label) ** 2, -1) * alive) / jnp.maximum(jnp.sum(alive), 1)


@functools.partial(jax.jit, static_argnums=(0, 1))
def _update(net, optimiser, params, opt_state, state, obs, reset, actions, label, alive):
    """One gradient step on one window of each episode of the batch; the state flows on with no gradient."""

    def loss_fn(p):
        aux, new_state = _aux_pass(net, p, obs, reset, state, actions)
        return _masked_error(aux, label, alive), new_state

    (loss, new_state), grads = jax.value_and_grad(loss_fn, has_aux=True)(params)
    updates, new_opt_state = optimiser.update(grads, opt_state, params)
    # a window where every episode has ended carries no label: Adam's momentum must not move the params on it
    keep = lambda new, old: jax.tree.map(lambda a, b: jnp.where(jnp.any(alive), a, b), new, old)  # noqa: E731
    return (
        keep(optax.apply_updates(params, updates), params),
        keep(new_opt_state, opt_state),
        jax.lax.stop_gradient(new_state),
        loss,
    )


def estimator_network(overrides: dict | None = None) -> NetworkConfig:
    """The `quick` preset's network with ``overrides`` ({field: value}, validated by NetworkConfig); ValueError for
    one this fit cannot train (it reads only the frames and actions, and fits a 3-entry auxiliary head)."""
    config = dataclasses.replace(presets.preset("quick").network, **(overrides or {}))
    if config.aux_outputs != LABEL or not config.recurrent:
        raise ValueError(
            f"the estimator fits a recurrent network's aux head to {LABEL} entries, got aux_outputs "
            f"{config.aux_outputs} on variant {config.variant!r}"
        )
    if config.norm == "batch":
        raise ValueError("the estimator reads frames and actions only: norm 'batch' is not supported")
    return config


def train(
    episodes: Episodes,
    window: int,
    frames_per_update: int,
    updates: int,
    seed: int,
    lr: float = 1e-3,
    config: NetworkConfig | None = None,
):
    """Fit the `quick` network's auxiliary head by truncated BPTT with a ``window``-step gradient horizon (module
    docstring); ``window`` 0: no memory, every step starts from the zero state (a one-frame estimator, run in
    windows of FRAME_ONLY_WINDOW). ``config``: the network (estimator_network() if None). Returns (params,
    [losses])."""
    config = config or estimator_network()
    frame_only, window = window == 0, window or FRAME_ONLY_WINDOW
    steps = episodes.obs.shape[1]
    if steps % window or frames_per_update % window or frames_per_update < window:
        raise ValueError(
            f"the window ({window} steps{' for window 0' if frame_only else ''}) must divide the episode "
            f"length ({steps}) and the frames per update ({frames_per_update}), at least one window"
        )
    batch = frames_per_update // window
    if batch > episodes.obs.shape[0]:
        raise ValueError(f"{batch} episodes per update, but only {episodes.obs.shape[0]} recorded")
    net, key = make_network(config), jax.random.PRNGKey(seed)
    key, k_init = jax.random.split(key)
    obs_shape = episodes.obs.shape[2:]
    params = net.init(
        k_init,
        jnp.zeros((1, 1, *obs_shape)),
        jnp.ones((1, 1), bool),
        initial_state(config, 1, obs_shape),
    )["params"]
    optimiser = optax.chain(optax.clip_by_global_norm(1.0), optax.adam(lr))
    opt_state, losses, chunks = optimiser.init(params), [], steps // window
    desc = "one frame" if frame_only else f"window {window}"
    for u in tqdm(range(updates), desc=desc, unit="update", mininterval=30):
        chunk = u % chunks
        if chunk == 0:  # a new batch of episodes, from their starts
            key, k_pick = jax.random.split(key)
            rows = jax.random.choice(k_pick, episodes.obs.shape[0], (batch,), replace=False)
            state = initial_state(config, batch, obs_shape)
        span = slice(chunk * window, (chunk + 1) * window)
        reset = jnp.zeros((batch, window), bool).at[:, 0].set(chunk == 0) | frame_only
        params, opt_state, state, loss = _update(
            net,
            optimiser,
            params,
            opt_state,
            state,
            episodes.obs[rows, span],
            reset,
            episodes.action[rows, span],
            episodes.label[rows, span],
            episodes.alive[rows, span],
        )
        losses.append(loss)  # kept on the device: no host sync per update
    return params, [float(x) for x in np.asarray(jnp.stack(losses))]


def estimate(
    params, episodes: Episodes, chunk: int = 100, frame_only: bool = False, config: NetworkConfig | None = None
) -> np.ndarray:
    """[E, T, 3] the network's estimate over whole episodes, its state carried from each episode's start (as acting
    carries it; ``frame_only``: the zero state at every step), run ``chunk`` steps per call."""
    config = config or estimator_network()
    net = make_network(config)
    count, steps = episodes.obs.shape[:2]
    state, out = initial_state(config, count, episodes.obs.shape[2:]), []
    run = jax.jit(functools.partial(_aux_pass, net))
    for start in range(0, steps, chunk):
        span = slice(start, start + chunk)
        reset = jnp.zeros((count, min(chunk, steps - start)), bool).at[:, 0].set(start == 0) | frame_only
        aux, state = run(params, episodes.obs[:, span], reset, state, episodes.action[:, span])
        out.append(np.asarray(aux))
    return np.concatenate(out, axis=1)


def visible_centroid(episodes: Episodes, camera: env_lib.CameraConfig, desired: np.ndarray = DESIRED) -> np.ndarray:
    """[E, T, 3] the error to the newest frame's visible-surface centroid (surface.visible_tracking_state's, from the
    recorded depth; NaN on a frame without the target)."""
    depth = jnp.asarray(episodes.obs[..., -1], jnp.float32) * camera.far  # [E, T, H, W] m / k
    centroid, count = jax.vmap(jax.vmap(lambda d: surface_centroid(d, camera)))(depth)
    centroid, count = np.asarray(centroid), np.asarray(count)
    return np.where(count[..., None] > 0, (centroid - desired) / desired[2], np.nan)


def errors_by_target(guess: np.ndarray, episodes: Episodes, names: tuple[str, ...], skip: int) -> dict:
    """{target: {'lateral', 'range', '3d'}}: mean errors in metres / k over live steps after ``skip``."""
    miss = (guess - np.asarray(episodes.label)) * DESIRED[2]  # stand-off distances -> m / k
    live = np.asarray(episodes.alive).copy()
    live[:, :skip] = False
    live &= ~np.isnan(miss).any(-1)
    table = {}
    for i, name in enumerate(names):
        m = live & (np.asarray(episodes.target) == i)[:, None]
        table[name] = {
            "lateral": float(np.linalg.norm(miss[..., :2], axis=-1)[m].mean()),
            "range": float(np.abs(miss[..., 2])[m].mean()),
            "3d": float(np.linalg.norm(miss, axis=-1)[m].mean()),
        }
    return table


def agent_rows(run_dirs: list[str], episodes: Episodes, names: tuple[str, ...], skip: int) -> dict:
    """{'agent RUN': errors_by_target} of each trained run's own auxiliary head (its policy params, fitted in
    training to the same label) on ``episodes``, fed their frames and actions as the estimators are."""
    rows = {}
    for run_dir in run_dirs:
        loaded = runs.load_policy(run_dir, log=lambda *_: None)
        network, obs_shape = loaded.config.network, tuple(loaded.config.env.obs_shape)
        if obs_shape != tuple(episodes.obs.shape[2:]) or network.aux_outputs != LABEL:
            raise ValueError(
                f"{run_dir}: its network must read {tuple(episodes.obs.shape[2:])} frames alone and "
                f"have a {LABEL}-entry aux head (got {obs_shape}, aux_outputs {network.aux_outputs})"
            )
        guess = estimate(loaded.params, episodes, config=network)
        rows[f"agent {runs.row_name(run_dir)}"] = errors_by_target(guess, episodes, names, skip)
    return rows


def print_errors(rows: dict, per_target: str, width: int = 28) -> None:
    """Print {row: errors_by_target} as the mean 3-D, lateral and range errors, then ``per_target``'s per target."""
    label = {"3d": "3-D"}.get(per_target, per_target)
    print(f"{'estimate':{width}s} {'3-D':>5s} {'lat':>5s} {'range':>5s}   {label} per target (m / k)")
    for name, table in rows.items():
        mean = {k: np.mean([t[k] for t in table.values()]) for k in ("3d", "lateral", "range")}
        print(
            f"{name:{width}s} {mean['3d']:5.2f} {mean['lateral']:5.2f} {mean['range']:5.2f}   "
            + " ".join(f"{t}:{v[per_target]:.2f}" for t, v in table.items())
        )


def write_results(args: argparse.Namespace, **parts) -> None:
    """Write {'command': the arguments, **parts} as JSON to args.out (nothing if it is None)."""
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps({"command": vars(args) | {"out": str(args.out)}, **parts}, indent=1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--windows",
        type=int,
        nargs="*",
        default=[20, 100],
        help="gradient horizons, one arm each; 0: one frame, no memory; none: only the other rows",
    )
    ap.add_argument("--updates", type=int, default=1500)
    ap.add_argument("--frames-per-update", type=int, default=1600)
    ap.add_argument("--train-episodes", type=int, default=16, help="per training target")
    ap.add_argument("--val-episodes", type=int, default=4, help="per evaluated target")
    ap.add_argument("--steps", type=int, default=1000, help="steps per recorded episode")
    ap.add_argument("--skip", type=int, default=100, help="steps left out of the error (the approach)")
    ap.add_argument(
        "--network",
        nargs="*",
        default=[],
        metavar="FIELD=VALUE",
        help="NetworkConfig fields over the quick preset's, e.g. kernels=(8,2,3) strides=(8,2,1)",
    )
    ap.add_argument("--train-targets", default="train", help="a split or names / MJCF files, as `ramavt eval` takes")
    ap.add_argument("--eval-targets", default="val", help="the targets of the evaluated episodes, likewise")
    ap.add_argument(
        "--agents",
        nargs="*",
        default=[],
        metavar="RUN",
        help="training run folders whose own auxiliary heads are scored on the same episodes",
    )
    ap.add_argument("--max-offset", type=float, default=1.0, help="m * k, the behaviour's largest centre error")
    ap.add_argument("--random-share", type=float, default=0.2, help="the behaviour's share of random actions")
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--seed", type=int, default=0, help="the recorded episodes' draw (and the fit's, by default)")
    ap.add_argument("--fit-seed", type=int, help="the fit's initialisation and batches alone: other fits, same data")
    ap.add_argument("--out", type=Path)
    args = ap.parse_args()
    if min(args.windows, default=0) < 0 or args.updates < 1 or args.skip >= args.steps:
        ap.error("--windows must be >= 0, --updates >= 1 and --skip < --steps")
    try:
        overrides = {k: ast.literal_eval(v) for k, v in (item.split("=", 1) for item in args.network)}
        config = estimator_network(overrides)
        train_names = rollouts.resolve_targets(args.train_targets)
        val_names = rollouts.resolve_targets(args.eval_targets)
    except (ValueError, SyntaxError, TypeError) as e:
        ap.error(f"--network / --train-targets: {e}")
    camera = env_lib.CameraConfig(resolution=args.resolution)
    key = jax.random.PRNGKey(args.seed)
    behave = {"max_offset": args.max_offset, "random_share": args.random_share}
    if args.windows:
        train_eps = collect(train_names, args.train_episodes, args.steps, jax.random.fold_in(key, 0), camera, **behave)
    val_eps = collect(val_names, args.val_episodes, args.steps, jax.random.fold_in(key, 1), camera, **behave)
    rows = {
        "desired point": errors_by_target(np.zeros(val_eps.label.shape), val_eps, val_names, args.skip),
        "visible centroid": errors_by_target(visible_centroid(val_eps, camera), val_eps, val_names, args.skip),
    }
    rows |= agent_rows(args.agents, val_eps, val_names, args.skip)
    curves = {}
    for window in args.windows:
        fit_seed = args.seed if args.fit_seed is None else args.fit_seed
        params, losses = train(train_eps, window, args.frames_per_update, args.updates, fit_seed, config=config)
        name = f"window {window}" if window else "one frame"
        guess = estimate(params, val_eps, frame_only=window == 0, config=config)
        rows[name] = errors_by_target(guess, val_eps, val_names, args.skip)
        curves[name] = losses
    print_errors(rows, "3d")
    write_results(args, errors=rows, losses=curves)


if __name__ == "__main__":
    main()
