"""scripts/centre_precision.py: the ceiling told its own centre flies as the ceiling; told a wrong one, it scores less
by about the error per step once it holds station."""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
import centre_precision  # noqa: E402


def test_a_wrong_centre_costs_the_ceiling_about_its_size_per_step():
    table = centre_precision.precision_table(("Asteroid-v0",), episodes=2, offsets=[0.0, 0.5], visible=False,
                                             overrides={"max_steps": 200})
    exact, none, half = (table[name]["aer"] for name in ("exact", "offset 0", "offset 0.5"))
    assert none == exact  # the same episodes, the same plans
    # the reward's distance term is 1 per metre: held 0.5 m off for most of 200 steps costs on the order of 50
    assert 30.0 < exact - half < 100.0, (exact, half)
    assert table["offset 0.5"]["per_target"]["Asteroid-v0"] == half
