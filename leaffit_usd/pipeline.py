"""``convert``: 3DGS capture -> LeafFit USD asset, the whole pipeline in one call.

    load_cloud -> isolate_plant (table, pot, soil, background, floaters removed; --keep-scene
      turns it off; the plant kept in canonical order: the file's order changes nothing)
      -> make_frame (up, root: the table normal and the stem base at the soil
      when isolation found them) -> transform_cloud (working frame)
      -> segment_plant  (or --labels L.npz, then --edits E.json)
      -> fit_leaves -> build_template_mesh + build_stem
      -> asset_from_results (working -> asset frame) -> write_stage (atomic)

Each stage is the package function named above; this module only wires them, times them, logs
progress on stderr (logger ``leaffit_usd``) and returns a report (JSON-compatible dict: timings,
counts, sizes, fit errors). Nothing is written unless every stage succeeded: the stage file and
its sidecars are written atomically by ``usd.writer.write_stage`` as the last step.
"""
from __future__ import annotations

import dataclasses
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from leaffit_usd.version import __version__
from leaffit_usd.errors import InputFileError, ParameterError
from leaffit_usd.fit.params import FitParams
from leaffit_usd.isolate import IsolateParams
from leaffit_usd.isolate.stage import frame_from_isolation, isolate_stage  # noqa: F401 (API)
from leaffit_usd.prepare import FrameOptions, PreparedPlant
from leaffit_usd.mesh.stem import StemParams
from leaffit_usd.mesh.template import MeshParams
from leaffit_usd.segment.auto import SegmentParams
from leaffit_usd.serialize import jsonable
from leaffit_usd.usd.writer import WriteOptions

log = logging.getLogger("leaffit_usd")


@dataclass
class ConvertOptions:
    """Options of :func:`convert` (paper defaults everywhere; working units).

    up : (3,) up vector, input frame, or None to estimate it (the CLI parses --up)
    root : (3,) point, input frame (nearest Gaussian), or None for the lowest point along up;
        root_index : a Gaussian's index in the input file
    labels : path of a segmentation .npz (``labels`` int32 per input Gaussian, file order) to use
        instead of the automatic segmentation; edits : an edits.json replayed on the labels
    segment, fit, mesh, stem : the stages' parameters (``SegmentParams``, ``FitParams``,
        ``MeshParams``, ``StemParams``; e.g. ``fit=FitParams(K=16, steps=100)``)
    write : how the stage is written (``WriteOptions``: texture format and size, baked payload)
    up_axis : the stage's up axis, "Y" or "Z"; meters_per_unit; height_m : real plant height
    sheet_offset : front/back sheet separation, fraction of the template's extent (None: the
        default ``usd.assemble.DEFAULT_SHEET_OFFSET``)
    keep_scene : skip plant isolation (the input is already a trimmed plant)
    crop : "box:X0,Y0,Z0,X1,Y1,Z1" or "sphere:CX,CY,CZ,R" (input frame): keep only that region
    isolate : ``IsolateParams`` of the isolation stage
    tint : measure each leaf's colour against the template texture (``mesh.appearance``) and
        write it (USD ``primvars:leaffit:tint``, glTF ``COLOR_0``)
    instanced : glTF output only: template + EXT_mesh_gpu_instancing instead of evaluated leaves
    pot : when isolation finds a pot, add it and its soil as meshes (``mesh.pot``: a lathe fitted
        to the pot's Gaussians, a soil disc; vertex colours from theirs): USD ``Pot`` / ``Soil``
        prims, glTF nodes; never part of the leaves or the stem
    """

    up: np.ndarray | None = None
    root: np.ndarray | None = None
    root_index: int | None = None
    labels: str | None = None
    edits: str | None = None
    segment: SegmentParams = field(default_factory=SegmentParams)
    fit: FitParams = field(default_factory=FitParams)
    mesh: MeshParams = field(default_factory=MeshParams)
    stem: StemParams = field(default_factory=StemParams)
    write: WriteOptions = field(default_factory=WriteOptions)
    up_axis: str = "Y"
    meters_per_unit: float = 1.0
    height_m: float | None = None
    sheet_offset: float | None = None
    keep_scene: bool = False
    crop: str | None = None
    isolate: IsolateParams = field(default_factory=IsolateParams)
    tint: bool = True
    instanced: bool = False
    pot: bool = False


