"""`ramavt train`: every TrainConfig field is a flag (tyro), named by its group (``--learner.lr``,
``--network.lstm``, ``--env.camera.resolution``); ``--preset`` picks the defaults the flags change.

The command parses its flags and calls ``ramavt_jax.experiment.train_and_evaluate`` (train, plot, evaluate).
"""

from __future__ import annotations

import ast
import dataclasses
import json
import typing
from pathlib import Path
from typing import Annotated, Literal

import tyro
from tyro import constructors

from ramavt_jax import distributed
from ramavt_jax.cli.checks import positive
from ramavt_jax.env import EnvParams
from ramavt_jax.experiment import train_and_evaluate
from ramavt_jax.presets import PRESETS, preset
from ramavt_jax.train_config import TrainConfig
from ramavt_jax.training import driver

DEFAULT_PRESET = "general"
ENV_PARAMS_FLAG = "--env-params"
# EnvParams' scalar defaults: a command-line pair at its default undoes a preset's pair of that name
ENV_PARAMS_DEFAULTS = {f.name: f.default for f in dataclasses.fields(EnvParams) if f.default is not dataclasses.MISSING}
PresetName = Literal[tuple(PRESETS)]  # the choices of --preset: presets.PRESETS
# How tyro parses the one untyped-tuple field, TrainConfig.env_params (--env-params dist_weight=0.5
# lost_patience=10), and builds the config dataclasses (a failed check is a ConfigError)
FLAG_TYPES = constructors.ConstructorRegistry()


def _name_value_pairs(args: list[str]) -> tuple:
    pairs = []
    for arg in args:
        name, eq, text = arg.partition("=")
        if not eq:
            raise ValueError(f"--env-params takes NAME=VALUE pairs, got {arg!r}")
        try:
            value = ast.literal_eval(text)
        except (ValueError, SyntaxError):
            value = text
        pairs.append((name, value))
    return tuple(pairs)


def _is_pairs_type(type_) -> bool:
    """TrainConfig.env_params's type as tyro sees it: the bare `tuple` of its annotation, or, under a preset that
    sets some pairs (`sizes`), the type tyro narrows it to from that default, tuple[tuple[str, float], ...]."""
    if type_ is tuple:
        return True
    args = [a for a in typing.get_args(type_) if a is not Ellipsis]
    return (
        typing.get_origin(type_) is tuple
        and bool(args)
        and all(typing.get_origin(a) is tuple and typing.get_args(a)[:1] == (str,) for a in args)
    )


@FLAG_TYPES.primitive_rule
def _pairs_rule(info: constructors.PrimitiveTypeInfo) -> constructors.PrimitiveConstructorSpec | None:
    if not _is_pairs_type(info.type):
        return None
    return constructors.PrimitiveConstructorSpec(
        nargs="*",
        metavar="NAME=VALUE",
        instance_from_str=_name_value_pairs,
        is_instance=lambda x: isinstance(x, tuple),
        str_from_instance=lambda x: [f"{k}={v}" for k, v in x],
    )


class ConfigError(Exception):
    """A config's own check failed while tyro built it from the flags. tyro reports a ValueError raised by a nested
    config (``--run.*``, ``--env.camera.*``, ...) in a box over several lines; this type passes through tyro, and
    ``ramavt`` prints it as its usual one-line error."""


_busy: list = []  # inside _checked_configs_rule: tyro's own dataclass rule is wanted


@FLAG_TYPES.struct_rule
def _checked_configs_rule(info: constructors.StructTypeInfo) -> constructors.StructConstructorSpec | None:
    """The project's config dataclasses as tyro builds them, but a failed check raises ConfigError."""
    if _busy or not (dataclasses.is_dataclass(info.type) and info.type.__module__.startswith("ramavt_jax.")):
        return None
    _busy.append(info.type)
    try:
        spec = constructors.ConstructorRegistry.get_struct_spec(info)
    finally:
        _busy.pop()
    if not isinstance(spec, constructors.StructConstructorSpec):
        return None
    build = spec.instantiate

    def instantiate(*args, **kwargs):
        try:
            return build(*args, **kwargs)
        except ValueError as e:
            raise ConfigError(str(e)) from None

    return dataclasses.replace(spec, instantiate=instantiate)


def _print_summary(summary: driver.RunSummary, seeds: int) -> None:
    for one in summary.get("seeds", [summary]):
        print(
            json.dumps(
                {"run": one["out_dir"], **{k: v for k, v in one.items() if not isinstance(v, dict)}}, default=str
            )
        )
        if isinstance(one.get("eval"), dict):
            print(json.dumps(one["eval"], indent=1, default=str))
    mem = summary["memory"]
    print(
        f"memory per seed: state {mem['state_bytes_per_seed'] / 2**20:.1f} MiB (replay "
        f"{mem['replay_bytes_per_seed'] / 2**20:.1f} MiB); chunk working memory {mem['chunk_temp_bytes'] / 2**20:.1f} "
        f"MiB for {seeds} seed(s) on {summary['devices']} device(s), {summary['processes']} process(es)"
    )


