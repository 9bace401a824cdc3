"""Generator of the catalogue MJCF files in ``ramavt_jax/targets/models/`` (run ``python scripts/catalogue_gen.py``
from the repository root). It is build-time code: the package only reads the committed files.

Size rule: the task holds the target's centre 5 m in front of a 60-degree camera, where the view's half-width is
5 tan 30 = 2.89 m. A target whose bounding sphere (about its centre of mass) is larger than that sweeps its parts
out of the view, or through the chaser, as it tumbles, and no image-based tracker can hold it. So every class is
scaled by one factor, ``min(1, MAX_BOUND_RADIUS / largest bounding radius of the class)``, with
``MAX_BOUND_RADIUS = 2.4`` m (83 % of the half-width): each model keeps its shape and its size relative to the
other models of its class, and the largest of each class just fits. Densities stay, so masses scale with volume.

Every target is one ``<body name="target">`` with a free joint, built from MuJoCo primitives only, with an explicit
rgba and density per geom. Spacecraft use effective densities of hollow structures (tanks ~30-60 kg/m^3, buses and
modules ~100-400 kg/m^3, panels ~100 kg/m^3 at 3 cm thickness ~ 3 kg/m^2); asteroids are rock (~1800-2300 kg/m^3).
Asteroids are random clusters of ellipsoids and spheres drawn with fixed seeds, so the files are reproducible.

The XML files are committed; this script documents how they were made and regenerates them bit-for-bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from mjcf_builder import Target

MAX_BOUND_RADIUS = 2.4  # m: the largest bounding radius of a catalogue target (see the size rule above)
# The repository's model folder, not the imported package's: an installed copy of the package may live elsewhere.
MODEL_DIR = Path(__file__).resolve().parents[1] / "ramavt_jax" / "targets" / "models"

# Colours (rgb in [0, 1]).
GOLD = (0.83, 0.66, 0.22)  # gold MLI foil
SILVER = (0.78, 0.78, 0.80)  # aluminised MLI / bare aluminium
WHITE = (0.92, 0.92, 0.90)  # white paint / beta cloth
GREY = (0.55, 0.55, 0.57)
DARK = (0.22, 0.22, 0.24)  # nozzles, black paint
PANEL = (0.08, 0.12, 0.38)  # solar cells
PANEL2 = (0.14, 0.10, 0.30)  # older (purple-ish) solar cells
RADIATOR = (0.96, 0.96, 0.96)
SHIELD = (0.32, 0.22, 0.15)  # charred ablative heat shield
OLIVE = (0.50, 0.54, 0.44)  # Soviet-style green-grey insulation

# Effective densities (kg/m^3).
D_PANEL = 100.0
D_BUS = 300.0
D_MODULE = 150.0
D_TANK = 40.0
D_DENSE = 600.0  # engines, adapters, compact hardware
D_BOOM = 150.0


# ----------------------------------------------------------------------------------------------------------- satellites
def satellite_v0() -> Target:
    t = Target("Satellite-v0", "box-bus comsat: gold bus, two 2-panel solar wings, two side reflectors, apogee engine")
    t.box("bus", [0, 0, 0], [0.8, 0.7, 0.95], GOLD, D_BUS)
    t.box("radiator_n", [0, 0.72, 0], [0.78, 0.02, 0.9], RADIATOR, D_PANEL)
    t.box("radiator_s", [0, -0.72, 0], [0.78, 0.02, 0.9], RADIATOR, D_PANEL)
    for s, tag in ((1, "p"), (-1, "m")):
        t.cylinder(f"yoke_{tag}", [0, s * 0.74, 0], [0, s * 1.3, 0], 0.04, GREY, D_DENSE)
        t.box(f"wing_{tag}1", [0, s * 1.95, 0], [0.7, 0.62, 0.015], PANEL, D_PANEL)
        t.box(f"wing_{tag}2", [0, s * 3.2, 0], [0.7, 0.62, 0.015], PANEL, D_PANEL)
    t.ellipsoid("dish_e", [1.05, 0, 0.35], [0.08, 0.75, 0.75], WHITE, D_PANEL, euler=[0, -20, 0])
    t.ellipsoid("dish_w", [-1.05, 0, 0.35], [0.08, 0.65, 0.65], WHITE, D_PANEL, euler=[0, 20, 0])
    t.cylinder("feed_e", [0.8, 0, 1.0], [0.95, 0, 1.35], 0.07, GOLD, D_DENSE)
    t.cylinder("feed_w", [-0.8, 0, 1.0], [-0.95, 0, 1.35], 0.07, GOLD, D_DENSE)
    t.cylinder("omni", [0.3, 0.3, 0.95], [0.3, 0.3, 1.5], 0.03, WHITE, D_BOOM)
    t.cylinder("tt_c_dish", [-0.3, -0.2, 0.95], [-0.3, -0.2, 1.05], 0.3, WHITE, D_PANEL)
    t.cylinder("engine", [0, 0, -0.95], [0, 0, -1.3], 0.2, DARK, D_DENSE)
    return t


def satellite_v1() -> Target:
    t = Target(
        "Satellite-v1",
        "Earth observer: cylindrical silver bus, gold instrument box, one 2-panel canted wing, "
        "magnetometer boom, downlink dish",
    )
    t.cylinder("bus", [0, 0, -1.2], [0, 0, 0.8], 0.75, SILVER, D_BUS)
    t.box("instrument", [0, 0, 1.25], [0.6, 0.55, 0.45], GOLD, D_BUS)
    t.cylinder("aperture", [0.6, 0, 1.3], [0.75, 0, 1.3], 0.3, DARK, D_DENSE)
    t.box("star_tracker", [-0.45, 0.4, 1.75], [0.12, 0.12, 0.08], DARK, D_DENSE)
    t.cylinder("boom_sa", [0, -0.75, -0.3], [0, -1.5, -0.3], 0.05, GREY, D_DENSE)
    for i in range(2):
        t.box(f"wing_{i}", [0, -2.15 - 1.35 * i, -0.3], [1.0, 0.65, 0.015], PANEL, D_PANEL, euler=[0, 25, 0])
    t.cylinder("mag_boom", [0, 0.75, 0.5], [0, 2.6, 0.5], 0.025, WHITE, D_BOOM)
    t.sphere("magnetometer", [0, 2.65, 0.5], 0.08, GOLD, D_DENSE)
    t.cylinder("dish_mast", [0.0, 0.0, -1.2], [0.0, 0.0, -1.6], 0.05, GREY, D_DENSE)
    t.ellipsoid("dish", [0, 0, -1.65], [0.5, 0.5, 0.06], WHITE, D_PANEL)
    t.box("thruster_pod_a", [0.76, 0.0, -1.0], [0.08, 0.12, 0.12], DARK, D_DENSE)
    t.box("thruster_pod_b", [-0.76, 0.0, -1.0], [0.08, 0.12, 0.12], DARK, D_DENSE)
    return t


def satellite_v2() -> Target:
    t = Target(
        "Satellite-v2",
        "science probe: cylindrical gold bus, four petal solar panels in a cross, "
        "large high-gain dish on a mast, long whip antenna",
    )
    t.cylinder("bus", [0, 0, -0.9], [0, 0, 0.9], 0.85, GOLD, D_BUS)
    t.cylinder("deck", [0, 0, 0.9], [0, 0, 1.0], 0.9, SILVER, D_PANEL)
    for k in range(4):
        a = np.deg2rad(45 + 90 * k)
        c, s = np.cos(a), np.sin(a)
        # petal centred 1.0 m outside the bus, tilted 20 deg towards +z, long axis radial
        t.box(
            f"petal_{k}", [2.05 * c, 2.05 * s, -0.55], [1.15, 0.55, 0.015], PANEL, D_PANEL, euler=[0, -20, 45 + 90 * k]
        )
        t.cylinder(f"hinge_{k}", [0.85 * c, 0.85 * s, -0.75], [0.95 * c, 0.95 * s, -0.75], 0.05, GREY, D_DENSE)
    t.cylinder("mast", [0, 0, 1.0], [0, 0, 1.5], 0.08, GREY, D_DENSE)
    t.ellipsoid("hga", [0, 0, 1.65], [1.1, 1.1, 0.14], WHITE, D_PANEL)
    t.cylinder("subreflector_strut", [0, 0, 1.75], [0, 0, 2.3], 0.03, GREY, D_BOOM)
    t.sphere("subreflector", [0, 0, 2.35], 0.12, WHITE, D_DENSE)
    t.cylinder("whip", [0.6, -0.5, -0.9], [0.6, -0.5, -3.0], 0.02, WHITE, D_BOOM)
    t.cylinder("engine", [0, 0, -0.9], [0, 0, -1.25], 0.22, DARK, D_DENSE)
    t.box("sensor", [0.0, 0.88, 0.3], [0.2, 0.08, 0.2], DARK, D_DENSE)
    return t


# ------------------------------------------------------------------------------------------------------------- stations
def station_v0() -> Target:
    t = Target(
        "Station-v0",
        "truss station: 16 m main truss with eight big solar wings, a chain of white "
        "pressurised modules, radiators and a small service module with its own wings",
    )
    t.box("truss", [0, 0, 0], [0.3, 8.0, 0.3], GREY, 200.0)
    for ys in (5.3, 7.1):
        for sy in (1, -1):
            for sz in (1, -1):
                tag = f"{'p' if sy > 0 else 'm'}{int(ys)}{'u' if sz > 0 else 'd'}"
                t.box(f"wing_{tag}", [0, sy * ys, sz * 2.7], [0.02, 0.75, 2.3], PANEL, D_PANEL)
    z = -1.4
    t.cylinder("lab", [1.2, 0, z], [6.0, 0, z], 1.1, WHITE, D_MODULE)
    t.cylinder("node", [-1.2, 0, z], [1.2, 0, z], 1.15, SILVER, D_MODULE)
    t.cylinder("fgb", [-1.2, 0, z], [-5.5, 0, z], 1.0, WHITE, D_MODULE)
    t.cylinder("service", [-5.5, 0, z], [-8.5, 0, z], 1.0, SILVER, D_MODULE)
    t.box("sm_wing_p", [-7.2, 2.9, z], [0.6, 1.9, 0.015], PANEL2, D_PANEL)
    t.box("sm_wing_m", [-7.2, -2.9, z], [0.6, 1.9, 0.015], PANEL2, D_PANEL)
    t.cylinder("mast", [0, 0, 0.3], [0, 0, 1.3], 0.25, GREY, D_MODULE)
    t.box("radiator_p", [0, 3.0, 2.2], [1.6, 0.02, 1.1], RADIATOR, D_PANEL)
    t.box("radiator_m", [0, -3.0, 2.2], [1.6, 0.02, 1.1], RADIATOR, D_PANEL)
    t.cylinder("node_side", [0, 1.15, z], [0, 3.0, z], 0.9, WHITE, D_MODULE)
    t.sphere("cupola", [0, -1.3, z], 0.55, SILVER, D_MODULE)
    return t


def station_v1() -> Target:
    t = Target(
        "Station-v1",
        "modular station: spherical docking node with modules radiating along five "
        "directions, each with its own solar wings, a core module with an aft section and a lattice mast",
    )
    t.sphere("node", [0, 0, 0], 1.1, SILVER, D_MODULE)
    t.cylinder("core", [-1.0, 0, 0], [-6.0, 0, 0], 1.05, WHITE, D_MODULE)
    t.cylinder("core_aft", [-6.0, 0, 0], [-8.5, 0, 0], 0.75, GREY, D_MODULE)
    t.box("core_wing_p", [-3.5, 3.2, 0], [0.8, 2.1, 0.015], PANEL2, D_PANEL)
    t.box("core_wing_m", [-3.5, -3.2, 0], [0.8, 2.1, 0.015], PANEL2, D_PANEL)
    t.cylinder("mod_yp", [0, 1.0, 0], [0, 6.5, 0], 1.1, WHITE, D_MODULE)
    t.cylinder("mod_ym", [0, -1.0, 0], [0, -6.0, 0], 1.1, WHITE, D_MODULE)
    t.cylinder("mod_zp", [0, 0, 1.0], [0, 0, 5.5], 1.0, WHITE, D_MODULE)
    t.cylinder("mod_xp", [1.0, 0, 0], [3.5, 0, 0], 0.9, SILVER, D_MODULE)
    t.ellipsoid("docked_capsule", [4.6, 0, 0], [1.1, 1.0, 1.0], OLIVE, 400.0)
    t.box("yp_wing_u", [0, 5.5, 3.0], [0.75, 0.015, 1.9], PANEL, D_PANEL)
    t.box("yp_wing_d", [0, 5.5, -3.0], [0.75, 0.015, 1.9], PANEL, D_PANEL)
    t.box("ym_wing_u", [0, -5.0, 3.0], [0.75, 0.015, 1.9], PANEL2, D_PANEL)
    t.box("ym_wing_d", [0, -5.0, -3.0], [0.75, 0.015, 1.9], PANEL2, D_PANEL)
    t.box("zp_wing_a", [2.9, 0, 4.5], [1.8, 0.7, 0.015], PANEL, D_PANEL)
    t.box("zp_wing_b", [-2.9, 0, 4.5], [1.8, 0.7, 0.015], PANEL, D_PANEL)
    t.box("mast", [-4.5, 0, 2.9], [0.15, 0.15, 1.9], GREY, 200.0)
    t.box("mast_panel", [-4.5, 0, 5.0], [1.2, 0.015, 0.3], PANEL, D_PANEL)
    t.box("radiator", [-7.2, 0, -1.3], [0.8, 0.015, 0.55], RADIATOR, D_PANEL, euler=[90, 0, 0])
    t.cylinder("antenna_mast", [-2.0, 0, -1.0], [-2.0, 0, -2.2], 0.05, GREY, D_BOOM)
    t.ellipsoid("antenna_dish", [-2.0, 0, -2.3], [0.55, 0.55, 0.07], WHITE, D_PANEL)
    return t


def station_v2() -> Target:
    t = Target(
        "Station-v2",
        "T-shaped station: stepped core module with two laboratory modules on the forward "
        "node forming a T, huge wings at the ends of the labs, core wings and a docked cargo ship",
    )
    t.cylinder("core_big", [-4.2, 0, 0], [0.5, 0, 0], 1.4, WHITE, D_MODULE)
    t.cylinder("core_small", [0.5, 0, 0], [3.2, 0, 0], 1.0, WHITE, D_MODULE)
    t.sphere("node", [4.1, 0, 0], 1.05, SILVER, D_MODULE)
    t.cylinder("lab_p", [4.1, 1.0, 0], [4.1, 5.8, 0], 1.2, WHITE, D_MODULE)
    t.cylinder("lab_m", [4.1, -1.0, 0], [4.1, -5.8, 0], 1.2, WHITE, D_MODULE)
    t.box("lab_p_wing_a", [6.2, 6.4, 0], [2.0, 0.6, 0.015], PANEL, D_PANEL)
    t.box("lab_p_wing_b", [2.0, 6.4, 0], [2.0, 0.6, 0.015], PANEL, D_PANEL)
    t.box("lab_m_wing_a", [6.2, -6.4, 0], [2.0, 0.6, 0.015], PANEL, D_PANEL)
    t.box("lab_m_wing_b", [2.0, -6.4, 0], [2.0, 0.6, 0.015], PANEL, D_PANEL)
    t.box("lab_p_spine", [4.1, 6.4, 0], [4.2, 0.06, 0.06], GREY, 200.0)
    t.box("lab_m_spine", [4.1, -6.4, 0], [4.2, 0.06, 0.06], GREY, 200.0)
    t.box("core_wing_u", [-2.5, 0, 3.3], [0.7, 0.015, 1.9], PANEL, D_PANEL)
    t.box("core_wing_d", [-2.5, 0, -3.3], [0.7, 0.015, 1.9], PANEL, D_PANEL)
    t.cylinder("core_wing_mast", [-2.5, 0, -5.2], [-2.5, 0, 5.2], 0.05, GREY, D_BOOM)
    t.cylinder("cargo", [-4.2, 0, 0], [-7.4, 0, 0], 1.1, SILVER, 200.0)
    t.box("cargo_wing_p", [-6.2, 2.5, 0], [0.5, 1.4, 0.015], PANEL, D_PANEL)
    t.box("cargo_wing_m", [-6.2, -2.5, 0], [0.5, 1.4, 0.015], PANEL, D_PANEL)
    t.box("radiator_p", [5.5, 4.5, 1.3], [1.2, 1.4, 0.02], RADIATOR, D_PANEL)
    t.box("radiator_m", [5.5, -4.5, 1.3], [1.2, 1.4, 0.02], RADIATOR, D_PANEL)
    t.cylinder("robot_arm", [-1.0, 0.9, 1.1], [2.5, 2.2, 1.5], 0.08, WHITE, D_BOOM)
    t.cylinder("docking_port", [4.1, 0, 1.0], [4.1, 0, 1.6], 0.5, GREY, D_MODULE)
    return t


# -------------------------------------------------------------------------------------------------------------- rockets
def rocket_v0() -> Target:
    t = Target(
        "Rocket-v0",
        "Centaur-like upper stage: 3 m silver balloon tank with insulation bands, forward "
        "adapter, domed aft bulkhead, single bell nozzle and RCS pods",
    )
    t.cylinder("tank", [0, 0, -4.5], [0, 0, 4.5], 1.5, SILVER, D_TANK)
    for i, z in enumerate((-2.5, 0.0, 2.5)):
        t.cylinder(f"band_{i}", [0, 0, z - 0.08], [0, 0, z + 0.08], 1.53, GREY, D_TANK)
    t.ellipsoid("aft_dome", [0, 0, -4.5], [1.5, 1.5, 0.7], SILVER, D_TANK)
    t.cylinder("fwd_adapter", [0, 0, 4.5], [0, 0, 5.3], 1.35, GOLD, 150.0)
    t.cylinder("payload_ring", [0, 0, 5.3], [0, 0, 5.6], 0.9, GREY, 300.0)
    t.capsule("chamber", [0, 0, -5.0], [0, 0, -5.5], 0.3, DARK, D_DENSE)
    t.cylinder("nozzle", [0, 0, -5.6], [0, 0, -6.6], 0.6, DARK, 150.0)
    for k in range(4):
        a = np.deg2rad(45 + 90 * k)
        t.box(
            f"rcs_{k}",
            [1.58 * np.cos(a), 1.58 * np.sin(a), -4.0],
            [0.12, 0.12, 0.2],
            GREY,
            D_DENSE,
            euler=[0, 0, 45 + 90 * k],
        )
    t.cylinder("helium_bottle", [0.0, 1.4, -4.9], [0.0, 1.4, -5.5], 0.2, WHITE, 300.0)
    return t


def rocket_v1() -> Target:
    t = Target(
        "Rocket-v1",
        "Falcon-9-like second stage: 3.7 m white tank, stepped payload adapter, raceway, and a "
        "very large dark vacuum nozzle extension",
    )
    t.cylinder("tank", [0, 0, -2.8], [0, 0, 4.0], 1.83, WHITE, D_TANK)
    t.ellipsoid("aft_dome", [0, 0, -2.8], [1.83, 1.83, 0.6], WHITE, D_TANK)
    t.cylinder("black_band", [0, 0, 3.2], [0, 0, 4.0], 1.85, DARK, D_TANK)
    t.cylinder("pa_1", [0, 0, 4.0], [0, 0, 4.45], 1.35, GREY, 200.0)
    t.cylinder("pa_2", [0, 0, 4.45], [0, 0, 4.8], 0.85, GREY, 300.0)
    t.box("raceway", [1.86, 0, 0.4], [0.08, 0.18, 3.6], DARK, 200.0)
    t.ellipsoid("engine", [0, 0, -3.7], [0.55, 0.55, 0.7], DARK, D_DENSE)
    t.cylinder("nozzle_upper", [0, 0, -4.2], [0, 0, -5.2], 0.8, DARK, 100.0)
    t.cylinder("nozzle_ext", [0, 0, -5.2], [0, 0, -6.6], 1.2, (0.35, 0.33, 0.32), 50.0)
    t.sphere("copv_a", [1.1, 1.1, -2.9], 0.3, DARK, 300.0)
    t.sphere("copv_b", [-1.1, -1.1, -2.9], 0.3, DARK, 300.0)
    t.box("grid_fin_stub", [-1.86, 0, 3.6], [0.1, 0.3, 0.3], GREY, 300.0)
    return t


def rocket_v2() -> Target:
    t = Target(
        "Rocket-v2",
        "Soviet-style upper stage: green-grey stacked ellipsoidal tanks with a dark intertank, "
        "gold equipment bay, black aft skirt, a central and four vernier nozzles and external conduits",
    )
    t.cylinder("aft_skirt", [0, 0, -4.3], [0, 0, -3.0], 1.3, DARK, 80.0)
    t.ellipsoid("tank_lower", [0, 0, -1.6], [1.25, 1.25, 1.7], OLIVE, D_TANK)
    t.cylinder("intertank", [0, 0, -0.3], [0, 0, 0.8], 1.2, DARK, 80.0)
    t.ellipsoid("tank_upper", [0, 0, 2.1], [1.25, 1.25, 1.8], OLIVE, D_TANK)
    t.cylinder("equipment_bay", [0, 0, 3.4], [0, 0, 4.3], 1.3, GOLD, 150.0)
    t.cylinder("top_ring", [0, 0, 4.3], [0, 0, 4.5], 0.7, GREY, 300.0)
    t.cylinder("main_nozzle", [0, 0, -4.0], [0, 0, -5.0], 0.55, DARK, 150.0)
    for k in range(4):
        a = np.deg2rad(90 * k)
        c, s = 0.95 * np.cos(a), 0.95 * np.sin(a)
        t.capsule(f"vernier_{k}", [c, s, -4.2], [c, s, -4.8], 0.17, DARK, D_DENSE)
    t.cylinder("conduit_a", [1.3, 0.2, -3.0], [1.3, 0.2, 3.4], 0.09, GREY, 200.0)
    t.cylinder("conduit_b", [-1.3, -0.2, -3.0], [-1.3, -0.2, 3.4], 0.09, GREY, 200.0)
    t.box("antenna", [0, 1.35, 3.9], [0.25, 0.05, 0.25], WHITE, 300.0)
    return t


# ------------------------------------------------------------------------------------------------------------- capsules
def capsule_v0() -> Target:
    t = Target(
        "Capsule-v0",
        "Apollo-like command module: 3.9 m ablative heat shield, conical silver body as "
        "stacked cylinders, docking tunnel and probe, four RCS quads",
    )
    t.ellipsoid("heat_shield", [0, 0, 0.1], [1.95, 1.95, 0.35], SHIELD, 400.0)
    for i, (z0, z1, r) in enumerate(((0.1, 0.7, 1.8), (0.7, 1.3, 1.45), (1.3, 1.9, 1.1), (1.9, 2.4, 0.75))):
        t.cylinder(f"cone_{i}", [0, 0, z0], [0, 0, z1], r, SILVER, 350.0)
    t.cylinder("tunnel", [0, 0, 2.4], [0, 0, 2.85], 0.45, GREY, 300.0)
    t.capsule("probe", [0, 0, 2.85], [0, 0, 3.25], 0.08, GREY, D_DENSE)
    for k in range(4):
        a = np.deg2rad(90 * k)
        t.box(
            f"rcs_{k}", [1.5 * np.cos(a), 1.5 * np.sin(a), 1.0], [0.12, 0.12, 0.12], DARK, D_DENSE, euler=[0, 0, 90 * k]
        )
    t.box("window_a", [0.95, 0.75, 1.6], [0.02, 0.15, 0.12], DARK, 300.0, euler=[0, 0, 38])
    t.box("window_b", [0.95, -0.75, 1.6], [0.02, 0.15, 0.12], DARK, 300.0, euler=[0, 0, -38])
    return t


def capsule_v1() -> Target:
    t = Target(
        "Capsule-v1",
        "Soyuz-like descent module: 2.2 m bell-shaped green-grey body (ellipsoid), dark heat "
        "shield, hatch, periscope, parachute container and whip antennas",
    )
    t.ellipsoid("body", [0, 0, 0.95], [1.1, 1.1, 0.95], OLIVE, 550.0)
    t.ellipsoid("heat_shield", [0, 0, 0.15], [1.12, 1.12, 0.28], SHIELD, 550.0)
    t.cylinder("hatch", [0, 0, 1.8], [0, 0, 2.05], 0.38, GREY, 400.0)
    t.cylinder("periscope", [0.75, 0, 1.2], [1.05, 0, 1.35], 0.1, DARK, 400.0)
    t.box("chute_cover", [-0.85, 0.0, 1.35], [0.12, 0.4, 0.28], GREY, 300.0, euler=[0, -40, 0])
    t.box("window", [0.05, 0.92, 1.0], [0.12, 0.02, 0.12], DARK, 300.0)
    for k in range(3):
        a = np.deg2rad(60 + 120 * k)
        c, s = np.cos(a), np.sin(a)
        t.cylinder(f"whip_{k}", [0.7 * c, 0.7 * s, 1.6], [1.5 * c, 1.5 * s, 2.3], 0.015, WHITE, 300.0)
    t.sphere("retro_cover", [0, 0, -0.15], 0.25, DARK, 400.0)
    return t


def capsule_v2() -> Target:
    t = Target(
        "Capsule-v2",
        "Dragon-like capsule: 3.7 m flat heat shield, white stepped sidewall with black "
        "thruster pods, domed top with an opened nose cap",
    )
    t.cylinder("heat_shield", [0, 0, -0.2], [0, 0, 0.1], 1.85, SHIELD, 400.0)
    for i, (z0, z1, r) in enumerate(((0.1, 0.8, 1.75), (0.8, 1.5, 1.5), (1.5, 2.1, 1.2))):
        t.cylinder(f"wall_{i}", [0, 0, z0], [0, 0, z1], r, WHITE, 300.0)
    t.ellipsoid("dome", [0, 0, 2.1], [1.0, 1.0, 0.45], WHITE, 300.0)
    t.ellipsoid("nose_cap", [0.0, 0.85, 2.6], [0.6, 0.6, 0.12], WHITE, 200.0, euler=[-60, 0, 0])
    t.cylinder("hinge", [0, 0.5, 2.4], [0, 0.8, 2.6], 0.06, GREY, D_DENSE)
    for k in range(4):
        a = np.deg2rad(45 + 90 * k)
        t.box(
            f"pod_{k}",
            [1.55 * np.cos(a), 1.55 * np.sin(a), 1.05],
            [0.14, 0.3, 0.35],
            DARK,
            D_DENSE,
            euler=[0, -20, 45 + 90 * k],
        )
    t.box("window", [1.35, 0, 1.25], [0.05, 0.2, 0.2], DARK, 300.0)
    t.cylinder("trunk_ring", [0, 0, -0.45], [0, 0, -0.2], 1.6, GREY, 200.0)
    return t


# ------------------------------------------------------------------------------------------------------------ asteroids
def asteroid(name: str, seed: int, n: int, axes, lobes: int, density: float, comment: str) -> Target:
    """A rubble cluster: `lobes` big ellipsoids (1 = single body, 2 = contact binary) plus smaller boulders.

    axes are the overall half-extents (m) of the cluster; boulders sit around the surface of the lobes.
    """
    rng = np.random.default_rng(seed)
    axes = np.asarray(axes, float)
    t = Target(name, comment)
    base = np.array([0.56, 0.49, 0.41]) * rng.uniform(0.85, 1.1)  # grey-brown regolith

    def colour():
        return np.clip(base * rng.uniform(0.8, 1.15) + rng.uniform(-0.02, 0.02, 3), 0, 1)

    if lobes == 1:
        centres = [np.zeros(3)]
        lobe_axes = [0.62 * axes]
    else:
        off = np.array([0.45 * axes[0], 0, 0])
        centres = [off, -off * 0.9]
        lobe_axes = [np.array([0.55, 0.85, 0.85]) * axes, np.array([0.45, 0.65, 0.7]) * axes]
    for i, (c, la) in enumerate(zip(centres, lobe_axes)):
        t.ellipsoid(
            f"lobe_{i}", c, la * rng.uniform(0.9, 1.05, 3), colour(), density, euler=rng.uniform(-15, 15, 3).round(1)
        )
    for j in range(n - lobes):
        k = rng.integers(len(centres))
        d = rng.normal(size=3)
        d /= np.linalg.norm(d)
        pos = centres[k] + d * lobe_axes[k] * rng.uniform(0.75, 1.0)
        r = rng.uniform(0.3, 0.6) * lobe_axes[k].mean()
        if rng.uniform() < 0.3:
            t.sphere(f"boulder_{j}", pos, r * 0.8, colour(), density)
        else:
            half = r * rng.uniform(0.45, 1.0, 3)
            t.ellipsoid(f"boulder_{j}", pos, half, colour(), density, euler=rng.uniform(-180, 180, 3).round(1))
    return t


def asteroids() -> list[Target]:
    return [
        asteroid("Asteroid-v0", 100, 7, [1.0, 0.85, 0.75], 1, 2000.0, "2 m roundish rubble pile (7 primitives)"),
        asteroid("Asteroid-v1", 101, 9, [2.0, 1.0, 0.85], 1, 2200.0, "3 m elongated rock (9 primitives)"),
        asteroid("Asteroid-v2", 102, 5, [0.7, 0.6, 0.45], 1, 1800.0, "1.4 m flattened boulder (5 primitives)"),
        asteroid("Asteroid-v3", 103, 11, [1.6, 0.9, 0.8], 2, 2000.0, "3.2 m contact binary (11 primitives)"),
        asteroid("Asteroid-v4", 104, 8, [1.3, 0.75, 0.55], 1, 2300.0, "2.6 m flat elongated shard (8 primitives)"),
        asteroid("Asteroid-v5", 105, 12, [2.2, 1.2, 1.0], 2, 1900.0, "4.5 m bilobed rubble pile (12 primitives)"),
    ]


# ----------------------------------------------------------------------------------------------------------- validation
# Models of neither the training nor the test split (one per spacecraft class, two asteroids, as in the test split),
# for choosing among runs and settings without looking at the test split.
def validation_asteroids() -> list[Target]:
    return [
        asteroid("Asteroid-val0", 106, 6, [1.2, 1.0, 0.65], 1, 2100.0, "2.4 m lumpy oblate rock (6 primitives)"),
        asteroid("Asteroid-val1", 107, 10, [1.7, 0.95, 0.85], 2, 1950.0, "3.4 m contact binary (10 primitives)"),
    ]


def capsule_val0() -> Target:
    t = Target(
        "Capsule-val0",
        "Gemini-like two-part spacecraft: dark conical re-entry module on its heat shield, "
        "stepped white adapter section behind it with radiator panels, nose RCS section",
    )
    for i, (z0, z1, r) in enumerate(((-1.2, -0.8, 1.4), (-0.8, -0.4, 1.28), (-0.4, 0.0, 1.15))):
        t.cylinder(f"adapter_{i}", [0, 0, z0], [0, 0, z1], r, WHITE, 250.0)
    t.ellipsoid("heat_shield", [0, 0, 0.1], [1.12, 1.12, 0.18], SHIELD, 450.0)
    for i, (z0, z1, r) in enumerate(((0.15, 0.75, 1.05), (0.75, 1.3, 0.8), (1.3, 1.8, 0.58))):
        t.cylinder(f"cabin_{i}", [0, 0, z0], [0, 0, z1], r, DARK, 400.0)
    t.cylinder("rcs_section", [0, 0, 1.8], [0, 0, 2.3], 0.45, DARK, 350.0)
    t.cylinder("rendezvous_nose", [0, 0, 2.3], [0, 0, 2.55], 0.3, SILVER, 350.0)
    for k in range(2):
        a = np.deg2rad(60 + 180 * k)
        t.box(
            f"hatch_{k}",
            [0.72 * np.cos(a), 0.72 * np.sin(a), 1.1],
            [0.03, 0.28, 0.4],
            GREY,
            300.0,
            euler=[0, -25, 60 + 180 * k],
        )
    t.box("radiator", [1.42, 0, -0.7], [0.02, 0.45, 0.4], RADIATOR, 200.0)
    return t


def rocket_val0() -> Target:
    t = Target(
        "Rocket-val0",
        "Delta-IV-like cryogenic upper stage: wide white hydrogen tank over a narrower "
        "orange oxygen tank hung on exposed struts, RL10-like engine with a long extendable nozzle",
    )
    ORANGE = (0.80, 0.45, 0.18)
    t.cylinder("lh2_tank", [0, 0, 0.2], [0, 0, 4.4], 2.0, WHITE, D_TANK)
    t.ellipsoid("lh2_dome_top", [0, 0, 4.4], [2.0, 2.0, 0.9], WHITE, D_TANK)
    t.ellipsoid("lh2_dome_aft", [0, 0, 0.2], [2.0, 2.0, 0.6], WHITE, D_TANK)
    t.ellipsoid("lox_tank", [0, 0, -1.6], [1.55, 1.55, 1.05], ORANGE, D_TANK)
    for k in range(4):
        a = np.deg2rad(45 + 90 * k)
        c, s = np.cos(a), np.sin(a)
        t.cylinder(f"strut_{k}", [1.85 * c, 1.85 * s, 0.0], [1.2 * c, 1.2 * s, -2.2], 0.06, GREY, 300.0)
    t.cylinder("thrust_frame", [0, 0, -2.6], [0, 0, -2.9], 0.7, GREY, 300.0)
    t.capsule("engine", [0, 0, -2.9], [0, 0, -3.4], 0.35, DARK, D_DENSE)
    t.cylinder("nozzle", [0, 0, -3.4], [0, 0, -4.6], 0.75, DARK, 100.0)
    t.cylinder("nozzle_ext", [0, 0, -4.6], [0, 0, -5.3], 1.05, (0.35, 0.33, 0.32), 50.0)
    t.cylinder("forward_ring", [0, 0, 5.3], [0, 0, 5.5], 1.3, GREY, 200.0)
    t.sphere("helium_a", [1.4, 0, -2.3], 0.32, DARK, 300.0)
    t.sphere("helium_b", [-1.4, 0, -2.3], 0.32, DARK, 300.0)
    return t


def satellite_val0() -> Target:
    t = Target(
        "Satellite-val0",
        "mobile-comms satellite: white box bus, large offset mesh reflector on a long "
        "boom, two short single-panel wings, feed array and radiators",
    )
    t.box("bus", [0, 0, 0], [0.6, 0.6, 0.8], WHITE, D_BUS)
    t.box("radiator_n", [0, 0.62, 0], [0.58, 0.02, 0.75], RADIATOR, D_PANEL)
    t.box("radiator_s", [0, -0.62, 0], [0.58, 0.02, 0.75], RADIATOR, D_PANEL)
    for s, tag in ((1, "p"), (-1, "m")):
        t.cylinder(f"yoke_{tag}", [0, s * 0.64, 0], [0, s * 1.1, 0], 0.04, GREY, D_DENSE)
        t.box(f"wing_{tag}", [0, s * 1.85, 0], [0.65, 0.75, 0.015], PANEL2, D_PANEL)
    t.cylinder("boom", [0.6, 0, 0.6], [2.0, 0, 1.9], 0.05, GREY, D_BOOM)
    t.ellipsoid("reflector", [2.35, 0, 2.25], [0.05, 1.35, 1.35], GOLD, 60.0, euler=[0, -45, 0])
    t.box("feed_array", [0.62, 0, 0.4], [0.05, 0.35, 0.3], DARK, D_DENSE)
    t.cylinder("engine", [0, 0, -0.8], [0, 0, -1.15], 0.2, DARK, D_DENSE)
    t.cylinder("tt_c_antenna", [-0.3, 0.3, 0.8], [-0.3, 0.3, 1.2], 0.06, WHITE, D_BOOM)
    return t


def station_val0() -> Target:
    t = Target(
        "Station-val0",
        "Skylab-like station: wide orbital workshop with one surviving wing, airlock and "
        "docking adapter in line, a solar observatory on a truss with four windmill arrays, docked capsule",
    )
    t.cylinder("workshop", [-6.4, 0, 0], [2.5, 0, 0], 3.0, WHITE, D_MODULE)
    t.cylinder("aft_skirt", [-6.4, 0, 0], [-7.0, 0, 0], 2.6, GREY, D_MODULE)
    t.box("wing", [-3.0, 6.3, 0], [3.0, 3.2, 0.015], PANEL, D_PANEL)
    t.box("wing_beam", [-3.0, 3.2, 0], [3.0, 0.2, 0.1], GREY, 200.0)
    t.cylinder("airlock", [2.5, 0, 0], [4.5, 0, 0], 1.6, GOLD, D_MODULE)
    t.cylinder("docking_adapter", [4.5, 0, 0], [7.5, 0, 0], 1.4, SILVER, D_MODULE)
    t.ellipsoid("capsule", [8.4, 0, 0], [0.9, 1.3, 1.3], SILVER, 400.0)
    t.box("atm_truss", [5.5, 0, 2.3], [0.3, 0.3, 1.0], GREY, 200.0)
    t.box("atm", [5.5, 0, 4.0], [1.1, 1.1, 1.0], GOLD, D_MODULE)
    for k in range(4):
        a = np.deg2rad(45 + 90 * k)
        c, s = np.cos(a), np.sin(a)
        t.box(
            f"windmill_{k}", [5.5, 3.4 * c, 4.0 + 3.4 * s], [0.015, 2.1, 0.6], PANEL, D_PANEL, euler=[45 + 90 * k, 0, 0]
        )
    t.box("radiator", [-6.7, 0, -2.7], [0.3, 1.2, 0.015], RADIATOR, D_PANEL)
    return t


def bound_radius(target: Target) -> float:
    """Bounding radius (m) about the centre of mass of the model as written, computed by the loader (MuJoCo)."""
    import tempfile

    from ramavt_jax.targets import load_numpy

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"{target.name}.xml"
        path.write_text(target.xml())
        return load_numpy(path)[1].bound_radius


def all_targets() -> list[Target]:
    """The catalogue, each class scaled by the size rule (module docstring): the 18 training and test targets, then
    the validation targets.

    A class's factor is set by its training and test models; its validation models take that factor and must fit
    under the cap, since a larger one would rescale the class and so change the models agents are trained and
    tested on."""
    classes = [
        (asteroids(), validation_asteroids()),
        ([capsule_v0(), capsule_v1(), capsule_v2()], [capsule_val0()]),
        ([rocket_v0(), rocket_v1(), rocket_v2()], [rocket_val0()]),
        ([satellite_v0(), satellite_v1(), satellite_v2()], [satellite_val0()]),
        ([station_v0(), station_v1(), station_v2()], [station_val0()]),
    ]
    for members, validation in classes:
        scale = min(1.0, MAX_BOUND_RADIUS / max(bound_radius(t) for t in members))
        for t in members + validation:
            t.scale, t.scale_reason = scale, f"size rule: bounding radius <= {MAX_BOUND_RADIUS} m"
        for t in validation:
            if bound_radius(t) > MAX_BOUND_RADIUS + 1e-6:
                raise ValueError(
                    f"{t.name}: bounding radius {bound_radius(t):.3f} m at its class's scale {scale:.4f} "
                    f"exceeds {MAX_BOUND_RADIUS} m; make it smaller than its class's largest model"
                )
    return [t for members, _ in classes for t in members] + [t for _, validation in classes for t in validation]


def main() -> None:
    MODEL_DIR.mkdir(exist_ok=True)
    for t in all_targets():
        (MODEL_DIR / f"{t.name}.xml").write_text(t.xml())
        print(f"wrote {MODEL_DIR / (t.name + '.xml')}  ({len(t.geoms)} geoms, scale {t.scale:.4f})")


if __name__ == "__main__":
    main()
