"""Procedural training targets: random spacecraft built from MuJoCo primitives, for training on more shapes than the
catalogue's twelve training models (build time; the package does not import this).

    python scripts/procedural_targets.py --count 48 --seed 0 --out runs/procedural
    ramavt train --preset quick --env.targets $(python scripts/procedural_targets.py --list-train runs/procedural)

Model ``index`` is of kind ``KINDS[index % 4]``, its parameters drawn from ``numpy.random.default_rng([seed,
index])``, so a model depends only on the seed and its index:

- ``sat``: a box or cylinder bus with zero, one or two solar wings of 1-3 panels (one wing: the silhouette's
  centre lies well off the centre of mass, as on the validation satellite), maybe a dish on a boom, instrument boxes
  and an engine;
- ``stack``: a rocket-like stack of 2-4 coaxial cylinders of varied radii with a nozzle and maybe side pods;
- ``modules``: a station-like chain of 2-4 modules with wings on some of them and maybe a side module;
- ``rock``: a cluster of 3-8 overlapping ellipsoids and spheres.

Densities follow the catalogue's (panels light, buses and rock heavy), so light appendages move the silhouette's
centre away from the centre of mass. Every model is scaled to a bounding radius (about its centre of mass) drawn
uniformly in [1.0, 2.4] m (the catalogue has 0.56-2.4 m; a thin model much smaller covers few pixels), and has at
most ``MAX_GEOMS`` geoms, the most a catalogue training model has, so that training on them pads the geom arrays no
further (the renderer's cost grows with that pad).
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import numpy as np
from catalogue_gen import (
    D_BOOM,
    D_BUS,
    D_DENSE,
    D_MODULE,
    D_PANEL,
    D_TANK,
    DARK,
    GOLD,
    GREY,
    OLIVE,
    PANEL,
    PANEL2,
    RADIATOR,
    SILVER,
    WHITE,
    bound_radius,
)
from mjcf_builder import Target

MAX_GEOMS = 21  # the most geoms of a catalogue training model (Station-v1): the pad training already has
RADIUS_RANGE = (1.0, 2.4)  # m: bounding radii drawn (module docstring)
# Shape grounds (--ground): models for evaluation only, of any size a user may bring, with their masses spread unlike
# the catalogue's, so that a tracker cannot read the centre of mass off the silhouette by habit.
GROUND_RADIUS_RANGE = (0.3, 12.0)  # m: bounding radii drawn log-uniformly
GROUND_DENSITY_SPREAD = 3.0  # each geom's density times a factor drawn log-uniformly in [1/3, 3]
GROUND_SEEDS = {"val-shapes": 1001, "test-shapes": 2002}  # seed of each ground; never 0 (the training models')
GROUND_COUNT = 24  # models per ground: six of each kind
KINDS = ("sat", "stack", "modules", "rock")
BODY_COLOURS = (GOLD, SILVER, WHITE, GREY, OLIVE)
PANEL_COLOURS = (PANEL, PANEL2)


def _u(rng: np.random.Generator, low: float, high: float) -> float:
    return float(rng.uniform(low, high))


def _wing(t: Target, rng, tag: str, side: int, root_y: float, z: float) -> None:
    """A solar wing along +-y (side 1 or -1) from y = root_y: a yoke, then 1-3 panels, maybe canted."""
    panels, half_x, half_y = int(rng.integers(1, 4)), _u(rng, 0.35, 0.8), _u(rng, 0.35, 0.75)
    yoke = _u(rng, 0.2, 0.6)
    cant = [0, _u(rng, -30, 30), 0] if rng.random() < 0.4 else None
    colour = PANEL_COLOURS[int(rng.integers(2))]
    t.cylinder(f"yoke_{tag}", [0, side * root_y, z], [0, side * (root_y + yoke), z], 0.04, GREY, D_DENSE)
    for i in range(panels):
        y = root_y + yoke + half_y * (2 * i + 1) + 0.05 * i
        t.box(f"wing_{tag}{i}", [0, side * y, z], [half_x, half_y, 0.015], colour, D_PANEL, euler=cant)


def _satellite(t: Target, rng) -> None:
    colour = BODY_COLOURS[int(rng.integers(len(BODY_COLOURS)))]
    if rng.random() < 0.5:
        half = [_u(rng, 0.3, 0.9), _u(rng, 0.3, 0.9), _u(rng, 0.3, 1.0)]
        t.box("bus", [0, 0, 0], half, colour, D_BUS)
    else:
        radius, length = _u(rng, 0.35, 0.9), _u(rng, 0.4, 1.2)
        t.cylinder("bus", [0, 0, -length], [0, 0, length], radius, colour, D_BUS)
        half = [radius, radius, length]
    sides = {0: (), 1: (int(rng.choice([-1, 1])),), 2: (1, -1)}[int(rng.choice(3, p=[0.15, 0.35, 0.5]))]
    for side in sides:
        _wing(t, rng, "p" if side > 0 else "m", side, half[1], _u(rng, -0.5, 0.5) * half[2])
    if rng.random() < 0.6:  # a dish on a boom from the edge of the bus's top, pulled in towards its middle
        start = np.array([rng.choice([-1, 1]) * half[0], 0.0, half[2]]) * _u(rng, 0.5, 1.0)
        direction = np.array([start[0], _u(rng, -0.5, 0.5), _u(rng, 0.3, 1.5)])
        end = start + direction / np.linalg.norm(direction) * _u(rng, 0.4, 1.8)
        dish = _u(rng, 0.3, 1.2)
        t.cylinder("boom", start, end, 0.04, GREY, D_BOOM)
        t.ellipsoid("dish", end, [dish, dish, 0.06], WHITE, D_PANEL, euler=[0, _u(rng, -60, 60), 0])
    faces = 3 if t.geoms[0][0] == "box" else 1  # a cylinder's flat faces are its ends (+-z) only
    for i in range(int(rng.integers(0, 3))):  # instrument boxes on the faces
        face = np.eye(3)[2 - int(rng.integers(faces))] * rng.choice([-1, 1])
        size = [_u(rng, 0.08, 0.35) for _ in range(3)]
        t.box(
            f"instrument_{i}",
            face * (np.array(half) + size) + (1 - np.abs(face)) * rng.uniform(-0.3, 0.3, 3),
            size,
            BODY_COLOURS[int(rng.integers(len(BODY_COLOURS)))],
            D_DENSE,
        )
    if rng.random() < 0.7:
        t.cylinder("engine", [0, 0, -half[2]], [0, 0, -half[2] - _u(rng, 0.2, 0.5)], _u(rng, 0.1, 0.3), DARK, D_DENSE)


def _stack(t: Target, rng) -> None:
    stages, z, radius = [], 0.0, _u(rng, 0.6, 1.6)  # (bottom, top, radius) of each coaxial stage
    for i in range(int(rng.integers(2, 5))):
        length = _u(rng, 0.8, 4.0)
        colour = BODY_COLOURS[int(rng.integers(len(BODY_COLOURS)))]
        density = D_TANK if i % 2 == 0 else D_MODULE  # tanks alternate with denser inter-stage structure
        t.cylinder(f"stage_{i}", [0, 0, z], [0, 0, z + length], radius, colour, density)
        stages.append((z, z + length, radius))
        z, radius = z + length, radius * _u(rng, 0.5, 1.2)
    t.cylinder("nozzle", [0, 0, 0], [0, 0, -_u(rng, 0.5, 1.5)], _u(rng, 0.3, 0.8), DARK, D_DENSE)
    for i in range(int(rng.integers(0, 3))):  # side pods against the stage at their height
        angle, bottom, top, stage_radius = _u(rng, 0, 2 * np.pi), *stages[int(rng.integers(len(stages)))]
        pod = _u(rng, 0.15, 0.5)
        low = _u(rng, bottom, max(bottom, top - pod))
        centre = [np.cos(angle) * (stage_radius + pod), np.sin(angle) * (stage_radius + pod), low]
        t.capsule(f"pod_{i}", centre, [centre[0], centre[1], min(top, low + _u(rng, 0.5, 2.0))], pod, GREY, D_DENSE)


def _modules(t: Target, rng) -> None:
    chain, x = [], 0.0  # (start, end, radius) of each module along x
    for i in range(int(rng.integers(2, 5))):
        length, radius = _u(rng, 2.0, 6.0), _u(rng, 0.8, 1.6)
        colour = BODY_COLOURS[int(rng.integers(len(BODY_COLOURS)))]
        t.cylinder(f"module_{i}", [x, 0, 0], [x + length, 0, 0], radius, colour, D_MODULE)
        if rng.random() < 0.6:  # a pair of wings (or one) across this module, their roots on its hull
            half_x, half_y = _u(rng, 0.6, 2.0), _u(rng, 1.0, 3.0)
            colour = PANEL_COLOURS[int(rng.integers(2))]
            for side in (1, -1) if rng.random() < 0.7 else (int(rng.choice([-1, 1])),):
                t.box(
                    f"wing_{i}{'p' if side > 0 else 'm'}",
                    [x + length / 2, side * (radius + half_y), 0],
                    [min(half_x, length / 2), half_y, 0.015],
                    colour,
                    D_PANEL,
                )
        chain.append((x, x + length, radius))
        x += length
    if rng.random() < 0.5:  # a side module rising from a module's hull
        start, end, radius = chain[int(rng.integers(len(chain)))]
        at, length, side = _u(rng, start, end), _u(rng, 2.0, 5.0), rng.choice([-1, 1])
        t.cylinder(
            "side_module",
            [at, 0, side * radius],
            [at, 0, side * (radius + length)],
            _u(rng, 0.5, 1.0) * radius,
            WHITE,
            D_MODULE,
        )
    if rng.random() < 0.5:  # a radiator panel flat against a module's underside
        start, end, radius = chain[int(rng.integers(len(chain)))]
        half = [_u(rng, 0.3, 0.5) * (end - start), _u(rng, 0.5, 1.5), 0.02]
        t.box("radiator", [(start + end) / 2, 0, -radius - 0.02], half, RADIATOR, D_PANEL)


def _rock(t: Target, rng) -> None:
    """A cluster of lobes, each centred inside an earlier one's smallest half-axis so that the rock is one piece."""
    colour, density = (_u(rng, 0.3, 0.6),) * 3, _u(rng, 1800, 2300)
    centres, axes = [np.zeros(3)], [rng.uniform(0.6, 1.1, 3)]
    for _ in range(int(rng.integers(2, 8))):
        k, direction = int(rng.integers(len(centres))), rng.normal(size=3)
        centres.append(centres[k] + direction / np.linalg.norm(direction) * axes[k].min() * _u(rng, 0.5, 0.9))
        axes.append(rng.uniform(0.3, 0.9, 3))
    for i, (centre, half) in enumerate(zip(centres, axes)):
        if rng.random() < 0.3:
            t.sphere(f"lobe_{i}", centre, float(half.mean()), colour, density)
        else:
            t.ellipsoid(f"lobe_{i}", centre, half, colour, density, euler=list(rng.uniform(-90, 90, 3)))