def _to_dict(p) -> dict:
    if hasattr(p, "to_dict"):
        return p.to_dict()
    return dataclasses.asdict(p) if dataclasses.is_dataclass(p) else dict(p)


class _Timer:
    """Per-stage wall-clock timings with numbered progress lines on stderr."""

    def __init__(self, n_stages: int):
        self.n, self.i, self.timings = n_stages, 0, {}

    def stage(self, name: str, what: str):
        timer = self

        class _Ctx:
            def __enter__(self):
                timer.i += 1
                log.info("[%d/%d] %s ...", timer.i, timer.n, what)
                self.t0 = time.perf_counter()

            def __exit__(self, exc_type, exc, tb):
                dt = time.perf_counter() - self.t0
                timer.timings[name] = round(dt, 4)
                if exc_type is None:
                    log.info("[%d/%d] %s done in %.2f s", timer.i, timer.n, what, dt)
                return False

        return _Ctx()


def load_labels(path, cloud) -> np.ndarray:
    """Labels from a segmentation .npz (file order) -> (N,) int32 in cloud order
    (``segment.labels_file.cloud_labels``: negative values unassigned, leaves renumbered 1..L).
    Raises InputFileError for a missing/malformed file or a count that does not match."""
    from leaffit_usd.segment.labels_file import cloud_labels

    return cloud_labels(path, cloud)[0]


def auto_segment(cloud_working, root_index, seg_params):
    """segment_plant with the orientation-aware normals when the segmentation module offers them."""
    from leaffit_usd.segment import auto

    pts = np.asarray(cloud_working.means, np.float64)
    normals = auto.working_normals(cloud_working) if hasattr(auto, "working_normals") else None
    return auto.segment_plant(pts, root_index, seg_params, normals=normals)


def _segmentation_from_labels(cloud_working, labels, root_index, seg_params, auto_seg=None):
    """A Segmentation carrying given labels (from --labels / --edits).

    The stem needs the rootward tree, which only the automatic segmentation builds: it is run
    for its tree and geodesic distances, then the labels are replaced and every per-leaf field
    that refers to its own leaf numbering (apexes, tips, bases) is cleared, so the fit derives
    each leaf's base/tip from ``dist_root`` instead.
    """
    import dataclasses as dc

    if auto_seg is None:
        auto_seg = auto_segment(cloud_working, root_index, seg_params)
    labels = np.asarray(labels, np.int32)
    nodes = np.asarray(auto_seg.tree_nodes, np.int64)
    return dc.replace(auto_seg, labels=labels,
                      apex_indices=np.zeros(0, np.int64), apex_labels=np.zeros(0, np.int32),
                      leaf_tip=np.zeros(0, np.int64), leaf_base=np.zeros(0, np.int64),
                      tree_leaf=labels[nodes] if len(nodes) else np.zeros(0, np.int32),
                      params={**dict(auto_seg.params or {}), "labels_from": "file"})


def encode_classes(cloud, iso) -> str:
    """Isolation classes in FILE order (uint8; 255 = dropped at load), zlib + base64: compact
    enough for a JSON report. Decode with :func:`leaffit_usd.isolate.decode_classes`."""
    from leaffit_usd.isolate import encode_classes as enc

    return enc(cloud.to_file_order(np.asarray(iso.classes, np.uint8), fill=255).astype(np.uint8))


