"""Save and load the pipeline's dataclass values as .npz (arrays) + JSON (scalars, dicts).

Each stage's result is a dataclass of numpy arrays and plain scalars; ``save_value`` writes its
fields to one .npz (non-array fields JSON-encoded under ``__json__``), atomically.
:func:`jsonable` turns parameters and reports into JSON-compatible values.
"""
from __future__ import annotations

import dataclasses
import json
from pathlib import PurePath

import numpy as np

from leaffit_usd.io_util import atomic_path


def save_value(value, path) -> None:
    """Write a dataclass of arrays/scalars to ``path`` (.npz), atomically."""
    arrays, plain = {}, {}
    for f in dataclasses.fields(value):
        v = getattr(value, f.name)
        if isinstance(v, np.ndarray):
            arrays[f.name] = v
        else:
            plain[f.name] = v
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, __json__=np.array(json.dumps(plain)), **arrays)


def load_value(cls, path):
    """Read what :func:`save_value` wrote back into ``cls``."""
    with np.load(path, allow_pickle=False) as z:
        plain = json.loads(str(z["__json__"])) if "__json__" in z else {}
        arrays = {k: z[k] for k in z.files if k != "__json__"}
    names = {f.name for f in dataclasses.fields(cls)}
    return cls(**{k: v for k, v in {**plain, **arrays}.items() if k in names})


def jsonable(v):
    """Parameters (dataclasses, numpy scalars/arrays, paths) -> JSON-compatible values."""
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return jsonable(dataclasses.asdict(v))
    if isinstance(v, dict):
        return {str(k): jsonable(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [jsonable(x) for x in v]
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, PurePath):
        return str(v)
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    return repr(v)
