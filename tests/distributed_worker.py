"""Subprocess worker for tests/test_distributed.py (device counts are fixed when JAX starts, so these checks run
in a fresh interpreter with XLA_FLAGS=--xla_force_host_platform_device_count=N). Prints one JSON line."""

import json
import sys

import jax
import numpy as np


def _max_diff(a, b) -> float:
    return max(
        float(np.max(np.abs(np.asarray(x, np.float64) - np.asarray(y, np.float64))))
        for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b))
    )


def sharded_vs_unsharded(chunks: int) -> dict:
    from ramavt_jax import distributed
    from ramavt_jax.presets import preset
    from ramavt_jax.training import program

    cfg = preset("smoke")
    mesh = distributed.make_mesh()
    states, metrics = {}, {}
    for name, m in (("single", None), ("sharded", mesh)):
        prog = program.compiled_program(cfg, None, 1, m)
        state = prog.init(jax.random.PRNGKey(0))
        ms = []
        for _ in range(chunks):
            state, met = prog.chunk(state)
            ms.append(jax.device_get(met))
        states[name], metrics[name] = state, ms
    sh = states["sharded"]

    def placement(x):
        return {
            "devices": sorted(d.id for d in x.sharding.device_set),
            "shard_shapes": sorted({tuple(s.data.shape) for s in x.addressable_shards}),
            "distinct_shards": len(
                {tuple((i.start, i.stop) for i in s.index if isinstance(i, slice)) for s in x.addressable_shards}
            ),
            "replicated": bool(x.sharding.is_fully_replicated),
            "shape": list(x.shape),
        }

    return {
        "device_count": jax.device_count(),
        "params_max_diff": _max_diff(states["single"].learner.params, sh.learner.params),
        "params_max_abs": max(float(np.max(np.abs(np.asarray(x)))) for x in jax.tree.leaves(sh.learner.params)),
        "loss_single": [float(m.loss_sum.sum()) for m in metrics["single"]],
        "loss_sharded": [float(m.loss_sum.sum()) for m in metrics["sharded"]],
        "updates": int(sh.learner.updates),
        "episode_length_single": [float(m.episode_length_sum.sum()) for m in metrics["single"]],
        "episode_length_sharded": [float(m.episode_length_sum.sum()) for m in metrics["sharded"]],
        "obs": placement(sh.actor.obs),
        "lstm_h": placement(sh.actor.net_state.h),
        "env_pos": placement(sh.actor.env_state.chaser_pos),
        "replay_obs": placement(sh.replay.experience.obs),
        "param": placement(jax.tree.leaves(sh.learner.params)[0]),
    }


def seeds_over_devices() -> dict:
    """2 seeds in one program on 2 devices (one seed per device) vs the same program on one device."""
    from ramavt_jax import distributed
    from ramavt_jax.presets import preset
    from ramavt_jax.training import program

    cfg = preset("smoke")
    keys = np.stack([np.asarray(jax.random.PRNGKey(s)) for s in (3, 4)])
    out = {}
    for name, mesh in (("single", None), ("sharded", distributed.make_mesh())):
        prog = program.compiled_program(cfg, None, 2, mesh)
        state = prog.init(keys)
        for _ in range(2):
            state, _ = prog.chunk(state)
        out[name] = state
    obs = out["sharded"].actor.obs
    try:
        program.compiled_program(cfg, None, 3, distributed.make_mesh())
        error = None
    except distributed.ShardingError as e:
        error = str(e)
    return {
        "params_max_diff": _max_diff(out["single"].learner.params, out["sharded"].learner.params),
        "obs_devices": len(obs.sharding.device_set),
        "obs_shard_shapes": sorted({tuple(s.data.shape) for s in obs.addressable_shards}),
        "three_seeds_error": error,
    }


def indivisible() -> dict:
    from ramavt_jax import distributed
    from ramavt_jax.presets import preset
    from ramavt_jax.training import program

    cfg = preset("smoke")  # 8 envs; the test starts 3 devices
    try:
        program.compiled_program(cfg, None, 1, distributed.make_mesh())
    except distributed.ShardingError as e:
        return {"error": str(e)}
    return {"error": None}


if __name__ == "__main__":
    mode = sys.argv[1]
    if mode == "shard":
        out = sharded_vs_unsharded(int(sys.argv[2]))
    elif mode == "seeds":
        out = seeds_over_devices()
    else:
        out = indivisible()
    print("RESULT " + json.dumps(out))
