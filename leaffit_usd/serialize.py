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
        elif isinstance(v, list) and v and all(dataclasses.is_dataclass(x) for x in v):
            # a list of dataclass values (levels of detail): arrays under NAME__i__FIELD
            cls = type(v[0])
            plain[f.name] = {"__list_of__": f"{cls.__module__}:{cls.__qualname__}", "n": len(v)}
            for i, x in enumerate(v):
                for g in dataclasses.fields(x):
                    item = getattr(x, g.name)
                    if item is not None:
                        arrays[f"{f.name}__{i}__{g.name}"] = np.asarray(item)
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
    for k, v in list(plain.items()):
        if isinstance(v, dict) and "__list_of__" in v:
            import importlib

            mod, qual = v["__list_of__"].split(":")
            item_cls = getattr(importlib.import_module(mod), qual)
            plain[k] = [item_cls(**{g.name: arrays.get(f"{k}__{i}__{g.name}")
                                    for g in dataclasses.fields(item_cls)
                                    if f"{k}__{i}__{g.name}" in arrays})
                        for i in range(int(v["n"]))]
    arrays = {k: a for k, a in arrays.items() if "__" not in k}
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
