"""The evaluation report: the result of :func:`ramavt_jax.evaluation.tables.run_suite` as Markdown (Table I:
tracking performance, Table II: perturbations, Table III: ablation, the arms over training seeds, the per-target
rows, and the paper's numbers for comparison), written with the result as ``tables.md`` and ``results.json``.

Every table shows, beside AEL / AER, the tracking error (stand-off units: m for catalogue targets), the share of
steps within 0.25 and 0.5 of the desired point, the lost episodes and the AER as a fraction of the mpc ceiling's.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

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
            seeds_of = (
                f"an ensemble of training seeds {', '.join(map(str, i['seeds']))} greedy on their mean Q"
                if i.get("members")
                else f"training seed {i.get('seed')}"
            )
            head.append(
                f"- {r['name']}: the agent shipped with the package, variant {i.get('variant')}, trained by "
                f"`{i.get('command')}` ({seeds_of}, {i.get('chunks')} chunks), "
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
