"""Running policies for whole episodes and summarising them (episode length / reward tables), the EnvParams fields
evaluation sets, the perturbation settings of Table II and the target specs accepted by ``ramavt eval``.

The compiled program that flies the episodes, and the per-step and per-episode arrays it returns, are in
:mod:`ramavt_jax.evaluation.episode_program`."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import jax
import numpy as np

from ramavt_jax import env as env_lib
from ramavt_jax import targets as targets_lib
from ramavt_jax.baselines import Policy
from ramavt_jax.evaluation import episode_program, statistics
from ramavt_jax.targets import specs

# EnvParams fields whose evaluation values (env.eval_params) replace a run's training values: each target at its own
# size and shape, one speed rule for every row of a table, Table II's perturbations as the flown setting says, and
# the benchmark's start distribution (a run may train on wider starts for practice; every row flies the same ones)
EVAL_FIELDS = (
    "dist_weight",
    "lost_patience",
    "size_scale_min",
    "size_scale_max",
    "size_scale_prob",
    "stretch_max",
    "stretch_prob",
    "offset_max",
    "offset_prob",
    "speed_standoff_power",
    "small_standoff_power",
    "actuator_noise",
    "delay_max",
    "blur_frames",
    "perturb_prob",
    "init_xy_std",
    "init_z_min",
    "init_z_max",
)


def run_env_overrides(env_params) -> dict:
    """A training run's EnvParams overrides (TrainConfig.env_params) that also hold in evaluation: all but the
    EVAL_FIELDS, which evaluation sets to the reported-table values."""
    return {k: v for k, v in dict(env_params).items() if k not in EVAL_FIELDS}


def run_episodes(
    tracking_env: env_lib.TrackingEnv,
    policy: Policy,
    params: env_lib.EnvParams,
    key: jax.Array,
    num_episodes: int,
    num_steps: int | None = None,
    record: bool = False,
    policy_params=None,
) -> tuple[episode_program.EpisodeStats, episode_program.EpisodeRecord | None]:
    """Run `num_episodes` episodes in parallel (one per env, no auto-reset) for `num_steps` (default max_steps).

    Returns EpisodeStats [N] and, if `record`, the per-step EpisodeRecord [T, N]. Jit-compiled as one lax.scan.
    Episodes that do not fit in memory side by side run in batches that fly exactly the episodes of the unbatched
    run (each episode's keys are its slice of the keys of all ``N``), so results never depend on free memory.

    With ``policy_params`` (a pytree of arrays), ``policy`` is a function ``policy_params -> Policy`` (e.g.
    ``greedy.GreedyPolicyOf``) applied inside the compiled program: the parameters are an input of the program, not
    constants in it, so every parameter set of the same shapes (a run's checkpoints) reuses one compile.
    """
    steps = int(num_steps if num_steps is not None else np.asarray(params.max_steps))
    fn = episode_program.episode_runner(tracking_env, policy, steps, record)
    compiled = episode_program.compiled_runner(fn, params, key, num_episodes, num_episodes, policy_params)
    batch = episode_program.episodes_that_fit(compiled, num_episodes)
    if batch >= num_episodes:
        return compiled(params, key, policy_params, 0)
    # too many episodes side by side for the memory: batches of equal size (one compile), and the rest (a second)
    starts = range(0, num_episodes, batch)
    parts = [
        jax.device_get(
            episode_program.compiled_runner(fn, params, key, min(batch, num_episodes - s), num_episodes, policy_params)(
                params, key, policy_params, s
            )
        )
        for s in starts
    ]
    stats = jax.tree.map(lambda *xs: np.concatenate(xs), *(p[0] for p in parts))
    rec = None if not record else jax.tree.map(lambda *xs: np.concatenate(xs, axis=1), *(p[1] for p in parts))
    return stats, rec


def episode_starts(
    tracking_env: env_lib.TrackingEnv, params: env_lib.EnvParams, key: jax.Array, num_episodes: int
) -> env_lib.EnvState:
    """The initial states [N] of the episodes :func:`run_episodes` flies for ``key``: no policy acts on them yet, so
    every policy's episodes start from these (for sorting episodes by how they start, say)."""
    keys = jax.random.split(episode_program.episode_keys(key)[0], num_episodes)
    return jax.vmap(tracking_env.reset, in_axes=(0, None))(keys, params)[1]


@dataclasses.dataclass(frozen=True)
class Summary:
    """Table I columns for one set of episodes."""

    episodes: int
    length_mean: float
    length_min: float
    length_max: float
    return_mean: float
    return_min: float
    return_max: float
    lost_fraction: float  # ended by losing the target
    truncated_fraction: float = float("nan")  # tracked until max_steps
    length_std: float = float("nan")  # sample standard deviation (ddof 1)
    return_std: float = float("nan")
    # 95 % bootstrap intervals of the means, episodes resampled within each target (statistics.bootstrap_ci)
    length_ci_low: float = float("nan")
    length_ci_high: float = float("nan")
    return_ci_low: float = float("nan")
    return_ci_high: float = float("nan")
    # Tracking error in stand-off units (metres for catalogue targets), each episode's mean over its steps, then
    # the mean over episodes (NaN: not recorded); the within fractions likewise, of each episode's steps.
    error_mean: float = float("nan")
    error_ci_low: float = float("nan")
    error_ci_high: float = float("nan")
    within_quarter_fraction: float = float("nan")  # steps within 0.25 of the desired point
    within_half_fraction: float = float("nan")  # steps within 0.5

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def summarise(stats: episode_program.EpisodeStats) -> Summary:
    """Table I columns (mean / min / max of episode length and return) plus how the episodes ended.

    An episode that was neither lost nor truncated (run for fewer steps than max_steps) counts in neither fraction.
    """
    length = np.asarray(stats.length, dtype=np.float64).reshape(-1)
    ret = np.asarray(stats.episode_return, dtype=np.float64).reshape(-1)
    lost = np.asarray(stats.terminated, bool).reshape(-1)
    trunc = ~lost if stats.truncated is None else np.asarray(stats.truncated, bool).reshape(-1)
    if length.size == 0:
        raise ValueError("summarise: no episodes")
    strata = np.asarray(stats.target_index).reshape(-1)
    return Summary(
        episodes=int(length.size),
        length_mean=float(length.mean()),
        length_min=float(length.min()),
        length_max=float(length.max()),
        return_mean=float(ret.mean()),
        return_min=float(ret.min()),
        return_max=float(ret.max()),
        lost_fraction=float(lost.mean()),
        truncated_fraction=float(trunc.mean()),
        length_std=statistics.sample_std(length),
        return_std=statistics.sample_std(ret),
        **_intervals("length", length, strata),
        **_intervals("return", ret, strata),
        **_tracking_columns(stats.tracking, length, strata),
    )


def _intervals(name: str, values: np.ndarray, strata: np.ndarray) -> dict:
    """{name_ci_low, name_ci_high}: the 95 % stratified bootstrap interval of the mean of `values` [N]."""
    low, high = statistics.bootstrap_ci(values, strata)
    return {f"{name}_ci_low": low, f"{name}_ci_high": high}


def _tracking_columns(tracking: episode_program.TrackingSums | None, length: np.ndarray, strata: np.ndarray) -> dict:
    """Summary's tracking-error fields from the per-episode sums (empty without them: the fields stay NaN)."""
    if tracking is None:
        return {}
    steps = np.maximum(length, 1)  # an episode has at least one step; guards a zero-step run
    error = np.asarray(tracking.error, np.float64).reshape(-1) / steps
    quarter = np.asarray(tracking.within_quarter, np.float64).reshape(-1) / steps
    half = np.asarray(tracking.within_half, np.float64).reshape(-1) / steps
    return {
        "error_mean": float(error.mean()),
        **_intervals("error", error, strata),
        "within_quarter_fraction": float(quarter.mean()),
        "within_half_fraction": float(half.mean()),
    }


def concat_stats(stats: Sequence[episode_program.EpisodeStats]) -> episode_program.EpisodeStats:
    """Join the episodes of several runs (e.g. one per target) into one EpisodeStats."""
    stats = list(stats)
    if any(s.truncated is None for s in stats):
        stats = [s.replace(truncated=None) for s in stats]
    if any(s.tracking is None for s in stats):
        stats = [s.replace(tracking=None) for s in stats]
    return jax.tree.map(lambda *xs: np.concatenate([np.asarray(x).reshape(-1) for x in xs]), *stats)


def evaluate_per_target(
    config: env_lib.EnvConfig,
    policy: Policy,
    key: jax.Array,
    episodes_per_target: int,
    params_overrides: dict | None = None,
    eval_settings: bool = True,
) -> dict[str, Summary]:
    """Summary per target of `config.targets`; one compiled program serves all targets (the target is pinned by
    `EnvParams.target_probs`, a traced value)."""
    tracking_env = env_lib.TrackingEnv(config)
    make = tracking_env.eval_params if eval_settings else tracking_env.default_params
    params = make(**(params_overrides or {}))
    results = {}
    for i, name in enumerate(config.targets):
        stats, _ = run_episodes(
            tracking_env, policy, tracking_env.pinned(params, i), jax.random.fold_in(key, i), episodes_per_target
        )
        results[name] = summarise(stats)
    return results


# ============================================================================================ perturbations
# Table II of the paper; the original benchmark's values: command * (1 + 0.3 N(0, 1)), step duration dt + U(0, 0.5) s,
# observation = mean of the last 3 frames (the paper gives no frame count; 3 is our choice).
PERTURBATION_VALUES = {"actuator_noise": 0.3, "delay_max": 0.5, "blur_frames": 3}
PERTURBATIONS: dict[str, tuple[str, ...]] = {
    "actuator_noise": ("actuator_noise",),
    "time_delay": ("delay_max",),
    "blur": ("blur_frames",),
    "all": ("actuator_noise", "delay_max", "blur_frames"),
    "none": (),
}


def perturbation_overrides(name: str, values: dict | None = None) -> dict:
    """EnvParams overrides of one Table II setting ('actuator_noise' | 'time_delay' | 'blur' | 'all' | 'none')."""
    if name not in PERTURBATIONS:
        raise ValueError(f"unknown perturbation setting {name!r}; choose one of {list(PERTURBATIONS)}")
    values = {**PERTURBATION_VALUES, **(values or {})}
    return {field: values[field] for field in PERTURBATIONS[name]}


# ============================================================================================ targets
def resolve_targets(spec: str | Sequence[str]) -> tuple[str, ...]:
    """A split (targets_lib.SPLITS: 'test', 'val', 'val-sizes', ...) | comma-separated catalogue names and/or MJCF
    file paths, each with an optional size suffix ``@<radius>m`` (``Satellite-v2@0.3m``); a split of models at their
    own sizes takes one too (``val@0.3m``: each of its models at that size).

    Raises ValueError naming the entry that is neither a catalogue name nor a readable MJCF file, or has a bad size."""
    items = [s.strip() for s in spec.split(",")] if isinstance(spec, str) else [str(s).strip() for s in spec]
    items = [s for s in items if s]
    if not items:
        raise ValueError(
            f"no targets given: use a split ({', '.join(targets_lib.SPLITS)}) or comma-separated names / MJCF files"
        )
    out: list[str] = []
    for item in items:
        if item in targets_lib.SPLITS:
            out.extend(targets_lib.split(item))
            continue
        base, radius = specs.sized_spec(item)  # a bad size: TargetError naming the range
        if radius is not None and base in targets_lib.SPLITS:
            members = targets_lib.split(base)
            if any(specs.sized_spec(m)[1] is not None for m in members):
                raise targets_lib.TargetError(
                    f"target {item!r}: the split {base!r} holds resized models already; a size suffix goes on a "
                    f"split of models at their own sizes ({', '.join(s for s in targets_lib.SPLITS if s != base)})"
                )
            out.extend(specs.sized_name(f"{m}@{radius:g}m") for m in members)
            continue
        try:
            targets_lib.resolve(item)
        except (ValueError, OSError) as e:
            splits = ", ".join(targets_lib.SPLITS)
            raise targets_lib.TargetError(f"{e} (the splits {splits} are accepted too)") from None
        out.append(specs.sized_name(item))  # one spelling per size: one set of episodes
    return tuple(dict.fromkeys(out))  # keep order, drop repeats
