"""Learning experiments: arms of the `quick` preset, each changing one thing, trained with several seeds as one
vmapped program and evaluated on the SAME held-out episodes (fixed evaluation key; the episodes do not depend on the
policy). Results go to OUT/<arm>/ (run folders seed_k/) and OUT/<arm>/heldout.json; `report` prints the table.

    python lab/learning_arms.py train base see grid boot all --seeds 3 --out runs/arms
    python lab/learning_arms.py train rgbd color --seeds 3 --out runs/arms       # Table I's inputs
    python lab/learning_arms.py eval base see grid boot all baselines --out runs/arms
    python lab/learning_arms.py train long-lr2 --seeds 3 --out runs/arms  # seed 0: ramavt_depth_long
    python lab/learning_arms.py train q-rgbd q-color q-origin q-aug q-se q-mha --seeds 3 --out runs/arms  # Tables
    python lab/learning_arms.py report --out runs/arms
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from lab import arm_components as parts
from ramavt_jax import baselines, greedy, presets
from ramavt_jax import env as env_lib
from ramavt_jax import targets as targets_lib
from ramavt_jax.evaluation import runs, statistics
from ramavt_jax.train import Components, default_loss_terms
from ramavt_jax.training.driver import run as train_run


def _net(cfg, **kw):
    return dataclasses.replace(cfg, network=dataclasses.replace(cfg.network, **kw))


def _obs(cfg, mode: str):
    return dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, obs_mode=mode))


def _env(cfg, **params):
    """The run's EnvParams overrides with `params` added (the others kept)."""
    return cfg.override(env_params={**dict(cfg.env_params), **params})


_res64 = presets.at_64x64  # 64x64 depth with an 8x8 first patch (the 4x4 token grid kept): the sizes preset's


# One change per arm against 'base', the quick preset as it was before the learning fixes (a 2x2 final map, an
# encoder blind to depth scale and position, 'target lost' as a terminal state, no previous action); 'all' combines
# the first three changes, 'prev' is 'all' + the previous action into the LSTM, and 'prev-aux' ('prev' + the
# auxiliary tracking-error loss) with twice the learning rate ('aux-lr2') was the quick preset before the patch
# layers ('patch', below); 'avg-12' was the quick preset until 'avg-1536k', and that until 'expert-margin', the quick
# preset now (arm_config checks that).
_LR = 5e-4  # the quick preset's learning rate before 'aux-lr2': every arm's, unless it changes it


def _base(c):
    net = dataclasses.replace(
        c.network,
        coord_channels=False,
        pooled_skip=False,
        kernels=(3, 3, 3),
        strides=(2, 1, 1),
        pools=(True, True, True),
        prev_action=False,
        aux_outputs=0,
    )
    return c.override(
        network=net,
        bootstrap_lost=False,
        aux_weight=0.0,
        lr=_LR,
        total_env_steps=384_000,
        max_grad_norm=10.0,  # every arm before 'clip-1' clipped at norm 10
        bootstrap_from="target",  # and every arm before 'online-boot' bootstrapped from the target net
        policy_params="target",
        policy_average_from=None,  # and acted with the target params
        expert_margin_weight=0.0,
    )  # and every arm before 'expert-margin' had no margin loss


ARMS = {
    "base": _base,
    "see": lambda c: _net(_base(c), coord_channels=True, pooled_skip=True),  # depth scale + position visible
    "grid": lambda c: _net(_base(c), pools=(True, True, False)),  # 4x4 feature map (16 attention tokens) at 32x32
    "boot": lambda c: _base(c).override(bootstrap_lost=True),  # no incentive to lose the target
    "all": lambda c: _net(_base(c), coord_channels=True, pooled_skip=True, pools=(True, True, False)).override(
        bootstrap_lost=True
    ),
}
# Table I's inputs at the quick budget: 'all' seeing colour or colour + depth instead of depth.
ARMS["rgbd"] = lambda c: _obs(ARMS["all"](c), "rgbd")
ARMS["color"] = lambda c: _obs(ARMS["all"](c), "color")
# Train on the evaluation's reward weight (1.0 per metre, not the original training value 0.5): AER is scored with 1.0.
ARMS["dw1"] = lambda c: ARMS["all"](c).override(env_params=(("dist_weight", 1.0),))
# R2D2's recurrent input: the previous action one-hot beside the encoder's features at the LSTM's input.
ARMS["prev"] = lambda c: _net(ARMS["all"](c), prev_action=True)
# Table III's ablation at the quick budget, each one change to the plain DRQN ('origin') as in the paper: + label-
# preserving augmentation (cutout), + SE, + MHA; 'all' is the RAMAVT row (SE + MHA, no augmentation).
ARMS["origin"] = lambda c: _net(ARMS["all"](c), variant="origin")
ARMS["aug"] = lambda c: ARMS["origin"](c).override(augment=True)
ARMS["se"] = lambda c: _net(ARMS["all"](c), variant="se")
ARMS["mha"] = lambda c: _net(ARMS["all"](c), variant="mha")
# The longer CPU budget: 'all' with 3x the env steps, slower exploration decay, a bigger replay (the first `long`
# preset; 'long-lr2' below was the preset until 'avg-2304k' replaced it, and `ramavt train --preset long $L10`
# gives it back, lab/reproduce.md; a test checks both).
_LONGER = dict(total_env_steps=1_152_000, eps_decay_steps=400_000, capacity_steps=128_000, checkpoint_every_chunks=6)
ARMS["long"] = lambda c: ARMS["all"](c).override(**_LONGER)
# The same budget with the previous-action input ('prev', the quick preset's network).
ARMS["long-prev"] = lambda c: ARMS["prev"](c).override(**_LONGER)
# Each one change to 'prev' (the quick preset when they ran). SE without the attention (the best
# AER of Table III's single modules):
ARMS["prev-se"] = lambda c: _net(ARMS["prev"](c), variant="se")
# Two levers on distance keeping: the evaluation's distance weight in training, and a learning rate decaying
# (cosine) to a tenth over the run ('prev-lrdecay', retired with the package's arm fields: lab/README.md).
ARMS["prev-dw1"] = lambda c: ARMS["prev"](c).override(env_params=(("dist_weight", 1.0),))
# The opposite lever (prev-lrdecay lost AER): twice the learning rate throughout.
ARMS["prev-lr2"] = lambda c: ARMS["prev"](c).override(lr=2 * _LR)
# A dueling head ('prev-duel', retired) and advantage learning (alpha 0.9, the published value: targets of worse
# actions lowered, widening the gaps; its TD term in COMPONENTS below).
ARMS["prev-al"] = lambda c: ARMS["prev"](c)


