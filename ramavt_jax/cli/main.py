"""`ramavt` command line: targets | render | train | eval | curve | plot | bench.

Each subcommand is a typed function; tyro builds the parser from its signature (`ramavt <cmd> --help`). Errors
in the input (the project's own error types, bad paths, bad values, a full disk, and tyro's own: a mistyped flag,
a value of the wrong type or not among the choices) are printed as one line and exit with status 2; ``--debug``
(anywhere on the line) or ``RAMAVT_DEBUG=1`` shows the traceback instead. JAX's persistent
compilation cache is on (see :func:`enable_compile_cache`), so repeating or resuming a command does not recompile.
"""

from __future__ import annotations

import dataclasses
import difflib
import inspect
import os
import signal
import sys
import threading
import time
import typing
from pathlib import Path

import tyro

from ramavt_jax.cli import commands, curve, evaluate, train
from ramavt_jax.cli.checks import UsageError
from ramavt_jax.train_state import TrainingDivergedError
from ramavt_jax.training.interrupts import TrainingInterrupted
from ramavt_jax.training.metrics import process_start_time

USAGE_ERROR = 2  # exit status of a bad input (as argparse / tyro use for bad flags)
INTERRUPTED = 130  # a Ctrl-C outside training (training exits with 128 + the signal number)


def compile_cache_dir() -> Path | None:
    """Where JAX keeps compiled programs between runs: ``RAMAVT_COMPILE_CACHE`` (a folder, or 'off' / '0' to
    disable), else ``$XDG_CACHE_HOME/ramavt_jax/jax`` (default ``~/.cache/ramavt_jax/jax``)."""
    setting = os.environ.get("RAMAVT_COMPILE_CACHE", "")
    if setting.lower() in ("off", "0", "false", "no"):
        return None
    if setting:
        return Path(setting).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "ramavt_jax" / "jax"


def enable_compile_cache() -> Path | None:
    """Turn on JAX's persistent compilation cache in :func:`compile_cache_dir` (silently off if not writable)."""
    import jax

    path = compile_cache_dir()
    if path is None:
        return None
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError:
        return None
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path


def _exit_on_signal(signum, frame) -> None:
    """Outside training (compiling, evaluating, rendering) a signal ends the command at once, in one line: raising
    KeyboardInterrupt inside a running XLA compile can crash the process. Training installs its own handler that
    saves first (ramavt_jax.training.interrupts)."""
    print(f"\nramavt: {signal.Signals(signum).name}: stopped", file=sys.stderr, flush=True)
    os._exit(128 + signum)


def _one_line(e: BaseException) -> str:
    return " ".join(str(e).split()) or type(e).__name__


class FlagError(UsageError):
    """A command line tyro cannot parse (a mistyped flag, a value of the wrong type), in one line."""


def _flags(fn) -> list[str]:
    """The flags of a command function as tyro spells them (``--learner.max-grad-norm``; a parameter named
    ``config`` is flattened, as `ramavt train` declares it): the candidates of a 'did you mean'."""
    out: list[str] = []

    def walk(cls, prefix: str) -> None:
        hints = typing.get_type_hints(cls)
        for f in dataclasses.fields(cls):
            sub = hints.get(f.name)
            if dataclasses.is_dataclass(sub):
                walk(sub, f"{prefix}{f.name}.")
            else:
                out.append("--" + f"{prefix}{f.name}".replace("_", "-"))
                out.append("--" + f"{prefix}no-{f.name}".replace("_", "-"))

    try:
        hints = typing.get_type_hints(fn)
        for name in inspect.signature(fn).parameters:
            sub = hints.get(name)
            if dataclasses.is_dataclass(sub):
                walk(sub, "" if name == "config" else f"{name}.")
            else:
                out += ["--" + name.replace("_", "-"), "--no-" + name.replace("_", "-")]
    except (TypeError, ValueError, NameError):
        pass
    return out


def _flag_of(event) -> tuple[str, str]:
    """(the flag, what it expects) of a tyro parse-error event's argument."""
    lowered = event.argument.lowered
    return "/".join(lowered.name_or_flags), str(lowered.metavar or "")


