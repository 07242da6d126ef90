"""The Khronos glTF validator (npm ``gltf-validator``, run with node) as a Python call.

``make setup`` installs it into ``build/gltf-validator`` (``npm install --prefix``); elsewhere
point ``LEAFFIT_GLTF_VALIDATOR`` at a ``node_modules`` folder holding ``gltf-validator``.
"""
from __future__ import annotations

import json
import os
import shutil
import subprocess
from dataclasses import dataclass, field
from pathlib import Path

SCRIPT = Path(__file__).with_name("validate_gltf.cjs")
REPO_MODULES = Path(__file__).resolve().parents[2] / "build" / "gltf-validator" / "node_modules"


def find_validator() -> tuple[str, Path] | None:
    """(node executable, node_modules folder holding gltf-validator), or None if either is missing."""
    node = shutil.which("node")
    if node is None:
        return None
    for d in (os.environ.get("LEAFFIT_GLTF_VALIDATOR"), REPO_MODULES):
        if d and (Path(d) / "gltf-validator" / "package.json").is_file():
            return node, Path(d)
    return None


@dataclass
class GltfValidation:
    """The validator's verdict. errors/warnings/infos/hints : counts; messages : the issues
    (dicts with code, message, severity 0 error .. 3 hint, pointer); report : the whole JSON."""

    errors: int
    warnings: int
    infos: int
    hints: int
    messages: list = field(default_factory=list)
    report: dict = field(default_factory=dict)

    def codes(self, severity: int) -> list[str]:
        return sorted({m["code"] for m in self.messages if m.get("severity") == severity})


def validate_gltf(path, timeout: float = 120.0) -> GltfValidation:
    """Run the Khronos validator on ``path`` (.glb/.gltf). Raises RuntimeError when it is not
    installed or fails to run."""
    found = find_validator()
    if found is None:
        raise RuntimeError("the Khronos glTF validator is not installed (node + npm gltf-validator; "
                           "run 'make setup')")
    node, modules = found
    env = {**os.environ, "NODE_PATH": str(modules)}
    r = subprocess.run([node, str(SCRIPT), str(path)], capture_output=True, text=True,
                       timeout=timeout, env=env)
    if r.returncode != 0:
        raise RuntimeError(f"gltf-validator failed on {path}: {r.stderr.strip()[:500]}")
    rep = json.loads(r.stdout)
    iss = rep.get("issues", {})
    return GltfValidation(errors=int(iss.get("numErrors", 0)), warnings=int(iss.get("numWarnings", 0)),
                          infos=int(iss.get("numInfos", 0)), hints=int(iss.get("numHints", 0)),
                          messages=list(iss.get("messages", [])), report=rep)
