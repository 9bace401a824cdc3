"""Running policies for whole episodes and summarising them (episode length / reward tables), the perturbation
settings of Table II and the target specs accepted by ``ramavt eval``."""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from ramavt_jax import env as env_lib
from ramavt_jax import targets as targets_lib
from ramavt_jax.baselines import Policy
from ramavt_jax.evaluation import statistics
from ramavt_jax.training import memory as memplan

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


@struct.dataclass
class EpisodeRecord:
    """Per-step arrays of one batch of episodes run side by side, [T, N] (or [T, N, 3])."""

    reward: jax.Array
    action: jax.Array
    terminated: jax.Array
    truncated: jax.Array
    alive: jax.Array  # the step belongs to the episode (False after it ended)
    rel_pos: jax.Array  # [T, N, 3] target centre in the camera frame after the step
    chaser_pos: jax.Array  # [T, N, 3] Hill frame
    target_pos: jax.Array  # [T, N, 3] Hill frame
    in_view: jax.Array


@struct.dataclass
class EpisodeStats:
    """One entry per episode, [N]."""

    length: jax.Array
    episode_return: jax.Array
    terminated: jax.Array  # ended by losing the target
    target_index: jax.Array
    truncated: jax.Array | None = None  # ended by reaching max_steps (None: unknown, taken as ~terminated)
    tracking: TrackingSums | None = None  # per-episode sums of the tracking error (None: not recorded)


@struct.dataclass
class TrackingSums:
    """Per-episode sums over the episode's steps, [N]. Distances are in stand-off units: metres for every catalogue
    target, metres / k for a target held at the scaled stand-off k (env.standoff_scale)."""

    error: jax.Array  # sum of |target centre - desired point| / k
    within_quarter: jax.Array  # steps with that distance <= 0.25
    within_half: jax.Array  # steps with that distance <= 0.5

    @staticmethod
    def zeros(n: int) -> TrackingSums:
        return TrackingSums(jnp.zeros(n), jnp.zeros(n, jnp.int32), jnp.zeros(n, jnp.int32))

    def add(self, tracking_error: jax.Array, scale: jax.Array, alive: jax.Array) -> TrackingSums:
        """Add one step: tracking_error [N, 3] (m, camera frame), scale [N], alive [N] bool (ended: nothing)."""
        distance = jnp.linalg.norm(tracking_error, axis=-1) / scale
        return TrackingSums(
            error=self.error + jnp.where(alive, distance, 0.0),
            within_quarter=self.within_quarter + (alive & (distance <= 0.25)),
            within_half=self.within_half + (alive & (distance <= 0.5)),
        )


def run_episodes(
    tracking_env: env_lib.TrackingEnv,
    policy: Policy,
    params: env_lib.EnvParams,
    key: jax.Array,
    num_episodes: int,
    num_steps: int | None = None,
    record: bool = False,
    policy_params=None,
) -> tuple[EpisodeStats, EpisodeRecord | None]:
    """Run `num_episodes` episodes in parallel (one per env, no auto-reset) for `num_steps` (default max_steps).

    Returns EpisodeStats [N] and, if `record`, the per-step EpisodeRecord [T, N]. Jit-compiled as one lax.scan.
    Episodes that do not fit in memory side by side run in batches that fly exactly the episodes of the unbatched
    run (each episode's keys are its slice of the keys of all ``N``), so results never depend on free memory.

    With ``policy_params`` (a pytree of arrays), ``policy`` is a function ``policy_params -> Policy`` (e.g.
    ``greedy.GreedyPolicyOf``) applied inside the compiled program: the parameters are an input of the program, not
    constants in it, so every parameter set of the same shapes (a run's checkpoints) reuses one compile.
    """
    steps = int(num_steps if num_steps is not None else np.asarray(params.max_steps))
    fn = _episode_runner(tracking_env, policy, steps, record)
    compiled = _compiled_runner(fn, params, key, num_episodes, num_episodes, policy_params)
    batch = episodes_that_fit(compiled, num_episodes)
    if batch >= num_episodes:
        return compiled(params, key, policy_params, 0)
    # too many episodes side by side for the memory: batches of equal size (one compile), and the rest (a second)
    starts = range(0, num_episodes, batch)
    parts = [
        jax.device_get(
            _compiled_runner(fn, params, key, min(batch, num_episodes - s), num_episodes, policy_params)(
                params, key, policy_params, s
            )
        )
        for s in starts
    ]
    stats = jax.tree.map(lambda *xs: np.concatenate(xs), *(p[0] for p in parts))
    rec = None if not record else jax.tree.map(lambda *xs: np.concatenate(xs, axis=1), *(p[1] for p in parts))
    return stats, rec