BUILDERS = {"sat": _satellite, "stack": _stack, "modules": _modules, "rock": _rock}


def procedural_target(seed: int, index: int) -> Target:
    """Model ``index`` of ``seed``: its kind cycles through KINDS, its parameters from default_rng([seed, index]);
    scaled to a bounding radius drawn in RADIUS_RANGE."""
    rng = np.random.default_rng([seed, index])
    kind = KINDS[index % len(KINDS)]
    t = Target(
        f"Gen{seed}-{kind}{index:03d}", f"procedural {kind}, seed {seed}", generator="scripts/procedural_targets.py"
    )
    BUILDERS[kind](t, rng)
    if len(t.geoms) > MAX_GEOMS:  # the builders' counts stay below it; a change to them must too
        raise ValueError(f"{t.name}: {len(t.geoms)} geoms, more than MAX_GEOMS = {MAX_GEOMS}")
    radius = _u(rng, *RADIUS_RANGE)
    t.scale, t.scale_reason = radius / bound_radius(t), f"bounding radius {radius:.2f} m drawn in {RADIUS_RANGE} m"
    return t


def ground_target(seed: int, index: int) -> Target:
    """Model ``index`` of a shape ground: `procedural_target`'s shape, each geom's density times a log-uniform factor
    in [1/GROUND_DENSITY_SPREAD, GROUND_DENSITY_SPREAD], rescaled to a bounding radius drawn log-uniformly in
    GROUND_RADIUS_RANGE (draws from default_rng([seed, index, 1]): the shape is the training generator's)."""
    t = procedural_target(seed, index)
    rng = np.random.default_rng([seed, index, 1])
    spread = np.log(GROUND_DENSITY_SPREAD)
    t.geoms = [(kind, name, rgb, density * float(np.exp(rng.uniform(-spread, spread))), attrs)
               for kind, name, rgb, density, attrs in t.geoms]  # fmt: skip
    low, high = np.log(GROUND_RADIUS_RANGE)
    radius = float(np.exp(rng.uniform(low, high)))
    t.scale *= radius / bound_radius(t)  # about the centre of mass the new densities put elsewhere
    t.scale_reason = f"bounding radius {radius:.2f} m drawn log-uniformly in {GROUND_RADIUS_RANGE} m"
    t.comment += f", densities spread {GROUND_DENSITY_SPREAD:g}x (a shape ground's)"
    return t


