"""The `ramavt` command line: listing, rendering an episode, clear errors."""

import pytest

from ramavt_jax import cli


def test_targets_lists_catalogue(capsys):
    cli.main(["targets"])
    out = capsys.readouterr().out
    lines = [line for line in out.splitlines()[1:] if line.strip()]
    assert len(lines) == 18
    assert sum(" test " in line for line in lines) == 6
    cli.main(["targets", "--split", "test"])
    assert len(capsys.readouterr().out.strip().splitlines()) == 7


def test_render_writes_gif(tmp_path, capsys):
    out = tmp_path / "episode.gif"
    cli.main(["render", "--target", "Capsule-v0", "--policy", "oracle", "--steps", "6", "--resolution", "16",
              "--size", "64", "--out", str(out)])
    assert out.is_file() and out.stat().st_size > 1000
    import imageio.v2 as imageio

    frames = imageio.mimread(out)
    assert len(frames) == 6 and frames[0].shape[1] == 3 * 64
    assert "6 steps tracked" in capsys.readouterr().out


def test_render_unknown_target_is_a_clear_error(tmp_path):
    with pytest.raises(ValueError, match="unknown target"):
        cli.main(["render", "--target", "Enterprise", "--steps", "2", "--out", str(tmp_path / "x.gif")])
