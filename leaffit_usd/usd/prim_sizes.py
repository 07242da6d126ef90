"""What each byte of a written stage is for: the data each prim holds (``convert --report``).

A crate file stores each attribute's value as one array (compressed when it is large), so the
honest per-prim figure is the raw size of its authored values: the sum, over the prim's
attributes and their time samples, of the values' element count x element size (the sizes
numpy gives them). Every layer the stage composes is read (payloads loaded, the default variant
selections). The shares are of that total; the files' own sizes are reported beside them.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np


def _value_bytes(value) -> int:
    """Raw bytes of one authored value (an array's elements, a string's characters)."""
    if value is None:
        return 0
    if isinstance(value, str):
        return len(value.encode())
    try:
        a = np.asarray(value)
    except (TypeError, ValueError):
        return 0
    return int(a.nbytes) if a.dtype != object else 0


def prim_data_sizes(path, top: int = 12) -> dict:
    """{"total_bytes", "prims": [{"path", "bytes", "share"} ...]} for the stage at ``path``: the
    ``top`` prims holding the most data, largest first, and the rest summed as "(other prims)"."""
    from pxr import Usd

    stage = Usd.Stage.Open(str(Path(path)), Usd.Stage.LoadAll)
    sizes = {}
    for prim in stage.Traverse():
        n = 0
        for attr in prim.GetAttributes():
            if not attr.HasAuthoredValue():
                continue
            samples = attr.GetTimeSamples()
            if samples:
                n += sum(_value_bytes(attr.Get(t)) for t in samples)
            else:
                n += _value_bytes(attr.Get())
        if n:
            sizes[str(prim.GetPath())] = n
    total = sum(sizes.values())
    ranked = sorted(sizes.items(), key=lambda kv: (-kv[1], kv[0]))
    rows = [{"path": p, "bytes": b, "share": round(b / total, 4) if total else 0.0} for p, b in ranked[:top]]
    rest = sum(b for _, b in ranked[top:])
    if rest:
        rows.append({"path": "(other prims)", "bytes": rest, "share": round(rest / total, 4)})
    return {"total_bytes": int(total), "prims": rows,
            "how": "raw size of each prim's authored values (before the crate's compression)"}