def write_models(out: Path, count: int, seed: int = 0, ground: bool = False) -> list[Path]:
    """Write models 0..count-1 of ``seed`` (`ground_target`'s if ``ground``, else `procedural_target`'s) to ``out``
    (created if missing) -> their paths, in index order."""
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for index in range(count):
        t = (ground_target if ground else procedural_target)(seed, index)
        paths.append(out / f"{t.name}.xml")
        paths[-1].write_text(t.xml())
    return paths


_NAME = re.compile(r"^Gen(?P<seed>\d+)-[a-z]+(?P<index>\d+)$")


def training_targets(folder: Path) -> list[str]:
    """The catalogue's training targets, then every .xml in ``folder``: the generated ones by seed and index (the
    order `write_models` returns; a target's list index is what an episode draws), any other file after them by name.
    Raises ValueError for a folder without models."""
    from ramavt_jax.targets import TRAIN_TARGETS

    def order(path: Path):
        match = _NAME.match(path.stem)
        return (0, int(match["seed"]), int(match["index"]), "") if match else (1, 0, 0, path.name)

    paths = sorted(folder.glob("*.xml"), key=order)
    if not paths:
        raise ValueError(f"no .xml models in {folder}; write them first (--out {folder})")
    return [*TRAIN_TARGETS, *(str(p) for p in paths)]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--count", type=int, default=48, help="models to write (their kinds cycle through KINDS)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("runs/procedural"))
    parser.add_argument(
        "--ground",
        action="store_true",
        help="write a shape ground's models (ground_target: sizes 0.3-12 m, densities spread) instead",
    )
    parser.add_argument(
        "--list-train",
        type=Path,
        metavar="DIR",
        help="print the catalogue's training targets and the models in DIR (training_targets), and exit",
    )
    args = parser.parse_args()
    if args.list_train is not None:
        try:
            print(" ".join(training_targets(args.list_train)))
        except ValueError as exc:
            parser.error(str(exc))
        return
    if args.count < 1:
        parser.error("--count must be at least 1")
    for path in write_models(args.out, args.count, args.seed, ground=args.ground):
        print(f"wrote {path}")


if __name__ == "__main__":
    main()
