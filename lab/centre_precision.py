"""How precisely a tracker must know where the target's centre of mass is: the ceiling (the true-state look-ahead,
`mpc`) flown with a wrong centre, on the same episodes as with the right one.

    python lab/centre_precision.py --targets val --episodes 20 --offsets 0.05 0.1 0.2 0.3 \
        --out results/val/centre_precision.json

Arms, each told a centre other than the true one (the env still scores the true one):

- `offset S`: off by a fixed vector of S metres times the target's stand-off scale k (plain metres for every
  catalogue target), in a direction drawn per episode: an estimate with a constant error of that size.
- `visible`: the centroid of the visible surface in the newest frame (lab.surface.visible_tracking_state): holding the
  image's centre, with the centre's true velocity known (the planner's model moves the told point with the centre,
  so it cannot foresee the centroid wandering as the target turns). On a frame without the target the true centre
  is told (that function's fallback), which helps recovery: its lost share is a floor. `visible lateral` /
  `visible range` take only its offset across the image / along the boresight, the true centre on the other axes.

Every arm flies the episodes of `ramavt eval --targets T --episodes N --seed S` without perturbation (those of the
learning arms and the recorded ceiling), so they compare paired.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import jax.numpy as jnp

from lab.surface import visible_tracking_state
from ramavt_jax import baselines
from ramavt_jax import env as env_lib
from ramavt_jax.baselines import Policy
from ramavt_jax.evaluation import rollouts, tables
from ramavt_jax.imitation import true_tracking_state

VISIBLE_AXES = {"visible": (1.0, 1.0, 1.0), "visible lateral": (1.0, 1.0, 0.0), "visible range": (0.0, 0.0, 1.0)}


def told_centre(state: env_lib.EnvState, offset_cam: jax.Array) -> env_lib.EnvState:
    """The env state with the target's centre moved by ``offset_cam`` [3] m (camera frame): what the planner reads."""
    return state.replace(target_pos=state.target_pos + env_lib.HILL_FROM_CAM @ offset_cam)


def offset_ceiling(ceiling: Policy, size: float, random_size: bool = False, random_share: float = 0.0) -> Policy:
    """``ceiling`` told a centre ``size`` * k metres off the true one (``random_size``: a size uniform in [0, size]),
    in a direction drawn per episode; with a uniformly random action instead of its own on a share ``random_share``
    of the steps (lab/centre_estimator.py's behaviour)."""

    def init(key):
        if random_size:
            key, k_size = jax.random.split(key)
        direction = jax.random.normal(key, (3,))
        scale = jax.random.uniform(k_size, (), maxval=size) if random_size else size
        return scale * direction / jnp.linalg.norm(direction)

    def act(key, offset, obs, state, params):
        # four keys, none used twice; the coin and the random action keep the draws the recorded results were made
        # with (split(key, 4)[:3] is split(key, 3)), and the ceiling's own keys are inert in its noise-free model
        k_init, k_coin, k_random, k_act = jax.random.split(key, 4)
        action, _ = ceiling.act(k_act, ceiling.init(k_init), obs, told_centre(state, offset * state.scale), params)
        if random_share:
            random_action = jax.random.randint(k_random, (), 0, env_lib.NUM_ACTIONS)
            action = jnp.where(jax.random.uniform(k_coin) < random_share, random_action, action)
        return action, offset

    return Policy(f"offset {size}", init, act)


def visible_offset(
    state: env_lib.EnvState, params: env_lib.EnvParams, camera: env_lib.CameraConfig, axes: tuple[float, float, float]
) -> jax.Array:
    """[3] m, camera frame: the visible surface's centroid minus the centre, on the axes where ``axes`` is 1 (0 on the
    others, and on all of them when the frame shows no target: surface.visible_tracking_state's fallback)."""
    true = true_tracking_state(state, params)[:3]
    seen = visible_tracking_state(state, params, camera)[:3]
    return (seen - true) * params.desired_pos[2] * state.scale * jnp.asarray(axes, jnp.float32)  # stand-off -> m


def visible_ceiling(
    ceiling: Policy, camera: env_lib.CameraConfig, axes: tuple[float, float, float], name: str = "visible"
) -> Policy:
    """``ceiling`` told the visible surface's centroid (visible_offset) instead of the centre."""

    def act(key, pstate, obs, state, params):
        k_init, k_act = jax.random.split(key)
        told = told_centre(state, visible_offset(state, params, camera, axes))
        action, _ = ceiling.act(k_act, ceiling.init(k_init), obs, told, params)
        return action, pstate

    return Policy(name, lambda key: jnp.zeros(()), act)


