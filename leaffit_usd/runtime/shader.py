"""The GLSL deformer snippet shipped in ``leaffit_usd/runtime/glsl/``, and a headless runner.

Files:
  ``glsl/leaffit_mls.glsl``    the MLS function ``vec3 leaffit_mls(vec3 v, int K, float sigma,
                               float reg, int instance)`` (+ ``leaffit_mls_weighted``), a line-by-line
                               transcription of ``leaffit_usd.fit.mls``; paste or include it.
  ``glsl/leaffit_deform.vert`` a minimal vertex shader applying it and the PointInstancer
                               transform (instance attributes: position, orientation wxyz, scale).

:func:`vertex_shader_source` expands the include; :class:`GLDeformer` runs the shader on any
OpenGL 4.3+ context through moderngl (headless: EGL, e.g. Mesa llvmpipe on the CPU) and reads the
deformed vertices back by transform feedback. moderngl is an optional dependency (test extra),
imported only here and only when a context is created.
"""
from __future__ import annotations

import re
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.fit.params import MAX_K

GLSL_DIR = Path(__file__).with_name("glsl")
SNIPPET = GLSL_DIR / "leaffit_mls.glsl"
VERTEX_SHADER = GLSL_DIR / "leaffit_deform.vert"
VARIANTS = ("controls", "weights")

_INCLUDE = re.compile(r'^\s*//\s*#leaffit_include\s+"([^"]+)"\s*$', re.M)


def snippet_source() -> str:
    """The MLS function snippet (no #version line)."""
    return SNIPPET.read_text()


def vertex_shader_source(variant: str = "controls", max_k: int = MAX_K, wind: bool = False) -> str:
    """The complete vertex shader (GLSL 4.30 core) with the snippet included.

    variant : "controls" (weights computed per vertex from the control points, the default) or
        "weights" (per-vertex (V, K) weights precomputed on the CPU, read from an SSBO)
    max_k : size of the per-vertex weight array (LEAFFIT_MAX_K); K must not exceed it
    wind : with the wind term (``LEAFFIT_WIND``: each leaf turned about its axis, see
        ``leaffit_deform.vert`` and ``usd.wind``)
    """
    if variant not in VARIANTS:
        raise ParameterError("variant", " or ".join(repr(v) for v in VARIANTS), variant)
    defines = f"#define LEAFFIT_MAX_K {int(max_k)}\n"
    if variant == "weights":
        defines += "#define LEAFFIT_USE_WEIGHTS 1\n"
    if wind:
        defines += "#define LEAFFIT_WIND 1\n"
    text = VERTEX_SHADER.read_text()
    return _INCLUDE.sub(lambda m: defines + (GLSL_DIR / m.group(1)).read_text(), text, count=1)


@dataclass
class ValidatorResult:
    """Outcome of a static ``glslangValidator`` check (``available`` False: tool not installed)."""

    available: bool
    ok: bool
    output: str


def validate_static(source: str, stage: str = "vert") -> ValidatorResult:
    """Compile ``source`` with ``glslangValidator -S <stage>`` (Khronos reference front end)."""
    exe = shutil.which("glslangValidator")
    if exe is None:
        return ValidatorResult(False, False, "glslangValidator not found (apt-get install glslang-tools)")
    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / f"leaffit.{stage}"
        path.write_text(source)
        r = subprocess.run([exe, "-S", stage, str(path)], capture_output=True, text=True, timeout=60)
    return ValidatorResult(True, r.returncode == 0, (r.stdout + r.stderr).strip())


def create_headless_context():
    """A standalone OpenGL 4.3+ moderngl context via EGL (no display needed).

    Raises RuntimeError with the reason when moderngl or a suitable GL driver is missing.
    """
    try:
        import moderngl
    except ImportError as e:  # optional dependency
        raise RuntimeError(f"moderngl is not installed ({e})") from e
    try:
        return moderngl.create_standalone_context(backend="egl", require=430)
    except Exception as e:  # noqa: BLE001 - any driver failure means "no context"
        raise RuntimeError(f"no headless OpenGL 4.3 context via EGL: {type(e).__name__}: {e}") from e