def make_train_cmd(preset_name: str, clock_start: float | None = None):
    """The `ramavt train` function whose TrainConfig defaults are ``preset(preset_name)``; its runs' clock
    (metrics' ``since_start_s``) counts from ``clock_start`` (an epoch second; None: when it is called)."""
    default = preset(preset_name)

    def train(
        config: Annotated[TrainConfig, tyro.conf.arg(name="")] = default,
        preset: PresetName = preset_name,  # noqa: A002 (read before parsing: see main)
        seeds: int = 1,
        seed: int = 0,
        out: Path = Path(f"runs/{preset_name}"),
        resume: bool = True,
        progress: bool = True,
        devices: int = 0,
        coordinator_address: str | None = None,
        num_processes: int | None = None,
        process_id: int | None = None,
    ) -> None:
        """Train a tracker (recurrent DQN with burn-in), then evaluate it greedily on the train, val and test targets.

        Writes metrics.jsonl, checkpoints/ (re-running the same command resumes; a larger --run.total-env-steps
        extends the run), training_curves.png, eval.json. Every training field is a flag, grouped as below
        (--env.*, --network.*, --acting.*, --replay.*, --learner.*, --run.*); --preset picks their defaults.
        SIGINT / SIGTERM save the chunk in flight and exit with 130 / 143.

        Args:
            config: the training configuration (defaults: the preset's).
            preset: the named defaults of presets.PRESETS: 'general' (the default: minutes on 2 CPU cores, 32x32
                depth, small RAMAVT, trained on targets resized to [0.15, 5]x, wide starts and Table II's
                perturbations: for any target), 'quick' (the same network on the catalogue's sizes without
                perturbations), 'long' (quick trained 1.5x as long), 'sizes' (quick at 64x64 with resized targets
                and wider starts), 'robust' (quick trained under Table II's perturbations),
                'paper' (256x256, full RAMAVT, batch 64, lr 1e-4, gamma 0.99, 50,000-step replay),
                'smoke' (plumbing checks).
            seeds: number of independent seeds, trained together as ONE jitted program (vmap over seeds, each with
                its own envs and replay) into out/seed_<k>/ (each a complete run folder).
            seed: first seed.
            out: run directory.
            resume: continue from out/checkpoints when present (--no-resume: start afresh, replacing them).
            progress: show progress lines and a progress bar.
            devices: split the envs and replay over this many devices (0 = all visible; 1 = one device). More CPU
                devices for testing: XLA_FLAGS=--xla_force_host_platform_device_count=4.
            coordinator_address: multi-host run: host:port of process 0 (or JAX_COORDINATOR_ADDRESS).
            num_processes: multi-host run: number of processes (or JAX_NUM_PROCESSES).
            process_id: multi-host run: this process's index (or JAX_PROCESS_ID).
        """
        positive("--seeds", seeds)
        positive("--devices", devices, minimum=0)
        config = config.override(env_params=with_preset_pairs(default.env_params, config.env_params))
        distributed.initialize(coordinator_address, num_processes, process_id)
        summary = train_and_evaluate(
            config,
            out,
            seed=seed,
            seeds=seeds,
            resume=resume,
            progress=progress,
            devices=devices,
            clock_start=clock_start,
        )
        if distributed.is_primary():
            _print_summary(summary, seeds)

    return train


def with_preset_pairs(preset_pairs: tuple, flag_pairs: tuple) -> dict:
    """The preset's EnvParams (name, value) pairs with the command line's added name by name (`--preset sizes
    --env-params stretch_max=1.5` keeps its size randomisation). A command-line pair at EnvParams' default removes
    the preset's pair of that name, so the config is the one built without it (`--env-params init_xy_std=1` after
    `--preset sizes` is the preset before its wider starts, equal to it as a config)."""
    preset_values, merged = dict(preset_pairs), {**dict(preset_pairs), **dict(flag_pairs)}
    for name, value in flag_pairs:
        default = ENV_PARAMS_DEFAULTS.get(name)
        if name in preset_values and preset_values[name] != default and value == default:
            del merged[name]
    return merged


def joined_env_params(args: list[str]) -> list[str]:
    """A `ramavt train` command line with every --env-params joined into the first one, pairs in order (a later
    pair of a name wins): flags kept in shell variables (lab/reproduce.md's $WR0, then a command's own
    --env-params) add up instead of the last one replacing the others."""
    pairs, rest, first, i = [], [], None, 0
    while i < len(args):
        arg = args[i]
        if arg != ENV_PARAMS_FLAG and not arg.startswith(ENV_PARAMS_FLAG + "="):
            rest.append(arg)
            i += 1
            continue
        first = len(rest) if first is None else first
        pairs += [arg.split("=", 1)[1]] if arg != ENV_PARAMS_FLAG else []
        i += 1
        while i < len(args) and not args[i].startswith("--"):
            pairs.append(args[i])
            i += 1
    return args if first is None else [*rest[:first], ENV_PARAMS_FLAG, *pairs, *rest[first:]]


def preset_in(argv: list[str]) -> str:
    """The --preset value of a `ramavt train` command line (DEFAULT_PRESET when absent)."""
    for i, arg in enumerate(argv):
        if arg == "--preset" and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith("--preset="):
            return arg.split("=", 1)[1]
    return DEFAULT_PRESET