def _with_aux(cfg):
    return cfg.override(network=dataclasses.replace(cfg.network, aux_outputs=3), aux_weight=1.0)


# An auxiliary loss: the LSTM output predicts the true tracking error (simulator state, training only), so the
# encoder and memory are taught where the target is, boresight distance above all, from the first update on.
ARMS["prev-aux"] = lambda c: _with_aux(ARMS["prev"](c))
# The same auxiliary loss on the long budget (one change to `long`); with twice the learning rate ('long-lr2',
# below) it was the `long` preset until 2026-12-06 and the shipped agent until 2026-12-03 (ramavt_depth_long).
ARMS["long-aux"] = lambda c: _with_aux(ARMS["long"](c))
# Each one change to 'prev-aux' (the quick preset then): the auxiliary loss weighted 3x, twice the
# learning rate (a decaying one cost AER: the agent is still learning at the end), a dueling head ('aux-duel',
# retired), advantage learning (its TD term in COMPONENTS).
ARMS["aux-w3"] = lambda c: ARMS["prev-aux"](c).override(aux_weight=3.0)
ARMS["aux-lr2"] = lambda c: ARMS["prev-aux"](c).override(lr=2 * _LR)
ARMS["aux-al"] = lambda c: ARMS["prev-aux"](c)
# aux-lr2 gained most with the target params: four times the learning rate, and twice it on the long budget.
ARMS["aux-lr4"] = lambda c: ARMS["prev-aux"](c).override(lr=4 * _LR)
ARMS["long-lr2"] = lambda c: ARMS["long-aux"](c).override(lr=2 * _LR)
# Tables I and III, each row one change to the quick preset ('aux-lr2', the depth /
# RAMAVT row; evaluated with the target params, as the preset acts): the inputs, and the paper's ablation rows.
ARMS["q-rgbd"] = lambda c: _obs(ARMS["aux-lr2"](c), "rgbd")
ARMS["q-color"] = lambda c: _obs(ARMS["aux-lr2"](c), "color")
ARMS["q-origin"] = lambda c: _net(ARMS["aux-lr2"](c), variant="origin")
ARMS["q-aug"] = lambda c: ARMS["q-origin"](c).override(augment=True)
ARMS["q-se"] = lambda c: _net(ARMS["aux-lr2"](c), variant="se")
ARMS["q-mha"] = lambda c: _net(ARMS["aux-lr2"](c), variant="mha")
# Chosen on the validation split with 5 seeds per arm (`ramavt train --seeds 5` + `ramavt eval --targets val`;
# docs/experiments.md): the first two blocks as patch layers (4x4, then 2x2 patches, no max-pools; the learner 1.7x
# faster), then, in the time saved, twice the env steps: 'patch-768k' was the quick preset until 'clip-1'.
ARMS["patch"] = lambda c: _net(ARMS["aux-lr2"](c), kernels=(4, 2, 3), strides=(4, 2, 1), pools=(False, False, False))
ARMS["patch-768k"] = lambda c: ARMS["patch"](c).override(total_env_steps=768_000)
# Each one change to 'patch-768k' (the quick preset then), on the validation split: a shorter discount horizon (the
# ceiling's one-step look-ahead is within 4 AER of its 12-step one, so the task looks myopic), and size
# randomisation over [0.15, 5]x (bounding radii of about 0.1-12 m) for targets of other sizes (split 'val-sizes'),
# trained before the stand-off speed rule (1 m/s at every size: speed_standoff_power 0).
ARMS["gamma09"] = lambda c: ARMS["patch-768k"](c).override(gamma=0.9)
ARMS["size-wide"] = lambda c: ARMS["patch-768k"](c).override(
    env_params={"size_scale_min": 0.15, "size_scale_max": 5.0, "speed_standoff_power": 0.0}
)
# Size randomisation towards small sizes only ([0.15, 1]x): size-wide's gain on other sizes was all on the small
# models and its cost on the large ones; the command speed rule (EnvParams.speed_standoff_power) now serves large
# targets. (R2D2's value rescaling of the targets, 'value-rescale', one change to the preset: retired with the
# package's arm fields, lab/README.md.)
ARMS["size-small"] = lambda c: ARMS["patch-768k"](c).override(
    env_params={"size_scale_min": 0.15, "size_scale_max": 1.0}
)
# size-small on the budget of 'patch-1152k' (one change to 'size-small'): whether more env steps buy back its cost
# on the catalogue's sizes.
ARMS["size-small-1152k"] = lambda c: ARMS["size-small"](c).override(total_env_steps=1_152_000)
# size-small gained most on the small models and cost 72 AER on the catalogue's sizes: resize only half of the
# episodes (one change to 'size-small').
ARMS["size-half"] = lambda c: ARMS["size-small"](c).override(
    env_params={"size_scale_min": 0.15, "size_scale_max": 1.0, "size_scale_prob": 0.5}
)
# Each one change to the preset, on the validation split: a replay 4x as long (64k steps hold about one episode per
# env, so the late fall of the training curve might be forgetting); exploration decaying in half the steps (the
# time to a tracker that beats the depth tracker); 64x64 images with an 8x8 first patch, so that the attention
# keeps its 4x4 token grid (whether more pixels buy tracking precision).
ARMS["replay-256k"] = lambda c: ARMS["patch-768k"](c).override(capacity_steps=256_000)
ARMS["eps-100k"] = lambda c: ARMS["patch-768k"](c).override(eps_decay_steps=100_000)
# The actions' Q-values differ by a few cm of distance keeping (0.1 s at 1 m/s), small against the values
# themselves: advantage learning (alpha 0.9) lowers the targets of worse actions (not measured on an earlier
# network). The auxiliary head's estimate of the tracking error correlates weakly with the true error along
# the boresight (lab/aux_error.py); its loss (squared error in stand-off units) is a minor part of the total
# (0.0022 of 0.0077 in the last chunk of a `sizes` run, metrics.jsonl): weighted 10x, it shapes the encoder and
# memory more towards where the target is. (Advantage learning's TD term: COMPONENTS.)
ARMS["adv-learning"] = lambda c: ARMS["patch-768k"](c)
ARMS["aux-w10"] = lambda c: ARMS["patch-768k"](c).override(aux_weight=10.0)
# The policy acts with the target net's Polyak average (tau 0.01, about the last 100 updates), which scored far above
# the online params on every seed: a slower average (tau 0.005, about 200 updates), for the TD targets as well.
ARMS["polyak-0005"] = lambda c: ARMS["patch-768k"](c).override(polyak_tau=0.005)
# The auxiliary head barely follows the boresight error, and a tumbling target's visible surface moves about its
# centre: more memory to average the centre's range over steps (an LSTM of 256 units instead of 128).
ARMS["lstm256"] = lambda c: _net(ARMS["patch-768k"](c), lstm=256)
# The replay stores observations as uint8 (ReplayConfig.obs_dtype): depth / far in steps of 1/255, 7.8 cm at far
# 20 m, about the boresight precision asked for; the policy acts on the unquantised frames. float16 keeps about 5 mm
# at the stand-off.
ARMS["replay-f16"] = lambda c: ARMS["patch-768k"](c).override(obs_dtype="float16")
# The memory is trained by backpropagation through 20 steps (2 s) after a 10-step burn-in, while inferring where a
# tumbling target's centre lies behind its visible surface takes longer (the probes of lab/aux_error.py: the
# frames show range within a target, the surface-to-centre relation is not learned): windows of 40 trained steps,
# 16 of them per batch, so that each update trains the same frames and the run the same number of updates.
ARMS["window-40"] = lambda c: ARMS["patch-768k"](c).override(train_len=40, batch_size=16)
# The learner's updates are most of a chunk's time (100 updates and 32k env steps per chunk at replay ratio 2): at
# replay ratio 1 a chunk takes less time (measured: about 0.65x), so a run reaches a given number of env steps
# sooner, with half the updates on them (the time to a tracker that beats the depth tracker).
ARMS["rr1"] = lambda c: ARMS["patch-768k"](c).override(replay_ratio=1.0)
# rr1 is not above the depth tracker after 786 updates (16 chunks), the preset after 972-1072: the start of learning
# is bound by updates more than by env steps, and a learning rate twice the preset's takes larger steps per update.
ARMS["lr-2e-3"] = lambda c: ARMS["patch-768k"](c).override(lr=2e-3)
# The preset fits its own training targets to 69 % of the ceiling and the probes find the range within a target in
# single frames but not the surface-to-centre relation across targets: an encoder twice as wide (32-64-64 channels).
ARMS["wide"] = lambda c: _net(ARMS["patch-768k"](c), channels=(32, 64, 64))
# The start of learning (the time to a tracker that beats the depth tracker): the policy acts with the target net's
# Polyak average, which lags the online params by about 1 / tau updates (100 at tau 0.01, one chunk); tau 0.02 halves
# that lag, for the TD targets as well. And a burn-in of 5 steps instead of 10 before the 20 trained ones: each
# update runs the network over fewer frames (from the stored recurrent state, as R2D2 does), so a chunk takes less time.
ARMS["polyak-002"] = lambda c: ARMS["patch-768k"](c).override(polyak_tau=0.02)
ARMS["burn-5"] = lambda c: ARMS["patch-768k"](c).override(burn_in=5)
# Runs of the preset (and of several arms) collapse late in one seed in five or ten, with the gradient norm rising
# from about 0.4 to 2.3 over the collapse: gradients clipped at a global norm of 1 instead of 10 (the quick preset
# from 4345e80 until 'clip-1152k').
ARMS["clip-1"] = lambda c: ARMS["patch-768k"](c).override(max_grad_norm=1.0)
# Each one change to 'clip-1' (the quick preset then): 1.15M env steps ('patch-1152k' gained nothing on 'patch-768k',
# but late collapses may have eaten the extra steps; the quick budget of 6 min leaves room for them; 'clip-1152k' was
# the quick preset until 'online-boot'), and the faster target average of 'polyak-002' (a chunk earlier above the
# depth tracker, lower at the end before the clip).
ARMS["clip-1152k"] = lambda c: ARMS["clip-1"](c).override(total_env_steps=1_152_000)
ARMS["clip-polyak-002"] = lambda c: ARMS["clip-1"](c).override(polyak_tau=0.02)
# The sizes preset then ('size-small-1152k') with the quick preset's clip: one change to it.
ARMS["size-small-clip-1"] = lambda c: ARMS["size-small-1152k"](c).override(max_grad_norm=1.0)
# 1.54M env steps, a third more than the quick preset (whose main job takes 4 min 26 s of the 6 allowed), trained by
# resuming 'clip-1152k''s runs: no schedule depends on the run's length, and a resumed run is bit-exact.
ARMS["clip-1536k"] = lambda c: ARMS["clip-1152k"](c).override(total_env_steps=1_536_000)
# The agent's gap to the ceiling is distance keeping, not lost targets: train on the evaluation's distance weight
# (1.0 per metre instead of the original training value 0.5), one change to the quick preset ('prev-dw1' lost AER on
# every seed of an early, weaker preset).
ARMS["clip-dw1"] = lambda c: ARMS["clip-1152k"](c).override(env_params=(("dist_weight", 1.0),))
# 64x64 depth on the quick preset ('res64' was one change to 'patch-768k', at norm 10, with one seed far below the
# others): more pixels across the target, the first patch 8x8 so the attention keeps its 4x4 token grid.
ARMS["clip-res64"] = lambda c: _res64(ARMS["clip-1152k"](c))
ARMS["res64"] = lambda c: _res64(ARMS["patch-768k"](c))
# The gap to the ceiling is largest on the panelled shapes (the validation satellite and station), and linear probes
# find no trace of the satellite's tracking error in the agent's memory (docs/experiments.md): more training shapes,
# each catalogue model stretched along its principal axes in half the episodes (factors up to 1.5 ** (4/3) per
# axis, volume kept), one change to the quick preset and to the sizes preset then ('size-small-1152k').
_STRETCH = {"stretch_max": 1.5, "stretch_prob": 0.5}
ARMS["stretch"] = lambda c: _env(ARMS["clip-1152k"](c), **_STRETCH)
ARMS["size-stretch"] = lambda c: _env(ARMS["size-small-1152k"](c), **_STRETCH)
# Prioritised sequence replay with R2D2's settings (priority exponent 0.9, importance exponent 0.6, priorities
# 0.9 max + 0.1 mean |TD error|), one change to the quick preset.
ARMS["per"] = lambda c: ARMS["clip-1152k"](c).override(priority_exponent=0.9)
# Targets of other sizes, each one change to the sizes preset then ('size-small-1152k'): resized up to 4x as well as
# down to 0.15x (under the stand-off speed rule a large target looks and moves, in stand-off units, like a 2.5 m one
# held at 5 m, larger than most catalogue targets, and drifts k times slower). (The stand-off scale k as an input,
# 'size-standoff', and the command gain, 'size-command': retired with the package's arm fields, lab/README.md.)
ARMS["size-up"] = lambda c: _env(ARMS["size-small-1152k"](c), size_scale_max=4.0)
# Targets from the online net's own trained pass (PQN's recipe without its LayerNorm): one forward pass fewer per
# update; the target net is still averaged, for acting. The quick preset since it crossed the depth tracker two chunks
# sooner at the same final AER.
ARMS["online-boot"] = lambda c: ARMS["clip-1152k"](c).override(bootstrap_from="online")
# The sizes preset then ('size-small-1152k') with the quick preset's targets from the online net: one change to it.
ARMS["size-online-boot"] = lambda c: ARMS["size-small-1152k"](c).override(bootstrap_from="online")
# Polyak-Ruppert tail averaging: the policy is the mean of the target net's params at the ends of the last 12 of the
# 36 chunks (one change: the parameter set the policy acts with; training is the same). The quick preset since it
# scored higher with a narrower spread over seeds on validation.
ARMS["avg-12"] = lambda c: ARMS["online-boot"](c).override(policy_average_from=24, policy_params="averaged")
# Exploration decaying over 100k env steps instead of 200k: with targets from the online net learning starts sooner,
# and acting greedily sooner may then bring the crossing of the depth tracker forward (with the target net it
# did not: eps-100k).
ARMS["avg-eps-100k"] = lambda c: ARMS["avg-12"](c).override(eps_decay_steps=100_000)
# The quick preset as it is now (clip 1, targets from the online net, the tail average) with the sizes preset's size
# randomisation: one change to 'avg-12', and the sizes preset until 'size-res64'; the earlier sizes preset,
# 'size-small-1152k', kept the quick preset's settings of its time (norm 10, targets and policy from the target net).
ARMS["size-quick"] = lambda c: _env(ARMS["avg-12"](c), size_scale_min=0.15, size_scale_max=1.0)
# 'size-quick' at 64x64 depth (an 8x8 first patch keeps the 4x4 token grid): small targets cover 4x the pixels. The
# sizes preset from when it scored higher on val-sizes until 'size-1536k'.
ARMS["size-res64"] = lambda c: _res64(ARMS["size-quick"](c))

