"""Which captures a batch converts, and the name each one's output folder gets.

Inputs (``leaffit-usd batch INPUT...``), each one of:

* a capture file (any format ``load_cloud`` reads, USD included);
* a folder, searched recursively for point-cloud captures (:data:`SEARCH_SUFFIXES`; USD and glTF
  files in a folder are not taken: a folder of captures often also holds converted stages and
  GLBs; nor ``.txt``, which may be notes);
* a manifest, ``.csv`` (a header row) or ``.json`` (a list of objects, or ``{"captures": [...]}``)
  with one capture per row: ``input`` (required; relative to the manifest's folder) and optional
  per-capture options :data:`MANIFEST_FIELDS` (``name``, ``root``, ``up``, ``height``, ...).

Names: the file's stem (``plant.ply`` -> ``plant``, ``plant.compressed.ply`` -> ``plant``); for
the INRIA 3DGS output layout, ``<scene>/point_cloud/iteration_N/point_cloud.ply`` or
``<scene>/point_cloud.ply``, the scene folder's name (and of several ``iteration_N`` of one scene
found in a folder, only the highest N is taken). Characters other than letters, digits, ``.``,
``-``, ``_`` become ``_``. Clashes get ``-2``, ``-3``... in the order of the sorted input paths,
so the same inputs always give the same names; each renaming is reported.
"""
from __future__ import annotations

import csv
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

from leaffit_usd.errors import InputFileError, UserError

from leaffit_usd.splats.formats import SUPPORTED_SUFFIXES

#: suffixes accepted when a file is named explicitly: every format ``load_cloud`` reads
FILE_SUFFIXES = tuple(s for s in SUPPORTED_SUFFIXES if s.count(".") == 1)
#: file suffixes a folder search takes as captures (lower case): the point-cloud formats, not
#: USD or glTF (converted assets sit beside captures) nor ``.txt`` (notes do)
SEARCH_SUFFIXES = tuple(s for s in FILE_SUFFIXES if not s.startswith((".usd", ".gl", ".txt")))
MANIFEST_SUFFIXES = (".csv", ".json")

#: manifest column -> ConvertOptions field, with the value's type
MANIFEST_FIELDS = {
    "root": ("root", str),
    "root_index": ("root_index", int),
    "up": ("up", str),
    "height": ("height_m", float),
    "labels": ("labels", Path),
    "edits": ("edits", Path),
    "up_axis": ("up_axis", str),
    "meters_per_unit": ("meters_per_unit", float),
}

_INRIA_ITER = re.compile(r"^iteration_(\d+)$")


@dataclass
class Capture:
    """One capture to convert.

    path : the capture file (absolute); name : its output folder's name (unique in the batch)
    overrides : ConvertOptions field overrides from a manifest row (paths absolute)
    source : where it came from (the folder, manifest or file given on the command line)
    renamed_from : the name before clash resolution, "" when not renamed
    """

    path: Path
    name: str
    overrides: dict = field(default_factory=dict)
    source: str = ""
    renamed_from: str = ""


def capture_name(path: Path) -> str:
    """The output name of a capture file (see the module doc), before clash resolution."""
    path = Path(path)
    parts = path.parts
    if path.name.lower() == "point_cloud.ply":
        parent = path.parent
        if _INRIA_ITER.match(parent.name) and parent.parent.name == "point_cloud" and len(parts) >= 4:
            return sanitize_name(parent.parent.parent.name)
        if len(parts) >= 2 and parent.name:
            return sanitize_name(parent.name)
    stem = path.name
    for suf in (path.suffix, ".compressed"):
        if suf and stem.lower().endswith(suf.lower()):
            stem = stem[: -len(suf)]
    return sanitize_name(stem)


def _abs(p) -> Path:
    """Absolute, normalised, symlinks kept (a link's name is the capture's name)."""
    return Path(os.path.abspath(p))


def sanitize_name(name: str) -> str:
    """A folder-safe name: letters, digits, ``.-_``; never empty, never starting with a dot."""
    s = re.sub(r"[^A-Za-z0-9._-]", "_", str(name)).lstrip(".")
    return s or "capture"


def _inria_latest(files: list[Path]) -> list[Path]:
    """Of several ``<scene>/point_cloud/iteration_N/point_cloud.ply`` keep the highest N per scene."""
    best: dict[Path, tuple[int, Path]] = {}
    rest = []
    for f in files:
        m = _INRIA_ITER.match(f.parent.name)
        if f.name.lower() == "point_cloud.ply" and m and f.parent.parent.name == "point_cloud":
            scene = f.parent.parent.parent
            n = int(m.group(1))
            if scene not in best or n > best[scene][0]:
                best[scene] = (n, f)
        else:
            rest.append(f)
    return sorted(rest + [f for _, f in best.values()])


def search_folder(folder: Path, exclude: Path | None = None) -> list[Path]:
    """Capture files under ``folder`` (recursive, sorted; hidden folders and ``exclude`` skipped)."""
    folder = Path(folder)
    out = []
    ex = exclude.resolve() if exclude is not None else None
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder)
        if any(part.startswith(".") for part in rel.parts):
            continue
        if ex is not None and (p.resolve() == ex or ex in p.resolve().parents):
            continue
        if p.is_file() and p.suffix.lower() in SEARCH_SUFFIXES:
            out.append(_abs(p))
    return _inria_latest(out)


