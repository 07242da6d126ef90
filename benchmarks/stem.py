"""Stem surface error against the true tubes: ``mesh.stem.build_stem`` alone, ground-truth labels.

For every plant (the committed samples regenerated with their exact tube surfaces, and the
external ``paper8`` plants of ``../shared/plants`` when present): the working frame from the
GT up axis and root, the GT labels (so the stem is judged alone, not the segmentation) on the
Gaussians ``convert``'s isolation keeps (it drops the floaters it finds), the stem built from the
stem Gaussians, mapped back to the input frame and scored by
``../shared/plants/eval_deform.py``'s ``evaluate_stem``: Corr = mean distance from the stem
mesh to the true tube surface, Comp = mean distance the other way, HD = max of both (x10 of
plant-height-normalised distances). Beside it on our sample plants, ``perfect``: the HD of the
true tubes' visible surface closed at each petiole's end (:func:`perfect_stem`), what a flawless
stem of this design scores, and the least HD any stem with closed petiole tips can score
(:func:`closure_bound`). Skips with a message when ``../shared/plants`` is absent.

    .venv/bin/python benchmarks/stem.py [--sets suite,paper8] [--work DIR]
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from render import SHARED, paper8_plants, suite_plants  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"


def sampling_floor(gt_path: Path, seed: int = 0) -> float:
    """The Corr a perfect stem would score (x10 of height): ``evaluate_stem`` measures the
    distance to the nearest of the GT's tube samples, not to the surface, so even the exact tubes
    score the mean gap between samples. Estimated model-free: the mean nearest-neighbour distance
    between two random halves of the samples, / sqrt(2) (half the density: sqrt(2) the spacing);
    on the sample plants it equals the score of the generator's exact tubes to 1e-4."""
    from scipy.spatial import cKDTree

    with np.load(gt_path) as z:
        G = np.asarray(z["stem_samples"], np.float64) / float(z["plant_height"])
    p = np.random.default_rng(seed).permutation(len(G))
    return 10.0 * float(cKDTree(G[p[::2]]).query(G[p[1::2]])[0].mean()) / np.sqrt(2.0)


def _inside_tubes(q: np.ndarray, tubes) -> np.ndarray:
    """(n,) bool: the points ``q`` (n, 3) strictly inside some open tube of ``tubes`` (the
    generator's ``Axis``: centreline ``pts``, ``radius``): within a segment's length along it
    and nearer its axis than the radius there, less 0.1 % (a point on a tube's own wall is not
    inside it)."""
    from scipy.spatial import cKDTree

    tree = cKDTree(q)
    out = np.zeros(len(q), bool)
    for a in tubes:
        seg = np.diff(a.pts, axis=0)
        L2 = np.maximum((seg ** 2).sum(1), 1e-300)
        near = tree.query_ball_point(a.pts, float(a.radius.max() + np.sqrt(L2.max())))
        cand = np.unique(np.concatenate([np.asarray(x, np.int64) for x in near]))
        for k in range(len(seg)):
            x = q[cand] - a.pts[k]
            t = (x @ seg[k]) / L2[k]
            r = a.radius[k] + np.clip(t, 0, 1) * (a.radius[k + 1] - a.radius[k])
            d = np.linalg.norm(x - np.outer(t, seg[k]), axis=1)
            out[cand[(t > 0) & (t < 1) & (d < 0.999 * r)]] = True
    return out


