"""Attribute the measured time of a jitted CPU program to the Python source that produced it.

`trace_breakdown(compiled_fn, args, calls, label)` runs ``calls`` calls under ``jax.profiler.trace``, takes every
XLA:CPU thunk event (fusions, loops, copies, scatters, ...), turns it into *exclusive* time (minus the events nested in
it on the same thread) and maps the thunk's HLO instruction to its Python call stack (the ``StackFrames`` table of
the compiled HLO text). ``label(stack)`` names the part of the program a stack belongs to; the result is
{label: seconds per call}.
"""

from __future__ import annotations

import collections
import glob
import gzip
import json
import re
import shutil
import tempfile

import jax


def _parse_hlo_stacks(text: str):
    """instruction name -> list of (file, function, line), innermost first."""
    def table(name):
        m = re.search(rf"^{name}\n(.*?)(?:\n\n|\Z)", text, re.S | re.M)
        return m.group(1).splitlines() if m else []

    files = {int(i): s.strip('"') for i, s in (ln.split(" ", 1) for ln in table("FileNames"))}
    funcs = {int(i): s.strip('"') for i, s in (ln.split(" ", 1) for ln in table("FunctionNames"))}
    locs = {}
    for ln in table("FileLocations"):
        i, rest = ln.split(" ", 1)
        kv = dict(re.findall(r"(\w+)=(\d+)", rest))
        locs[int(i)] = (files.get(int(kv["file_name_id"]), "?"), funcs.get(int(kv["function_name_id"]), "?"), int(kv["line"]))
    frames = {}
    for ln in table("StackFrames"):
        i, rest = ln.split(" ", 1)
        kv = dict(re.findall(r"(\w+)=(\d+)", rest))
        frames[int(i)] = (int(kv["file_location_id"]), int(kv["parent_frame_id"]))

    def stack(fid):
        out, seen = [], set()
        while fid in frames and fid not in seen:
            seen.add(fid)
            loc, parent = frames[fid]
            out.append(locs.get(loc, ("?", "?", 0)))
            fid = parent
        return out

    inst = {}
    for m in re.finditer(r"%?([\w.\-]+) = [^\n]*?stack_frame_id=(\d+)", text):
        inst[m.group(1)] = stack(int(m.group(2)))
    ops = {m.group(1): m.group(2) for m in re.finditer(r"%?([\w.\-]+) = [^\n]*?op_name=\"([^\"]*)\"", text)}
    return inst, ops


def _exclusive(events):
    """Exclusive durations (us) of X events, nesting by containment per thread."""
    out = []
    by_tid = collections.defaultdict(list)
    for e in events:
        by_tid[e["tid"]].append(e)
    for evs in by_tid.values():
        evs.sort(key=lambda e: (e["ts"], -e["dur"]))
        stack = []  # [event, child time]
        for e in evs:
            while stack and e["ts"] >= stack[-1][0]["ts"] + stack[-1][0]["dur"] - 1e-3:
                done = stack.pop()
                out.append((done[0]["name"], done[0]["dur"] - done[1]))
            if stack:
                stack[-1][1] += e["dur"]
            stack.append([e, 0.0])
        while stack:
            done = stack.pop()
            out.append((done[0]["name"], done[0]["dur"] - done[1]))
    return out


def trace_breakdown(fn, args, calls: int, label, hlo_text: str):
    """{label: seconds per call} for `calls` calls of the compiled `fn(*args)` (already warmed up)."""
    inst, ops = _parse_hlo_stacks(hlo_text)
    tmp = tempfile.mkdtemp(prefix="ramavt_trace_")
    try:
        with jax.profiler.trace(tmp, create_perfetto_trace=True):
            for _ in range(calls):
                jax.block_until_ready(fn(*args))
        path = glob.glob(f"{tmp}/**/*.trace.json.gz", recursive=True)[0]
        events = [e for e in json.load(gzip.open(path))["traceEvents"] if e.get("ph") == "X"]
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    total = collections.Counter()
    for name, us in _exclusive(events):
        if name not in inst and name not in ops:
            continue  # Python / runtime events
        total[label(inst.get(name, []), ops.get(name, ""), name)] += us * 1e-6 / calls
    return dict(total.most_common())
