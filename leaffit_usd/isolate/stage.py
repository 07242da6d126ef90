"""Isolation as a command runs it: the plant cloud and its classes (``isolate_stage``), then the
frame from the scene's cues (``frame_from_isolation``). Used by ``convert``, ``segment`` and
``isolate``; here rather than in ``pipeline`` so that ``segment`` does not import meshing and
USD writing (half a second of start-up)."""
from __future__ import annotations

import logging

import numpy as np

from leaffit_usd.errors import InputFileError, ParameterError
from leaffit_usd.geometry.sampling import canonical_order
from leaffit_usd.isolate.result import BACKGROUND, FLOATER, GROUND, PLANT, POT, SOIL, Isolation
from leaffit_usd.isolate.scene import Crop, IsolateParams, isolate_plant
from leaffit_usd.splats.frame import make_frame

log = logging.getLogger("leaffit_usd")


def _user_up(up):
    """The user's up as a (3,) unit vector (input frame), or None for auto."""
    if up is None or (isinstance(up, str) and up.strip().lower() == "auto"):
        return None
    if isinstance(up, str):
        raise ParameterError("up", "'auto', None or a (3,) vector (commands._args.parse_up reads CLI text)", up)
    u = np.asarray(up, np.float64)
    if u.shape != (3,) or not np.isfinite(u).all() or np.linalg.norm(u) < 1e-12:
        raise ParameterError("up", "a non-zero (3,) vector", up)
    return u / np.linalg.norm(u)


#: isolation is undone when it would remove more than this share of the Gaussians it did not
#: explain by a surface (the ground plane, the pot or the soil), or of those nearest the user's root
MAX_UNEXPLAINED = 0.5
ROOT_NEIGHBOURS = 64


def isolate_stage(cloud, keep_scene: bool = False, crop=None, up=None, params: IsolateParams | None = None,
                  canonical: bool = False, root=None, root_index=None):
    """Plant isolation for a command: ``(plant cloud, Isolation)``.

    cloud : GaussianCloud, input frame; keep_scene : skip the automatic classification (the
    crop, when given, still applies); crop : a ``Crop`` or its text; up : the user's ``--up``
    (None/"auto", an axis text or a vector). The plant cloud is ``cloud.subset(plant)``: its
    ``file_index`` still names each Gaussian's position in the input file. With ``canonical``
    its Gaussians come in :func:`~leaffit_usd.geometry.sampling.canonical_order` (an order of
    their positions alone: what follows then does not depend on the file's order), else in file
    order. Logs what each class removed. Raises UserError when nothing is left.
    """

    if crop is not None and not isinstance(crop, Crop):
        crop = Crop.parse(crop)
    params = (params or IsolateParams()).validate()
    if keep_scene:
        classes = np.zeros(len(cloud), np.uint8)
        if crop is not None:
            classes[~crop.contains(cloud.means)] = BACKGROUND
        iso = Isolation(classes, enabled=False,
                        params={"keep_scene": True, "crop": None if crop is None else str(crop)})
    else:
        iso = keep_the_plant(cloud, isolate_plant(cloud, params, up=_user_up(up), crop=crop),
                             root, root_index)
    log.info("      isolation: %s", iso.describe())
    if iso.up is not None:
        log.info("      up from the %s: (%.3f, %.3f, %.3f)", iso.up_source, *iso.up)
    keep = iso.plant_mask
    if keep.sum() < 10:
        raise InputFileError("input", f"isolation left {int(keep.sum())} Gaussians of {len(cloud)} "
                             "(check --crop, or pass --keep-scene for a trimmed plant)")
    if canonical:
        plant = np.flatnonzero(keep)
        return cloud.subset(plant[canonical_order(cloud.means[plant])]), iso
    return (cloud if keep.all() else cloud.subset(keep)), iso


def keep_the_plant(cloud, iso: Isolation, root=None, root_index=None) -> Isolation:
    """``iso``, or the capture kept whole (every Gaussian PLANT but those outside the crop) with
    one warning line naming ``--keep-scene``, when isolation would lose the plant:

    * it removes, as background objects or floaters, more than ``MAX_UNEXPLAINED`` of the
      Gaussians that no surface explains (all but the ground, pot and soil): a plant of uneven
      density broken into pieces by its holes, not a plant among objects;
    * or it removes most (``MAX_UNEXPLAINED``) of the ``ROOT_NEIGHBOURS`` Gaussians nearest the
      root the user clicked (root : (3,) input frame, or root_index : a file index).
    """
    cls = np.asarray(iso.classes)
    cropped = np.zeros(len(cls), bool)
    if iso.params.get("crop"):
        from leaffit_usd.isolate.scene import Crop
        cropped = ~Crop.parse(iso.params["crop"]).contains(cloud.means)
    surface = np.isin(cls, (GROUND, POT, SOIL))
    loose = np.isin(cls, (BACKGROUND, FLOATER)) & ~cropped
    why = None
    if loose.sum() > MAX_UNEXPLAINED * max(int((~surface & ~cropped).sum()), 1):
        why = (f"it would remove {int(loose.sum()):,} of the {int((~surface & ~cropped).sum()):,} "
               "Gaussians that are not ground, pot or soil as background or floaters")
    point = None
    if root is not None:
        point = np.asarray(root, np.float64)
    elif root_index is not None:
        pos = np.flatnonzero(np.asarray(cloud.file_index) == int(root_index))
        point = np.asarray(cloud.means[pos[0]], np.float64) if len(pos) else None
    if why is None and point is not None and len(cls):
        from leaffit_usd.geometry.knn import knn
        _, near = knn(cloud.means, ROOT_NEIGHBOURS, point[None])
        if (cls[near[0]] != PLANT).mean() > MAX_UNEXPLAINED:
            why = "it would remove most of what lies at the root you gave"
    if why is None:
        return iso
    log.warning("isolation kept the whole capture: %s; pass --keep-scene to skip isolation, or "
                "--crop to give the plant's region", why)
    classes = np.where(cropped, BACKGROUND, PLANT).astype(np.uint8)
    return Isolation(classes, enabled=True, params={**iso.params, "kept_whole": why},
                     timings=iso.timings)


def frame_from_isolation(plant, iso, up=None, root=None, root_index=None, cloud=None):
    """``splats.frame.make_frame`` on the isolated plant, with the scene's cues when the user
    left them to us: ``up`` None (auto) -> the table normal; ``root`` None and no ``root_index``
    -> the stem base at the soil (``iso.root_index`` indexes ``cloud``, the cloud isolation ran
    on). up : (3,) vector or None; root : (3,) point or None, input frame."""
    auto_up = up is None
    auto_root = root is None and root_index is None
    if auto_up and iso.up is not None:
        up = np.asarray(iso.up, np.float64)
    if auto_root and iso.root_index is not None and cloud is not None:
        root_index = int(cloud.file_index[iso.root_index])
        log.info("      root: the stem base at the soil (Gaussian %d)", root_index)
    return make_frame(plant, up=up, root=root, root_index=root_index)