def perfect_stem(name: str, n: int = 400_000) -> dict | None:
    """What a perfect stem of the issue's design scores: the true tubes' visible surface (none of
    it inside another tube, where no Gaussian shows it: a petiole starts inside its parent) and a
    flat disc closing each petiole at its leaf base (a closed tip as near the open true end as any
    can be: its centre lies one end radius from the tube's wall), ``n`` samples of it scored like
    ``evaluate_stem`` against the same GT samples. Our sample plants only (the generator's
    tubes); None for others.

    Returns x10 of plant height: ``hd`` (its HD), ``corr`` (its mean distance to the GT
    samples), ``hidden`` (of the GT samples inside another tube, the farthest from the visible
    surface), ``tip`` (the largest petiole end radius), ``closed_bound`` (:func:`closure_bound`);
    and ``hidden_share``, the fraction of the GT samples inside another tube."""
    from scipy.spatial import cKDTree

    from samples.generate import (STEM_SAMPLES, committed_plants, make_plant, plant_tubes,
                                  stem_samples_rng, tube_surface_samples)

    if name not in committed_plants():
        return None
    spec, seed = committed_plants()[name]
    _, gt = make_plant(spec, seed)
    tubes = plant_tubes(spec, seed)
    rng = np.random.default_rng([int(seed), 0x5EED])
    X = tube_surface_samples(tubes, n, rng)
    X = X[~_inside_tubes(X, tubes)]
    area = sum(2 * np.pi * float((np.diff(a.s) * 0.5 * (a.radius[1:] + a.radius[:-1])).sum()) for a in tubes)
    caps, tip = [], 0.0
    for a in tubes:
        if a.kind != "petiole":
            continue
        r = float(a.radius[-1])
        tip = max(tip, r)
        t = (a.pts[-1] - a.pts[-2]) / np.linalg.norm(a.pts[-1] - a.pts[-2])
        e1 = np.cross(t, [1.0, 0, 0] if abs(t[0]) < 0.9 else [0, 1.0, 0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(t, e1)
        m = max(int(round(n * np.pi * r * r / area)), 50)
        rr, ph = r * np.sqrt(rng.uniform(size=m)), rng.uniform(0, 2 * np.pi, m)
        caps.append(a.pts[-1] + rr[:, None] * (np.cos(ph)[:, None] * e1 + np.sin(ph)[:, None] * e2))
    # the tubes' frame -> input: fitted on the GT samples, which are the same draws mapped (exact)
    G = np.asarray(gt.stem_samples, np.float64)
    G0 = tube_surface_samples(tubes, STEM_SAMPLES, stem_samples_rng(seed))
    A = np.linalg.lstsq(np.c_[G0, np.ones(len(G0))], G, rcond=None)[0]
    P = np.c_[np.concatenate([X] + caps), np.ones(len(X) + sum(map(len, caps)))] @ A
    scale = float(np.cbrt(abs(np.linalg.det(A[:3]))))
    hid = _inside_tubes(G0, tubes)
    H = float(gt.height)
    d_gp = cKDTree(P).query(G)[0] / H
    d_pg = cKDTree(G).query(P)[0] / H
    return dict(hd=10 * float(max(d_gp.max(), d_pg.max())), corr=10 * float(d_pg.mean()),
                hidden=10 * float(d_gp[hid].max()) if hid.any() else 0.0, hidden_share=float(hid.mean()),
                tip=10 * tip * scale / H, closed_bound=closure_bound(tubes, A, G, H))


def closure_bound(tubes, A: np.ndarray, G: np.ndarray, H: float, n: int = 400) -> float:
    """A lower bound (x10 of plant height) on the HD of *any* stem that closes every petiole over
    the outer half of its length (issue 14 asks for a closed, tapered tip at each leaf base).

    A cap that closes a tube spans its cross-section, so it meets the tube's axis; a point on the
    axis is at least the local radius from every sample of the true, open tube wall. Per petiole
    the best closure is the axis point of its outer half nearest to any GT sample (``n`` points
    along it; on these plants the end itself: petioles are thinnest there), and the stem's HD
    (mesh -> GT side) is at least the worst petiole's value. A *sampled* HD can come in a little
    under it only when its samples miss the cap's centre (``perfect_stem``'s random disc).
    ``tubes``: the generator's (its frame), ``A`` (4, 3) its affine map to the input frame,
    ``G`` (S, 3) the GT samples (input frame), ``H`` the plant height (input units)."""
    from scipy.spatial import cKDTree

    tree, bound = cKDTree(G), 0.0
    for a in tubes:
        if a.kind != "petiole":
            continue
        arc = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(a.pts, axis=0), axis=1))]
        s = np.linspace(0.5, 1.0, n) * arc[-1]
        axis = np.stack([np.interp(s, arc, a.pts[:, k]) for k in range(3)], 1)
        d = tree.query(np.c_[axis, np.ones(n)] @ A)[0]
        bound = max(bound, float(d.min()))
    return 10 * bound / H


