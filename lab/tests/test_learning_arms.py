"""The learning experiments' script: every Table arm is one change to the row it is compared with, and `report`
prints what the JSON says."""

import dataclasses
import json
from pathlib import Path

import pytest

from lab import learning_arms  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]


def _flat(x, prefix: str = "") -> dict:
    """A nested config dataclass as {'group.field': value}."""
    if not dataclasses.is_dataclass(x):
        return {prefix[:-1]: x}
    out = {}
    for f in dataclasses.fields(x):
        out.update(_flat(getattr(x, f.name), f"{prefix}{f.name}."))
    return out


def _changes(arm: str, reference: str) -> dict:
    ref, cfg = _flat(learning_arms.arm_config(reference)), _flat(learning_arms.arm_config(arm))
    assert ref.keys() == cfg.keys()
    return {k: cfg[k] for k in cfg if cfg[k] != ref[k]}


@pytest.mark.parametrize(
    "arm, reference, change",
    [
        ("q-rgbd", "aux-lr2", {"env.obs_mode": "rgbd"}),
        ("q-color", "aux-lr2", {"env.obs_mode": "color"}),
        ("q-origin", "aux-lr2", {"network.variant": "origin"}),
        ("q-se", "aux-lr2", {"network.variant": "se"}),
        ("q-mha", "aux-lr2", {"network.variant": "mha"}),
        ("q-aug", "q-origin", {"learner.augment": True}),
        ("aux-lr2", "prev-aux", {"learner.lr": 2 * learning_arms._LR}),
        (
            "patch",
            "aux-lr2",
            {"network.kernels": (4, 2, 3), "network.strides": (4, 2, 1), "network.pools": (False, False, False)},
        ),  # one change: the stem
        ("patch-768k", "patch", {"run.total_env_steps": 768_000}),
        ("replay-256k", "patch-768k", {"replay.capacity_steps": 256_000}),
        ("eps-100k", "patch-768k", {"acting.eps_decay_steps": 100_000}),
        ("aux-w10", "patch-768k", {"learner.aux_weight": 10.0}),
        ("polyak-0005", "patch-768k", {"learner.polyak_tau": 0.005}),
        ("lstm256", "patch-768k", {"network.lstm": 256}),
        ("replay-f16", "patch-768k", {"replay.obs_dtype": "float16"}),
        ("window-40", "patch-768k", {"replay.train_len": 40, "replay.batch_size": 16}),  # same frames per update
        ("rr1", "patch-768k", {"learner.replay_ratio": 1.0}),
        ("lr-2e-3", "patch-768k", {"learner.lr": 2e-3}),
        ("wide", "patch-768k", {"network.channels": (32, 64, 64)}),
        ("polyak-002", "patch-768k", {"learner.polyak_tau": 0.02}),
        ("burn-5", "patch-768k", {"replay.burn_in": 5}),
        ("clip-1", "patch-768k", {"learner.max_grad_norm": 1.0}),
        ("clip-1152k", "clip-1", {"run.total_env_steps": 1_152_000}),
        ("clip-polyak-002", "clip-1", {"learner.polyak_tau": 0.02}),
        ("size-small-clip-1", "size-small-1152k", {"learner.max_grad_norm": 1.0}),
        ("clip-dw1", "clip-1152k", {"env_params": (("dist_weight", 1.0),)}),
        ("stretch", "clip-1152k", {"env_params": (("stretch_max", 1.5), ("stretch_prob", 0.5))}),
        ("per", "clip-1152k", {"replay.priority_exponent": 0.9}),
        ("size-up", "size-small-1152k", {"env_params": (("size_scale_max", 4.0), ("size_scale_min", 0.15))}),
        ("online-boot", "clip-1152k", {"learner.bootstrap_from": "online"}),
        ("size-online-boot", "size-small-1152k", {"learner.bootstrap_from": "online"}),
        # one change: the parameters the policy acts with
        ("avg-12", "online-boot", {"run.policy_average_from": 24, "run.policy_params": "averaged"}),
        ("avg-eps-100k", "avg-12", {"acting.eps_decay_steps": 100_000}),
        ("batch-64", "avg-12", {"replay.batch_size": 64, "learner.replay_ratio": 4.0}),
        ("fresh-replay", "avg-12", {"replay.capacity_steps": 2560, "learner.learning_starts": 2560}),
        ("eps-100k-polyak-002", "avg-eps-100k", {"learner.polyak_tau": 0.02}),
        (
            "perturb-05",
            "avg-12",
            {
                "env.frame_history": 3,
                "env_params": (("actuator_noise", 0.3), ("blur_frames", 3), ("delay_max", 0.5), ("perturb_prob", 0.5)),
            },
        ),
        (
            "perturb-1",
            "perturb-05",
            {"env_params": (("actuator_noise", 0.3), ("blur_frames", 3), ("delay_max", 0.5), ("perturb_prob", 1.0))},
        ),
        ("avg-2304k", "avg-12", {"run.total_env_steps": 2_304_000, "run.policy_average_from": 60}),
        ("offset-04", "avg-12", {"env_params": (("offset_max", 0.4),)}),
        ("eps-end-001", "avg-12", {"acting.eps_end": 0.01}),
        ("aux-velocity", "avg-1536k", {"network.aux_outputs": 6}),
        ("lr-half", "avg-1536k", {"learner.lr": 5e-4}),
        ("gamma-099", "avg-1536k", {"learner.gamma": 0.99}),
        ("lr-double", "avg-1536k", {"learner.lr": 2e-3}),
        ("gamma-08", "avg-1536k", {"learner.gamma": 0.8}),
        ("n-step-3", "avg-1536k", {"learner.n_step": 3}),
        ("expert-margin", "avg-1536k", {"learner.expert_margin_weight": 1.0}),
        ("expert-margin-w3", "expert-margin", {"learner.expert_margin_weight": 3.0}),
        ("aux-velocity-margin", "expert-margin", {"network.aux_outputs": 6}),
        ("rgbd-margin", "expert-margin", {"env.obs_mode": "rgbd"}),
        ("size-margin", "size-1536k", {"learner.expert_margin_weight": 1.0}),
        ("long-margin", "avg-2304k", {"learner.expert_margin_weight": 1.0}),
        (
            "size-wide-starts",
            "size-margin",
            {"env_params": (("init_xy_std", 2.0), ("size_scale_max", 1.0), ("size_scale_min", 0.15))},
        ),
        ("size-wide-search", "size-wide-starts", {"learner.blind_label": "none"}),
        ("size-wide-retreat", "size-wide-starts", {"learner.blind_label": "retreat"}),
        ("size-retreat", "size-margin", {"learner.blind_label": "retreat"}),
        (
            "size-wider-retreat",
            "size-wide-retreat",
            {"env_params": (("init_xy_std", 3.0), ("size_scale_max", 1.0), ("size_scale_min", 0.15))},
        ),
        (
            "perturb-05-margin",
            "expert-margin",
            {
                "env.frame_history": 3,
                "env_params": (("actuator_noise", 0.3), ("blur_frames", 3), ("delay_max", 0.5), ("perturb_prob", 0.5)),
            },
        ),
        ("size-1536k", "size-res64", {"run.total_env_steps": 1_536_000, "run.policy_average_from": 36}),
        ("avg-1536k", "avg-12", {"run.total_env_steps": 1_536_000, "run.policy_average_from": 36}),
        ("size-quick", "avg-12", {"env_params": (("size_scale_max", 1.0), ("size_scale_min", 0.15))}),
        (
            "size-res64",
            "size-quick",
            {"env.camera.resolution": 64, "network.kernels": (8, 2, 3), "network.strides": (8, 2, 1)},
        ),
        (
            "size-stretch",
            "size-small-1152k",
            {
                "env_params": (
                    ("size_scale_max", 1.0),
                    ("size_scale_min", 0.15),
                    ("stretch_max", 1.5),
                    ("stretch_prob", 0.5),
                )
            },
        ),
        ("clip-1536k", "clip-1152k", {"run.total_env_steps": 1_536_000}),
        (
            "clip-res64",
            "clip-1152k",
            {"env.camera.resolution": 64, "network.kernels": (8, 2, 3), "network.strides": (8, 2, 1)},
        ),
        (
            "res64",
            "patch-768k",
            {"env.camera.resolution": 64, "network.kernels": (8, 2, 3), "network.strides": (8, 2, 1)},
        ),  # one change: the image, its patch kept 4x4 tokens
    ],
)
def test_each_table_arm_is_one_change(arm, reference, change):
    assert _changes(arm, reference) == change


