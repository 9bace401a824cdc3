"""`ramavt` command line: targets | render | train | eval | curve | plot | bench.

Each subcommand is a typed function; tyro builds the parser from its signature (`ramavt <cmd> --help`). Errors
in the input (the project's own error types, bad paths, bad values) are printed as one line and exit with status
2; ``--debug`` (anywhere on the line) or ``RAMAVT_DEBUG=1`` shows the traceback instead. JAX's persistent
compilation cache is on (see :func:`enable_compile_cache`), so repeating or resuming a command does not recompile.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from pathlib import Path

import tyro

from ramavt_jax.cli import commands, curve, evaluate, train
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
    with train.FLAG_TYPES:
        tyro.extras.subcommand_cli_from_dict(cmds, prog="ramavt", args=argv)


def main(argv: list[str] | None = None) -> None:
    """Entry point of the `ramavt` script (``argv`` None: the process's own command line, and training's clock counts
    from the process's start; a list, as from Python code: from this call)."""
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
    except (ValueError, OSError, TrainingDivergedError, train.ConfigError) as e:
        if debug:
            raise
        print(f"ramavt: error: {_one_line(e)} (--debug shows the traceback)", file=sys.stderr)
        raise SystemExit(USAGE_ERROR) from None
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


if __name__ == "__main__":
    main()
