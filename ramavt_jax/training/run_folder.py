"""The run folder written by ``ramavt train``: its layout, its metrics.jsonl, the config check and the lock. Its files
are written whole or not at all (:mod:`ramavt_jax.training.files`).

Layout (one seed; ``--seeds N`` writes one such folder per seed, ``out/seed_<k>/``)::

    out/config.json          {"seed": k, "config": TrainConfig.to_dict()}
    out/metrics.jsonl        one strict-JSON record per chunk (NaN written as null)
    out/checkpoints/<chunk>/ orbax checkpoints (the last ``keep_checkpoints``)
    out/eval.json            final greedy and random-agent evaluation (written by the evaluation layer)
    out/training_curves.png  (written by the figures layer)
    out/tb/                  TensorBoard events (config.run.tensorboard)
    out/.lock                held by the process training into the folder
"""

from __future__ import annotations

import json
import os
import re
import socket
from pathlib import Path
from typing import Any

from ramavt_jax.config_dicts import without_retired_fields
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import files

__all__ = [
    "CONFIG_FILE",
    "METRICS_FILE",
    "CHECKPOINTS",
    "EVAL_FILE",
    "CURVES_FILE",
    "RESUMABLE_FIELDS",
    "seed_dir",
    "seed_folders",
    "is_seed_dir",
    "read_metrics",
    "append_metrics",
    "resumed_rows",
    "sync_metrics",
    "write_metrics",
    "config_differences",
    "default_json",
    "missing_fields",
    "read_config",
    "check_config",
    "RunFolderError",
    "RunLock",
    "check_writable",
    "lock_folder",
]

CONFIG_FILE, METRICS_FILE, CHECKPOINTS, EVAL_FILE = "config.json", "metrics.jsonl", "checkpoints", "eval.json"
CURVES_FILE = "training_curves.png"
LOCK_FILE = ".lock"
# TrainConfig fields that may change when a run is resumed: they do not change the checkpointed state (a larger
# total_env_steps extends the run)
RESUMABLE_FIELDS = (
    "run.total_env_steps",
    "run.eval_episodes",
    "run.eval_max_steps",
    "run.checkpoint_every_chunks",
    "run.keep_checkpoints",
    "run.tensorboard",
    "run.max_loss",
)
# Fields added to TrainConfig after run folders of earlier versions were written, each defaulting to what those
# runs were trained with: a config.json without such a field reads as its default. Any other missing field means a
# file cut short or edited, and is refused. (Fields since removed: config_dicts.RETIRED_FIELDS.)
ADDED_FIELDS = (
    "replay.priority_exponent",
    "replay.importance_exponent",
    "replay.priority_max_share",
    "learner.bootstrap_from",
    "run.policy_average_from",
    "learner.expert_margin_weight",
    "learner.blind_label",
    "run.max_loss",
)
_SEED_DIR = re.compile(r"seed_\d+")


class RunFolderError(ValueError):
    """A run folder cannot be used as asked (config mismatch, locked, not writable)."""


# ============================================================================================ layout
def seed_dir(out: str | os.PathLike, seed: int) -> Path:
    """The folder of one seed of a ``--seeds N`` run."""
    return Path(out) / f"seed_{seed}"


def seed_folders(out: str | os.PathLike, seeds: list[int]) -> list[Path]:
    """The run folders of ``seeds``: ``out`` itself for one seed, ``out/seed_<k>`` for several."""
    return [Path(out)] if len(seeds) == 1 else [seed_dir(out, s) for s in seeds]


def is_seed_dir(path: str | os.PathLike) -> bool:
    """Whether ``path`` is one seed's folder of a ``--seeds N`` sweep (its parent names the sweep)."""
    return bool(_SEED_DIR.fullmatch(Path(path).name))


# ============================================================================================ metrics.jsonl
def _decoded(raw: bytes) -> str:
    try:
        return raw.decode("utf-8")
    except UnicodeDecodeError as e:
        raise ValueError(f"byte {raw[e.start]:#04x} at column {e.start + 1} is not UTF-8 text") from None


def read_metrics(path: str | os.PathLike, log=print) -> list[dict]:
    """The records of a metrics.jsonl ([] when missing); null numbers come back as NaN. A torn last line (a crash
    while it was written) is skipped and reported through ``log`` in one line; a damaged line before it (not JSON,
    or not UTF-8 text) is a RunFolderError naming the file and line."""
    path = Path(path)
    if not path.exists():
        return []
    try:
        data = path.read_bytes()
    except OSError as e:
        raise RunFolderError(f"cannot read {path}: {e.strerror or e}") from None
    lines = [(i, raw) for i, raw in enumerate(data.split(b"\n"), 1) if raw.strip()]
    records = []
    for i, raw in lines:
        try:
            records.append(json.loads(_decoded(raw)))
        except ValueError as e:
            if i != lines[-1][0]:
                raise RunFolderError(f"{path} line {i} is not a JSON record ({e}); fix or delete that line") from None
            log(f"{path}: skipped its last line, written only in part (a crash while writing it)")
    return [{k: float("nan") if v is None else v for k, v in r.items()} for r in records]


