"""Writes examples/targets/: five target models of shapes the catalogue does not have, from a 0.3 m cubesat to a
12 m station, for checking how trackers carry to user models of any size (`ramavt eval --targets
examples/targets/cubesat-0.3m.xml,...`). Each model is built at unit scale and then scaled so that its bounding
radius (about the centre of mass) is exactly the size in its name.

    python scripts/user_targets.py            # rewrites examples/targets/*.xml
"""

from __future__ import annotations

import tempfile
from pathlib import Path

from ramavt_jax import targets

OUT = Path(__file__).resolve().parents[1] / "examples" / "targets"

# (name, bounding radius in m, description, geoms at unit scale: (type, pos, size, rgba, extra attributes))
GREY, GOLD, BLUE, WHITE, DARK = (
    "0.6 0.6 0.62 1",
    "0.83 0.66 0.22 1",
    "0.08 0.12 0.38 1",
    "0.92 0.92 0.9 1",
    "0.25 0.25 0.27 1",
)
MODELS = [
    (
        "cubesat-0.3m",
        0.3,
        "3U cubesat with two deployed panels",
        [
            ("box", "0 0 0", "0.05 0.05 0.15", GREY, ""),
            ("box", "0 0.16 0.05", "0.05 0.11 0.003", BLUE, ""),
            ("box", "0 -0.16 0.05", "0.05 0.11 0.003", BLUE, ""),
            ("cylinder", "0 0 0.17", "0.01 0.02", DARK, ""),
        ],
    ),
    (
        "cubesat-0.45m",
        0.45,
        "6U cubesat with a long boom",
        [
            ("box", "0 0 0", "0.1 0.05 0.15", GREY, ""),
            ("box", "0.18 0 0", "0.08 0.05 0.003", BLUE, ""),
            ("cylinder", "0 0 0.25", "0.005 0.1", DARK, ""),
            ("sphere", "0 0 0.36", "0.02", WHITE, ""),
        ],
    ),
    (
        "fragment-1.2m",
        1.2,
        "debris fragment: a torn tank with a bent strut",
        [
            ("ellipsoid", "0 0 0", "0.5 0.3 0.25", WHITE, 'euler="10 20 0"'),
            ("ellipsoid", "0.4 0.2 0.1", "0.25 0.15 0.2", GREY, 'euler="0 40 30"'),
            ("capsule", "-0.4 -0.2 0", "0.04 0.35", DARK, 'euler="60 0 20"'),
        ],
    ),
    (
        "tug-4m",
        4.0,
        "space tug: two spherical tanks, a truss and a docking ring",
        [
            ("sphere", "0 0 0.6", "0.5", WHITE, ""),
            ("sphere", "0 0 -0.6", "0.5", WHITE, ""),
            ("box", "0 0 0", "0.12 0.12 1.3", DARK, ""),
            ("cylinder", "0 0 1.45", "0.45 0.08", GOLD, ""),
            ("box", "0 1.3 0", "0.4 0.7 0.01", BLUE, ""),
        ],
    ),
    (
        "station-12m",
        12.0,
        "station: three modules in a T with two solar arrays",
        [
            ("cylinder", "0 0 0", "0.45 2.0", WHITE, ""),
            ("cylinder", "0 0 2.6", "0.35 0.6", GREY, ""),
            ("cylinder", "0 1.2 0", "0.35 1.2", WHITE, 'euler="90 0 0"'),
            ("box", "2.2 0 0.5", "1.5 0.6 0.01", BLUE, ""),
            ("box", "-2.2 0 0.5", "1.5 0.6 0.01", BLUE, ""),
            ("sphere", "0 0 -2.2", "0.5", GOLD, ""),
        ],
    ),
]


def _scale(text: str, factor: float) -> str:
    return " ".join(f"{float(v) * factor:.4f}" for v in text.split())


def mjcf(name: str, description: str, geoms, factor: float) -> str:
    """The model's MJCF with every position and size multiplied by ``factor`` (angles are left alone)."""
    lines = [
        f"<!-- {name}: {description}. A user model for size checks (scripts/user_targets.py); not in the "
        "catalogue's splits. -->",
        f'<mujoco model="{name}">',
        '  <compiler angle="degree" inertiafromgeom="true"/>',
        '  <option gravity="0 0 0"/>',
        "  <worldbody>",
        '    <body name="target">',
        "      <freejoint/>",
    ]
    for i, (kind, pos, size, rgba, extra) in enumerate(geoms):
        attrs = f'name="g{i}" type="{kind}" pos="{_scale(pos, factor)}" size="{_scale(size, factor)}" rgba="{rgba}"'
        lines.append(f'      <geom {attrs} density="200" {extra}/>'.replace(" />", "/>"))
    lines += ["    </body>", "  </worldbody>", "</mujoco>", ""]
    return "\n".join(lines)


def main() -> None:
    OUT.mkdir(parents=True, exist_ok=True)
    for name, radius, description, geoms in MODELS:
        with tempfile.TemporaryDirectory() as tmp:  # the unit-scale model's bounding radius sets the factor
            unit = Path(tmp) / f"{name}.xml"
            unit.write_text(mjcf(name, description, geoms, 1.0))
            factor = radius / targets.load_numpy(unit)[1].bound_radius
        path = OUT / f"{name}.xml"
        path.write_text(mjcf(name, description, geoms, factor))
        print(f"{path}: bounding radius {targets.load_numpy(path)[1].bound_radius:.3f} m")


if __name__ == "__main__":
    main()
