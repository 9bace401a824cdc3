"""The new renderer against the previous one (render/legacy.py) on the same scenes, calls interleaved.

    python benchmarks/compare_renderers.py [ENVS]

Scenes: bench_render.make_scene (training targets, random attitudes) pulled to 1.5-7.5 m so that about 9 % of the
pixels hit. Prints the image agreement, then min and median ms per render_batch call (depth only, RGBD, and all
targets behind the camera = the renderer's fixed cost) for the old, the new and the new renderer with the general
kernel only (specialise=False).
"""
import time, statistics, jax, jax.numpy as jnp, numpy as np, sys
sys.path.insert(0, __import__('os').path.dirname(__file__))
from bench_render import make_scene
from ramavt_jax import render as R
from ramavt_jax.render import legacy, renderer
N=int(sys.argv[1]) if len(sys.argv)>1 else 64
batch,pos,rot,*_ = make_scene(N)
pos = pos.at[:,2].set(pos[:,2]*0.5+1.5)  # nearer: more hits
cam=R.CameraConfig(resolution=64); light=R.default_lighting()
fns = {}
for sh in (False, True):
    a = legacy.render_batch(batch,pos,rot,cam,light,shade=sh)
    for spec in (False, True):
        b = renderer.render_batch(batch,pos,rot,cam,light,shade=sh,specialise=spec)
        print("shade",sh,"spec",spec,"hit", float(a.hit.mean()), "hit mismatch", int((a.hit!=b.hit).sum()), "depth err", float(jnp.abs(a.depth-b.depth).max()), "rgb err>1e-3", int((jnp.abs(a.rgb-b.rgb).max(-1)>1e-3).sum()))
    fns[f"legacy shade={sh}"] = jax.jit(lambda b_,p_,r_,sh=sh: (lambda fr: fr.depth.sum()+fr.rgb.sum())(legacy.render_batch(b_,p_,r_,cam,light,shade=sh)))
    fns[f"new shade={sh}"] = jax.jit(lambda b_,p_,r_,sh=sh: (lambda fr: fr.depth.sum()+fr.rgb.sum())(renderer.render_batch(b_,p_,r_,cam,light,shade=sh)))
    fns[f"new-general shade={sh}"] = jax.jit(lambda b_,p_,r_,sh=sh: (lambda fr: fr.depth.sum()+fr.rgb.sum())(renderer.render_batch(b_,p_,r_,cam,light,shade=sh,specialise=False)))
far = pos.at[:,2].set(-1e6)
fns["legacy culled"] = lambda b_,p_,r_: legacy.render_batch(b_,far,r_,cam,light,shade=False).depth.sum()
fns["new culled"] = lambda b_,p_,r_: renderer.render_batch(b_,far,r_,cam,light,shade=False).depth.sum()
ts = {k: [] for k in fns}
for k,f in fns.items(): jax.block_until_ready(f(batch,pos,rot))
for _ in range(15):
    for k,f in fns.items():
        t0=time.perf_counter(); jax.block_until_ready(f(batch,pos,rot)); ts[k].append(time.perf_counter()-t0)
for k,v in ts.items(): print(f"{k:28s} min {min(v)*1e3:7.3f} ms  median {statistics.median(v)*1e3:7.3f}")
