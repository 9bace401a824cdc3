"""The encoder's conv implementations against the im2col baseline, at a training preset's sizes, timed interleaved.

    python lab/benchmarks/bench_conv.py                 # quick preset -> benchmarks/results_conv.json
    python lab/benchmarks/bench_conv.py --seeds 3       # the layers also vmapped over 3 seeds' kernels

Two parts, every implementation's calls alternating with the others' in the same process (same machine load):
  layers   each conv of the preset's encoder alone, over the frames one learner update feeds it: the forward of
           the passes without a gradient (target net + online burn-in: B * (L + burn_in) frames) and the kernel
           gradient of the trained part (B * (train_len + 1) frames), for 'im2col' (the baseline), 'lax', 'hybrid'
  update   one whole learner update (Trainer.update on a full replay of random data) per conv_impl

Medians over ``--rounds`` rounds of the fastest of 3 back-to-back calls; the 1-minute load average is printed
beside the figures. Compare within one run.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import os
import statistics
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp

sys.path[:0] = [str(Path(__file__).resolve().parent), str(Path(__file__).resolve().parents[2] / "benchmarks")]
from bench_train import _filled_replay, machine_info, merge_json  # noqa: E402

from ramavt_jax import presets, train_config  # noqa: E402
from ramavt_jax import train as T  # noqa: E402
from ramavt_jax.layers import CONV_FUNCTIONS, conv_out_size  # noqa: E402

IMPLS = ("im2col", "lax", "hybrid")  # the first is the baseline


def _encoder_layers(cfg: train_config.TrainConfig) -> list[dict]:
    """(input shape, kernel shape, stride) of each conv of the preset's encoder, as one frame reaches it."""
    net, (h, w, c) = cfg.network, cfg.env.obs_shape
    c = c + 1 if net.coord_channels else c  # the hit mask joins the frame; the coordinate planes are added apart
    layers = []
    for ch, k, s, pool in zip(net.channels, net.kernels, net.strides, net.pools):
        layers.append(dict(frame=(h, w, c), kernel=(k, k, c, ch), stride=s))
        h, w, c = conv_out_size(h, k, s), conv_out_size(w, k, s), ch
        if pool:  # max_pool2: 2x2, ceil mode
            h, w = -(-h // 2), -(-w // 2)
    return layers


def _layer_fns(layer: dict, seeds: int):
    """{impl: (forward, kernel gradient)} jitted for one layer (vmapped over seeds' kernels when seeds > 1)."""
    fns = {}
    for impl in IMPLS:
        conv = functools.partial(CONV_FUNCTIONS[impl], stride=layer["stride"])
        fwd = conv
        grad = jax.grad(lambda k, x, conv=conv: jnp.sum(jnp.sin(conv(x, k))))
        if seeds > 1:
            fwd, grad = jax.vmap(fwd), jax.vmap(grad)
        fns[impl] = (jax.jit(fwd), jax.jit(grad))
    return fns


def _interleaved(calls: dict, rounds: int, repeats: int = 3) -> dict:
    """{name: median seconds per call}: each round times ``repeats`` back-to-back calls of each function in turn
    (after one warm-up call each); the median over rounds of the fastest call of the round."""
    for fn in calls.values():
        jax.block_until_ready(fn())
    times = {name: [] for name in calls}
    for _ in range(rounds):
        for name, fn in calls.items():
            best = float("inf")
            for _ in range(repeats):
                t = time.perf_counter()
                jax.block_until_ready(fn())
                best = min(best, time.perf_counter() - t)
            times[name].append(best)
    return {name: statistics.median(ts) for name, ts in times.items()}


def bench_layers(cfg: train_config.TrainConfig, seeds: int, rounds: int) -> list[dict]:
    r = cfg.replay
    no_grad_frames = r.batch_size * (2 * r.burn_in + r.train_len + 1)
    grad_frames = r.batch_size * (r.train_len + 1)
    rows = []
    for i, layer in enumerate(_encoder_layers(cfg)):
        lead = (seeds,) if seeds > 1 else ()
        kx, kk = jax.random.split(jax.random.PRNGKey(i))
        x_fwd = jax.random.uniform(kx, (*lead, no_grad_frames, *layer["frame"]))
        x_grad = x_fwd[..., :grad_frames, :, :, :]
        kernel = 0.1 * jax.random.normal(kk, (*lead, *layer["kernel"]))
        fns = _layer_fns(layer, seeds)
        calls = {}
        for impl, (fwd, grad) in fns.items():
            calls[f"{impl} forward"] = lambda fwd=fwd: fwd(x_fwd, kernel)
            calls[f"{impl} kernel gradient"] = lambda grad=grad: grad(kernel, x_grad)
        med = _interleaved(calls, rounds)
        row = dict(
            layer=f"conv{i}",
            frame=layer["frame"],
            kernel=layer["kernel"],
            stride=layer["stride"],
            forward_frames=no_grad_frames,
            gradient_frames=grad_frames,
            ms={name: 1e3 * t for name, t in med.items()},
        )
        rows.append(row)
        print(
            f"  conv{i} {layer['frame']} -> {layer['kernel'][-1]} stride {layer['stride']}: "
            + ", ".join(f"{name} {1e3 * t:.1f} ms" for name, t in med.items()),
            flush=True,
        )
    return rows


def bench_update(cfg: train_config.TrainConfig, rounds: int) -> dict:
    key = jax.random.PRNGKey(0)
    trainers = {
        impl: T.Trainer(cfg.override(network=dataclasses.replace(cfg.network, conv_impl=impl))) for impl in IMPLS
    }
    base = trainers[IMPLS[0]]
    learner, replay_state = jax.jit(base.init)(key).learner, _filled_replay(base, key)
    updates = {impl: jax.jit(tr.update) for impl, tr in trainers.items()}
    med = _interleaved({impl: lambda u=u: u(learner, replay_state, key) for impl, u in updates.items()}, rounds)
    trained = cfg.replay.batch_size * cfg.replay.train_len
    out = {
        impl: dict(update_ms=1e3 * t, trained_frames_per_s=trained / t, vs_im2col=med[IMPLS[0]] / t)
        for impl, t in med.items()
    }
    for impl, row in out.items():
        print(
            f"  update, conv_impl={impl}: {row['update_ms']:.1f} ms, {row['trained_frames_per_s']:.0f} trained "
            f"frames/s, {row['vs_im2col']:.2f}x im2col",
            flush=True,
        )
    return out


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="quick", choices=sorted(presets.PRESETS))
    p.add_argument("--seeds", type=int, default=1, help="vmap the layers over this many seeds' kernels")
    p.add_argument("--rounds", type=int, default=15)
    p.add_argument("--skip-update", action="store_true", help="only the layers")
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "results_conv.json"))
    a = p.parse_args(argv)
    if a.seeds < 1 or a.rounds < 1:
        p.error("--seeds and --rounds must be >= 1")
    cfg = presets.preset(a.preset, eval_episodes=0, learning_starts=0)
    load0, t0 = os.getloadavg(), time.time()
    print(f"conv implementations at the {a.preset} preset's sizes, {a.seeds} seed(s), load {load0[0]:.2f}")
    res = {"preset": a.preset, "seeds": a.seeds, "rounds": a.rounds, "layers": bench_layers(cfg, a.seeds, a.rounds)}
    if not a.skip_update:
        res["update"] = bench_update(cfg, a.rounds)
    res["machine"] = machine_info(load0, t0)
    print(f"load {load0[0]:.2f} -> {os.getloadavg()[0]:.2f}, {time.time() - t0:.0f} s")
    merge_json(a.out, f"{a.preset}_seeds{a.seeds}", res)


if __name__ == "__main__":
    main()