def write_metrics(path: Path, records: list[dict]) -> None:
    files.write_atomic(path, "".join(files.dumps(r) + "\n" for r in records))


def append_metrics(path: Path, record: dict) -> None:
    """Append one record (a line) to a metrics.jsonl; :func:`sync_metrics` flushes it with its chunk's checkpoint."""
    try:
        with path.open("a") as f:
            f.write(files.dumps(record) + "\n")
    except OSError as e:
        raise files.write_error(path, e, "a row cut short there is skipped on resume") from None


def sync_metrics(path: Path) -> None:
    """Flush a metrics.jsonl's appended rows to the disk (before the checkpoint of their chunks is written)."""
    try:
        if path.exists():
            files.fsync_file(path)
    except OSError as e:
        raise files.write_error(
            path, e, "its rows since the last checkpoint may be cut short; they are rebuilt on resume"
        ) from None


def resumed_rows(path: Path, chunk: int, saved, log=print) -> list[dict]:
    """The rows of a metrics.jsonl a run resumed from checkpoint ``chunk`` keeps: its rows up to that chunk, with
    those the file lost (a row torn or never flushed when the power went) rebuilt from ``saved``, the rows the
    checkpoints hold (each those of its chunks since the one before it): a list, or a function that reads them,
    called only when a row is missing. A row that can be neither read nor rebuilt is a RunFolderError, in one line:
    the log and the checkpoints never disagree."""
    rows = {int(r["chunk"]): r for r in read_metrics(path, log) if r["chunk"] <= chunk}
    if callable(saved):
        saved = saved() if any(c not in rows for c in range(1, chunk + 1)) else None
    rebuilt = [int(r["chunk"]) for r in saved or () if int(r["chunk"]) not in rows and r["chunk"] <= chunk]
    for r in saved or ():
        if int(r["chunk"]) in rebuilt:
            rows[int(r["chunk"])] = {k: float("nan") if v is None else v for k, v in r.items()}
    missing = [c for c in range(1, chunk + 1) if c not in rows]
    if missing:
        shown = ", ".join(map(str, missing[:5])) + (f" (and {len(missing) - 5} more)" if len(missing) > 5 else "")
        raise RunFolderError(
            f"{path} lacks the rows of chunk(s) {shown}, which checkpoint {chunk} covers, and the checkpoint cannot "
            f"rebuild them; restore the file, or train the folder afresh with --no-resume"
        )
    if rebuilt:
        log(f"{path}: rebuilt the row(s) of chunk(s) {', '.join(map(str, rebuilt))} from checkpoint {chunk}")
    return [rows[c] for c in sorted(rows)]


# ============================================================================================ config check
def _flatten(d: Any, prefix: str = "") -> dict:
    if not isinstance(d, dict):
        return {prefix: d}
    out = {}
    for k, v in d.items():
        out.update(_flatten(v, f"{prefix}.{k}" if prefix else k))
    return out


def _sorted_pairs(config: dict) -> dict:
    """A config dict with its env_params pairs in name order: their order means nothing to the env, and `ramavt
    train` writes them sorted (a dict of overrides is sorted by TrainConfig) while earlier runs hold them in
    command-line order."""
    pairs = config.get("env_params")
    if not isinstance(pairs, (list, tuple)):
        return config
    return {**config, "env_params": sorted(([*p] for p in pairs), key=lambda p: str(p[0]))}


def default_json() -> dict:
    """TrainConfig's default values as a config dict (the fields an older config.json lacks take these)."""
    return json.loads(json.dumps(TrainConfig().to_dict(), default=str))


def config_differences(saved: dict, current: dict, defaults: dict | None = None) -> dict[str, tuple]:
    """{dotted field: (saved value, current value)} for every field that differs between two config dicts. A field
    the saved config lacks (written before the field existed) counts as its value in ``defaults`` (a config dict
    of the defaults), so a new field left at its default does not block a resume; a retired field at its old value
    (config_dicts.RETIRED_FIELDS) counts as absent, at another value is refused (ValueError)."""
    saved = without_retired_fields(saved)
    a, b = _flatten(_sorted_pairs(saved)), _flatten(_sorted_pairs(current))
    d = _flatten(_sorted_pairs(defaults or {}))
    a.update({k: d[k] for k in d if k not in a})
    return {k: (a.get(k), b.get(k)) for k in sorted(set(a) | set(b)) if a.get(k) != b.get(k)}