def test_quick_preset_is_the_depth_row():
    assert learning_arms.arm_config("expert-margin") == learning_arms.presets.preset("quick", eval_episodes=0)


def test_sizes_preset_is_the_arm_chosen_for_other_sizes():
    sizes = learning_arms.presets.preset("sizes", eval_episodes=0)
    assert learning_arms.arm_config("size-wider-retreat") == sizes
    assert dict(sizes.env_params) == {"size_scale_min": 0.15, "size_scale_max": 1.0, "init_xy_std": 3.0}


def test_reproduce_flags_give_the_sizes_preset_before_the_blind_starts_back(monkeypatch):
    """lab/reproduce.md's $WR0 after `--preset sizes` parses to arm 'size-margin', the sizes preset until
    'size-wide-retreat' (the preset's wider starts removed, not set to their default)."""
    assert _config_of_reproduce_flags(monkeypatch, "WR0", "sizes") == learning_arms.arm_config("size-margin")


def _config_of_reproduce_flags(monkeypatch, names: str, preset: str):
    """The TrainConfig that `ramavt train --preset PRESET $NAME ...` builds for the space-separated NAMEs, with each
    one's flags as lab/reproduce.md sets them (NAME="..." on a line of its own)."""
    import re

    from ramavt_jax import cli
    from ramavt_jax.cli import train as cli_train

    text = (ROOT / "lab" / "reproduce.md").read_text()
    flags = [f for name in names.split() for f in re.search(rf'^{name}="([^"]*)"$', text, re.M).group(1).split()]
    seen = {}
    monkeypatch.setattr(cli_train, "train_and_evaluate", lambda config, out, **kw: seen.update(config=config))
    monkeypatch.setattr(cli_train, "_print_summary", lambda *a: None)
    cli.main(["train", "--preset", preset, *flags, "--run.eval-episodes", "0", "--out", "x"])
    return seen["config"]