# Twice the sequences per update (64), at the same number of updates (replay ratio 4: trained frames per env frame
# double with the batch), one change to the quick preset: less noise in each gradient of the few-cm gaps between
# actions' values, at 1.4-1.7x the training time as measured (the preset's main job takes 3 min 45 s of the 6
# allowed).
ARMS["batch-64"] = lambda c: ARMS["avg-12"](c).override(batch_size=64, replay_ratio=4.0)
# PQN's data flow within this learner: a replay of the last two rollouts only (64 envs x 40 steps; learning from
# the second rollout on, as the buffer holds no more), so every window is at most two iterations old; each frame is
# still trained twice on average (replay ratio 2). One change to the quick preset. Its stored states would allow no
# burn-in; that was not tried, as this arm lost on its own.
ARMS["fresh-replay"] = lambda c: ARMS["avg-12"](c).override(capacity_steps=2560, learning_starts=2560)
# For the start of learning only (trained for the first 10 chunks, whose training does not depend on the run's
# length): the faster target average of 'polyak-002' (a chunk or two sooner to the depth tracker with targets from the
# target net) on top of 'avg-eps-100k' (the earliest crossing so far, chunk 7 in the median). With targets from the
# online net the target params feed no update and training acts with the online params, so this changes only the
# policy flown: an average over about 50 updates instead of 100.
ARMS["eps-100k-polyak-002"] = lambda c: ARMS["avg-eps-100k"](c).override(polyak_tau=0.02)
# Table II's perturbations in training (the preset trains on clean episodes): actuator noise 0.3, time delay up to
# 0.5 s and the 3-frame average blur, each on in half the episodes, drawn per perturbation and episode, so an
# eighth of the episodes stay clean and an eighth have all three. One change to the quick preset (the frame history
# the blur needs comes with it; evaluation flies each Table II setting as it is, whatever a run trained with).
_table2_in_training = presets.under_table2_perturbations  # the robust preset's, at any share


