"""The paper's evaluation tables, run: a set of policies over targets and perturbation settings, as a JSON-able
result (:func:`run_suite`), with each policy's control-loop speed. :mod:`ramavt_jax.evaluation.report` renders the
result as Markdown and writes it (tables.md, results.json).

Table I   one row per (policy, input mode): average / min / max episode length and reward, lost fraction, speed (Hz).
Table II  the perturbation suite per policy: actuator noise, time delay, image blur, all three, none.
Table III the ablation: one row per trained run folder (AEL, AER, speed), baselines for reference.

Every policy sees the same episodes: the key of (setting, target) does not depend on the policy (common random
numbers), so differences between rows are not reset luck. It depends only on the seed, the setting's name and the
target's name (episode_key), never on which other settings, targets or policies were requested.

Beside AEL / AER every table reports the tracking error (distance of the target centre from the desired point, in
stand-off units: metres for catalogue targets), the fractions of steps within 0.25 and 0.5 of it, the lost
fraction and each row's AER as a fraction of the mpc ceiling's on the same episodes (when an mpc row is present).
"""

from __future__ import annotations

import dataclasses
import os
import platform
import time
import zlib
from collections.abc import Callable

import jax

from ramavt_jax import env as env_lib
from ramavt_jax.baselines import Policy
from ramavt_jax.evaluation import rollouts


@dataclasses.dataclass
class Entry:
    """One evaluated policy in one input mode."""

    name: str
    kind: str  # 'baseline' | 'checkpoint'
    policy: Policy
    env_config: env_lib.EnvConfig
    env_overrides: dict = dataclasses.field(default_factory=dict)  # EnvParams overrides (a run's training values)
    input_label: str = ""  # what the Input column shows
    info: dict = dataclasses.field(default_factory=dict)


def stable_hash(name: str) -> int:
    """A hash of `name` that is the same in every process and release (Python's hash() is salted per process)."""
    return zlib.crc32(name.encode("utf-8"))


def episode_key(root: jax.Array, setting: str, target: str) -> jax.Array:
    """The key of a (setting, target)'s episodes: a function of the seed's key and the two names only."""
    return jax.random.fold_in(jax.random.fold_in(root, stable_hash(setting)), stable_hash(target))


def settings_for(tables: tuple[int, ...], only: tuple[str, ...] = ()) -> list[str]:
    """The perturbation settings flown for ``tables``: all of rollouts.PERTURBATIONS with Table II, else 'none';
    ``only`` (with Table II) keeps those of them, and 'none', which Tables I and III and every fraction need."""
    if not only:
        return list(rollouts.PERTURBATIONS) if 2 in tables else ["none"]
    unknown = [s for s in only if s not in rollouts.PERTURBATIONS]
    if unknown or 2 not in tables:
        raise ValueError(
            f"settings {' '.join(only)}: each must be one of {', '.join(rollouts.PERTURBATIONS)}, with Table II"
        )
    return [s for s in rollouts.PERTURBATIONS if s == "none" or s in only]


def suite_env(env_config: env_lib.EnvConfig, targets: tuple[str, ...], values: dict) -> env_lib.TrackingEnv:
    """The env of an entry's episodes: its config on ``targets``, with the frame history of the blur setting in every
    setting (``values``: the perturbation values), so one env, and one compile, serves every setting."""
    history = max(env_config.frame_history, int(values["blur_frames"]))
    return env_lib.TrackingEnv(dataclasses.replace(env_config, targets=tuple(targets), frame_history=history))


def evaluate_setting(
    tracking_env: env_lib.TrackingEnv,
    policy,
    env_overrides: dict,
    episodes: int,
    max_steps: int,
    root: jax.Array,
    setting: str,
    values: dict,
    policy_params=None,
) -> dict:
    """{'overall': Summary dict, 'per_target': {target: Summary dict}} of ``policy`` in one setting: ``episodes`` per
    target of ``tracking_env`` (a :func:`suite_env`), those of ``episode_key(root, setting, target)``. With
    ``policy_params``, ``policy`` is a function of them (rollouts.run_episodes)."""
    params = tracking_env.eval_params(
        **{**env_overrides, "max_steps": max_steps, **rollouts.perturbation_overrides(setting, values)}
    )
    per_target, all_stats = {}, []
    for i, target in enumerate(tracking_env.config.targets):
        key = episode_key(root, setting, target)  # same episodes for every policy and request
        stats, _ = rollouts.run_episodes(
            tracking_env, policy, tracking_env.pinned(params, i), key, episodes, policy_params=policy_params
        )
        stats = jax.device_get(stats)
        all_stats.append(stats)
        per_target[target] = rollouts.summarise(stats).as_dict()
    return {"overall": rollouts.summarise(rollouts.concat_stats(all_stats)).as_dict(), "per_target": per_target}


def recorded_eval_params(params: env_lib.EnvParams) -> dict:
    """The evaluation fields of the task a table flies (results.json settings.eval_params), as Python floats."""
    return {name: float(getattr(params, name)) for name in rollouts.EVAL_FIELDS}


