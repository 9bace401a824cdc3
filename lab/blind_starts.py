"""How often a policy loses episodes that start with the target out of view (a blank first image), against those
that start in view: the share of the lost episodes a search behaviour could save.

    python lab/blind_starts.py runs/size_margin/seed_{0..4} --targets val-sizes --episodes 400 \
        --out results/val/blind_starts/size_margin.json

About 4 % of the reset distribution's episodes start out of view (x, y ~ N(0, 1) k against z ~ U[2, 12) k and a
60-degree view), and an image policy cannot tell from its blank first image where the target is. Every policy
flies the same episodes (those of `ramavt eval --targets ... --episodes N --seed S` with no perturbation), so arms
compare paired. "Starts out of view" is read at the reset, before any action: the same set for every policy. The
interval is a 95 % bootstrap over the blind-start episodes, each scored by the share of the policies (seeds) that
lose it.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import jax
import numpy as np

from lab.lost_episodes import load
from ramavt_jax import env as env_lib
from ramavt_jax import greedy, imitation
from ramavt_jax.evaluation import rollouts, statistics, tables

SEARCH_STEPS = 20  # the evaluation's lost patience: a blind start still unseen after these steps is lost


def fly(
    spec: str, names: tuple[str, ...], episodes: int, seed: int, resolution: int, search: str = "learned"
) -> dict[str, dict]:
    """Per target: 'blind' [N] bool (out of view at the reset, before any action), 'lost' [N] bool (terminated),
    and over the first SEARCH_STEPS steps 'action' [S, N] int and 'unseen' [S, N] bool (the step's action was chosen
    with the target not yet in view at the reset or after any earlier step) of one policy."""
    policy, env_config, run_overrides = load(spec, resolution, names, search)
    tracking_env = env_lib.TrackingEnv(env_config)
    params = tracking_env.eval_params(**run_overrides)
    root, out = jax.random.PRNGKey(seed), {}
    for index, name in enumerate(names):
        pinned, key = tracking_env.pinned(params, index), tables.episode_key(root, "none", name)
        starts = rollouts.episode_starts(tracking_env, pinned, key, episodes)
        blind = np.asarray(imitation.unseen_yet(starts, env_config.camera))  # at the reset: out of view
        stats, rec = jax.device_get(rollouts.run_episodes(tracking_env, policy, pinned, key, episodes, record=True))
        first = jax.tree.map(lambda x: np.asarray(x)[:SEARCH_STEPS], rec)  # [S, N, ...]
        shown = np.cumsum(first.in_view, axis=0) > 0  # [S, N] in view after this step or an earlier
        unseen = blind & ~np.concatenate([np.zeros_like(shown[:1]), shown[:-1]])  # [S, N]
        out[name] = {
            "blind": blind,
            "lost": np.asarray(stats.terminated),
            "action": first.action,
            "unseen": unseen & first.alive,
        }
    return out


def summarise(flown: list[dict[str, dict]], names: tuple[str, ...]) -> dict:
    """Counts per target and policy, and the share of blind starts lost over all policies with its interval."""
    blind = np.concatenate([flown[0][n]["blind"] for n in names])  # [E] the same episodes for every policy
    lost = np.stack([np.concatenate([f[n]["lost"] for n in names]) for f in flown])  # [P, E]
    share = lost[:, blind].mean(0)  # [blind episodes] share of the policies that lose each
    low, high = statistics.bootstrap_ci(share)  # NaNs under two blind starts
    per_target = {
        n: {
            "blind_starts": int(flown[0][n]["blind"].sum()),
            "blind_lost": [int((f[n]["lost"] & f[n]["blind"]).sum()) for f in flown],
            "seen_lost": [int((f[n]["lost"] & ~f[n]["blind"]).sum()) for f in flown],
        }
        for n in names
    }
    return {
        "episodes": int(blind.size),
        "blind_starts": int(blind.sum()),
        "blind_lost_share": float(share.mean()) if share.size else float("nan"),
        "ci95": [low, high],
        "blind_lost_per_policy": [int(x) for x in lost[:, blind].sum(1)],
        "seen_lost_per_policy": [int(x) for x in lost[:, ~blind].sum(1)],
        "per_target": per_target,
        "blind_episodes": np.flatnonzero(blind).tolist(),  # indices into the targets' episodes, in order
        "lost_episodes_per_policy": [np.flatnonzero(row).tolist() for row in lost],
        # how each policy searches: its commands (env_config.ACTIONS rows) while the target is not yet in view
        "actions_before_first_sight_per_policy": [
            np.bincount(
                np.concatenate([f[n]["action"][f[n]["unseen"]] for n in names]).astype(int),
                minlength=env_lib.NUM_ACTIONS,
            ).tolist()
            for f in flown
        ],
    }


def lost_shares(record: dict) -> np.ndarray:
    """[E] for each episode of a written record, the share of its policies that lose it."""
    lost = np.zeros((len(record["lost_episodes_per_policy"]), record["episodes"]))
    for row, episodes in zip(lost, record["lost_episodes_per_policy"]):
        row[episodes] = 1.0
    return lost.mean(0)


def same_episodes(*records: dict) -> None:
    """Exit with a one-line message unless every record flew the same episodes."""
    same = ("targets", "episodes_per_target", "seed")
    if any(r[k] != records[0][k] for r in records for k in same):
        raise SystemExit(f"the records flew different episodes: {[[r[k] for k in same] for r in records]}")


PER_POLICY = (
    "policies",
    "blind_lost_per_policy",
    "seen_lost_per_policy",
    "lost_episodes_per_policy",
    "actions_before_first_sight_per_policy",
)


def merge(records: list[dict]) -> dict:
    """One record of the policies of several records of the same episodes (say seeds 0-4 and 5-9 of an arm), its
    share of blind starts lost and interval over all of them, as if they had been flown in one command."""
    same_episodes(*records)
    merged = {**records[0], **{k: [x for r in records for x in r[k]] for k in PER_POLICY}}
    merged["per_target"] = {
        name: {
            **target,
            **{k: [x for r in records for x in r["per_target"][name][k]] for k in ("blind_lost", "seen_lost")},
        }
        for name, target in records[0]["per_target"].items()
    }
    share = lost_shares(merged)[np.asarray(merged["blind_episodes"], int)]
    merged["blind_lost_share"], merged["ci95"] = float(share.mean()), list(statistics.bootstrap_ci(share))
    return merged


def compare(before: dict, after: dict) -> dict:
    """Paired change from ``before`` to ``after`` (records of the same episodes) in the share of episodes lost, over
    the blind starts and over all episodes: mean difference (after - before) with its 95 % bootstrap interval."""
    same_episodes(before, after)
    diff, blind = lost_shares(after) - lost_shares(before), np.asarray(before["blind_episodes"], int)
    return {
        name: {
            "before": float(lost_shares(before)[idx].mean()),
            "after": float(lost_shares(after)[idx].mean()),
            "difference": float(diff[idx].mean()),
            "ci95": list(statistics.bootstrap_ci(diff[idx])),
        }
        for name, idx in (("blind_starts", blind), ("all_episodes", np.arange(diff.size)))
    }


def fly_all(args, ap) -> dict:
    """The record of the command line's policies, each flown on the same episodes."""
    if args.episodes < 1:
        ap.error(f"--episodes must be >= 1, got {args.episodes}")
    names = rollouts.resolve_targets(args.targets)
    flown = []
    for spec in args.policies:
        flown.append(fly(spec, names, args.episodes, args.seed, args.resolution, args.blind_search))
        print(
            f"{spec}: {sum(int((f['lost'] & f['blind']).sum()) for f in flown[-1].values())} blind starts lost, "
            f"{sum(int((f['lost'] & ~f['blind']).sum()) for f in flown[-1].values())} others",
            flush=True,
        )
    return {
        "policies": args.policies,
        "targets": list(names),
        "episodes_per_target": args.episodes,
        "seed": args.seed,
        "blind_search": args.blind_search,
        **summarise(flown, names),
    }