ARMS["perturb-05"] = lambda c: _table2_in_training(ARMS["avg-12"](c), 0.5)
# The same with all three in every training episode, as Table II's 'all' setting flies them.
ARMS["perturb-1"] = lambda c: _table2_in_training(ARMS["avg-12"](c), 1.0)
# Twice the env steps (2.30M, 72 chunks), the policy still the average over the last 12 chunks (61-72): one change to
# the quick preset; the long preset from when it scored higher on validation over ten seeds until 'long-margin'.
ARMS["avg-2304k"] = lambda c: ARMS["avg-12"](c).override(total_env_steps=2_304_000, policy_average_from=60)
# Exploration at the end of training, one change to the quick preset: a lower final rate (1 % of steps random
# instead of 5 %: near the desired point one random step costs more than the agent's own error).
ARMS["eps-end-001"] = lambda c: ARMS["avg-12"](c).override(eps_end=0.01)
# Centre-offset randomisation, one change to the quick preset: each training target's geometry moved off its centre
# of mass by up to 0.4 bounding radii (EnvParams.offset_max). The validation targets the preset tracks worst
# (Satellite-val0, Station-val0) are those whose visible surface is centred farthest from their centre (0.43 and
# 0.35 m to the side at 5 m, averaged over attitudes, against 0.03-0.18 m for the others: lab/centroid_offset.py).
ARMS["offset-04"] = lambda c: _env(ARMS["avg-12"](c), offset_max=0.4)
# The quick preset at 1.54M env steps (48 chunks; the policy the average over chunks 37-48): the preset's main job
# took 225 s of its 6 minutes (177 s of training, results/wall_times.json), so a third more env steps still fits.
# The quick preset since it scored higher on validation over ten seeds.
ARMS["avg-1536k"] = lambda c: ARMS["avg-12"](c).override(total_env_steps=1_536_000, policy_average_from=36)
# The auxiliary head also fitted to the target's velocity relative to the chaser (NetworkConfig.aux_outputs = 6),
# one change to the quick preset at 1.54M env steps: holding the centre still takes commands that match the target's
# drift on average, which the agent must read from successive frames; the ceiling knows it and after the approach
# commands no motion on 17 % of the steps, the 1.15M preset on 1-6 % (lab/position_error.py).
ARMS["aux-velocity"] = lambda c: _net(ARMS["avg-1536k"](c), aux_outputs=6)
# Half the learning rate (5e-4 instead of 1e-3), one change to the quick preset at 1.54M env steps: 1e-3 was chosen
# at 384k env steps, before the clip, the online targets and the tail average; a longer run may prefer smaller steps.
ARMS["lr-half"] = lambda c: ARMS["avg-1536k"](c).override(lr=5e-4)
# Twice the learning rate (2e-3), the other side: half of it lost 25 points (P = 0.27), and with gradients clipped
# at norm 1 a larger rate may buy more of the 1.54M env steps without the instability 1e-3 was chosen to avoid.
ARMS["lr-double"] = lambda c: ARMS["avg-1536k"](c).override(lr=2e-3)
# The sizes preset at the quick preset's 1.54M env steps (48 chunks, the policy the average over chunks 37-48): one
# change to 'size-res64', as 'avg-1536k' was to 'avg-12'. The sizes preset from when it scored higher on val-sizes
# and val over ten seeds until 'size-margin'.
ARMS["size-1536k"] = lambda c: ARMS["size-res64"](c).override(total_env_steps=1_536_000, policy_average_from=36)
# Shape variety, one change to the quick preset: the twelve catalogue training models and 48 procedural ones
# (scripts/procedural_targets.py, seed 0: satellites with up to two wings, booms and dishes, stacks, module chains,
# rocks), an episode drawing each of the 60 equally often. The validation models the agent tracks worst are those
# whose silhouette is centred farthest off the centre of mass, and no change to the learner moved them; a wider
# variety of such relations in training may.
PROCEDURAL_DIR = Path(__file__).resolve().parents[1] / "runs" / "procedural"  # where the models are written