def test_reproduce_flags_give_the_earlier_sizes_preset_back(monkeypatch):
    """lab/reproduce.md's $S10, put after `--preset sizes`, parses (through the CLI) to the earlier sizes preset,
    arm 'size-small-1152k', so the commands recorded before the preset changed still run as they ran."""
    assert _config_of_reproduce_flags(monkeypatch, "S10", "sizes") == learning_arms.arm_config("size-small-1152k")


def test_reproduce_flags_give_the_sizes_preset_at_1152k_back(monkeypatch):
    """$WR0 $Q36 after `--preset sizes` is the sizes preset before it trained 1.54M env steps (arm 'size-res64')."""
    assert _config_of_reproduce_flags(monkeypatch, "WR0 Q36", "sizes") == learning_arms.arm_config("size-res64")


def test_long_preset_is_the_arm_chosen_for_a_longer_budget():
    assert learning_arms.arm_config("long-margin") == learning_arms.presets.preset("long", eval_episodes=0)


def test_reproduce_flags_give_the_earlier_long_preset_back(monkeypatch):
    """lab/reproduce.md's $L10, put after `--preset long`, parses to arm 'long-lr2', the long preset until
    2026-12-06, whose seed 0 was the earlier shipped agent (retired from the wheel; its files are in git history)."""
    earlier = learning_arms.arm_config("long-lr2")
    assert _config_of_reproduce_flags(monkeypatch, "L10", "long") == earlier


def test_table2_training_flags_give_the_perturb_arm(monkeypatch):
    """lab/reproduce.md's $T2 flags, after `--preset quick $Q36`, parse to arm 'perturb-05' (Table II in training)."""
    assert _config_of_reproduce_flags(monkeypatch, "Q36 T2", "quick") == learning_arms.arm_config("perturb-05")


def test_reproduce_flags_give_the_quick_preset_before_the_clip_back(monkeypatch):
    """lab/reproduce.md's $Q10 and $Q768, which carry `--preset quick` themselves, parse to arms 'patch-768k' (the
    quick preset at norm 10) and 'clip-1'."""
    assert _config_of_reproduce_flags(monkeypatch, "Q10", "quick") == learning_arms.arm_config("patch-768k")
    assert _config_of_reproduce_flags(monkeypatch, "Q768", "quick") == learning_arms.arm_config("clip-1")


def test_reproduce_flags_give_the_earlier_quick_preset_back(monkeypatch):
    """lab/reproduce.md's $Q36, put after `--preset quick`, parses to arm 'avg-12', the quick preset until
    'avg-1536k', so the commands recorded before still run as they ran."""
    assert _config_of_reproduce_flags(monkeypatch, "Q36", "quick") == learning_arms.arm_config("avg-12")


def test_robust_preset_is_the_arm_chosen_under_perturbations(monkeypatch):
    """The robust preset is arm 'perturb-05-margin', and so is lab/reproduce.md's $T2 after `--preset quick`."""
    robust = learning_arms.presets.preset("robust", eval_episodes=0)
    assert learning_arms.arm_config("perturb-05-margin") == robust
    assert _config_of_reproduce_flags(monkeypatch, "T2", "quick") == robust


def test_reproduce_flags_give_the_long_preset_before_the_margin_loss_back(monkeypatch):
    """lab/reproduce.md's $M0 after `--preset long` parses to arm 'avg-2304k', the long preset until 'long-margin'."""
    assert _config_of_reproduce_flags(monkeypatch, "M0", "long") == learning_arms.arm_config("avg-2304k")