def run_plant(d: Path, work: Path) -> dict:
    from eval_deform import evaluate_stem

    from leaffit_usd.isolate.stage import isolate_stage
    from leaffit_usd.mesh.stem import StemParams, build_stem
    from leaffit_usd.pipeline import load_labels
    from leaffit_usd.segment.result import Segmentation
    from leaffit_usd.splats import load_cloud
    from leaffit_usd.splats.frame import make_frame
    from leaffit_usd.splats.transform import transform_cloud

    cloud = load_cloud(d / "point_cloud.ply")
    with np.load(d / "gt.npz") as z:
        up, root = np.asarray(z["up"], float), np.asarray(z["root"], float)
    # the Gaussians `convert` keeps: its isolation drops the floaters it finds (counted as stem
    # here, the ones beside a stem changed it: pothos_sh3 0.16 here against 0.26 converted)
    cloud, _ = isolate_stage(cloud, up=up)
    ch = make_frame(cloud, up=up, root=root)
    cw = transform_cloud(cloud, ch.frame.input_to_working)
    seg = Segmentation(labels=load_labels(d / "gt.npz", cloud), root_index=int(ch.root_index))
    t0 = time.perf_counter()
    st = build_stem(seg, np.asarray(cw.means, np.float64), None, StemParams(), colors=cw.colors)
    dt = time.perf_counter() - t0
    out = work / f"{d.name}.stem.npz"
    out.parent.mkdir(parents=True, exist_ok=True)
    np.savez(out, vertices=ch.frame.to_input(st.points), faces=st.faces)
    r = evaluate_stem(d / "gt.npz", out)
    return dict(plant=d.name, stem_corr=r["stem_corr"], stem_comp=r["stem_comp"], stem_hd=r["stem_hd"],
                floor=sampling_floor(d / "gt.npz"),
                perfect=perfect_stem(d.name),
                tubes=int(st.info.get("tubes", 0)), skeleton=st.info.get("skeleton"),
                vertices=[int(len(st.points))] + [int(len(l.points)) for l in st.lods], seconds=round(dt, 2))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sets", default="suite,paper8")
    ap.add_argument("--work", default=None, help="folder for the plants (default: a temp dir)")
    ap.add_argument("--out", default=str(RESULTS / "stem.json"))
    args = ap.parse_args(argv)
    if not (SHARED / "eval_deform.py").is_file():
        print(f"skipping: {SHARED} is absent (the stem's evaluator is not part of the repo)")
        return 0
    sys.path.insert(0, str(SHARED))
    work = Path(args.work) if args.work else Path(tempfile.mkdtemp(prefix="leaffit_stem_"))
    sets = [s.strip() for s in args.sets.split(",")]
    plants = ([("suite", d) for d in suite_plants(work / "suite")] if "suite" in sets else []) + \
             ([("paper8", d) for d in paper8_plants()] if "paper8" in sets else [])
    rows = []
    print(f"{'set':7s} {'plant':17s} {'Corr':>7s} {'floor':>7s} {'Comp':>7s} {'HD':>7s} {'perfect':>8s} "
          f"{'closed>=':>8s} {'tubes':>5s}  vertices LOD0/1/2   s")
    for tag, d in plants:
        r = run_plant(d, work / "out")
        r["set"] = tag
        rows.append(r)
        print(f"{tag:7s} {r['plant']:17s} {r['stem_corr']:7.4f} {r['floor']:7.4f} {r['stem_comp']:7.4f} "
              f"{r['stem_hd']:7.4f} {format(r['perfect']['hd'], '8.4f') if r['perfect'] else '-':>8s} "
              f"{format(r['perfect']['closed_bound'], '8.4f') if r['perfect'] else '-':>8s} "
              f"{r['tubes']:5d}  {'/'.join(map(str, r['vertices'])):17s} {r['seconds']:.1f}", flush=True)
    for tag in sorted({r["set"] for r in rows}):
        rs = [r for r in rows if r["set"] == tag]
        print(f"{tag:7s} {'mean':17s} {np.mean([r['stem_corr'] for r in rs]):7.4f} "
              f"{np.mean([r['floor'] for r in rs]):7.4f} "
              f"{np.mean([r['stem_comp'] for r in rs]):7.4f} {np.mean([r['stem_hd'] for r in rs]):7.4f}  "
              f"(HD max {max(r['stem_hd'] for r in rs):.4f})")
    print("(x10 of plant height; Corr = mean stem mesh -> true tube samples, Comp = the reverse; floor = "
          "the Corr of the exact tubes: the samples' own spacing; perfect = the HD of the true tubes' "
          "visible surface with each petiole closed at its leaf base, our sample plants only; closed>= = "
          "the least HD of any stem whose petioles are closed at their leaf ends)")
    for r in rows:
        if r["perfect"]:
            p = r["perfect"]
            print(f"  perfect {r['plant']}: HD {p['hd']:.4f} (GT samples inside another tube, "
                  f"{100 * p['hidden_share']:.1f} %: up to {p['hidden']:.4f} from the visible surface; "
                  f"largest petiole end radius {p['tip']:.4f}; any stem with closed petiole tips: "
                  f"HD >= {p['closed_bound']:.4f})")
    from benchmarks.machine import machine_info
    from leaffit_usd.io_util import atomic_write_bytes

    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    atomic_write_bytes(args.out, (json.dumps(dict(rows=rows, machine=machine_info()), indent=1)
                                  + "\n").encode())
    return 0


if __name__ == "__main__":
    sys.exit(main())
