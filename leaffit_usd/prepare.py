"""The front half of every command, in one place: load -> isolate -> canonical order -> frame ->
working cloud -> normals. ``convert``, ``segment`` and ``edit`` ask a :class:`PreparedPlant` for
the capture and so see the same plant, frame and segmentation.

Index spaces (each array below says which):

* **file**: a Gaussian's position in the input file (its identity: labels, edits);
* **loaded**: the loaded cloud's order (the file's, less the invalid Gaussians dropped at load;
  ``loaded.file_index`` maps it to the file);
* **plant**: the isolated plant in canonical order (an order of the positions alone, so nothing
  after depends on the file's order); ``plant.file_index`` maps it to the file, ``plant_in_loaded``
  to the loaded cloud. ``working`` is the same Gaussians in the working frame, same order.

Only light packages are imported here (splats, isolate, segment): ``segment`` and ``edit`` start
without meshing or USD.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np

from leaffit_usd.isolate import IsolateParams, Isolation
from leaffit_usd.isolate.stage import frame_from_isolation, isolate_stage
from leaffit_usd.splats.cloud import GaussianCloud
from leaffit_usd.splats.frame import Frame

log = logging.getLogger("leaffit_usd")


@dataclass(frozen=True)
class FrameOptions:
    """The user's frame choices. up : (3,) input frame or None (the scene's cue, else estimated);
    root : (3,) point, input frame (the nearest Gaussian) or None; root_index : a file index."""

    up: np.ndarray | None = None
    root: np.ndarray | None = None
    root_index: int | None = None


@dataclass
class PreparedPlant:
    """A capture ready for segmentation (see the module docstring for the index spaces).

    loaded : GaussianCloud, input frame, loaded order
    iso : Isolation, classes in loaded order
    plant : GaussianCloud, input frame, plant order (isolated, canonical)
    plant_in_loaded : (P,) int64, each plant Gaussian's index in ``loaded``
    frame : Frame, input <-> working
    root_index : int, the root Gaussian, plant order
    working : GaussianCloud, working frame, plant order
    loaded_file_index : (N,) int64, ``loaded.file_index`` (kept when ``convert`` drops ``loaded``
        and ``plant`` to save memory)
    """

    loaded: GaussianCloud
    iso: Isolation
    plant: GaussianCloud
    plant_in_loaded: np.ndarray
    frame: Frame
    root_index: int
    working: GaussianCloud
    loaded_file_index: np.ndarray
    _normals: np.ndarray | None = field(default=None, repr=False)

    @classmethod
    def from_cloud(cls, loaded: GaussianCloud, frame: FrameOptions | None = None,
                   isolate: IsolateParams | None = None, keep_scene: bool = False,
                   crop=None, timings: dict | None = None) -> "PreparedPlant":
        """Isolate, order and frame an already loaded cloud (input frame, loaded order).
        timings : filled with the seconds of "isolate" and "frame" when given."""
        import time

        from leaffit_usd.splats.transform import transform_cloud

        fo = frame or FrameOptions()
        t0 = time.perf_counter()
        plant, iso = isolate_stage(loaded, keep_scene, crop, fo.up, isolate, canonical=True,
                                   root=fo.root, root_index=fo.root_index)
        t1 = time.perf_counter()
        choice = frame_from_isolation(plant, iso, fo.up, fo.root, fo.root_index, cloud=loaded)
        if timings is not None:
            timings.update(isolate=round(t1 - t0, 4), frame=round(time.perf_counter() - t1, 4))
        pos = np.empty(int(loaded.file_count), np.int64)
        pos[np.asarray(loaded.file_index)] = np.arange(len(loaded))
        return cls(loaded=loaded, iso=iso, plant=plant,
                   plant_in_loaded=pos[np.asarray(plant.file_index)], frame=choice.frame,
                   root_index=int(choice.root_index),
                   working=transform_cloud(plant, choice.frame.input_to_working),
                   loaded_file_index=np.asarray(loaded.file_index, np.int64))

    @classmethod
    def open(cls, path, frame: FrameOptions | None = None, isolate: IsolateParams | None = None,
             keep_scene: bool = False, crop=None, prim: str | None = None) -> "PreparedPlant":
        """Load the capture at ``path`` (any format ``load_cloud`` reads) and prepare it."""
        from leaffit_usd.splats import load_cloud

        return cls.from_cloud(load_cloud(path, prim=prim), frame, isolate, keep_scene, crop)

    @property
    def normals(self) -> np.ndarray:
        """(P, 3) float64 unit normals, working frame, NaN where a Gaussian is not flat
        (``segment.auto.working_normals``)."""
        if self._normals is None:
            from leaffit_usd.segment.auto import working_normals

            self._normals = working_normals(self.plant, self.frame.rotation)
        return self._normals

    def segment(self, params=None, timings: dict | None = None):
        """The automatic Segmentation of the plant (plant order): ``segment.auto.segment_plant``
        on the working cloud with its normals, from the root."""
        from leaffit_usd.segment.auto import SegmentParams, segment_plant

        pts = np.asarray(self.working.means, np.float64)
        return segment_plant(pts, self.root_index, params or SegmentParams(), normals=self.normals,
                             timings=timings)

    def file_classes(self) -> np.ndarray:
        """(file_count,) uint8 isolation class per file Gaussian (255: dropped at load)."""
        return self.loaded.to_file_order(np.asarray(self.iso.classes, np.uint8), fill=255).astype(np.uint8)

    def file_labels(self, labels: np.ndarray) -> np.ndarray:
        """(file_count,) int32: plant-order ``labels`` (P,) in file order; -1 for what isolation
        removed, 0 for what was dropped at load."""
        out = np.zeros(int(self.plant.file_count), np.int32)
        out[self.loaded_file_index] = -1
        out[np.asarray(self.plant.file_index)] = np.asarray(labels, np.int32)
        return out