def convert(input_path, output_path, options: ConvertOptions | None = None) -> dict:
    """Convert a 3DGS capture (.ply / USD splats) into a LeafFit USD stage.

    Returns the report dict: ``timings`` (s per stage), ``counts``, ``sizes`` (bytes, with the
    compression ratio input/output), ``fit`` (errors), ``outputs``, ``params``.
    Raises UserError subclasses for bad input or options; nothing is written on failure.
    """
    from leaffit_usd.io_util import file_sha256
    from leaffit_usd.splats import load_cloud
    from leaffit_usd.usd.assemble import DEFAULT_SHEET_OFFSET, asset_from_results
    from leaffit_usd.usd.writer import LeafTextures

    o = options or ConvertOptions()
    t_start = time.perf_counter()
    input_path, output_path = Path(input_path), Path(output_path)
    _check_options(o, output_path)

    from leaffit_usd.fit.register import fit_leaves
    from leaffit_usd.mesh.stem import build_stem
    from leaffit_usd.mesh.template import build_template_mesh

    fit_p, mesh_p, stem_p = o.fit, o.mesh, o.stem

    T = _Timer(8 if o.tint else 7)
    with T.stage("load", f"loading {input_path.name}"):
        cloud_in = load_cloud(input_path)
        sha = file_sha256(input_path)
        log.info("      %d Gaussians (SH degree %d)", len(cloud_in), cloud_in.sh_degree)
    front = {}
    with T.stage("isolate", "isolating the plant (ground, pot, soil, background, floaters), "
                 "choosing the frame" if not o.keep_scene else "isolation off (--keep-scene), "
                 "choosing the frame"):
        # the plant in an order of positions alone, so the asset does not depend on the file's
        # order (a converter may sort the splats, e.g. by Morton code); the same front half as
        # `segment` and `edit` (leaffit_usd.prepare)
        prep = PreparedPlant.from_cloud(cloud_in, FrameOptions(o.up, o.root, o.root_index),
                                        o.isolate, o.keep_scene, o.crop, timings=front)
        frame, root_index, iso, cloud, cw = prep.frame, prep.root_index, prep.iso, prep.plant, prep.working
        # memory: from here on the loaded cloud is needed only for its count and the classes in
        # file order; dropping it (and, below, the isolated input-frame cloud) keeps one full
        # copy of the Gaussians alive instead of three (~250 MB per million at SH degree 3)
        loaded = _Loaded(len(cloud_in), encode_classes(cloud_in, iso))
        pot = _pot_mesh(cloud_in, iso, frame) if o.pot else None
        del cloud_in
        prep.loaded = None
        pts = np.asarray(cw.means, np.float64)
        if o.edits is None:   # --edits replays its strokes on the input-frame cloud
            prep.normals   # noqa: B018 - computed now, from the input-frame plant it then drops
            cloud = prep.plant = _FileIds.of(cloud)
    T.timings.update(front)
    with T.stage("segment", "segmenting leaves" if o.labels is None else f"reading labels {o.labels}"):
        seg = _segment_stage(prep, cloud, o, input_path)
        n_leaves = seg.n_leaves
        cloud = _FileIds.of(cloud)
        prep = None
    with T.stage("fit", f"fitting the template to {n_leaves} leaves (K={fit_p.K}, {fit_p.solver()})"):
        fits = fit_leaves(cw, seg, fit_p)
    with T.stage("mesh", "building the template mesh and textures"):
        template = build_template_mesh(cw, fits, mesh_p)
    with T.stage("stem", "building the stem"):
        stem = build_stem(seg, pts, fits, stem_p, colors=cw.colors)
    tints = None
    if o.tint:
        from leaffit_usd.mesh.appearance import measure_leaf_tints
        with T.stage("tint", "measuring per-leaf colour (tint)"):
            tints = measure_leaf_tints(cw, np.asarray(seg.labels), fits, template)
    params = _params_record(o, iso, int(cloud.file_index[root_index]))
    with T.stage("write", f"writing {output_path}"):
        asset = asset_from_results(
            template, fits, stem, frame, up_axis=str(o.up_axis).upper(),
            meters_per_unit=float(o.meters_per_unit), height_m=o.height_m,
            sheet_offset=DEFAULT_SHEET_OFFSET if o.sheet_offset is None else float(o.sheet_offset),
            input_sha256=sha, params=params,
            extra_metadata={"input_name": input_path.name}, pot=pot)
        if tints is not None:
            asset.tints = tints.tints
        result = _write_output(output_path, asset, LeafTextures(template.front_texture,
                                                                template.back_texture), o)

    report = _report(input_path, output_path, sha, result, {**T.timings, "total": round(
        time.perf_counter() - t_start, 4)}, cloud, loaded, iso, fits, template, asset, frame, root_index)
    report["tint"] = None if tints is None else {
        "per_leaf": np.round(tints.tints, 4).tolist(), "samples": tints.samples.tolist(),
        "space": "linear RGB gain on the template texture"}
    all_bytes = report["sizes"]["output_with_sidecars_bytes"]
    log.info("wrote %s (%d file(s), %.1f KB; input %.1f KB, ratio %.1fx) in %.1f s", output_path,
             len(result.files), all_bytes / 1024, report["sizes"]["input_bytes"] / 1024,
             report["sizes"]["compression_ratio"], report["timings"]["total"])
    return report