def test_reproduce_flags_give_the_sizes_preset_before_the_margin_loss_back(monkeypatch):
    """lab/reproduce.md's $WR0 $M0 after `--preset sizes` parses to arm 'size-1536k', the sizes preset until
    'size-margin'."""
    assert _config_of_reproduce_flags(monkeypatch, "WR0 M0", "sizes") == learning_arms.arm_config("size-1536k")


def test_reproduce_flags_give_the_quick_preset_before_the_margin_loss_back(monkeypatch):
    """lab/reproduce.md's $M0 after `--preset quick` parses to arm 'avg-1536k', the quick preset until
    'expert-margin'."""
    assert _config_of_reproduce_flags(monkeypatch, "M0", "quick") == learning_arms.arm_config("avg-1536k")


def test_reproduce_flags_give_the_blind_start_arms(monkeypatch):
    """lab/reproduce.md's $W, $WS and $WR after `--preset sizes` parse to arms 'size-wide-starts', 'size-wide-search'
    and 'size-wide-retreat', $WR0 $R to 'size-retreat' and $WR3 to 'size-wider-retreat' (the preset since)."""
    assert _config_of_reproduce_flags(monkeypatch, "W", "sizes") == learning_arms.arm_config("size-wide-starts")
    assert _config_of_reproduce_flags(monkeypatch, "WS", "sizes") == learning_arms.arm_config("size-wide-search")
    assert _config_of_reproduce_flags(monkeypatch, "WR", "sizes") == learning_arms.arm_config("size-wide-retreat")
    assert _config_of_reproduce_flags(monkeypatch, "WR0 R", "sizes") == learning_arms.arm_config("size-retreat")
    assert _config_of_reproduce_flags(monkeypatch, "WR3", "sizes") == learning_arms.arm_config("size-wider-retreat")


def test_report_prints_the_seeds(tmp_path, capsys):
    names = list(learning_arms.targets_lib.TEST_TARGETS)
    seeds = [
        {"AEL": ael, "AER": aer, "lost": 0.0, "per_target": {n: {"AEL": ael, "AER": aer} for n in names}}
        for ael, aer in ((1000.0, 412.0), (980.0, -35.0))
    ]
    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "heldout.json").write_text(
        json.dumps(
            {
                "arm": "x",
                "policy_params": "target",
                "seeds": seeds,
                "AEL_mean": 990.0,
                "AEL_std": 10.0,
                "AER_mean": 188.5,
                "AER_std": 223.5,
            }
        )
    )
    learning_arms.report(tmp_path)
    out = capsys.readouterr().out
    assert "| x [target params] | 990.0 ± 10.0 | 188.5 ± 223.5 | 0 | 1000, 980 | +412, -35 |" in out
    assert "| x [target params] | 990.0 ± 10.0 | 188.5 ± 223.5 | 0 | " + " | ".join(["990 / 188"] * len(names)) in out


def test_arm_table_reads_arm_names_with_a_colon(capsys):
    """'pretrained:ramavt_depth' names the shipped agent's row: the path ends at '.json:', not at the last colon."""
    from lab import arm_table

    test = ROOT / "results" / "test" / "results.json"
    arm = arm_table.load_arm(f"{test}:pretrained:ramavt_depth")
    assert arm.name == "pretrained:ramavt_depth" and arm.scores.shape == (1, 6)
    arm_table.main([f"{test}:depth tracker", f"{test}:pretrained:ramavt_depth", "--ceiling", str(test)])
    rows = [line for line in capsys.readouterr().out.splitlines() if line.startswith("| ") and "| seeds |" not in line]
    assert [r.split(" | ")[0] for r in rows] == ["| depth tracker", "| pretrained:ramavt_depth"]


@pytest.mark.parametrize(
    "arm, reference",
    [("prev-al", "prev"), ("aux-al", "prev-aux"), ("adv-learning", "patch-768k"), ("command-cost-005", "avg-1536k")],
)
def test_each_component_arm_is_its_parents_config_with_its_td_term_replaced(arm, reference):
    """An arm in COMPONENTS changes no config field (the package has none for it) and replaces the TD term alone."""
    from ramavt_jax import train

    config = learning_arms.arm_config(arm)
    assert config == learning_arms.arm_config(reference) and learning_arms.arm_components(reference, config) is None
    terms = learning_arms.arm_components(arm, config).loss_terms
    default = train.default_loss_terms(config)
    assert len(terms) == len(default) and terms[0] is not default[0]