def _procedural(c, count: int):
    scripts = str(Path(__file__).resolve().parents[1] / "scripts")  # procedural_targets imports its siblings there
    if scripts not in sys.path:
        sys.path.insert(0, scripts)
    import procedural_targets

    paths = procedural_targets.write_models(PROCEDURAL_DIR, count, seed=0)
    return c.override(env=dataclasses.replace(c.env, targets=c.env.targets + tuple(str(p) for p in paths)))


ARMS["procedural-48"] = lambda c: _procedural(ARMS["avg-1536k"](c), 48)
# A longer horizon, one change to the quick preset at 1.54M env steps: discount 0.99 instead of 0.97 (0.9 scored lower
# at 768k, gamma09). The agents circle the desired point instead of holding still; a 0.1 m better hold is worth more
# against the noise in the values when it counts over 100 steps instead of 33.
ARMS["gamma-099"] = lambda c: ARMS["avg-1536k"](c).override(gamma=0.99)
# A cost on moving in training (0.05 per step at full speed, the reward of a 0.1 m
# better hold for one step), one change to the quick preset at 1.54M env steps: after the approach the ceiling holds
# still on 17 % of the steps, the 1.15M preset on 1-6 % and the 1.54M one on none, circling the desired point; a
# move that only chases noise in the agent's estimate then costs more than it buys. (Its TD term: COMPONENTS.)
ARMS["command-cost-005"] = lambda c: ARMS["avg-1536k"](c)
# A lower discount, one change to the quick preset at 1.54M env steps: the ceiling's one-step look-ahead is
# within 4 of its 12-step search, so the task rewards little foresight, and with rewards scaled by 0.1 the value of
# one better step (about 0.005) is about two thousandths of Q at gamma 0.97 (about 2.8). A shorter horizon makes
# the gaps between actions a larger share of the values the network has to fit.
ARMS["gamma-08"] = lambda c: ARMS["avg-1536k"](c).override(gamma=0.8)
# Shorter returns, one change to the quick preset at 1.54M env steps: 3-step targets instead of 5 carry less of the
# exploring behaviour's commands (5 % random) into the values the greedy policy is judged by.
ARMS["n-step-3"] = lambda c: ARMS["avg-1536k"](c).override(n_step=3)
# DQfD's large-margin loss towards the true-state one-step look-ahead's action at every trained step, the agent's
# own steps labelled (DAgger), one change to the quick preset at 1.54M env steps: with the true state as input (a
# retired diagnostic) the learner still leaves 15 points of the ceiling, the gaps between actions being about 0.005 of a Q near 2.7;
# the labels say which action is best outright, from a controller within 1 % of the ceiling.
ARMS["expert-margin"] = lambda c: ARMS["avg-1536k"](c).override(expert_margin_weight=1.0)
# The margin loss weighted 3 instead of 1, one change to 'expert-margin': at weight 1 the greedy action matched the
# label on 42-48 % of the trained steps late in training; a larger weight asks for closer imitation.
ARMS["expert-margin-w3"] = lambda c: ARMS["expert-margin"](c).override(expert_margin_weight=3.0)
# The same 48 models added to the sizes preset's training targets at 1.54M env steps (one change to 'size-1536k'):
# the user models are shapes the catalogue does not have, flown at sizes it does not have, so more shapes in training
# may carry further there than on the catalogue's validation sizes.
ARMS["size-procedural-48"] = lambda c: _procedural(ARMS["size-1536k"](c), 48)
# The margin loss on the sizes preset and on the long one, one change each ('size-1536k', 'avg-2304k'): both presets
# were chosen before the labels. 'size-margin' is the sizes preset since it scored higher on val-sizes and val,
# 'long-margin' the long preset since it scored higher on val.
ARMS["size-margin"] = lambda c: ARMS["size-1536k"](c).override(expert_margin_weight=1.0)
ARMS["long-margin"] = lambda c: ARMS["avg-2304k"](c).override(expert_margin_weight=1.0)
# Table II's perturbations in half the training episodes on the quick preset with the labels (one change to
# 'expert-margin'): the labels come from the true state, which the perturbations do not touch.
ARMS["perturb-05-margin"] = lambda c: _table2_in_training(ARMS["expert-margin"](c), 0.5)

