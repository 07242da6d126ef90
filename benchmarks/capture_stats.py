"""Per-Gaussian statistics of a real 3DGS capture beside the generator's two modes.

    .venv/bin/python benchmarks/capture_stats.py [--out FILE.json]

Rows: the real capture ``../shared/real/houseplant.splat`` ("Houseplant", Marcel Padilla,
CC-BY-4.0; skipped with a message when ``../shared/real`` is absent), the generator's capture
realism (``PlantSpec(realism="capture")``: ``samples.generate.capture_realism_plants()``, also
in ``capture_suite()``) and the ideal sample plants (``committed_plants()``), each generated
from its spec and seed (no file needed).

Columns (over all Gaussians of the file, as issue 35's table):

* ``opacity median`` and ``opacity < 0.1``: activated opacities;
* ``needles``: the share with largest / middle axis > 3;
* ``flatness``: the median of middle / smallest axis.

Then, over the plant's Gaussians only (generated: GT labels >= 0; real: above the soil and not
pot-coloured, see ``real_classes``), on 3000 random probes whose 0.8 % H neighbourhood is a sheet
(smallest PCA eigenvalue < 0.15 x the middle one):

* ``sheet / H``: the median std of the neighbours' offsets along the patch normal / plant height
  (stacked layers and off-surface noise make it thick);
* ``|cos n|``: the median |cos| between the probe's shortest axis and the patch normal, and
  ``> 0.8``: the share above 0.8 (how well the shortest axis gives the normal);
* ``coverage``: median areal density x pi x the median largest x middle axis product (the
  areal density itself, Gaussians per H^2 of sheet over all its layers, is in the JSON);
* ``isolated``: the share of all Gaussians whose 8th neighbour is farther than 5x the median;
* ``pot+soil``: the share of pot and soil Gaussians, with the median soil and pot colours.

Writes benchmarks/results/capture_stats.json (with the machine, ``benchmarks/machine.py``).
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

REAL = Path(__file__).resolve().parents[1].parent / "shared" / "real"
HOUSEPLANT = REAL / "houseplant.splat"
#: the houseplant's frame (``../shared/real/README.md``): up is -Y, the soil surface near y = +0.2
REAL_UP, REAL_SOIL_Y = np.array([0.0, -1.0, 0.0]), 0.2
PROBES, PATCH, SHEET = 3000, 0.008, 0.15


def table_stats(cloud) -> dict:
    """Issue 35's four statistics over every Gaussian of ``cloud``."""
    op = cloud.opacities.astype(np.float64)
    s = np.sort(cloud.scales.astype(np.float64), axis=1)[:, ::-1]
    return {"gaussians": int(len(op)),
            "opacity_median": round(float(np.median(op)), 3),
            "opacity_below_0.1": round(float((op < 0.1).mean()), 4),
            "needles": round(float((s[:, 0] / s[:, 1] > 3).mean()), 4),
            "flatness_median": round(float(np.median(s[:, 1] / s[:, 2])), 2)}


def sheet_stats(cloud, plant: np.ndarray, height: float, rng: np.random.Generator) -> dict:
    """Sheet thickness, normal agreement and coverage over the plant's Gaussians (``plant``:
    (N,) bool), plus the isolated share over all Gaussians. ``height`` in input units."""
    means = cloud.means.astype(np.float64)
    sc = cloud.scales.astype(np.float64)
    order = np.argsort(-sc, axis=1)
    s = np.take_along_axis(sc, order, 1)
    Rm = cloud.rotation_matrices().astype(np.float64)
    idx = np.flatnonzero(plant)
    short = Rm[idx, :, order[idx, 2]]
    P = means[idx]
    tree = cKDTree(P)
    probe = rng.choice(len(P), min(PROBES, len(P)), replace=False)
    thick, cosn, dens = [], [], []
    rad = PATCH * height
    for i in probe:
        nb = tree.query_ball_point(P[i], rad)
        if len(nb) < 20:
            continue
        Q = P[nb] - P[nb].mean(0)
        w, V = np.linalg.eigh(Q.T @ Q / len(nb))
        if w[0] > SHEET * w[1]:
            continue
        thick.append(float(np.std(Q @ V[:, 0])) / height)
        cosn.append(abs(float(short[i] @ V[:, 0])))
        dens.append(len(nb) / (np.pi * rad * rad))
    cosn = np.array(cosn)
    d8 = cKDTree(means).query(means, k=9)[0][:, 8]
    return {"sheet_probes": len(cosn),
            "sheet_std_over_H": round(float(np.median(thick)), 5) if thick else None,
            "shortest_axis_cos_median": round(float(np.median(cosn)), 3) if len(cosn) else None,
            "shortest_axis_cos_above_0.8": round(float((cosn > 0.8).mean()), 3) if len(cosn) else None,
            "coverage": round(float(np.median(dens) * np.pi * np.median(s[idx, 0] * s[idx, 1])), 2)
            if dens else None,
            "areal_density_per_H2": round(float(np.median(dens)) * height * height) if dens else None,
            "axes_over_H": [round(float(v) / height, 5) for v in np.median(s[idx], 0)],
            "isolated": round(float((d8 > 5 * np.median(d8)).mean()), 4)}