_COMPILED_RUNS: dict = {}  # (runner, episodes, total, argument types) -> the compiled runner


def _compiled_runner(fn, params, key, num_episodes: int, total: int | None = None, policy_params=None):
    """``fn`` (an :func:`_episode_runner`) compiled for ``num_episodes`` of ``total`` episodes (default: all) and the
    types of ``params``, ``key`` and ``policy_params``; called as ``compiled(params, key, policy_params, offset)``
    for the episodes from ``offset`` on. Compiled ahead of time so its memory is known before anything is allocated
    (:func:`episodes_that_fit`); cached, so repeated calls (targets, settings, checkpoints) do not trace again."""
    total = num_episodes if total is None else total
    args = (params, key, policy_params)
    types = (jax.tree.structure(args), tuple(jax.typeof(x) for x in jax.tree.leaves(args)))
    cache_key = (fn, num_episodes, total, types)
    if cache_key not in _COMPILED_RUNS:
        if len(_COMPILED_RUNS) >= 64:
            _COMPILED_RUNS.pop(next(iter(_COMPILED_RUNS)))
        _COMPILED_RUNS[cache_key] = fn.lower(*args, num_episodes, total, 0).compile()
    return _COMPILED_RUNS[cache_key]


def episodes_that_fit(compiled, num_episodes: int) -> int:
    """How many of ``num_episodes`` episodes can run side by side: all of them when ``compiled`` (their runner)
    fits in the memory available (or either is unknown), else as many as fit at the same bytes per episode.
    Raises MemoryPlanError when not even one fits."""
    try:
        stats = compiled.memory_analysis()
        need = int(stats.temp_size_in_bytes + stats.output_size_in_bytes + stats.argument_size_in_bytes)
    except Exception:  # noqa: BLE001 (not every backend reports it)
        return num_episodes
    avail = memplan.available_bytes()
    if avail is None or need <= memplan.FRACTION * avail:
        return num_episodes
    batch = int(memplan.FRACTION * avail * num_episodes // need)
    if batch < 1:
        memplan.check_fits(need // num_episodes, "one evaluation episode", "lower the camera resolution")
    return max(batch, 1)


def _episode_keys(key: jax.Array) -> jax.Array:
    """[3] keys of a set of episodes: resets, policy inits, steps (each split per episode)."""
    return jax.random.split(key, 3)


def episode_starts(
    tracking_env: env_lib.TrackingEnv, params: env_lib.EnvParams, key: jax.Array, num_episodes: int
) -> env_lib.EnvState:
    """The initial states [N] of the episodes :func:`run_episodes` flies for ``key``: no policy acts on them yet, so
    every policy's episodes start from these (for sorting episodes by how they start, say)."""
    keys = jax.random.split(_episode_keys(key)[0], num_episodes)
    return jax.vmap(tracking_env.reset, in_axes=(0, None))(keys, params)[1]


@functools.lru_cache(maxsize=32)
def _episode_runner(tracking_env, policy, steps, record):
    """Jitted runner. With `record` the whole horizon is one lax.scan; without, a lax.while_loop that stops as soon
    as every episode has ended (random agents lose the target within ~200 steps). Both draw the same per-step keys,
    so the same key gives the same episodes either way. Without ``policy_params`` (None) ``policy`` is a Policy,
    with them a function of them that returns one (run_episodes)."""

    def run(params, key, policy_params, num_episodes, total, offset):
        pol = policy if policy_params is None else policy(policy_params)

        def split(k):  # episodes offset .. offset + num_episodes of the keys of all `total` episodes
            return jax.lax.dynamic_slice_in_dim(jax.random.split(k, total), offset, num_episodes)

        k_reset, k_policy, k_loop = _episode_keys(key)
        obs, state = jax.vmap(tracking_env.reset, in_axes=(0, None))(split(k_reset), params)
        pstate = jax.vmap(pol.init)(split(k_policy))
        alive = jnp.ones(num_episodes, bool)
        zeros = jnp.zeros(num_episodes)
        step_keys = jax.random.split(k_loop, steps)

        def body(carry, step_key):
            obs, state, pstate, alive, length, ret, term, trunc, track = carry
            k_act, k_env = jax.random.split(step_key)
            act_keys = split(k_act)
            action, pstate = jax.vmap(pol.act, in_axes=(0, 0, 0, 0, None))(act_keys, pstate, obs, state, params)
            env_keys = split(k_env)
            obs, state, reward, terminated, truncated, info = jax.vmap(tracking_env.step_env, in_axes=(0, 0, 0, None))(
                env_keys, state, action, params
            )
            length = length + alive
            ret = ret + jnp.where(alive, reward, 0.0)
            term = term | (alive & terminated)
            trunc = trunc | (alive & truncated)
            track = track.add(info["tracking_error"], state.scale, alive)
            out = None
            if record:
                out = EpisodeRecord(
                    reward=reward,
                    action=action,
                    terminated=terminated,
                    truncated=truncated,
                    alive=alive,
                    rel_pos=info["rel_pos"],
                    chaser_pos=state.chaser_pos,
                    target_pos=state.target_pos,
                    in_view=info["in_view"],
                )
            alive = alive & ~(terminated | truncated)
            return (obs, state, pstate, alive, length, ret, term, trunc, track), out

        none = jnp.zeros(num_episodes, bool)
        init = (obs, state, pstate, alive, zeros.astype(jnp.int32), zeros, none, none, TrackingSums.zeros(num_episodes))
        if record:
            carry, rec = jax.lax.scan(body, init, step_keys)
        else:

            def cond(c):
                t, carry = c
                return (t < steps) & carry[3].any()

            def loop(c):
                t, carry = c
                return t + 1, body(carry, step_keys[t])[0]

            _, carry = jax.lax.while_loop(cond, loop, (jnp.zeros((), jnp.int32), init))
            rec = None
        _, state, _, _, length, ret, term, trunc, track = carry
        stats = EpisodeStats(
            length=length,
            episode_return=ret,
            terminated=term,
            target_index=state.target_index,
            truncated=trunc,
            tracking=track,
        )
        return stats, rec

    return jax.jit(run, static_argnums=(3, 4))


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


def summarise(stats: EpisodeStats) -> Summary:
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


def _tracking_columns(tracking: TrackingSums | None, length: np.ndarray, strata: np.ndarray) -> dict:
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


def concat_stats(stats: Sequence[EpisodeStats]) -> EpisodeStats:
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
        base, radius = targets_lib.sized_spec(item)  # a bad size: TargetError naming the range
        if radius is not None and base in targets_lib.SPLITS:
            members = targets_lib.split(base)
            if any(targets_lib.sized_spec(m)[1] is not None for m in members):
                raise targets_lib.TargetError(
                    f"target {item!r}: the split {base!r} holds resized models already; a size suffix goes on a "
                    f"split of models at their own sizes ({', '.join(s for s in targets_lib.SPLITS if s != base)})"
                )
            out.extend(targets_lib.sized_name(f"{m}@{radius:g}m") for m in members)
            continue
        try:
            targets_lib.resolve(item)
        except (ValueError, OSError) as e:
            splits = ", ".join(targets_lib.SPLITS)
            raise targets_lib.TargetError(f"{e} (the splits {splits} are accepted too)") from None
        out.append(targets_lib.sized_name(item))  # one spelling per size: one set of episodes
    return tuple(dict.fromkeys(out))  # keep order, drop repeats