# Episodes that start with the target out of view (a blank first image): 4 % of the reset distribution, and the
# most of the sizes preset's lost validation episodes. Twice the start's lateral spread (one change to
# 'size-margin') makes 20 % of training starts blind, for practice at finding the target; then the labels left out
# before the target is first in view (one change to 'size-wide-starts'), so that the TD loss alone decides how to
# search there rather than the look-ahead's hidden label averaged over blank images.
ARMS["size-wide-starts"] = lambda c: _env(ARMS["size-margin"](c), init_xy_std=2.0)
ARMS["size-wide-search"] = lambda c: ARMS["size-wide-starts"](c).override(blind_label="none")
# No label before the target is first in view left search to the TD loss, and its seeds then lost more blind starts
# than with the look-ahead's labels (several moved towards the camera axis, which widens a target's bearing). The
# label 'retreat' at those steps instead (one change to 'size-wide-starts'): backing off along the axis shrinks the
# bearing of a target in any direction, the seeds that searched so lost the fewest.
ARMS["size-wide-retreat"] = lambda c: ARMS["size-wide-starts"](c).override(blind_label="retreat")
# The sizes preset since it lost a quarter of the blind starts 'size-margin' loses. The same label with the
# benchmark's starts (one change to 'size-margin'): whether the label alone does it, with blind starts in 4 % of the
# training episodes instead of 20 %.
ARMS["size-retreat"] = lambda c: ARMS["size-margin"](c).override(blind_label="retreat")
# Three of the preset's ten seeds still learn to move forward from a blank image. Starts spread three times as wide
# (one change to 'size-wide-retreat'): more blind starts in training, so more steps carry the back-off label.
ARMS["size-wider-retreat"] = lambda c: _env(ARMS["size-wide-retreat"](c), init_xy_std=3.0)

# The auxiliary head also fitted to the relative velocity, as 'aux-velocity' did before the labels, one change to
# 'expert-margin' (the quick preset). (The arms before it that gave the network the true state, the look-ahead's
# labels to a policy head, or the visible surface's centroid as an input were retired with the package's arm
# fields: lab/README.md.)
ARMS["aux-velocity-margin"] = lambda c: _net(ARMS["expert-margin"](c), aux_outputs=6)

# The gap is perception, on the shapes the agent trains on (80 % of the ceiling there) and more on new ones (71 %).
# An input and the training shapes, each one change to 'expert-margin' (the quick preset) now that the labels are on:
# colour beside depth (a part's albedo tells the body from its panels, whose layout places the centre of mass),
ARMS["rgbd-margin"] = lambda c: _obs(ARMS["expert-margin"](c), "rgbd")
# and the 48 procedural models beside the twelve (more relations between a surface and its centre to learn from).
ARMS["procedural-48-margin"] = lambda c: _procedural(ARMS["expert-margin"](c), 48)


# Arms that plug a component into the trainer through its extension points rather than a config field (the
# package keeps no field for them; docs/extending.md): {arm: config -> train.Components}. Their ARMS entry is the
# config they change, so an arm here is one change to its parent in its components.
def _td_replaced(term_of):
    """Components whose TD term (the first of train.default_loss_terms) is ``term_of(config)``."""
    return lambda c: Components(loss_terms=(term_of(c),) + default_loss_terms(c)[1:])


COMPONENTS = {
    # Advantage learning (alpha 0.9): the targets of worse actions lowered (arm_components.advantage_learning_term).
    "prev-al": _td_replaced(lambda c: parts.advantage_learning_term(c.learner.td, 0.9)),
    "aux-al": _td_replaced(lambda c: parts.advantage_learning_term(c.learner.td, 0.9)),
    "adv-learning": _td_replaced(lambda c: parts.advantage_learning_term(c.learner.td, 0.9)),
    # 0.05 (unscaled reward) per step at full speed off the TD targets' rewards (arm_components.command_cost_term).
    "command-cost-005": _td_replaced(lambda c: parts.command_cost_term(c.learner.td, 0.05, c.learner.reward_scale)),
}


