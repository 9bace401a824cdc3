"""Write the held-out catalogue targets at other sizes as user MJCF files, for testing an agent on target models it
has never seen (other shapes: the held-out split; other sizes: these copies). Prints the comma-separated list that
`ramavt eval --targets` takes.

    python scripts/resized_targets.py --out runs/resized --factors 0.6 4
    ramavt eval --policy pretrained --targets "$(python scripts/resized_targets.py --out runs/resized)" ...
"""

from __future__ import annotations

import argparse
from pathlib import Path

import catalogue_gen  # the catalogue generator beside this script
from ramavt_jax import targets as targets_lib


def write_resized(out: Path, factors: list[float], names=targets_lib.TEST_TARGETS) -> list[Path]:
    """One MJCF per (target, factor): every length of the catalogue model times `factor`."""
    out.mkdir(parents=True, exist_ok=True)
    models = {t.name: t for t in catalogue_gen.all_targets()}
    paths = []
    for name in names:
        for factor in factors:
            model = models[name]
            model.scale = factor * model.scale
            path = out / f"{name}_x{factor:g}.xml"
            path.write_text(model.xml())
            model.scale = model.scale / factor
            paths.append(path)
    return paths


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", type=Path, default=Path("runs/resized"))
    ap.add_argument("--factors", type=float, nargs="+", default=[0.6, 4.0])
    args = ap.parse_args()
    print(",".join(str(p) for p in write_resized(args.out, args.factors)))


if __name__ == "__main__":
    main()