def precision_table(
    targets: tuple[str, ...],
    episodes: int,
    offsets: list[float],
    seed: int = 0,
    resolution: int = 32,
    visible: bool = True,
    overrides: dict | None = None,
) -> dict:
    """{arm: {'aer': mean over targets, 'lost': share, 'per_target': {name: AER}}}; arm 'exact' is the ceiling.
    ``overrides``: EnvParams fields over the evaluation's (a shorter max_steps in tests)."""
    camera = env_lib.CameraConfig(resolution=resolution)
    config = env_lib.EnvConfig(camera=camera, targets=targets)
    ceiling = baselines.make_policy("mpc", camera)
    arms = {"exact": ceiling} | {f"offset {s:g}": offset_ceiling(ceiling, s) for s in offsets}
    if visible:
        arms |= {name: visible_ceiling(ceiling, camera, axes, name) for name, axes in VISIBLE_AXES.items()}
    overrides = dict(overrides or {})
    max_steps = int(overrides.pop("max_steps", 1000))
    tracking_env = tables.suite_env(config, targets, rollouts.PERTURBATION_VALUES)
    table = {}
    for name, policy in arms.items():
        result = tables.evaluate_setting(
            tracking_env,
            policy,
            overrides,
            episodes,
            max_steps,
            jax.random.PRNGKey(seed),
            "none",
            rollouts.PERTURBATION_VALUES,
        )
        table[name] = {
            "aer": float(result["overall"]["return_mean"]),
            "lost": float(result["overall"]["lost_fraction"]),
            "per_target": {t: float(s["return_mean"]) for t, s in result["per_target"].items()},
        }
    return table


def plot_precision(table: dict, marks: dict[str, float], path: Path) -> None:
    """The share of the exact ceiling's AER kept against the size of a fixed centre error (the 'offset S' rows of
    ``table``), with vertical ``marks`` {label: metres} (mean errors of estimates, which wander rather than stay
    fixed) and the 90 % line, written to ``path`` (PNG)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    exact = table["exact"]["aer"]
    sizes = sorted([0.0] + [float(name.split()[1]) for name in table if name.startswith("offset ")])
    kept = [1.0 if s == 0 else table[f"offset {s:g}"]["aer"] / exact for s in sizes]
    fig, ax = plt.subplots(figsize=(6.0, 3.6))
    ax.plot(sizes, kept, "o-", color="k", label="ceiling told a centre off by a fixed vector")
    ax.axhline(0.9, color="tab:red", lw=0.8, ls="--", label="90 % of the ceiling")
    for (label, metres), colour in zip(marks.items(), ("tab:blue", "tab:orange", "tab:green", "tab:purple")):
        ax.axvline(metres, color=colour, lw=1.0, label=f"{label}: {metres:.2f} m")
    ax.set_xlabel("centre error (m)")
    ax.set_ylabel("share of the ceiling's AER")
    ax.set_xlim(left=0.0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=120)
    plt.close(fig)


def _marks(items: list[str]) -> dict[str, float]:
    """'LABEL=METRES' strings -> {label: metres}; ValueError naming a bad one."""
    marks = {}
    for item in items:
        label, _, value = item.rpartition("=")
        try:
            marks[label] = float(value)
        except ValueError:
            raise ValueError(f"--mark {item!r}: expected LABEL=METRES") from None
        if not label:
            raise ValueError(f"--mark {item!r}: expected LABEL=METRES")
    return marks


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--targets", default="val", help="a split or catalogue names, as `ramavt eval --targets` takes")
    ap.add_argument("--episodes", type=int, default=20, help="episodes per target")
    ap.add_argument(
        "--offsets",
        type=float,
        nargs="*",
        default=[0.05, 0.1, 0.2, 0.3, 0.5],
        help="sizes of the fixed centre errors, metres / k",
    )
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--resolution", type=int, default=32)
    ap.add_argument("--out", type=Path, help="JSON file for the table")
    ap.add_argument("--table", type=Path, help="a JSON file written by --out: print (and plot) it, fly nothing")
    ap.add_argument("--plot", type=Path, help="PNG of the share kept against the centre error")
    ap.add_argument("--mark", nargs="*", default=[], metavar="LABEL=METRES", help="vertical lines on the plot")
    args = ap.parse_args()
    if args.episodes < 1 or any(s < 0 for s in args.offsets):
        ap.error("--episodes must be >= 1 and every --offsets value >= 0")
    try:
        marks = _marks(args.mark)
    except ValueError as e:
        ap.error(str(e))
    if args.table:
        table = json.loads(args.table.read_text())["table"]
        targets = tuple(table["exact"]["per_target"])
    else:
        targets = rollouts.resolve_targets(args.targets)
        table = precision_table(targets, args.episodes, args.offsets, args.seed, args.resolution)
    exact = table["exact"]["aer"]
    header = " ".join(f"{t[:14]:>14s}" for t in targets)
    print(f"{'centre told':16s} {'AER':>7s} {'of exact':>8s} {'lost':>5s}  {header}")
    for name, row in table.items():
        print(
            f"{name:16s} {row['aer']:7.1f} {row['aer'] / exact:8.0%} {row['lost']:5.1%}  "
            + " ".join(f"{row['per_target'][t]:14.1f}" for t in targets)
        )
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        command = {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}
        args.out.write_text(json.dumps({"command": command, "table": table}, indent=1))
    if args.plot:
        plot_precision(table, marks, args.plot)


if __name__ == "__main__":
    main()