def arm_components(name: str, config) -> Components | None:
    """The trainer components arm ``name`` plugs in for its ``config`` (None: the config's own)."""
    return COMPONENTS[name](config) if name in COMPONENTS else None


def arm_config(name: str, preset: str = "quick", **overrides):
    base = presets.preset(preset, eval_episodes=0, **overrides)
    if preset == "quick" and ARMS["expert-margin"](base) != base:
        raise SystemExit("the quick preset is no longer 'expert-margin' of these arms: update ARMS")
    if preset == "quick" and not overrides and ARMS["long-margin"](base) != presets.preset("long", eval_episodes=0):
        raise SystemExit("the long preset is no longer 'long-margin' of these arms: update ARMS")
    return ARMS[name](base)


# ----------------------------------------------------------------------------------------------- evaluation
def batched_rollout(tracking_env, params_b, policy, key, num_steps):
    """Episodes of one policy, one env per row of params_b ([N] leading axis): (length [N], return [N], lost [N]).
    Stops when all have ended. Keys depend only on `key` and N, so every policy sees the same episodes."""
    n = params_b.target_probs.shape[0]
    k_reset, k_policy, k_loop = jax.random.split(key, 3)
    obs, state = jax.vmap(tracking_env.reset)(jax.random.split(k_reset, n), params_b)
    pstate = jax.vmap(policy.init)(jax.random.split(k_policy, n))
    zeros_i, zeros_b = jnp.zeros(n, jnp.int32), jnp.zeros(n, bool)
    carry = (jnp.zeros((), jnp.int32), obs, state, pstate, jnp.ones(n, bool), zeros_i, jnp.zeros(n), zeros_b)

    def cond(c):
        return (c[0] < num_steps) & c[4].any()

    def body(c):
        t, obs, state, pstate, alive, length, ret, lost = c
        k_act, k_env = jax.random.split(jax.random.fold_in(k_loop, t))
        action, pstate = jax.vmap(policy.act)(jax.random.split(k_act, n), pstate, obs, state, params_b)
        obs, state, reward, term, trunc, _ = jax.vmap(tracking_env.step_env)(
            jax.random.split(k_env, n), state, action, params_b
        )
        length = length + alive
        ret = ret + jnp.where(alive, reward, 0.0)
        lost = lost | (alive & term)
        return t + 1, obs, state, pstate, alive & ~(term | trunc), length, ret, lost

    _, _, _, _, _, length, ret, lost = jax.lax.while_loop(cond, body, carry)
    return length, ret, lost


def heldout_setup(resolution: int, episodes: int, targets=targets_lib.TEST_TARGETS, obs_mode: str = "depth"):
    """The held-out episodes: the reset states depend only on the key and the targets, not on the input mode, so
    depth, colour and RGBD agents see the same episodes."""
    cfg = env_lib.EnvConfig(
        camera=env_lib.CameraConfig(resolution=resolution), targets=tuple(targets), obs_mode=obs_mode
    )
    tracking_env = env_lib.TrackingEnv(cfg)
    params = tracking_env.eval_params()
    ids = jnp.repeat(jnp.arange(len(targets)), episodes)
    params_b = jax.vmap(lambda i: params.replace(target_probs=jax.nn.one_hot(i, len(targets))))(ids)
    params_b = params_b.replace(
        catalogue=jax.tree.map(lambda a: jnp.broadcast_to(a, (ids.shape[0],) + a.shape), params.catalogue)
    )
    return tracking_env, params_b, np.asarray(ids)


def _summary(length, ret, lost, ids, names):
    length, ret, lost = (np.asarray(x, np.float64) for x in (length, ret, lost))
    per = {
        n: {
            "AEL": float(length[ids == i].mean()),
            "AER": float(ret[ids == i].mean()),
            "lost": float(lost[ids == i].mean()),
        }
        for i, n in enumerate(names)
    }
    return {"AEL": float(length.mean()), "AER": float(ret.mean()), "lost": float(lost.mean()), "per_target": per}


def evaluate_arm(
    out: Path, arm: str, episodes: int, key: jax.Array, max_steps: int = 1000, policy_params: str | None = None
) -> dict:
    """Every seed of the arm on the held-out episodes, acting with ``policy_params`` ('online' | 'target' |
    'averaged'; None = the runs' own RunConfig.policy_params)."""
    seed_dirs = sorted((out / arm).glob("seed_*")) or [out / arm]
    loaded = [runs.load_policy(d, policy_params=policy_params) for d in seed_dirs]
    config = loaded[0].config
    tracking_env, params_b, ids = heldout_setup(config.env.camera.resolution, episodes, obs_mode=config.env.obs_mode)
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *[lr.params for lr in loaded])

    @jax.jit
    def run_all(net_params):
        def one(p):
            policy = greedy.greedy_policy(config.network, p, tuple(config.env.obs_shape))
            return batched_rollout(tracking_env, params_b, policy, key, max_steps)

        return jax.lax.map(one, net_params)

    t = time.time()
    length, ret, lost = jax.device_get(run_all(stacked))
    seeds = [
        dict(_summary(length[k], ret[k], lost[k], ids, tracking_env.config.targets), run=str(d))
        for k, d in enumerate(seed_dirs)
    ]
    ael, aer = np.array([s["AEL"] for s in seeds]), np.array([s["AER"] for s in seeds])
    return {
        "arm": arm,
        "policy_params": config.run.policy_params,
        "episodes_per_target": episodes,
        "eval_wall_s": time.time() - t,
        "seeds": seeds,
        "AEL_mean": float(ael.mean()),
        "AEL_std": statistics.sample_std(ael),
        "AER_mean": float(aer.mean()),
        "AER_std": statistics.sample_std(aer),
    }


