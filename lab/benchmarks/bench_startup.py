"""The start-up of ``ramavt train`` (imports, compiling, the initial state) against an earlier git revision, interleaved.

    python lab/benchmarks/bench_startup.py --baseline b13b41f [--rounds 3] [--preset quick]

Each round runs, one after the other, this checkout's and the baseline's ``ramavt train`` as a fresh process (the
baseline's ``ramavt_jax`` from ``git archive`` first on PYTHONPATH) for ONE chunk of the preset, without the final
evaluation, with the persistent compile cache off, so that every process compiles from cold as on a fresh machine.
Both processes run with huge-page malloc, as the ``ramavt`` script starts them. The process's whole wall time is
measured from outside: both versions do the same work after their chunk (a checkpoint, the training-curve figure),
so the difference is the start-up's. Prints each run, the medians and the load average; writes JSON to ``--out``.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[2] / "benchmarks")]
from bench_train import code_version, export_package, merge_json  # noqa: E402

from ramavt_jax import presets  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DEFAULT_OUT = Path(__file__).resolve().parent / "results_startup.json"


def _environment(package_root: Path) -> dict:
    env = dict(os.environ, RAMAVT_COMPILE_CACHE="off", GLIBC_TUNABLES="glibc.malloc.hugetlb=1")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(package_root), env.get("PYTHONPATH")]))
    return env


def check_imports(package_root: Path, cwd: Path) -> None:
    """Refuse to time anything unless a process started as the timed ones are imports the package under
    ``package_root``."""
    where = subprocess.run(
        [sys.executable, "-c", "import ramavt_jax; print(ramavt_jax.__file__)"],
        cwd=cwd,
        env=_environment(package_root),
        capture_output=True,
        text=True,
    ).stdout.strip()
    if not Path(where).resolve().is_relative_to(package_root.resolve()):
        raise SystemExit(f"a process meant to import ramavt_jax from {package_root} imports {where or 'nothing'}")


def one_chunk_run(steps: int, preset: str, out: Path, package_root: Path) -> dict:
    """A fresh ``ramavt train`` process for one chunk (``steps`` env steps), with the ``ramavt_jax`` under
    ``package_root``: {'wall_s', 'compile_s', 'startup_s' (None before it was logged)} from its summary line.
    ``compile_s`` is the chunk's compile before 1fcfe87 and the chunk's and the initial state's after it."""
    cmd = [
        sys.executable,
        "-m",
        "ramavt_jax.cli",
        "train",
        "--preset",
        preset,
        "--no-progress",
        "--no-resume",
        "--out",
        str(out),
        "--run.total-env-steps",
        str(steps),
        "--run.eval-episodes",
        "0",
    ]
    t = time.perf_counter()
    # run from the output's folder: `python -m` puts the working directory first on sys.path
    done = subprocess.run(cmd, env=_environment(package_root), capture_output=True, text=True, cwd=out.parent)
    wall = time.perf_counter() - t
    summary = [json.loads(line) for line in done.stdout.splitlines() if line.startswith('{"run"')]
    if done.returncode or not summary:
        raise SystemExit(f"{' '.join(cmd)} failed (status {done.returncode}):\n{done.stderr[-2000:]}")
    return {"wall_s": wall, "compile_s": summary[0]["compile_s"], "startup_s": summary[0].get("startup_s")}


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--baseline", required=True, help="git revision to compare with (e.g. a commit or a tag)")
    p.add_argument("--preset", default="quick")
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--out", type=Path, default=DEFAULT_OUT)
    a = p.parse_args(argv)
    load = [os.getloadavg()[0]]
    runs: dict[str, list[dict]] = {"this": [], a.baseline: []}
    steps = presets.preset(a.preset).env_steps_per_chunk  # the same for both (the quick preset's is unchanged)
    with tempfile.TemporaryDirectory() as tmp:
        versions = [("this", REPO), (a.baseline, export_package(a.baseline, Path(tmp) / "pkg").parent)]
        for _, path in versions:
            check_imports(path, Path(tmp))
        for r in range(a.rounds):
            for name, path in versions if r % 2 == 0 else versions[::-1]:  # AB, BA, AB, ...: neither always goes first
                res = one_chunk_run(steps, a.preset, Path(tmp) / f"run_{name}", path)
                runs[name].append(res)
                print(
                    f"round {r}: {name:>10}: process {res['wall_s']:.1f} s, compile {res['compile_s']:.1f} s"
                    + (f", start-up {res['startup_s']:.1f} s" if res["startup_s"] is not None else ""),
                    flush=True,
                )
    load.append(os.getloadavg()[0])
    medians = {k: statistics.median(x["wall_s"] for x in v) for k, v in runs.items()}
    print(
        f"median process: this {medians['this']:.1f} s, {a.baseline} {medians[a.baseline]:.1f} s "
        f"({medians[a.baseline] - medians['this']:+.1f} s); load {load[0]:.1f} -> {load[1]:.1f}"
    )
    merge_json(
        a.out,
        f"{a.preset}_vs_{a.baseline}",
        dict(
            runs=runs,
            median_process_s=medians,
            load=load,
            rounds=a.rounds,
            date=time.strftime("%Y-%m-%d"),
            commit=code_version(),
        ),
    )


if __name__ == "__main__":
    main()