def read_manifest(path: Path) -> list[Capture]:
    """Captures of a .csv / .json manifest (see the module doc). Raises InputFileError."""
    path = Path(path)
    try:
        if path.suffix.lower() == ".csv":
            with open(path, newline="", encoding="utf-8-sig") as f:
                rows = [dict(r) for r in csv.DictReader(f)]
        else:
            data = json.loads(path.read_text(encoding="utf-8"))
            rows = data.get("captures") if isinstance(data, dict) else data
            if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
                raise InputFileError(path, 'expected a list of objects or {"captures": [...]}')
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, csv.Error) as e:
        raise InputFileError(path, f"not a readable manifest ({type(e).__name__}: {e})") from None
    base = _abs(path.parent)
    out = []
    for i, row in enumerate(rows, start=1):
        where = f"row {i}"
        row = {str(k).strip(): v for k, v in row.items() if k is not None}
        row = {k: v for k, v in row.items() if v is not None and str(v).strip() != ""}
        unknown = set(row) - set(MANIFEST_FIELDS) - {"input", "name"}
        if unknown:
            raise InputFileError(path, f"{where}: unknown column(s) {sorted(unknown)}; known: "
                                       f"input, name, {', '.join(MANIFEST_FIELDS)}")
        if "input" not in row:
            raise InputFileError(path, f"{where}: no 'input'")
        inp = Path(str(row["input"]).strip())
        inp = _abs(base / inp)
        if not inp.is_file():
            raise InputFileError(path, f"{where}: input {inp} is not a file")
        ov = {}
        for key, (fname, typ) in MANIFEST_FIELDS.items():
            if key not in row:
                continue
            v = row[key]
            try:
                if typ is Path:
                    q = Path(str(v).strip())
                    q = _abs(base / q)
                    if not q.is_file():
                        raise ValueError(f"{q} is not a file")
                    ov[fname] = str(q)
                elif typ is int:
                    if isinstance(v, bool) or (isinstance(v, float) and not v.is_integer()):
                        raise ValueError(v)
                    ov[fname] = int(v)
                elif typ is float:
                    ov[fname] = float(v)
                    if not ov[fname] > 0 or ov[fname] == float("inf"):
                        raise ValueError(v)
                elif isinstance(v, (list, tuple)):       # JSON: "root": [x, y, z]
                    ov[fname] = ",".join(repr(float(c)) for c in v)
                else:
                    ov[fname] = str(v).strip()
            except (TypeError, ValueError) as e:
                raise InputFileError(path, f"{where}: bad {key} {v!r} ({e})") from None
        if "up_axis" in ov:
            ov["up_axis"] = ov["up_axis"].upper()
            if ov["up_axis"] not in ("Y", "Z"):
                raise InputFileError(path, f"{where}: up_axis must be Y or Z, got {row['up_axis']!r}")
        name = sanitize_name(str(row["name"]).strip()) if "name" in row else capture_name(inp)
        out.append(Capture(inp, name, ov, source=str(path)))
    return out


def collect_captures(inputs: list, exclude: Path | None = None) -> list[Capture]:
    """Captures of the command line's inputs (files, folders, manifests), names made unique.

    exclude : a folder a search never enters (the batch's output folder).
    Raises UserError for a missing input, an unsupported file or when nothing is found.
    """
    found: list[Capture] = []
    for item in inputs:
        p = Path(item)
        if p.is_dir():
            files = search_folder(p, exclude)
            if not files:
                raise UserError(f"{p}: no captures found (searched for {', '.join(SEARCH_SUFFIXES)})")
            found += [Capture(f, capture_name(f), source=str(p)) for f in files]
        elif p.is_file():
            suf = p.suffix.lower()
            if suf in MANIFEST_SUFFIXES:
                found += read_manifest(p)
            elif suf in FILE_SUFFIXES:
                found.append(Capture(_abs(p), capture_name(_abs(p)), source=str(p)))
            else:
                raise InputFileError(p, f"not a capture ({', '.join(FILE_SUFFIXES)}) nor a manifest "
                                        f"({', '.join(MANIFEST_SUFFIXES)})")
        else:
            raise InputFileError(p, "no such file or folder")
    # the same file twice (e.g. a folder and a file in it): keep the first, unless a manifest
    # row gives it other options
    seen, unique = set(), []
    for c in found:
        key = (c.path.resolve(), json.dumps(c.overrides, sort_keys=True))
        if key not in seen:
            seen.add(key)
            unique.append(c)
    return resolve_clashes(unique)


def resolve_clashes(captures: list[Capture]) -> list[Capture]:
    """Unique names: the first (by input path) keeps its name, the others get -2, -3, ..."""
    order = sorted(range(len(captures)), key=lambda i: (str(captures[i].path), i))
    taken = {c.name.lower() for c in captures}
    used: set[str] = set()
    for i in order:
        c = captures[i]
        if c.name.lower() in used:
            k = 2
            while f"{c.name}-{k}".lower() in used or f"{c.name}-{k}".lower() in taken:
                k += 1
            c.renamed_from, c.name = c.name, f"{c.name}-{k}"
        used.add(c.name.lower())
    return captures
