"""Where a learner update's time goes: each piece of ``Trainer.update`` jitted and timed on its own (median of
``repeats`` calls after a warm-up), on a full replay of random data, at a training preset's sizes.

    python lab/benchmarks/profile_learner.py                    # quick preset -> benchmarks/results_learner_profile.json
    python lab/benchmarks/profile_learner.py --preset paper --batch-size 8

Pieces (B windows of L = burn_in + train_len + 1 steps):
  sample        replay.sample (gather B windows, dequantise)
  target_fwd    target net over the whole window [B, L] (only when the preset bootstraps from it)
  burn_in_fwd   online net over the burn-in [B, burn_in]
  loss_grad     value_and_grad of the TD loss: online net forward + backward over [B, train_len + 1]
  encoder_grad  the conv encoder alone, forward + backward over the same B * (train_len + 1) frames
  optimizer     clip + Adam + Polyak target update
  update        the whole update as training runs it (the pieces fused by XLA; it can be less than their sum)

``--trace`` adds a profiler trace of the whole update: every XLA:CPU thunk's exclusive time attributed to the
innermost line of ramavt_jax that produced it, split into forward and backward (lab/benchmarks/hlo_profile.py).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import optax
from bench_train import _filled_replay, _median_time, machine_info, merge_json  # noqa: E402 (the script's directory)
from hlo_profile import trace_breakdown  # noqa: E402
from profile_env import _line  # noqa: E402

from ramavt_jax import presets
from ramavt_jax import train as T
from ramavt_jax.network import Encoder, window_start_frames


def _label(stack, op_name, thunk):
    """'forward|backward | file:function: source line' of the innermost ramavt_jax frame of one thunk."""
    kind = "backward" if "transpose(" in op_name else "forward"
    own = next(((f, fn, ln) for f, fn, ln in stack if "ramavt_jax/" in f), None)
    if own is None:
        return f"{kind} | other (scan, optimizer internals) | {thunk.rsplit('.', 1)[0]}"
    short = own[0].split("ramavt_jax/")[1]
    return f"{kind} | {short}:{own[1]}: {_line(own[0], own[2])[:70]}"


def profile(
    preset: str, repeats: int, batch_size: int | None = None, trace: bool = False, network: dict | None = None
) -> dict:
    """The pieces' times at ``preset``'s sizes; ``network``: NetworkConfig fields replaced (e.g. the stem)."""
    cfg = presets.preset(preset, eval_episodes=0, learning_starts=0)
    if batch_size:
        cfg = cfg.override(batch_size=batch_size)
    if network:
        cfg = cfg.override(network=dataclasses.replace(cfg.network, **network))
    tr = T.Trainer(cfg)
    key = jax.random.PRNGKey(0)
    state = jax.jit(tr.init)(key)
    learner, replay_state = state.learner, _filled_replay(tr, key)
    params, burn = learner.params, cfg.replay.burn_in
    sample = jax.jit(tr.replay.sample)
    batch = sample(replay_state, key)
    prepare = jax.jit(tr.prepare)
    prepared = prepare(params, learner.target_params, batch, key)
    start = batch.start_state.replace(frames=window_start_frames(cfg.network, batch.obs))
    target_fwd = jax.jit(lambda p: tr.q_values(p, batch.obs, batch.reset, start, batch.action)[0])
    burn_fwd = jax.jit(
        lambda p: tr.q_values(p, batch.obs[:, :burn], batch.reset[:, :burn], start, batch.action[:, :burn])[1]
    )
    loss_grad = jax.jit(jax.value_and_grad(tr.trained_loss, has_aux=True))
    frames = prepared.obs.reshape(-1, *prepared.obs.shape[2:])
    encoder = Encoder(cfg.network)
    enc_params = params["encoder"]
    encoder_grad = jax.jit(jax.grad(lambda p: jnp.sum(encoder.apply({"params": p}, frames) ** 2)))
    grads = loss_grad(params, prepared)[1]

    def opt_step(lrn, g):
        updates, opt_state = tr.optimizer.update(g, lrn.opt_state, lrn.params)
        new = optax.apply_updates(lrn.params, updates)
        return new, opt_state, optax.incremental_update(new, lrn.target_params, cfg.learner.polyak_tau)

    optimizer = jax.jit(opt_step)
    update = jax.jit(tr.update)
    pieces = {
        "sample": lambda: sample(replay_state, key),
        "burn_in_fwd": lambda: burn_fwd(params),
        "loss_grad": lambda: loss_grad(params, prepared),
        "encoder_grad": lambda: encoder_grad(enc_params),
        "optimizer": lambda: optimizer(learner, grads),
        "update": lambda: update(learner, replay_state, key),
    }
    if cfg.learner.bootstrap_from == "target":  # with 'online' the update runs no target pass
        pieces["target_fwd"] = lambda: target_fwd(learner.target_params)
    times_ms = {name: 1e3 * _median_time(fn, repeats) for name, fn in pieces.items()}
    trained = cfg.replay.batch_size * cfg.replay.train_len
    breakdown = {}
    if trace:
        hlo = update.lower(learner, replay_state, key).compile().as_text()
        breakdown = trace_breakdown(update, (learner, replay_state, key), repeats, _label, hlo)
    return {
        "trace_ms": {k: 1e3 * v for k, v in breakdown.items()},
        "preset": preset,
        "bootstrap_from": cfg.learner.bootstrap_from,
        "batch_size": cfg.replay.batch_size,
        "burn_in": burn,
        "train_len": cfg.replay.train_len,
        "times_ms": times_ms,
        "updates_per_s": 1e3 / times_ms["update"],
        "trained_frames_per_s": trained * 1e3 / times_ms["update"],
    }


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--preset", default="quick", choices=sorted(presets.PRESETS))
    p.add_argument("--batch-size", type=int, default=None)
    p.add_argument("--repeats", type=int, default=20)
    p.add_argument("--trace", action="store_true", help="also attribute the update's time to source lines")
    p.add_argument("--out", default=str(Path(__file__).resolve().parent / "results_learner_profile.json"))
    p.add_argument(
        "--network",
        type=json.loads,
        default=None,
        help='NetworkConfig fields as JSON, e.g. \'{"kernels": [4, 3, 3], "strides": [4, 1, 1], '
        '"pools": [false, true, false]}\' (the patch stem)',
    )
    p.add_argument("--key", default=None, help="the result's key in --out (default: PRESET_bBATCH)")
    a = p.parse_args(argv)
    t0, load0 = time.time(), os.getloadavg()
    res = profile(a.preset, a.repeats, a.batch_size, a.trace, a.network)
    res["network_overrides"] = a.network
    res["machine"] = machine_info(load0, t0)
    total = res["times_ms"]["update"]
    for name, ms in res["times_ms"].items():
        print(f"{name:13} {ms:8.2f} ms  {100 * ms / total:5.1f} % of an update")
    print(
        f"update: {res['updates_per_s']:.1f}/s, {res['trained_frames_per_s']:.0f} trained frames/s "
        f"(load {load0[0]:.1f} -> {os.getloadavg()[0]:.1f})"
    )
    if res["trace_ms"]:
        traced = sum(res["trace_ms"].values())
        print(f"\nprofiler trace of the update ({traced:.1f} ms of thunks per update), top 30:")
        for name, ms in list(res["trace_ms"].items())[:30]:
            print(f"  {ms:7.2f} ms {100 * ms / traced:5.1f} %  {name}")
    merge_json(a.out, a.key or f"{a.preset}_b{res['batch_size']}", res)


if __name__ == "__main__":
    main()