class GLDeformer:
    """Runs ``leaffit_deform.vert`` on a moderngl context and captures the deformed vertices.

    ctx : a moderngl context (OpenGL >= 4.3); None creates a headless EGL one.
    variant : "controls" or "weights" (see :func:`vertex_shader_source`).
    wind : build the wind term in (:meth:`deform` then takes a ``usd.wind.WindParams``).
    """

    def __init__(self, ctx=None, variant: str = "controls", wind: bool = False):
        import moderngl

        self.ctx = ctx if ctx is not None else create_headless_context()
        self.variant = variant
        self.wind = bool(wind)
        self.program = self.ctx.program(vertex_shader=vertex_shader_source(variant, wind=self.wind),
                                        varyings=["out_position"])
        # EGL contexts have no default framebuffer: without one bound the draw (even with
        # rasterizer discard) silently produces zeros on Mesa.
        self._fbo = self.ctx.simple_framebuffer((1, 1))
        self._moderngl = moderngl

    def _wind_buffer(self, asset, wind):
        """The wind SSBO (binding 3: per instance (pivot, phase), (axis, 0), local frame) and the
        wind uniforms of one moment."""
        from leaffit_usd.usd.wind import WindParams, wind_data

        w = wind_data(asset)
        data = np.zeros((asset.n_leaves, 2, 4), np.float32)
        data[:, 0, :3], data[:, 0, 3], data[:, 1, :3] = w.pivots_local, w.phases, w.axes_local
        buf = self.ctx.buffer(np.ascontiguousarray(data).tobytes() or np.zeros(8, np.float32).tobytes())
        buf.bind_to_storage_buffer(3)
        m = wind if wind is not None else WindParams(strength=0.0)
        for name, value in (("leaffit_wind_time", m.time), ("leaffit_wind_strength", m.strength),
                            ("leaffit_wind_frequency", m.frequency)):
            if name in self.program:
                self.program[name].value = float(value)
        return buf

    def release(self) -> None:
        self._fbo.release()
        self.program.release()

    def deform(self, asset, model: np.ndarray | None = None, wind=None) -> np.ndarray:
        """Deformed vertices of every instance of ``asset`` (PlantAsset).

        model : (4, 4) asset -> output frame (None: identity, i.e. the asset frame; pass
            ``asset.asset_to_input`` for the input frame); wind : a ``usd.wind.WindParams``
            moment (needs ``wind=True`` at construction; None: at rest). Returns (L, V, 3) float32.
        """
        from leaffit_usd.fit.mls import mls_weights

        ctx, prog = self.ctx, self.program
        L, K = asset.targets.shape[:2]
        pts = np.ascontiguousarray(asset.template_points, np.float32)
        V = len(pts)
        if K > MAX_K:
            raise ParameterError("K", f"at most {MAX_K} control points for the GLSL snippet", K)
        if L == 0 or V == 0:
            return np.zeros((L, V, 3), np.float32)

        def vec4s(a):
            a = np.asarray(a, np.float32).reshape(-1, 3)
            return np.ascontiguousarray(np.column_stack([a, np.zeros(len(a), np.float32)]))

        bufs = [ctx.buffer(vec4s(asset.template_controls).tobytes()),
                ctx.buffer(vec4s(asset.targets).tobytes())]
        bufs[0].bind_to_storage_buffer(0)
        bufs[1].bind_to_storage_buffer(1)
        if self.variant == "weights":
            A = mls_weights(asset.template_controls, asset.template_points, asset.sigma, asset.reg)
            bufs.append(ctx.buffer(np.ascontiguousarray(A, np.float32).tobytes()))
            bufs[2].bind_to_storage_buffer(2)
        vbo = ctx.buffer(pts.tobytes())
        inst = np.column_stack([np.asarray(asset.positions, np.float32),
                                np.asarray(asset.orientations, np.float32),
                                np.asarray(asset.scales, np.float32)]).astype(np.float32)
        ibo = ctx.buffer(np.ascontiguousarray(inst).tobytes())
        out = ctx.buffer(reserve=L * V * 3 * 4)
        bufs += [vbo, ibo, out]
        if self.wind:
            bufs.append(self._wind_buffer(asset, wind))

        for name, value in (("leaffit_K", int(K)), ("leaffit_sigma", float(asset.sigma)),
                            ("leaffit_reg", float(asset.reg))):
            if name in prog:
                prog[name].value = value
        m = np.eye(4) if model is None else np.asarray(model, np.float64)
        prog["u_model"].write(np.ascontiguousarray(m.T, np.float32).tobytes())  # column-major
        if "u_view_projection" in prog:
            prog["u_view_projection"].write(np.eye(4, dtype=np.float32).tobytes())

        content = [(ibo, "3f 4f 3f/i", "in_instance_position", "in_instance_orientation",
                    "in_instance_scale")]
        if "in_position" in prog:       # unused (optimised out) in the "weights" variant
            content.insert(0, (vbo, "3f", "in_position"))
        vao = ctx.vertex_array(prog, content)
        try:
            self._fbo.use()
            ctx.error  # clear any earlier error flag
            vao.transform(out, mode=self._moderngl.POINTS, vertices=V, instances=L)
            ctx.finish()
            err = ctx.error
            if err != "GL_NO_ERROR":
                raise RuntimeError(f"OpenGL error after the deformer draw: {err}")
            result = np.frombuffer(out.read(), np.float32).reshape(L, V, 3).copy()
        finally:
            vao.release()
            for b in bufs:
                b.release()
        return result