def evaluate_baselines(resolution: int, episodes: int, key: jax.Array, max_steps: int = 1000) -> dict:
    tracking_env, params_b, ids = heldout_setup(resolution, episodes)
    out = {}
    for name in ("mpc", "proportional", "depth", "random"):
        policy = baselines.make_policy(name, tracking_env.config.camera, tracking_env.config.dynamics)
        length, ret, lost = jax.jit(lambda: batched_rollout(tracking_env, params_b, policy, key, max_steps))()
        out[name] = _summary(length, ret, lost, ids, tracking_env.config.targets)
    return out


# ----------------------------------------------------------------------------------------------- commands
def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("command", choices=("train", "eval", "report"))
    ap.add_argument("arms", nargs="*")
    ap.add_argument("--out", type=Path, default=Path("runs/arms"))
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--first-seed", type=int, default=0, help="train seeds first-seed .. first-seed + seeds - 1")
    ap.add_argument("--preset", default="quick")
    ap.add_argument("--episodes", type=int, default=10, help="held-out episodes per target")
    ap.add_argument("--eval-seed", type=int, default=0)
    ap.add_argument(
        "--policy-params",
        choices=("online", "target", "averaged"),
        default=None,
        help="evaluate these params (default: each run's own); writes heldout_<choice>.json",
    )
    args = ap.parse_args()
    key = jax.random.PRNGKey(args.eval_seed)
    for arm in args.arms:
        if args.command == "train":
            t = time.time()
            config = arm_config(arm, args.preset)
            train_run(
                config,
                args.out / arm,
                seed=args.first_seed,
                num_seeds=args.seeds,
                progress=False,
                components=arm_components(arm, config),
            )
            print(f"[{arm}] trained {args.seeds} seeds in {time.time() - t:.0f} s", flush=True)
        elif args.command == "eval" and arm == "baselines":
            res = evaluate_baselines(32, args.episodes, key)
            (args.out / "baselines.json").write_text(json.dumps(res, indent=1))
            print(json.dumps({k: (v["AEL"], v["AER"]) for k, v in res.items()}), flush=True)
        elif args.command == "eval":
            res = evaluate_arm(args.out, arm, args.episodes, key, policy_params=args.policy_params)
            name = "heldout.json" if args.policy_params is None else f"heldout_{args.policy_params}.json"
            (args.out / arm / name).write_text(json.dumps(res, indent=1))
            print(
                f"[{arm} {res['policy_params']}] AEL {res['AEL_mean']:.1f} ± {res['AEL_std']:.1f}  "
                f"AER {res['AER_mean']:.1f} ± {res['AER_std']:.1f}  ({res['eval_wall_s']:.0f} s)",
                flush=True,
            )
    if args.command == "report":
        report(args.out)


def _row_head(r: dict) -> str:
    """'| arm [tag] | AEL mean ± std | AER mean ± std | lost % |' of one heldout JSON."""
    params = r.get("policy_params")
    tag = f" [{params} params]" if params not in (None, "online") else ""
    lost = 100 * np.mean([s["lost"] for s in r["seeds"]])
    return (
        f"| {r['arm']}{tag} | {r['AEL_mean']:.1f} ± {r['AEL_std']:.1f} | {r['AER_mean']:.1f} ± "
        f"{r['AER_std']:.1f} | {lost:.0f} |"
    )


def report(out: Path) -> None:
    rows = [json.loads(p.read_text()) for p in sorted(out.glob("*/heldout*.json"))]
    names = list(targets_lib.TEST_TARGETS)
    print("| arm | AEL | AER | lost % | " + " | ".join(names) + " |")
    print("|---|---|---|---|" + "---|" * len(names))
    for r in rows:
        per = [np.mean([s["per_target"][n]["AEL"] for s in r["seeds"]]) for n in names]
        per_r = [np.mean([s["per_target"][n]["AER"] for s in r["seeds"]]) for n in names]
        print(_row_head(r) + " " + " | ".join(f"{a:.0f} / {b:.0f}" for a, b in zip(per, per_r)) + " |")
    base = out / "baselines.json"
    if base.exists():
        for name, s in json.loads(base.read_text()).items():
            cells = " | ".join(f"{s['per_target'][n]['AEL']:.0f} / {s['per_target'][n]['AER']:.0f}" for n in names)
            print(f"| {name} (baseline) | {s['AEL']:.1f} | {s['AER']:.1f} | {100 * s['lost']:.0f} | {cells} |")
    print("\n| arm | AEL | AER | lost % | AEL per seed | AER per seed |\n|---|---|---|---|---|---|")
    for r in rows:
        ael = ", ".join(f"{s['AEL']:.0f}" for s in r["seeds"])
        aer = ", ".join(f"{s['AER']:+.0f}" for s in r["seeds"])
        print(f"{_row_head(r)} {ael} | {aer} |")
    if rows:
        compare_report(rows, names)


def seed_scores(r: dict, names: list[str]) -> np.ndarray:
    """AER per seed and held-out target [seeds, targets] of one heldout JSON (rliable's score matrix)."""
    return np.array([[s["per_target"][n]["AER"] for n in names] for s in r["seeds"]])


def compare_report(rows: list[dict], names: list[str]) -> None:
    """Interquartile mean of AER over seeds x targets (95 % stratified bootstrap interval) and the probability of
    improvement over the reference arm ('base' if evaluated, else the first), both from rliable."""
    ref = next((r for r in rows if r["arm"] == "base"), rows[0])
    print(f"\n| arm | seeds | IQM AER [95 % CI] | P(arm > {ref['arm']}) |\n|---|---|---|---|")
    for r in rows:
        scores = seed_scores(r, names)
        low, high = statistics.iqm_ci(scores)
        poi = statistics.probability_of_improvement(scores, seed_scores(ref, names))
        print(f"| {r['arm']} | {len(scores)} | {statistics.iqm(scores):+.1f} [{low:+.1f}, {high:+.1f}] | {poi:.2f} |")


if __name__ == "__main__":
    main()
