"""Plant isolation: separate the plant from what a real capture keeps around it (table or floor,
pot, soil, background objects, floaters). A stage between loading and the frame; imports only
``leaffit_usd.splats`` and ``leaffit_usd.geometry``.

    from leaffit_usd.isolate import isolate_plant
    iso = isolate_plant(cloud)                 # Isolation: classes (N,) per Gaussian, cloud order
    plant = cloud.subset(iso.plant_mask)       # file_index keeps each Gaussian's identity
"""
from __future__ import annotations

from leaffit_usd.isolate.result import (BACKGROUND, CLASS_NAMES, FLOATER, GROUND, PLANT, POT, SOIL,
                                        Isolation, decode_classes, encode_classes)
from leaffit_usd.isolate.scene import Crop, IsolateParams, isolate_plant

__all__ = ["isolate_plant", "IsolateParams", "Isolation", "Crop", "CLASS_NAMES", "PLANT", "GROUND",
           "POT", "SOIL", "BACKGROUND", "FLOATER", "encode_classes", "decode_classes"]