def report(summary: dict) -> None:
    low, high = summary["ci95"]
    print(
        f"{summary['blind_starts']} of {summary['episodes']} episodes start out of view; lost: "
        f"{100 * summary['blind_lost_share']:.1f} % [{100 * low:.1f}, {100 * high:.1f}] of them "
        f"(per policy {summary['blind_lost_per_policy']}); other episodes lost per policy "
        f"{summary['seen_lost_per_policy']}; commands before first sight (actions 0-10) per policy "
        f"{summary['actions_before_first_sight_per_policy']}"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("policies", nargs="*", help="run folders (the seeds of one arm) or a baseline: depth | mpc")
    ap.add_argument(
        "--compare",
        nargs=2,
        type=Path,
        metavar=("BEFORE", "AFTER"),
        help="two written records of the same episodes: the paired change in the share lost, no flying",
    )
    ap.add_argument(
        "--merge",
        nargs="+",
        type=Path,
        metavar="RECORD",
        help="written records of the same episodes (more seeds of one arm) as one record, to --out",
    )
    ap.add_argument("--targets", default="val-sizes", help="a split or comma-separated catalogue names / MJCF files")
    ap.add_argument("--episodes", type=int, default=400, help="episodes per target")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--resolution", type=int, default=32, help="a baseline's camera (a trained policy uses its own)")
    ap.add_argument(
        "--blind-search",
        choices=greedy.BLIND_SEARCHES,
        default="learned",
        help="what a trained policy commands until the target is first in view (greedy.greedy_policy)",
    )
    ap.add_argument("--out", type=Path, default=None, help="JSON file to write")
    args = ap.parse_args()
    if args.compare:
        change = compare(*(json.loads(p.read_text()) for p in args.compare))
        for name, c in change.items():
            print(
                f"{name}: lost {100 * c['before']:.2f} % -> {100 * c['after']:.2f} %, change "
                f"{100 * c['difference']:+.2f} [{100 * c['ci95'][0]:+.2f}, {100 * c['ci95'][1]:+.2f}] points"
            )
        return
    if args.merge:
        record = merge([json.loads(p.read_text()) for p in args.merge])
    elif not args.policies:
        ap.error("give the policies to fly, --compare BEFORE AFTER or --merge RECORD ...")
    else:
        record = fly_all(args, ap)
    report(record)
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(record, indent=1) + "\n")


if __name__ == "__main__":
    main()
