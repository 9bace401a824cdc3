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
        locs[int(i)] = (
            files.get(int(kv["file_name_id"]), "?"),
            funcs.get(int(kv["function_name_id"]), "?"),
            int(kv["line"]),
        )
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


_BYTES = {
    "pred": 1,
    "s8": 1,
    "u8": 1,
    "bf16": 2,
    "f16": 2,
    "s16": 2,
    "u16": 2,
    "f32": 4,
    "s32": 4,
    "u32": 4,
    "f64": 8,
    "s64": 8,
    "u64": 8,
}
_SKIP = {"parameter", "constant", "bitcast", "get-tuple-element", "tuple", "while", "conditional", "call"}
_PARTIAL_READS = {"slice", "gather", "dynamic-slice"}  # read about as many bytes as they write, not their operand


def _shape_bytes(text: str) -> int:
    total = 0
    for dtype, dims in re.findall(r"\b(" + "|".join(_BYTES) + r")\[([\d,]*)\]", text):
        n = 1
        for d in filter(None, dims.split(",")):
            n *= int(d)
        total += n * _BYTES[dtype]
    return total


def _computations(text: str) -> dict:
    """name -> (is_entry, [(instruction, result type, opcode, rest of the line)], whether it only picks parts of its
    input: its root is a slice or gather, or a bitcast of one)."""
    comps = {}
    for block in re.split(r"\n(?=\S)", text):
        head = re.match(r"(ENTRY )?%?([\w.\-]+)", block.split("\n", 1)[0])
        if not head:
            continue
        lines = list(re.finditer(r"^\s*(ROOT )?%?([\w.\-]+) = (\S+|\(.*?\)) ([\w\-]+)\((.*)$", block, re.M))
        root = next((m.group(4) for m in lines if m.group(1)), None)
        picks = root in _PARTIAL_READS or (
            root in ("bitcast", "reshape") and any(m.group(4) in _PARTIAL_READS for m in lines)
        )
        comps[head.group(2)] = (bool(head.group(1)), [m.groups()[1:] for m in lines], picks)
    return comps


def _run_counts(comps: dict) -> dict:
    """How often each computation that runs as a whole (not a fusion body) runs per call: ENTRY once, a while body
    and condition times the loop's known trip count (times its caller's count), both branches of a conditional
    and any called computation as often as their caller."""
    calls = collections.defaultdict(list)  # caller -> [(callee, times per caller run)]
    for caller, (_, body, _) in comps.items():
        for _, _, op, rest in body:
            known = re.search(r'known_trip_count=\{"n":"(\d+)"\}', rest)
            trips = int(known.group(1)) if op == "while" and known else 1
            names = re.findall(r"(?:body|condition|to_apply|true_computation|false_computation)=%?([\w.\-]+)", rest)
            for group in re.findall(r"branch_computations=\{([^}]*)\}", rest):
                names += [n.strip().lstrip("%") for n in group.split(",")]
            calls[caller] += [(callee, trips) for callee in names]
    counts = {name: 1 for name, (entry, _, _) in comps.items() if entry}
    todo = list(counts)
    while todo:
        caller = todo.pop()
        for callee, trips in calls[caller]:
            if callee not in counts:
                counts[callee] = counts[caller] * trips
                todo.append(callee)
    return counts


def traffic_breakdown(hlo_text: str, label) -> tuple[dict, dict]:
    """Bytes each instruction of a compiled CPU program that is not inside a fusion reads and writes per call (see
    ``_run_counts`` for loops and branches), attributed like ``trace_breakdown``. Returns ({label: bytes}, totals)
    where totals has ``whole_operands`` (every operand counted whole, as XLA's cost analysis does) and ``used``
    (slices and gathers counted at their output's size: what they really read)."""
    inst, ops = _parse_hlo_stacks(hlo_text)
    comps = _computations(hlo_text)
    size = {name: _shape_bytes(typ) for _, body, _ in comps.values() for name, typ, _, _ in body}
    by_label, totals = collections.Counter(), {"whole_operands": 0, "used": 0}
    for comp, times in _run_counts(comps).items():
        for name, _, op, rest in comps.get(comp, (0, [], 0))[1]:
            if op in _SKIP:
                continue
            read = sum(size.get(o, 0) for o in re.findall(r"%([\w.\-]+)", rest.split(")", 1)[0]))
            fused = re.search(r"calls=%?([\w.\-]+)", rest)
            partial = op in _PARTIAL_READS or (op == "fusion" and fused and comps.get(fused.group(1), (0, 0, 0))[2])
            used = size[name] + (min(read, size[name]) if partial else read)
            totals["whole_operands"] += times * (size[name] + read)
            totals["used"] += times * used
            by_label[label(inst.get(name, []), ops.get(name, ""), name)] += times * used
    return dict(by_label.most_common()), totals