def _write_output(output_path: Path, asset, textures, o: ConvertOptions):
    """The asset written as ``output_path`` asks: a glTF / GLB, or the USD stage with its baked
    leaves and levels of detail (atomic). Returns a ``usd.writer.WriteResult``."""
    from leaffit_usd.export.gltf import GLTF_FORMATS, GltfOptions, write_gltf
    from leaffit_usd.runtime.evaluator import asset_leaves
    from leaffit_usd.usd.writer import WriteResult, write_stage

    if output_path.suffix.lower() in GLTF_FORMATS:
        g = write_gltf(output_path, asset, textures, GltfOptions(
            instanced=o.instanced, texture_format=o.write.texture_format,
            texture_max_size=int(o.write.texture_max_size), tint=o.tint))
        return WriteResult(path=output_path, files={"gltf": output_path}, sizes={"gltf": g.bytes})
    return write_stage(output_path, asset, textures, o.write,
                       leaves=asset_leaves(asset, separate_sheets=True),
                       lod_leaves=[asset_leaves(asset.at_lod(k), separate_sheets=True)
                                   for k in range(1, len(asset.lods) + 1)])


def _pot_mesh(cloud_in, iso, frame):
    """``mesh.pot.build_pot`` on the Gaussians isolation classed as pot and soil (working
    frame), or None when isolation found no pot (logged)."""
    from leaffit_usd.isolate import POT, SOIL
    from leaffit_usd.mesh.pot import build_pot

    cls = np.asarray(iso.classes)
    pot = None
    if iso.pot is not None and (cls == POT).any():
        pts = np.asarray(cloud_in.means, np.float64)
        p, s = cls == POT, cls == SOIL
        pot = build_pot(frame.to_working(pts[p]), cloud_in.colors[p], frame.to_working(pts[s]),
                        cloud_in.colors[s], frame.rotation @ np.asarray(iso.pot["axis"], np.float64),
                        frame.to_working(np.asarray(iso.pot["center"], np.float64)[None])[0])
    log.info("      pot: %s", "a lathe and a soil disc" if pot is not None else "none found")
    return pot


def _params_record(o: ConvertOptions, iso, root_gaussian: int) -> dict:
    """The parameters a conversion records in the stage (root_gaussian: the root's index in
    the input file)."""
    return {
        "segment": {**_to_dict(o.segment), "labels_file": None if o.labels is None else str(o.labels)},
        "edits": None if o.edits is None else str(o.edits),
        "fit": _to_dict(o.fit), "mesh": _to_dict(o.mesh), "stem": _to_dict(o.stem),
        "up": "auto" if o.up is None else [float(c) for c in o.up],
        "root": "auto" if o.root is None else [float(c) for c in o.root], "root_index": o.root_index,
        "root_gaussian": root_gaussian,
        "isolate": iso.params,
    }


def _check_options(o: ConvertOptions, output_path: Path) -> None:
    """Every option checked before the long run (UserError subclasses)."""
    from leaffit_usd.export.gltf import GLTF_FORMATS
    from leaffit_usd.usd.writer import FORMATS

    if output_path.suffix.lower() not in FORMATS + GLTF_FORMATS:
        raise ParameterError("-o/--output", f"a path ending in {', '.join(FORMATS + GLTF_FORMATS)}",
                             str(output_path))
    if str(o.up_axis).upper() not in ("Y", "Z"):
        raise ParameterError("--up-axis", "Y or Z", o.up_axis)
    o.write.validate()
    if not (np.isfinite(o.meters_per_unit) and o.meters_per_unit > 0):
        raise ParameterError("--meters-per-unit", "a positive number", o.meters_per_unit)
    if o.height_m is not None and not (np.isfinite(o.height_m) and o.height_m > 0):
        raise ParameterError("--height", "a positive height in metres", o.height_m)
    if o.labels is not None and not Path(o.labels).is_file():
        raise InputFileError(o.labels, "no such file")
    if o.edits is not None and not Path(o.edits).is_file():
        raise InputFileError(o.edits, "no such file")
    for p in (o.segment, o.fit, o.mesh, o.stem):
        p.validate()