def class_stats(cloud, pot: np.ndarray, soil: np.ndarray) -> dict:
    col = cloud.colors.astype(np.float64)
    return {"pot_soil_share": round(float((pot | soil).mean()), 3),
            "pot_colour_median": [round(float(c), 3) for c in np.median(col[pot], 0)] if pot.any() else None,
            "soil_colour_median": [round(float(c), 3) for c in np.median(col[soil], 0)] if soil.any() else None}


def real_classes(cloud):
    """(plant, pot, soil) (N,) bool masks of the houseplant from height and colour, and the plant
    height H (soil to the top, input units): soil = the band from 0.043 H above to 0.1 H below
    the soil surface, dark (mean RGB < 0.3) and not green; pot = from 0.11 H above the soil
    downwards, bright (mean RGB > 0.55, blue > 0.5) and not green; plant = the rest above
    0.07 H over the soil."""
    h = cloud.means.astype(np.float64) @ REAL_UP
    soil_h = REAL_SOIL_Y * float(REAL_UP @ [0, 1.0, 0])
    H = float(h.max() - soil_h)
    col = cloud.colors.astype(np.float64)
    lum = col.mean(1)
    green = (col[:, 1] > col[:, 0]) & (col[:, 1] > 1.2 * col[:, 2])
    up = (h - soil_h) / H
    soil = (up < 0.043) & (up > -0.1) & (lum < 0.3) & ~green
    pot = (up < 0.114) & (lum > 0.55) & (col[:, 2] > 0.5) & ~green
    plant = (up > 0.071) & ~pot
    return plant, pot, soil, H


def generated_rows(jobs):
    from samples.generate import make_plant

    rows = []
    for name, spec, seed in jobs:
        t0 = time.perf_counter()
        cloud, gt = make_plant(spec, seed)
        t_gen = time.perf_counter() - t0
        row = {"name": name, "realism": spec.realism, "seed": seed, "generate_s": round(t_gen, 2),
               **table_stats(cloud),
               **sheet_stats(cloud, gt.labels >= 0, gt.height, np.random.default_rng(0))}
        if gt.scene_class is not None:
            row.update(class_stats(cloud, gt.scene_class == 2, gt.scene_class == 3))
        else:
            row.update(class_stats(cloud, np.zeros(len(cloud), bool), np.zeros(len(cloud), bool)))
        rows.append(row)
    return rows


def jobs_capture():
    from samples.generate import capture_realism_plants

    return [(n, s, sd) for n, (s, sd) in capture_realism_plants().items()]


def jobs_ideal():
    from samples.generate import committed_plants

    return [(n, s, sd) for n, (s, sd) in committed_plants().items() if s.realism == "ideal"]


COLUMNS = [("opacity_median", "op med", "{:.2f}"), ("opacity_below_0.1", "op<0.1", "{:.1%}"),
           ("needles", "needles", "{:.1%}"), ("flatness_median", "flat", "{:.2f}"),
           ("sheet_std_over_H", "sheet/H", "{:.5f}"), ("shortest_axis_cos_median", "|cos n|", "{:.3f}"),
           ("shortest_axis_cos_above_0.8", ">0.8", "{:.2f}"), ("coverage", "cover", "{:.1f}"),
           ("isolated", "isol", "{:.2%}"), ("pot_soil_share", "pot+soil", "{:.0%}")]


def _fmt(row):
    cells = [f"{row['name']:28s}"]
    for key, _, f in COLUMNS:
        v = row.get(key)
        cells.append(f"{'-' if v is None else f.format(v):>8s}")
    return " ".join(cells)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(ROOT / "benchmarks/results/capture_stats.json"))
    args = ap.parse_args(argv)
    from benchmarks.machine import machine_info
    from leaffit_usd.io_util import atomic_write_bytes

    result = {"real": None, "capture": generated_rows(jobs_capture()),
              "ideal": generated_rows(jobs_ideal())}
    if HOUSEPLANT.is_file():
        from leaffit_usd.splats import load_cloud

        cloud = load_cloud(HOUSEPLANT)
        plant, pot, soil, H = real_classes(cloud)
        result["real"] = [{"name": "houseplant (Marcel Padilla)", "realism": "real",
                           "height_units": round(H, 4), **table_stats(cloud),
                           **sheet_stats(cloud, plant, H, np.random.default_rng(0)),
                           **class_stats(cloud, pot, soil)}]
    else:
        print(f"{REAL} is absent: the real capture's row is skipped")
    print(" " * 28 + " " + " ".join(f"{h:>8s}" for _, h, _ in COLUMNS))
    for group in ("real", "capture", "ideal"):
        print(f"-- {group}")
        for row in result[group] or []:
            print(_fmt(row))
    for group in ("real", "capture"):
        for row in result[group] or []:
            print(f"{row['name']}: pot colour {row['pot_colour_median']}, soil colour "
                  f"{row['soil_colour_median']}, axes / H {row['axes_over_H']}, Gaussians per "
                  f"H^2 of sheet {row['areal_density_per_H2']}")
    result["machine"] = machine_info()
    atomic_write_bytes(args.out, json.dumps(result, indent=1).encode())
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
