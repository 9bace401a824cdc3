"""The paper's evaluation tables: run a set of policies over targets and perturbation settings, write Markdown/JSON.

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
from pathlib import Path

import jax
import numpy as np

from ramavt_jax import env as env_lib
from ramavt_jax.baselines import Policy
from ramavt_jax.evaluation import rollouts, seeds
from ramavt_jax.training.files import dumps, replace_files

# The paper's numbers (RAMAVT, IEEE TAES; 256x256 renders of the SNCOAT benchmark, 6 held-out targets).
PAPER_TABLE1 = [  # name, input, AEL, min, max, AER, min, max, Hz
    ("Random", "-", 152.2, 21, 385, -1545.2, -3214.8, -178.4, 42703.5),
    ("DRLAVT", "rgbd", 857.9, 6, 1000, -268.9, -2341.4, 386.4, 63.1),
    ("DRLAVT", "depth", 901.1, 6, 1000, 430.3, -55.69, 382.2, 66.6),
    ("DRLAVT", "color", 841.6, 15, 1000, -201.9, -1798.7, 320.4, 68.9),
    ("RAMAVT", "rgbd", 952.4, 41, 1000, -398.5, -1523.2, 481.4, 202.7),
    ("RAMAVT", "depth", 959.1, 162, 1000, -59.4, -800.5, 445.4, 216.1),
    ("RAMAVT", "color", 685.3, 43, 1000, -1755.1, -4097.5, 434.7, 210.9),
]
PAPER_TABLE2 = [  # name, setting, AEL, AER (RAMAVT rows are RGBD: the 'none' row equals Table I's RGBD row)
    ("DRLAVT", "all", 456.3, -758.6),
    ("RAMAVT", "actuator_noise", 876.5, -438.9),
    ("RAMAVT", "time_delay", 596.6, -793.3),
    ("RAMAVT", "blur", 793.3, -810.1),
    ("RAMAVT", "all", 580.8, -971.8),
    ("RAMAVT", "none", 952.4, -398.5),
]
PAPER_TABLE3 = [  # name, AEL, AER, Hz (RGBD)
    ("Origin", 368.5, -1876.3, 214.3),
    ("Augment", 419.3, -1283.6, 215.7),
    ("SE", 625.8, -956.0, 211.3),
    ("MHA", 731.1, -845.7, 206.6),
    ("RAMAVT", 952.4, -398.5, 202.7),
]
SETTING_MARKS = {  # setting -> (actuator noise, time delay, image blur)
    "actuator_noise": (1, 0, 0),
    "time_delay": (0, 1, 0),
    "blur": (0, 0, 1),
    "all": (1, 1, 1),
    "none": (0, 0, 0),
}


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


def settings_for(tables: tuple[int, ...]) -> list[str]:
    return list(rollouts.PERTURBATIONS) if 2 in tables else ["none"]


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
) -> dict:
    """Evaluate every entry on every target (vmapped episodes) for each needed setting. Returns a JSON-able dict."""
    values = {**rollouts.PERTURBATION_VALUES, **(perturbation_values or {})}
    settings = settings_for(tables)
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


# ============================================================================================ Markdown
def _f(x, digits=1) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else f"{x:.{digits}f}"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join("---" for _ in header) + "|"]
    lines += ["| " + " | ".join(str(c) for c in r) + " |" for r in rows]
    return "\n".join(lines)


def _rows_in(result: dict, setting: str = "none"):
    """(row, that setting's results) for every row evaluated in ``setting``."""
    for r in result["rows"]:
        if setting in r["settings"]:
            yield r, r["settings"][setting]


# The readable columns of every table (see _quality_cells).
QUALITY_HEADER = ["error (m)", "<= 0.25 m %", "<= 0.5 m %", "lost %", "of ceiling %"]


def _pct(x) -> str:
    return "-" if x is None else _f(100 * x, 0)


def _ci(o: dict, name: str = "return") -> str:
    """'[low, high]': the 95 % bootstrap interval of the mean (results written before it existed: '-')."""
    low, high = o.get(f"{name}_ci_low"), o.get(f"{name}_ci_high")
    return "-" if low is None or not np.isfinite(low) else f"[{low:.1f}, {high:.1f}]"


def _quality_cells(o: dict) -> list[str]:
    """Tracking error (stand-off units: m for catalogue targets), steps within 0.25 / 0.5 of the desired point,
    lost episodes and the AER as a fraction of the mpc ceiling's, as table cells."""
    return [
        _f(o.get("error_mean"), 2),
        _pct(o.get("within_quarter_fraction")),
        _pct(o.get("within_half_fraction")),
        _pct(o["lost_fraction"]),
        _pct(o.get("ceiling_fraction")),
    ]


def table1_md(result: dict) -> str:
    rows = []
    for r, s in _rows_in(result):
        o = s["overall"]
        rows.append(
            [
                r["name"],
                r["input"],
                _f(o["length_mean"]),
                _f(o["length_min"], 0),
                _f(o["length_max"], 0),
                _f(o["return_mean"]),
                _ci(o),
                _f(o["return_min"]),
                _f(o["return_max"]),
                *_quality_cells(o),
                _f(r.get("speed_hz")),
            ]
        )
    return _table(
        [
            "Policy",
            "Input",
            "AEL",
            "EL min",
            "EL max",
            "AER",
            "AER 95 % CI",
            "ER min",
            "ER max",
            *QUALITY_HEADER,
            "Speed (Hz)",
        ],
        rows,
    )


def table2_md(result: dict) -> str:
    rows = []
    for r in result["rows"]:
        for setting in rollouts.PERTURBATIONS:
            s = r["settings"].get(setting)
            if s is None:
                continue
            marks = ["✓" if m else "-" for m in SETTING_MARKS[setting]]
            o = s["overall"]
            rows.append(
                [r["name"], r["input"], *marks, _f(o["length_mean"]), _f(o["return_mean"]), _ci(o), *_quality_cells(o)]
            )
    return _table(
        ["Policy", "Input", "Actuator noise", "Time delay", "Image blur", "AEL", "AER", "AER 95 % CI", *QUALITY_HEADER],
        rows,
    )


def table3_md(result: dict) -> str:
    rows = []
    for r, s in _rows_in(result):
        info = r.get("info", {})
        o = s["overall"]
        rows.append(
            [
                r["name"],
                info.get("variant", r["kind"]),
                str(info.get("augment", "-")),
                r["input"],
                _f(o["length_mean"]),
                _f(o["return_mean"]),
                _ci(o),
                *_quality_cells(o),
                _f(r.get("speed_hz")),
            ]
        )
    return _table(
        ["Run", "Variant", "Augment", "Input", "AEL", "AER", "AER 95 % CI", *QUALITY_HEADER, "Speed (Hz)"], rows
    )


def per_target_md(result: dict) -> str:
    rows = []
    for r, s in _rows_in(result):
        for target, o in s["per_target"].items():
            rows.append(
                [
                    r["name"],
                    r["input"],
                    target,
                    _f(o["length_mean"]),
                    _f(o["length_min"], 0),
                    _f(o["return_mean"]),
                    _ci(o),
                    *_quality_cells(o),
                ]
            )
    return _table(["Policy", "Input", "Target", "AEL", "EL min", "AER", "AER 95 % CI", *QUALITY_HEADER], rows)


def paper_md() -> str:
    t1 = _table(
        ["Name", "Input", "AEL", "EL min", "EL max", "AER", "ER min", "ER max", "Speed (Hz)"],
        [[str(c) for c in row] for row in PAPER_TABLE1],
    )
    t2 = _table(["Name", "Setting", "AEL", "AER"], [[str(c) for c in row] for row in PAPER_TABLE2])
    t3 = _table(["Name", "AEL", "AER", "Speed (Hz)"], [[str(c) for c in row] for row in PAPER_TABLE3])
    return f"Table I\n\n{t1}\n\nTable II (RGBD)\n\n{t2}\n\nTable III (RGBD)\n\n{t3}"


def to_markdown(result: dict, command: str = "") -> str:
    s, m = result["settings"], result["machine"]
    pv, task = s["perturbation_values"], s.get("eval_params", {})
    head = [
        "# Evaluation",
        "",
        f"- command: `{command}`" if command else "",
        f"- targets ({len(s['targets'])}): {', '.join(s['targets'])}",
        f"- episodes per target: {s['episodes_per_target']} (vmapped; {s['episodes_per_target'] * len(s['targets'])} "
        f"per row and setting), seed {s['seed']}, same initial states for every policy",
        f"- settings: reward dist_weight {task.get('dist_weight', 1.0):g}, "
        f"lost after > {task.get('lost_patience', 20):g} "
        f"consecutive lost steps, command speed x max(1, k) ** {task.get('speed_standoff_power', 0.0):g} x "
        f"min(1, k) ** {task.get('small_standoff_power', 0.0):g} (k: stand-off scale), max {s['max_steps']} steps, "
        f"greedy policies",
        f"- perturbations: actuator noise {pv['actuator_noise']} (command x (1 + a N(0,1))), time delay "
        f"U(0, {pv['delay_max']}) s added to each 0.1 s step, blur = mean of the last {pv['blur_frames']} frames",
        f"- speed: policy + env step of ONE env as one jitted call per step, {s['speed_steps']} steps (Hz)",
        "- error: distance of the target centre from the desired point, each episode's mean over its steps, in "
        "stand-off units (m; a target held at a scaled stand-off k counts metres / k); <= 0.25 / 0.5 m: share of "
        "steps that close; of ceiling: AER / the mpc row's AER on the same episodes; CI: 95 % bootstrap interval of "
        "the mean (episodes resampled within each target)",
        f"- machine: {m['cpu_count']} CPUs ({m['processor']}), {m['backend']} backend, jax {m['jax']}, load average "
        f"{', '.join(f'{x:.1f}' for x in m['load_average'] or [])} at the end",
        f"- wall time: {result.get('wall_s', float('nan')):.0f} s",
    ]
    rows = result["rows"]
    for r in rows:
        i = r["info"]
        if r["kind"] == "checkpoint" and i.get("pretrained"):  # a shipped agent: its own record of how it was made
            head.append(
                f"- {r['name']}: the agent shipped with the package, variant {i.get('variant')}, trained by "
                f"`{i.get('command')}` (training seed {i.get('seed')}, {i.get('chunks')} chunks), "
                f"{i.get('policy_params')} params, {r['resolution']}x{r['resolution']} {r['obs_mode']}"
            )
        elif r["kind"] == "checkpoint" and i.get("ensemble_of"):  # greedy on the mean Q of several runs
            head.append(
                f"- {r['name']}: the runs {', '.join(f'`{d}`' for d in i['ensemble_of'])} flying together, "
                f"greedy on their mean output (Q, or a policy head's logits), "
                f"{i.get('policy_params', 'online')} params, "
                f"{r['resolution']}x{r['resolution']} {r['obs_mode']}"
            )
        elif r["kind"] == "checkpoint":
            head.append(
                f"- {r['name']}: run `{i.get('run_dir')}`, variant {i.get('variant')}, training seed "
                f"{i.get('seed')}, checkpoint step {i.get('step')} ({i.get('env_steps')} env steps), "
                f"{i.get('policy_params', 'online')} params, "
                f"{r['resolution']}x{r['resolution']} {r['obs_mode']}"
            )
    parts = ["\n".join(h for h in head if h)]
    tables = s["tables"]
    if 1 in tables:
        parts.append("## Table I: tracking performance (no perturbation)\n\n" + table1_md(result))
    if 2 in tables:
        parts.append("## Table II: perturbations\n\n" + table2_md(result))
    if 3 in tables and any(r["kind"] == "checkpoint" for r in rows):
        parts.append("## Table III: ablation\n\n" + table3_md(result))
    if any(len(runs) > 1 for runs in seeds.arms(result).values()):
        parts.append("## Arms over training seeds (no perturbation)\n\n" + seeds.arms_md(result))
    parts.append("## Per target (no perturbation)\n\n" + per_target_md(result))
    parts.append("## The paper's numbers (for comparison; 256x256, their simulator)\n\n" + paper_md())
    return "\n\n".join(parts) + "\n"


def write(result: dict, out: Path, command: str = "") -> tuple[Path, Path]:
    """``out/tables.md`` and ``out/results.json``, replaced together (files.replace_files): a full disk or a
    crash leaves both earlier files, whole and agreeing."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    md, js = out / "tables.md", out / "results.json"
    arms = {setting: seeds.summarise_arms(result, setting) for setting in result["settings"]["perturbation_settings"]}
    texts = {
        md: to_markdown(result, command),
        js: dumps({**result, "arms": arms, "command": command}, indent=1, default=float),
    }
    replace_files({path: lambda tmp, text=text: tmp.write_text(text) for path, text in texts.items()})
    return md, js


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