def _segment_stage(prep, cloud, o: ConvertOptions, input_path: Path):
    """The Segmentation of the prepared plant ``prep`` (its working cloud): automatic, or
    --labels, then --edits (``cloud``: the plant, input frame). Raises InputFileError when it has
    no leaves."""
    cw, root_index = prep.working, prep.root_index
    auto_seg = None
    if o.labels is None:
        auto_seg = prep.segment(o.segment)
        labels = np.asarray(auto_seg.labels, np.int32)
    else:
        labels = load_labels(o.labels, cloud)
    if o.edits is not None:
        from leaffit_usd.segment.edits import apply_edits_file
        labels = apply_edits_file(labels, cloud, o.edits, input_path)
    if o.labels is None and o.edits is None:
        seg = auto_seg
    else:
        if auto_seg is None:  # the stem needs the automatic segmentation's rootward tree
            auto_seg = prep.segment(o.segment)
        seg = _segmentation_from_labels(cw, labels, root_index, o.segment, auto_seg)
    log.info("      %d leaves", seg.n_leaves)
    if seg.n_leaves == 0:
        raise InputFileError(input_path, "no leaves found (the segmentation is empty); "
                             "check --up/--root or pass --labels")
    return seg


@dataclass(frozen=True)
class _Loaded:
    """What the report keeps of the loaded cloud once it is dropped: its Gaussian count and
    the isolation classes in file order (:func:`encode_classes`)."""

    n: int
    classes: str


@dataclass(frozen=True)
class _FileIds:
    """What the later stages and the report need of the isolated input-frame cloud once its
    Gaussians are dropped: ``file_index`` (N,) int64 and ``file_count`` (as ``GaussianCloud``)."""

    file_index: np.ndarray
    file_count: int

    @staticmethod
    def of(cloud) -> "_FileIds":
        return cloud if isinstance(cloud, _FileIds) else _FileIds(cloud.file_index, cloud.file_count)

    def __len__(self) -> int:
        return len(self.file_index)


def _report(input_path: Path, output_path: Path, sha: str, result, timings: dict, cloud,
            loaded: _Loaded, iso, fits, template, asset, frame, root_index: int) -> dict:
    """The JSON-compatible report of one conversion (see :func:`convert`). cloud : the isolated
    cloud (or its :class:`_FileIds`); loaded : what is kept of the loaded one."""
    in_bytes = input_path.stat().st_size
    out_bytes = output_path.stat().st_size
    all_bytes = result.total_bytes if output_path.suffix.lower() != ".usdz" else out_bytes
    errors = np.asarray(fits.errors, np.float64)
    report = {
        "tool": "leaffit-usd", "version": __version__,
        "input": str(input_path), "input_sha256": sha, "output": str(output_path),
        "outputs": {k: str(v) for k, v in result.files.items()},
        "timings": timings,
        "counts": {
            "gaussians": int(len(cloud)), "gaussians_in_file": int(cloud.file_count),
            "gaussians_loaded": int(loaded.n),
            "leaves": int(asset.n_leaves), "K": int(asset.targets.shape[1]) if asset.n_leaves else int(fits.params.get("K", 0)),
            "template_label": int(fits.template_label),
            "template_vertices": int(len(asset.template_points)),
            "template_faces": int(len(asset.template_faces)),
            "stem_vertices": int(len(asset.stem_points)), "stem_faces": int(len(asset.stem_faces)),
            "rigid_fallback_leaves": int(np.asarray(fits.fallback, bool).sum()),
        },
        "sizes": {
            "input_bytes": int(in_bytes), "output_bytes": int(out_bytes),
            "output_with_sidecars_bytes": int(all_bytes), "files": result.sizes,
            "compression_ratio": round(in_bytes / max(all_bytes, 1), 3),
        },
        "fit": {
            "chamfer_mean": float(errors.mean()) if errors.size else None,
            "chamfer_max": float(errors.max()) if errors.size else None,
            "per_leaf": errors.round(7).tolist(),
            "units": "working units (plant height = 1)",
        },
        "frame": {**frame.to_dict(), "root_index": int(root_index)},
        "isolation": {**iso.to_dict(), "removed": iso.removed(),
                      "classes": loaded.classes,
                      "classes_encoding": "uint8 per input Gaussian in file order (0 plant, 1 ground, "
                                          "2 pot, 3 soil, 4 background, 5 floater, 255 dropped at "
                                          "load), zlib, base64"},
        "params": asset.metadata.get("params", {}),
        "mesh_report": jsonable(getattr(template, "report", {})),
    }
    return report