def missing_fields(saved: dict, defaults: dict) -> list[str]:
    """Dotted names of the fields of ``defaults`` (a config dict) that ``saved`` lacks."""
    have = _flatten(saved)
    return [k for k in _flatten(defaults) if k not in have and not any(h.startswith(k + ".") for h in have)]


def read_config(run_dir: str | os.PathLike, defaults: dict | None = None) -> dict:
    """A run folder's config.json ({"seed", "config"}), complete and without retired fields: RunFolderError (one
    line, naming the file and the first missing field) when it cannot be read or lacks a field of ``defaults``
    (default: TrainConfig's), or (naming the field) when it holds a retired field (config_dicts.RETIRED_FIELDS)
    at another value than its old default: the run used a research arm this version no longer has."""
    path = Path(run_dir) / CONFIG_FILE
    try:
        saved = json.loads(path.read_text())
        config = saved["config"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise RunFolderError(
            f"cannot read {path} ({type(e).__name__}: {e}); the checkpoints' metadata hold the "
            f"config too (pass --no-resume to train the folder afresh)"
        ) from None
    groups = ("acting", "replay", "learner", "run")
    if not (isinstance(config, dict) and all(isinstance(config.get(g), dict) for g in groups)):
        raise RunFolderError(
            f"{path} holds a config without the groups {', '.join(groups)} (the flat form of early "
            f"versions, which this version does not read); train the run again"
        )
    try:
        config = saved["config"] = without_retired_fields(config)
    except ValueError as e:
        raise RunFolderError(f"{path}: {e}") from None
    if defaults is None:
        defaults = default_json()
    missing = missing_fields(config, defaults)
    for name in [k for k in missing if k in ADDED_FIELDS]:  # written before the field existed
        group, field = name.split(".")
        config[group][field] = defaults[group][field]
        missing.remove(name)
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise RunFolderError(
            f"{path} is incomplete: it lacks {missing[0]}{more}; it was cut short or edited (the "
            f"checkpoints' metadata hold the full config); a default is not filled in silently"
        )
    return saved


def check_config(run_dir: Path, config_json: dict, seed: int, defaults: dict | None = None) -> None:
    """Refuse (one line, nothing written) to resume ``run_dir`` with a config that differs from its config.json in
    more than the resumable fields, or with an incomplete config.json; call before anything is written."""
    saved = read_config(run_dir, defaults)
    diff = config_differences(saved.get("config", {}), config_json, defaults)
    fixed = {k: v for k, v in diff.items() if k not in RESUMABLE_FIELDS}
    if saved.get("seed") != seed:
        fixed["seed"] = (saved.get("seed"), seed)
    if fixed:
        shown = ", ".join(f"{k} {a!r} -> {b!r}" for k, (a, b) in list(fixed.items())[:6])
        more = f" (and {len(fixed) - 6} more)" if len(fixed) > 6 else ""
        raise RunFolderError(
            f"{run_dir} holds a run with another config: {shown}{more}. Train into a new --out, or pass --no-resume "
            f"to start this folder afresh (its checkpoints are replaced); on resume only "
            f"{', '.join(RESUMABLE_FIELDS)} may change"
        )


# ============================================================================================ lock and paths
def check_writable(path: str | os.PathLike, what: str = "--out") -> Path:
    """Create the folder ``path`` if needed and check it can be written; one-line error otherwise."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise RunFolderError(f"{what} {path} is a file, not a folder; choose a folder path")
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise RunFolderError(f"cannot create {what} folder {path}: {e.strerror}") from None
    if not os.access(path, os.W_OK | os.X_OK):
        raise RunFolderError(f"{what} folder {path} is not writable; choose another folder")
    return path


class RunLock:
    """An exclusive ``fcntl.flock`` on ``folder/.lock`` naming the holder (pid, host); released on close or when
    the process dies."""

    def __init__(self, folder: Path, advice: str = "wait for that run to finish, stop it, or train into another --out"):
        import fcntl

        self.path = Path(folder) / LOCK_FILE
        self._file = open(self.path, "a+")  # noqa: SIM115 (held for the whole run)
        try:
            fcntl.flock(self._file.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._file.seek(0)
            holder = self._file.read().strip() or "another process"
            self._file.close()
            raise RunFolderError(f"{folder} is in use by {holder} (lock file {self.path}); {advice}") from None
        self._file.seek(0)
        self._file.truncate()
        self._file.write(f"process {os.getpid()} on {socket.gethostname()}\n")
        self._file.flush()

    def close(self) -> None:
        if not self._file.closed:
            self._file.close()

    def __enter__(self) -> RunLock:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def lock_folder(out) -> RunLock:
    """The run folder ``out``, created if needed and checked writable, locked against a second command (one-line
    RunFolderError otherwise). ``ramavt train`` holds it through the training, the final evaluation and the plots
    (experiment.train_and_evaluate passes it to training.driver.run)."""
    check_writable(out)
    return RunLock(Path(out))
