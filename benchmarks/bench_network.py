"""Network throughput: params, FLOPs/frame, batched forward, single-env acting Hz, train-step speed.

    python benchmarks/bench_network.py [--variants ramavt,drlavt] [--res 64,256] [--train-res 64] [--profile]
        [--out benchmarks/results_network.json]
    python benchmarks/bench_network.py --variants ramavt --res 64,256 --train-variants ""   # acting figures only

Timings vary ±30% on shared CPUs: each figure is the median of several timed repeats in one run.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import statistics
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import optax

from ramavt_jax.network import (
    NetworkConfig,
    count_params,
    flops_per_frame,
    init_params,
    initial_state,
    make_network,
)


def _time(fn, *args, repeats=5, min_time=0.3):
    """Median seconds per call (after a compile/warm-up call); each repeat loops until min_time."""
    out = fn(*args)
    jax.block_until_ready(out)
    meds = []
    for _ in range(repeats):
        n, t0 = 0, time.perf_counter()
        while True:
            out = fn(*args)
            jax.block_until_ready(out)
            n += 1
            if time.perf_counter() - t0 >= min_time:
                break
        meds.append((time.perf_counter() - t0) / n)
    return statistics.median(meds)


def bench_forward(cfg, res, ch, batch=64):
    net = make_network(cfg)
    obs_shape = (res, res, ch)
    v = init_params(cfg, jax.random.key(0), obs_shape)
    obs = jax.random.uniform(jax.random.key(1), (batch, 1, *obs_shape))
    reset = jnp.zeros((batch, 1), bool)
    s = initial_state(cfg, batch, obs_shape)
    f = jax.jit(lambda v, o, r, s: net.apply(v, o, r, s))
    return batch / _time(f, v, obs, reset, s)


def bench_acting(cfg, res, ch, steps=200):
    """Single env, T=1, B=1, jitted, carried state, greedy action pulled to the host each step."""
    net = make_network(cfg)
    obs_shape = (res, res, ch)
    v = init_params(cfg, jax.random.key(0), obs_shape)

    @jax.jit
    def act(v, o, r, s):
        q, s = net.apply(v, o[None, None], r[None, None], s)
        return jnp.argmax(q[0, 0]), s

    obs = jax.random.uniform(jax.random.key(1), obs_shape)
    r = jnp.zeros((), bool)
    s = initial_state(cfg, 1, obs_shape)
    a, s = act(v, obs, r, s)
    int(a)
    rates = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(steps):
            a, s = act(v, obs, r, s)
            int(a)  # the env needs the action on the host
        rates.append(steps / (time.perf_counter() - t0))
    return statistics.median(rates)


def make_train_step(cfg, obs_shape, b, t):
    net = make_network(cfg)
    opt = optax.adam(1e-4)

    def loss_fn(params, obs, reset, s, target):
        q, _ = net.apply({"params": params}, obs, reset, s)
        return jnp.mean(jnp.square(q - target))

    @jax.jit
    def step(params, opt_state, obs, reset, s, target):
        loss, g = jax.value_and_grad(loss_fn)(params, obs, reset, s, target)
        upd, opt_state = opt.update(g, opt_state, params)
        return optax.apply_updates(params, upd), opt_state, loss

    params = init_params(cfg, jax.random.key(0), obs_shape)["params"]
    obs = jax.random.uniform(jax.random.key(1), (b, t, *obs_shape))
    reset = jnp.zeros((b, t), bool).at[:, 0].set(True)
    s = initial_state(cfg, b, obs_shape)
    target = jax.random.normal(jax.random.key(2), (b, t, cfg.num_actions))
    return step, (params, opt.init(params), obs, reset, s, target), net


def bench_train(cfg, res, ch, b=32, t=12):
    step, args, _ = make_train_step(cfg, (res, res, ch), b, t)
    sec = _time(lambda *a: step(*a)[2], *args, repeats=3, min_time=1.0)
    return 1.0 / sec, b * t / sec


def profile_train(cfg, res, ch, b=32, t=12):
    """Where the time goes: encoder fwd / fwd+bwd vs LSTM fwd / fwd+bwd (ms per B x T batch)."""
    from ramavt_jax.layers import LSTMStack
    from ramavt_jax.network import Encoder

    obs_shape = (res, res, ch)
    params = init_params(cfg, jax.random.key(0), obs_shape)["params"]
    x = jax.random.uniform(jax.random.key(1), (b * t, *obs_shape))
    enc = Encoder(cfg)
    ep = params["encoder"]
    f_enc = jax.jit(lambda p, x: enc.apply({"params": p}, x))
    g_enc = jax.jit(jax.grad(lambda p, x: jnp.sum(enc.apply({"params": p}, x) ** 2)))
    out = {}
    out["encoder_fwd_ms"] = 1e3 * _time(f_enc, ep, x, repeats=3)
    out["encoder_fwd_bwd_ms"] = 1e3 * _time(g_enc, ep, x, repeats=3)
    if cfg.recurrent:
        lstm = LSTMStack(cfg.lstm, cfg.lstm_layers)
        lp = params["lstm"]
        xs = jax.random.normal(jax.random.key(2), (b, t, cfg.dense))
        r = jnp.zeros((b, t), bool)
        h0 = jnp.zeros((cfg.lstm_layers, b, cfg.lstm), jnp.float32)  # the LSTM alone: no frame buffer needed
        c0 = (h0, h0)
        f_l = jax.jit(lambda p, x: lstm.apply({"params": p}, x, r, c0)[0])
        g_l = jax.jit(jax.grad(lambda p, x: jnp.sum(lstm.apply({"params": p}, x, r, c0)[0] ** 2)))
        out["lstm_fwd_ms"] = 1e3 * _time(f_l, lp, xs, repeats=3)
        out["lstm_fwd_bwd_ms"] = 1e3 * _time(g_l, lp, xs, repeats=3)
    step, args, _ = make_train_step(cfg, obs_shape, b, t)
    out["train_step_ms"] = 1e3 * _time(lambda *a: step(*a)[2], *args, repeats=3, min_time=1.0)
    return out


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--variants", default="ramavt,drlavt,origin,se,mha")
    ap.add_argument("--res", default="64,256")
    ap.add_argument("--channels", type=int, default=1)
    ap.add_argument("--train-res", default="64")
    ap.add_argument("--train-variants", default="ramavt,drlavt")
    ap.add_argument("--profile", action="store_true")
    ap.add_argument("--extra", default="", help="comma list of extra ramavt configs: lax,bf16,nonorm,batchnorm")
    ap.add_argument("--out", default=str(Path(__file__).resolve().parent / "results_network.json"))
    args = ap.parse_args()
    ch = args.channels
    results = {
        "platform": platform.processor() or platform.machine(),
        "devices": str(jax.devices()),
        "jax": jax.__version__,
        "loadavg_start": os.getloadavg(),
        "rows": [],
        "train": [],
        "profile": [],
    }

    print(f"{'variant':8s} {'res':>4s} {'params':>10s} {'MFLOP/frame':>12s} {'fwd obs/s B64':>14s} {'acting Hz':>10s}")
    for variant in args.variants.split(","):
        cfg = NetworkConfig(variant=variant)
        for res in map(int, args.res.split(",")):
            shape = (res, res, ch)
            row = dict(
                variant=variant,
                res=res,
                channels=ch,
                params=count_params(jax.eval_shape(lambda k: init_params(cfg, k, shape), jax.random.key(0))),
                flops_per_frame=flops_per_frame(cfg, shape),
                forward_obs_per_s=bench_forward(cfg, res, ch),
                acting_hz=bench_acting(cfg, res, ch),
            )
            results["rows"].append(row)
            print(
                f"{variant:8s} {res:4d} {row['params']:10,d} {row['flops_per_frame'] / 1e6:12.1f} "
                f"{row['forward_obs_per_s']:14,.0f} {row['acting_hz']:10,.0f}",
                flush=True,
            )

    train_cfgs = [(v, NetworkConfig(variant=v)) for v in args.train_variants.split(",") if v]
    extras = {
        "lax": dict(conv_impl="lax"),
        "bf16": dict(dtype="bfloat16"),
        "nonorm": dict(norm="none"),
        "batchnorm": dict(norm="batch"),
    }
    for e in filter(None, args.extra.split(",")):
        train_cfgs.append((f"ramavt+{e}", dataclasses.replace(NetworkConfig(), **extras[e])))
    print(f"\n{'train config':16s} {'res':>4s} {'updates/s':>10s} {'frames/s':>10s}   (B=32 x T=12, adam, MSE)")
    for name, cfg in train_cfgs:
        for res in map(int, args.train_res.split(",")):
            ups, fps = bench_train(cfg, res, ch)
            results["train"].append(dict(config=name, res=res, updates_per_s=ups, frames_per_s=fps))
            print(f"{name:16s} {res:4d} {ups:10.2f} {fps:10,.0f}", flush=True)
            if args.profile:
                prof = profile_train(cfg, res, ch)
                results["profile"].append(dict(config=name, res=res, **prof))
                print("   " + ", ".join(f"{k}={v:.1f}" for k, v in prof.items()), flush=True)

    results["loadavg_end"] = os.getloadavg()
    os.makedirs(os.path.dirname(args.out) or ".", exist_ok=True)
    with open(args.out, "w") as f:
        json.dump(results, f, indent=1)
    print(f"\nwrote {args.out}")


if __name__ == "__main__":
    main()