def run_suite(
    entries: list[Entry],
    targets: tuple[str, ...],
    episodes: int,
    max_steps: int,
    seed: int,
    tables: tuple[int, ...] = (1, 2, 3),
    perturbation_values: dict | None = None,
    speed_steps: int = 200,
    log: Callable[[str], None] = print,
    only_settings: tuple[str, ...] = (),
) -> dict:
    """Evaluate every entry on every target (vmapped episodes) for each needed setting (`settings_for`). Returns a
    JSON-able dict."""
    values = {**rollouts.PERTURBATION_VALUES, **(perturbation_values or {})}
    settings = settings_for(tables, only_settings)
    root = jax.random.PRNGKey(seed)
    results, task = [], None
    for entry in entries:
        t_entry = time.time()
        tracking_env = suite_env(entry.env_config, targets, values)
        config = tracking_env.config
        params = tracking_env.eval_params(**entry.env_overrides, max_steps=max_steps)
        entry_task = recorded_eval_params(params)
        if task not in (None, entry_task):  # every row of a table flies the same task
            raise ValueError(f"{entry.name} is evaluated with {entry_task}, the rows before it with {task}")
        task = entry_task
        row = {
            "name": entry.name,
            "kind": entry.kind,
            "input": entry.input_label or config.obs_mode,
            "obs_mode": config.obs_mode,
            "resolution": config.camera.resolution,
            "dynamics": config.dynamics,
            "info": entry.info,
            "settings": {},
        }
        log(
            f"{entry.name} ({row['input']}): {len(settings)} setting(s) x {len(targets)} target(s) x {episodes} "
            f"episodes, up to {max_steps} steps ..."
        )
        for setting in settings:
            t0 = time.time()
            res = evaluate_setting(
                tracking_env, entry.policy, entry.env_overrides, episodes, max_steps, root, setting, values
            )
            overall = res["overall"]
            row["settings"][setting] = {**res, "wall_s": time.time() - t0}
            log(
                f"{entry.name:<22} {row['input']:<6} {setting:<15} AEL {overall['length_mean']:7.1f} "
                f"AER {overall['return_mean']:9.1f} lost {overall['lost_fraction']:.2f} ({time.time() - t0:.0f} s)"
            )
        row["speed_hz"] = None
        if speed_steps > 0:
            row["speed_hz"] = measure_speed(
                tracking_env, entry.policy, tracking_env.pinned(params, 0), jax.random.fold_in(root, 99), speed_steps
            )
            log(f"{entry.name:<22} {row['input']:<6} speed {row['speed_hz']:.1f} Hz (single env, {speed_steps} steps)")
        row["wall_s"] = time.time() - t_entry
        results.append(row)
    add_ceiling_fractions(results)
    return {
        "settings": {
            "seed": seed,
            "episodes_per_target": episodes,
            "targets": list(targets),
            "max_steps": max_steps,
            "eval_params": task or {},
            "perturbation_values": values,
            "perturbation_settings": settings,
            "tables": list(tables),
            "speed_steps": speed_steps,
        },
        "machine": machine_info(),
        "rows": results,
    }


def add_ceiling_fractions(rows: list[dict]) -> None:
    """Add 'ceiling_fraction' (AER / the mpc ceiling's AER on the same episodes) to every summary of every row, in
    place, overall and per target; None where no mpc row ran that setting. The first mpc row is the ceiling."""
    ceiling = next((r for r in rows if r.get("info", {}).get("variant") == "mpc"), None)
    for row in rows:
        for setting, res in row["settings"].items():
            ref = ceiling["settings"].get(setting) if ceiling is not None else None
            pairs = [(res["overall"], ref and ref["overall"])]
            pairs += [(o, ref and ref["per_target"].get(t)) for t, o in res["per_target"].items()]
            for summary, top in pairs:
                summary["ceiling_fraction"] = _fraction(summary["return_mean"], top)


def _fraction(value: float, ceiling: dict | None) -> float | None:
    if ceiling is None or not ceiling["return_mean"] > 0:  # a fraction of a non-positive ceiling reads backwards
        return None
    return float(value / ceiling["return_mean"])


def machine_info() -> dict:
    return {
        "platform": platform.platform(),
        "processor": platform.processor() or platform.machine(),
        "cpu_count": os.cpu_count(),
        "jax": jax.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "load_average": list(os.getloadavg()) if hasattr(os, "getloadavg") else None,
    }


# ============================================================================================ speed
def measure_speed(
    tracking_env: env_lib.TrackingEnv, policy: Policy, params: env_lib.EnvParams, key: jax.Array, steps: int = 200
) -> float:
    """Control-loop rate in Hz of one env: policy.act + env.step as one jitted call per step (greedy, batch 1),
    timed over `steps` calls after a warm-up call. Includes dispatch overhead, as a real control loop would."""

    @jax.jit
    def step(carry, k):
        obs, state, pstate = carry
        k_act, k_env = jax.random.split(k)
        action, pstate = policy.act(k_act, pstate, obs, state, params)
        obs, state, *_ = tracking_env.step_env(k_env, state, action, params)
        return obs, state, pstate

    k_reset, k_pol, k_loop = jax.random.split(key, 3)
    obs, state = jax.jit(tracking_env.reset)(k_reset, params)
    carry = (obs, state, jax.jit(policy.init)(k_pol))
    keys = list(jax.random.split(k_loop, steps + 1))
    carry = jax.block_until_ready(step(carry, keys[0]))
    t0 = time.perf_counter()
    for k in keys[1:]:
        carry = step(carry, k)
    jax.block_until_ready(carry)
    return steps / (time.perf_counter() - t0)