def _parse_error_message(event, cmds: dict, argv: list[str]) -> str | None:
    """One line for a tyro parse-error event (tyro._errors, a private API: None, or any surprise, leaves the event
    to tyro's own box)."""
    from tyro import _errors as events

    cmd = argv[0] if argv and argv[0] in cmds else None
    where = f"`ramavt {cmd} --help`" if cmd else "`ramavt --help`"
    if isinstance(event, events.UnrecognizedArgs):
        token = str(event.tokens[0])
        if cmd is None:
            close = difflib.get_close_matches(token, list(cmds), n=1)
            hint = f" (did you mean {close[0]}?)" if close else ""
            return f"unknown command {token!r}{hint}; choose one of {', '.join(cmds)}"
        if not token.startswith("-"):
            return f"unexpected value {token!r} (a flag that takes no value given one?); {where} lists the options"
        name = token.split("=", 1)[0]
        close = difflib.get_close_matches(name, _flags(cmds[cmd]), n=1, cutoff=0.6)
        hint = f" (did you mean {close[0]}?)" if close else ""
        return f"unrecognized option {name} for `ramavt {cmd}`{hint}; {where} lists the options"
    if isinstance(event, events.InvalidChoice):
        flag, _ = _flag_of(event)
        return f"{flag} must be one of {', '.join(map(str, event.choices))}, got {event.value!r}"
    if isinstance(event, events.InstantiationFailure):
        message = " ".join(str(event.message).split())
        if event.argument is None:
            return message
        flag, expects = _flag_of(event)
        return message if flag in message else f"{flag} expects {expects}: {message}"
    if isinstance(event, events.BadValue):
        flag, expects = _flag_of(event)
        if event.offending_value is not None:
            return f"{flag} takes no value, got {event.offending_value!r}"
        return f"{flag} expects {expects}"
    if isinstance(event, events.MissingSubcommand):
        return f"choose a command: {', '.join(cmds)} ({where})"
    if isinstance(event, events.MissingArgs):
        names = ", ".join("/".join(a.arg.lowered.name_or_flags) for a in event.missing_arguments)
        return f"missing {names}; {where}"
    return None


def _one_line_parse_errors(cmds: dict, argv: list[str]):
    """A context in which tyro's parse errors raise FlagError (one line) instead of drawing a box; with a tyro
    without the hook (its API is private), nothing changes."""
    import contextlib

    try:
        from tyro import _errors as events

        register = events.on_parse_error
    except (ImportError, AttributeError):
        return contextlib.nullcontext()

    def hook(event) -> None:
        try:
            message = _parse_error_message(event, cmds, argv)
        except Exception:  # noqa: BLE001 (the event's fields are tyro internals: on a surprise, tyro's own box)
            return
        if message is not None:
            raise FlagError(message)

    return register(hook)


def _dispatch(argv: list[str], clock_start: float) -> None:
    if argv[:1] == ["bench"]:
        return commands.bench_main(argv[1:])
    cmds = {
        "targets": commands.targets_cmd,
        "render": commands.render_cmd,
        "train": train.make_train_cmd(
            train.preset_in(argv[1:]) if argv[:1] == ["train"] else train.DEFAULT_PRESET, clock_start
        ),
        "eval": evaluate.eval_cmd,
        "curve": curve.curve_cmd,
        "plot": evaluate.plot_cmd,
        "bench": commands.bench_main,  # listed for --help; dispatched above
    }
    if argv[:1] == ["train"]:
        argv = train.joined_env_params(argv)
    with train.FLAG_TYPES, _one_line_parse_errors(cmds, argv):
        tyro.extras.subcommand_cli_from_dict(cmds, prog="ramavt", args=argv)


def _quiet_shutdown(code: int) -> None:
    """Once the command has ended (its last line printed), a signal while the interpreter shuts down (JAX's and
    orbax's clean-up take a moment: a second Ctrl-C often lands there) ends the process at once with the command's
    exit status, instead of a traceback from an exit handler."""

    def handler(signum, frame) -> None:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(code)

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, handler)


def _exit_status(e: BaseException | None) -> int:
    if e is None:
        return 0
    if isinstance(e, SystemExit):
        return e.code if isinstance(e.code, int) else (0 if e.code is None else 1)
    return 1


def main(argv: list[str] | None = None) -> None:
    """Entry point of the `ramavt` script (``argv`` None: the process's own command line, and training's clock counts
    from the process's start; a list, as from Python code: from this call)."""
    own_process = argv is None
    main_thread = threading.current_thread() is threading.main_thread()
    ended = None
    try:
        _main(argv)
    except BaseException as e:
        ended = e
        raise
    finally:
        if own_process and main_thread:
            _quiet_shutdown(_exit_status(ended))


def _main(argv: list[str] | None) -> None:
    clock_start = process_start_time() if argv is None else time.time()
    argv = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in argv or os.environ.get("RAMAVT_DEBUG", "") not in ("", "0")
    argv = [a for a in argv if a != "--debug"]
    enable_compile_cache()
    main_thread = threading.current_thread() is threading.main_thread()
    old = {sig: signal.signal(sig, _exit_on_signal) for sig in (signal.SIGINT, signal.SIGTERM)} if main_thread else {}
    try:
        _dispatch(argv, clock_start)
    except TrainingInterrupted as e:
        if debug:
            raise
        print(f"ramavt: {_one_line(e)}", file=sys.stderr)
        raise SystemExit(e.exit_code) from None
    except KeyboardInterrupt:
        if debug:
            raise
        print("ramavt: interrupted", file=sys.stderr)
        raise SystemExit(INTERRUPTED) from None
    except FlagError as e:
        print(f"ramavt: error: {_one_line(e)}", file=sys.stderr)
        raise SystemExit(USAGE_ERROR) from None
    except (ValueError, OSError, OverflowError, TrainingDivergedError, train.ConfigError) as e:
        if debug:
            raise
        print(f"ramavt: error: {_one_line(e)} (--debug shows the traceback)", file=sys.stderr)
        raise SystemExit(USAGE_ERROR) from None
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


if __name__ == "__main__":
    main()
