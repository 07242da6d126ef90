"""The codeless LeafFitMLSDeformerAPI schema is registered on import and usable."""
import json
import os
import subprocess
import sys

import leaffit_usd  # noqa: F401
from leaffit_usd.usd import schema as S


def test_registry_knows_api_and_fallbacks():
    from pxr import Usd, UsdGeom

    assert S.is_known()
    defn = Usd.SchemaRegistry().FindAppliedAPIPrimDefinition(S.API_NAME)
    assert defn is not None
    assert S.ATTR_SIGMA in defn.GetPropertyNames()
    stage = Usd.Stage.CreateInMemory()
    prim = UsdGeom.PointInstancer.Define(stage, "/I").GetPrim()
    assert not prim.HasAPI(S.API_NAME)
    assert prim.ApplyAPI(S.API_NAME)
    assert prim.HasAPI(S.API_NAME)
    # fallbacks visible through the composed prim definition
    assert abs(prim.GetAttribute(S.ATTR_SIGMA).Get() - 0.1) < 1e-7
    assert prim.GetAttribute(S.ATTR_VARIANT).Get() == "affine"
    assert prim.GetAttribute(S.ATTR_K).Get() == 32
    assert prim.GetAttribute(S.ATTR_TARGETS_PRIMVAR).Get() == S.TARGETS_PRIMVAR


def test_plug_info_has_no_placeholders():
    text = (S.SCHEMA_DIR / "plugInfo.json").read_text()
    assert "@PLUG_INFO" not in text
    data = json.loads("".join(l for l in text.splitlines(True) if not l.startswith("#")))
    plug = data["Plugins"][0]
    assert plug["Root"] == "." and plug["ResourcePath"] == "." and "LibraryPath" not in plug
    assert S.API_NAME in plug["Info"]["Types"]


def test_registration_after_registry_use_is_what_import_prevents():
    """Registering after the schema registry was used fails silently: import order matters."""
    code = (
        "from pxr import Usd, UsdGeom\n"
        "Usd.SchemaRegistry()  # first use of the registry\n"
        "import leaffit_usd.usd.schema as S\n"
        "print(S.is_known())\n"
    )
    # a clean environment: this process imported leaffit_usd, which named the plug-in in
    # PXR_PLUGINPATH_NAME, and a child would inherit it
    env = {k: v for k, v in os.environ.items() if k != "PXR_PLUGINPATH_NAME"}
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    # documents the USD pitfall (why leaffit_usd registers at import time)
    assert out.stdout.strip() == "False"
    code_ok = "import leaffit_usd\nimport leaffit_usd.usd.schema as S\nprint(S.is_known())\n"
    out = subprocess.run([sys.executable, "-c", code_ok], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.strip() == "True"


def test_import_names_the_plugin_without_loading_usd():
    """Without pxr loaded, ``import leaffit_usd`` does not import it (start-up of commands that
    never touch USD) and USD still finds the schema when it starts later; with pxr loaded first
    (its registry not yet used), the import registers through USD's API."""
    env = {k: v for k, v in os.environ.items() if k != "PXR_PLUGINPATH_NAME"}
    code = ("import sys, leaffit_usd\n"
            "print('pxr' in sys.modules)\n"
            "import leaffit_usd.usd.schema as S\n"
            "print(S.is_known())\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.split() == ["False", "True"]
    code = "import pxr.Plug\nimport leaffit_usd, leaffit_usd.usd.schema as S\nprint(S.is_known())\n"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, env=env)
    assert out.stdout.strip() == "True"
