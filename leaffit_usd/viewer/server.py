"""The local web server behind ``leaffit-usd edit``: one plant, one editing session, loopback only.

Security model (the server edits files on the user's disk, so it trusts nothing from the page):

* bound to 127.0.0.1 on a free port; requests from any other address are refused (403);
* a random token (``secrets.token_urlsafe``) is the first path segment of every URL
  (``http://127.0.0.1:PORT/<token>/``); relative URLs in the page keep it, so scripts, data and
  API calls all carry it; anything else gets 403. A Host header that is not a loopback name is
  refused too (DNS rebinding);
* request bodies are bounded (``MAX_BODY`` bytes, 413 beyond);
* no file path is ever read from a request: Save writes the two output paths fixed when the
  server was started (next to the input, or given on the command line);
* a strict Content-Security-Policy (no inline script, same-origin only) on every response.

API (all under ``/<token>/``; JSON unless said otherwise):

* ``GET  ``                 the page; ``GET static/<file>`` its scripts and styles
* ``GET  api/meta``         counts, plant height, up axis, output file names, defaults
* ``GET  api/points``       binary: float32 (N, 3) positions (display frame, see below) then
                            uint8 (N, 3) RGB colours
* ``GET  api/state``        labels (base64 int32 LE), selection (base64 packbits), leaves (each with
                            its ``confidence`` and ``doubtful`` flag), ``least_confident``, undo/redo
* ``GET  api/splats``       binary: the Gaussians to draw as splats (:meth:`ViewerSession.splats_bytes`)
* ``POST api/leaf``         ``{label}`` -> the fitted leaf of that instance (display frame, see
                            :meth:`ViewerSession.leaf_preview`)
* ``POST api/pick``         ``{origin: [3], direction: [3]}`` (display frame) -> ``{index, t}``
* ``POST api/preview``      ``{op}`` -> selection the op would give (not recorded)
* ``POST api/op``           ``{op}`` -> apply and record; returns the state
* ``POST api/undo|redo``    -> state;  ``POST api/save`` -> written file names
* ``POST api/stop``         stop the server (the page's Quit button)

While the session is starting (:meth:`ViewerSession.starting`: the segmentation and geodesics
are built after the server is up, so a large capture is drawn at once), ``api/state`` answers
``{ready: false, phase}`` and every POST but ``stop`` answers 503.

Confidence: the segmentation the session starts from may give a confidence per leaf (the
automatic one does; a labels file may carry a ``confidence`` array). A leaf of the current labels
keeps the confidence of the starting leaf with its number while more than half of its Gaussians
still come from that leaf (edits may grow or trim it); leaves made by edits, and leaves mostly
made of another leaf's Gaussians, have none (null). A leaf is ``doubtful`` below
:data:`leaffit_usd.segment.result.DOUBTFUL_CONFIDENCE`; ``least_confident`` is the leaf with the
lowest known confidence when that is below 1 (else null); the page opens on it.

Display frame: ``(x_input - centre) / height`` — the input frame translated and scaled so the
page works with numbers near 1 (float32-friendly); the server maps rays back exactly.
"""
from __future__ import annotations

import base64
import hmac
import ipaddress
import json
import logging
import secrets
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from leaffit_usd.errors import UserError
from leaffit_usd.segment.result import DOUBTFUL_CONFIDENCE

log = logging.getLogger("leaffit_usd")

MAX_BODY = 256 * 1024  # bytes; the largest legitimate request is a long brush stroke (~10k centres)
STATIC_DIR = Path(__file__).with_name("static")
CSP = ("default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; "
       "connect-src 'self'; base-uri 'none'; form-action 'none'; frame-ancestors 'none'")
LOOPBACK_HOSTS = {"127.0.0.1", "localhost", "::1", "[::1]"}


def is_loopback(addr: str | None) -> bool:
    """True for 127.0.0.0/8 and ::1 (IPv4-mapped too)."""
    if not addr:
        return False
    try:
        ip = ipaddress.ip_address(addr.split("%")[0])
    except ValueError:
        return False
    if isinstance(ip, ipaddress.IPv6Address) and ip.ipv4_mapped is not None:
        ip = ip.ipv4_mapped
    return ip.is_loopback


@dataclass
class ViewerSession:
    """Everything the server serves and edits: one cloud, its segmenter, its BVH, output paths.

    cloud : GaussianCloud, input frame (as loaded)
    height : plant height, input units (the display frame's unit)
    segmenter : ManualSegmenter on ``cloud.means`` (cloud order), or None while starting
    bvh : GaussianBVH on the cloud (input frame), or None while starting
    edits_template : Edits with the input hash, height, samples and base labels filled in (None
        while starting)
    edits_out, labels_out : where Save writes (fixed at start; never from a request)
    root_index : root Gaussian (cloud order) to carry into the labels file, or None
    up : (3,) unit up axis, input frame (for the camera)
    confidence : (L0,) float64 in [0, 1] or None, confidence of each STARTING leaf (label l+1 of
        the labels the session started from at index l); see :func:`carried_confidence`
    frame : the plant's input <-> working ``Frame`` (the leaf preview fits in the working frame;
        None: ``splats.frame.make_frame`` on the cloud when a preview is first asked for)
    phase : "ready", or what is being prepared (the page shows the capture meanwhile; every
        editing route answers 503 until ready); failed : why starting failed, or None

    A session is built at once by :func:`build_session`, or in the background: the server starts
    on :meth:`starting` (the capture is drawn at once) and :meth:`attach` hands it the built one.
    """

    cloud: object
    height: float
    edits_out: Path
    labels_out: Path
    segmenter: object = None
    bvh: object = None
    edits_template: object = None
    root_index: int | None = None
    up: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    input_name: str = ""
    saved_ops: list = field(default_factory=list)  # operations at the last save (for "dirty")
    confidence: np.ndarray | None = None
    frame: object = None
    phase: str = "ready"
    failed: str | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)

    def __post_init__(self):
        m = np.asarray(self.cloud.means, np.float64)
        self.centre = (m.min(0) + m.max(0)) / 2 if len(m) else np.zeros(3)
        self.height = float(self.height)
        self._splats = None
        self._previewer = None
        self._preview_lock = threading.Lock()

    @classmethod
    def starting(cls, cloud, height: float, edits_out, labels_out, up=None, input_name: str = "",
                 frame=None, phase: str = "starting") -> "ViewerSession":
        """A session that serves ``cloud`` (drawn at once) while the rest is built elsewhere."""
        return cls(cloud=cloud, height=height, edits_out=Path(edits_out), labels_out=Path(labels_out),
                   up=np.asarray([0.0, 0.0, 1.0] if up is None else up, np.float64),
                   input_name=input_name, frame=frame, phase=phase)

    @property
    def ready(self) -> bool:
        return self.phase == "ready" and self.segmenter is not None

    def attach(self, built: "ViewerSession") -> None:
        """Take the segmenter, BVH and the rest from ``built`` (same cloud and height); ready."""
        if built.cloud is not self.cloud or built.height != self.height:
            raise ValueError("attach: the built session is of another cloud or height")
        with self.lock:
            for name in ("segmenter", "bvh", "edits_template", "root_index", "confidence", "saved_ops"):
                setattr(self, name, getattr(built, name))
            self.phase = "ready"

    # ---- payloads --------------------------------------------------------------------------
    def meta(self) -> dict:
        from leaffit_usd.segment.manual import OPERATIONS

        return {
            "n": len(self.cloud), "input": self.input_name, "height": self.height,
            "up": [float(v) for v in self.up], "edits_out": self.edits_out.name,
            "labels_out": self.labels_out.name, "brush_radius": 0.05,
            "operations": list(OPERATIONS),
            "samples": int(len(self.segmenter.geodesics.samples)) if self.segmenter else None,
            "doubtful_below": DOUBTFUL_CONFIDENCE, "ready": self.ready, "phase": self.phase,
        }

    def splats_bytes(self) -> bytes:
        """The splats for the page, 30 bytes a Gaussian (little-endian, cloud order, N = len(cloud)):

        positions (N, 3) float32, display frame | scales (N, 3) float16, display units (standard
        deviations along the Gaussian's axes) | rotations (N, 4) int16, unit quaternion (w, x, y, z)
        x 32767, rounded | colours (N, 4) uint8: RGB (the DC colour) and opacity x 255, rounded.
        Float16 scales are within 0.05% of the float32 values and int16 quaternions within 0.01
        degrees of the rotation; colours are 8 bits as the page draws them. The projected
        ellipses stay within 0.2% of float64 ones (``tests/viewer/test_splats.py``; int8
        quaternions, as some splat formats use, were 12% off on needle-like Gaussians).
        Computed once.
        """
        if self._splats is None:
            c = self.cloud
            pos = ((np.asarray(c.means, np.float64) - self.centre) / self.height).astype("<f4")
            scales = (np.asarray(c.scales, np.float64) / self.height).astype("<f2")
            rot = np.clip(np.round(np.asarray(c.rotations, np.float64) * 32767), -32767, 32767).astype("<i2")
            rgba = np.round(np.c_[c.colors, c.opacities] * 255).astype(np.uint8)
            self._splats = pos.tobytes() + scales.tobytes() + rot.tobytes() + rgba.tobytes()
        return self._splats

    def leaf_preview(self, label: int) -> dict:
        """The fitted leaf of instance ``label`` (current labels), display frame, as JSON-ready
        data: ``{label, vertices (base64 float32 (V, 3)), faces (base64 uint32 (F, 3)), edges
        (base64 uint32 (E, 2)), fallback, error, ms}``; ``{label, none: why}`` when there is no
        fit to show. See :mod:`leaffit_usd.viewer.leaf_preview` (the fast path used)."""
        with self.lock:
            members = np.flatnonzero(self.segmenter.labels == int(label))
        t0 = time.perf_counter()
        if self._previewer is None:
            self.warm_preview()
        with self._preview_lock:   # one fit at a time; edits go on meanwhile
            try:
                m = self._previewer.preview(int(label), members)
            except LookupError as e:
                return {"label": int(label), "none": str(e)}
        b64 = lambda a: base64.b64encode(np.ascontiguousarray(a).tobytes()).decode()  # noqa: E731
        return {"label": m.label, "vertices": b64(m.vertices.astype("<f4")),
                "faces": b64(m.faces.astype("<u4")), "edges": b64(m.edges.astype("<u4")),
                "fallback": m.fallback, "error": m.error, "ms": (time.perf_counter() - t0) * 1e3}

    def warm_preview(self) -> None:
        """Choose the preview's template now (the first preview then costs one fit only); a
        plant with no leaf has none (nothing to do)."""
        with self._preview_lock:
            if self._previewer is None:
                from leaffit_usd.viewer.leaf_preview import LeafPreviewer

                self._previewer = LeafPreviewer(self._working(), self.segmenter.initial.labels,
                                                self._working_to_display())
            try:
                self._previewer.choose_template()
            except LookupError:
                pass

    def _working(self):
        """The session's cloud in the working frame (same order)."""
        from leaffit_usd.splats.transform import transform_cloud

        if self.frame is None:
            from leaffit_usd.splats.frame import make_frame

            self.frame = make_frame(self.cloud, up=self.up).frame
        return transform_cloud(self.cloud, self.frame.input_to_working)

    def _working_to_display(self) -> np.ndarray:
        """(4, 4) float64, working frame -> display frame."""
        d = np.eye(4)
        d[:3, :3] /= self.height
        d[:3, 3] = -self.centre / self.height
        return d @ self.frame.working_to_input

    def points_bytes(self) -> bytes:
        pos = ((np.asarray(self.cloud.means, np.float64) - self.centre) / self.height).astype("<f4")
        rgb = np.round(self.cloud.colors * 255).astype(np.uint8)
        return pos.tobytes() + rgb.tobytes()

    def leaves(self) -> tuple[list[dict], int]:
        """(rows, stem count) of the current labels: one row per leaf present, by label:
        ``{label, count, confidence (float or None), doubtful (bool)}``."""
        seg = self.segmenter
        labels = seg.labels
        counts = np.bincount(labels, minlength=1)
        conf = carried_confidence(seg.initial.labels, labels, self.confidence)
        rows = []
        for k in np.flatnonzero(counts).tolist():
            if k == 0:
                continue
            c = conf.get(k)
            rows.append({"label": int(k), "count": int(counts[k]),
                         "confidence": None if c is None else round(float(c), 4),
                         "doubtful": c is not None and c < DOUBTFUL_CONFIDENCE})
        return rows, int(counts[0])

    def state(self) -> dict:
        """The editing state (see the module docstring); ``{ready: False, phase, failed}`` while
        the session is still starting."""
        if not self.ready:
            return {"ready": False, "phase": self.phase, "failed": self.failed}
        seg = self.segmenter
        labels = seg.labels
        leaves, stem = self.leaves()
        return {
            "labels": base64.b64encode(labels.astype("<i4").tobytes()).decode(),
            "selection": _pack(seg.selection), "selected": int(seg.selection.sum()),
            "leaves": leaves, "stem": stem, "least_confident": least_confident(leaves),
            "can_undo": seg.can_undo, "can_redo": seg.can_redo, "n_ops": len(seg.operations),
            "dirty": seg.operations != self.saved_ops, "ready": True,
        }

    # ---- actions ---------------------------------------------------------------------------
    def pick(self, origin, direction) -> dict:
        o = np.asarray(origin, np.float64) * self.height + self.centre
        d = np.asarray(direction, np.float64)
        r = self.bvh.pick(o, d)
        return {"index": r.index, "t": (r.t / self.height) if r.hit else None}

    def save(self) -> dict:
        from leaffit_usd.segment.edits import Edits, save_edits, to_file_operations
        from leaffit_usd.segment.labels_file import write_labels_file

        seg = self.segmenter
        t = self.edits_template
        edits = Edits(input_sha256=t.input_sha256, n_gaussians=t.n_gaussians, height=t.height,
                      n_samples=t.n_samples, operations=to_file_operations(seg.operations, self.cloud),
                      base_labels_sha256=t.base_labels_sha256, base_leaves=t.base_leaves,
                      input_name=t.input_name, normals=t.normals)
        labels = self.cloud.to_file_order(seg.final_labels().astype(np.int32), fill=0)
        write_labels_file(self.labels_out, labels, root_index=None if self.root_index is None
                          else int(self.cloud.file_index[self.root_index]))
        save_edits(edits, self.edits_out)
        self.saved_ops = list(seg.operations)
        log.info("saved %s (%d operations) and %s (%d leaves)", self.edits_out, len(edits.operations),
                 self.labels_out, int(labels.max(initial=0)))
        return {"edits": self.edits_out.name, "labels": self.labels_out.name,
                "operations": len(edits.operations), "leaves": int(labels.max(initial=0))}


def carried_confidence(initial: np.ndarray, current: np.ndarray, confidence) -> dict[int, float]:
    """{current leaf label: confidence} for the leaves that are still, mostly, a starting leaf.

    initial, current : (N,) int labels (session start, now; 0 = stem); confidence : (L0,) float
    with starting leaf l+1 at index l, or None (then ``{}``). Leaf k keeps ``confidence[k-1]``
    when more than half of its current Gaussians had label k at the start (edits keep a leaf's
    number; new leaves take numbers past the largest present, which may be a deleted leaf's, so
    the number alone does not say it is the same leaf). Other leaves are absent (unknown).
    """
    if confidence is None:
        return {}
    conf = np.asarray(confidence, np.float64)
    initial = np.asarray(initial)
    current = np.asarray(current)
    counts = np.bincount(current, minlength=1)
    same = current == initial
    kept = np.bincount(current[same], minlength=len(counts))
    return {k: float(conf[k - 1]) for k in range(1, min(len(counts), len(conf) + 1))
            if counts[k] > 0 and 2 * kept[k] > counts[k]}


def least_confident(leaves: list[dict]) -> int | None:
    """Label of the row with the lowest known confidence (smallest label on ties), or None when
    no leaf has one below 1 (nothing to point at)."""
    known = [(r["confidence"], r["label"]) for r in leaves if r["confidence"] is not None]
    if not known:
        return None
    c, label = min(known)
    return label if c < 1.0 else None


def _pack(mask: np.ndarray) -> str:
    """(N,) bool -> base64 of np.packbits (bit 7 of byte 0 = Gaussian 0)."""
    return base64.b64encode(np.packbits(mask).tobytes()).decode()


def create_app(session: ViewerSession, token: str, max_body: int = MAX_BODY, on_stop=None):
    """The flask app serving ``session`` under ``/<token>/``. ``on_stop()`` is called by api/stop."""
    from flask import Flask

    app = Flask("leaffit_usd.viewer", static_folder=None)
    app.config["MAX_CONTENT_LENGTH"] = max_body
    app.json.sort_keys = False
    _add_guards(app, token, max_body)
    _add_read_routes(app, session, f"/{token}")
    _add_edit_routes(app, session, f"/{token}", max_body, on_stop)
    return app


def _add_guards(app, token: str, max_body: int) -> None:
    """Loopback clients only, the right Host and token, bounded bodies, strict headers."""
    from flask import abort, jsonify, request

    @app.before_request
    def _guard():
        if not is_loopback(request.remote_addr):
            abort(403, "only local clients may connect")
        host = (request.host or "").rsplit(":", 1)[0] if not (request.host or "").startswith("[") \
            else request.host.split("]")[0] + "]"
        if host not in LOOPBACK_HOSTS:
            abort(403, "bad Host header")
        parts = request.path.split("/", 2)
        if len(parts) < 2 or not hmac.compare_digest(parts[1].encode(), token.encode()):
            abort(403, "missing or wrong token")
        if request.content_length is not None and request.content_length > max_body:
            abort(413)

    @app.after_request
    def _headers(resp):
        resp.headers["Content-Security-Policy"] = CSP
        resp.headers["X-Content-Type-Options"] = "nosniff"
        resp.headers["Referrer-Policy"] = "no-referrer"
        resp.headers["Cache-Control"] = "no-store"
        return resp

    @app.errorhandler(UserError)
    def _user_error(e):
        return jsonify(error=str(e)), 400


def _json_body(max_body: int) -> dict:
    """The request's JSON object (400 otherwise; 413 past ``max_body`` bytes)."""
    from flask import abort, request

    raw = request.get_data(cache=False)  # 413 past MAX_CONTENT_LENGTH when the length is declared
    if len(raw) >= max_body:  # a chunked body is cut at the limit by werkzeug: refuse it too
        abort(413)
    try:
        data = json.loads(raw)
    except ValueError:
        data = None
    if not isinstance(data, dict):
        abort(400, "expected a JSON object")
    return data


def _op_of(data: dict) -> dict:
    from flask import abort

    op = data.get("op")
    if not isinstance(op, dict):
        abort(400, "expected {\"op\": {...}}")
    return op


def _add_read_routes(app, session: ViewerSession, base: str) -> None:
    """The page, its static files, and the session's meta / points / state."""
    from flask import Response, abort, jsonify, send_from_directory

    @app.get(base + "/")
    def index():
        return send_from_directory(STATIC_DIR, "index.html")

    @app.get(base + "/static/<path:name>")
    def static_file(name):
        if name not in STATIC_FILES:
            abort(404)
        return send_from_directory(STATIC_DIR, name, mimetype=STATIC_FILES[name])

    @app.get(base + "/api/meta")
    def meta():
        return jsonify(session.meta())

    @app.get(base + "/api/points")
    def points():
        return Response(session.points_bytes(), mimetype="application/octet-stream")

    @app.get(base + "/api/splats")
    def splats():
        return Response(session.splats_bytes(), mimetype="application/octet-stream")

    @app.get(base + "/api/state")
    def state():
        with session.lock:
            return jsonify(session.state())


def _add_edit_routes(app, session: ViewerSession, base: str, max_body: int, on_stop) -> None:
    """Picking, previews, operations, undo / redo, save, stop (503 until the session is ready)."""
    from flask import abort, jsonify, request

    @app.before_request
    def _ready():
        if request.method == "POST" and not request.path.endswith("/api/stop") and not session.ready:
            return jsonify(error=session.failed or f"still starting: {session.phase}"), 503
        return None

    @app.post(base + "/api/leaf")
    def leaf():
        data = _json_body(max_body)
        label = data.get("label")
        if isinstance(label, bool) or not isinstance(label, int) or label < 1:
            abort(400, "expected {label: a leaf label >= 1}")
        return jsonify(session.leaf_preview(label))

    @app.post(base + "/api/pick")
    def pick():
        data = _json_body(max_body)
        try:
            o = np.asarray(data["origin"], np.float64).reshape(3)
            d = np.asarray(data["direction"], np.float64).reshape(3)
        except (KeyError, TypeError, ValueError):
            abort(400, "expected {origin: [x, y, z], direction: [x, y, z]}")
        t0 = time.perf_counter()
        with session.lock:
            out = session.pick(o, d)
        out["ms"] = (time.perf_counter() - t0) * 1e3
        return jsonify(out)

    @app.post(base + "/api/preview")
    def preview():
        op = _op_of(_json_body(max_body))
        t0 = time.perf_counter()
        with session.lock:
            sel = session.segmenter.preview(op)
        return jsonify(selection=_pack(sel), selected=int(sel.sum()), ms=(time.perf_counter() - t0) * 1e3)

    @app.post(base + "/api/op")
    def apply_op():
        op = _op_of(_json_body(max_body))
        t0 = time.perf_counter()
        with session.lock:
            session.segmenter.apply(op, op_no=len(session.segmenter.operations))
            out = session.state()
        out["ms"] = (time.perf_counter() - t0) * 1e3
        return jsonify(out)

    @app.post(base + "/api/undo")
    def undo():
        with session.lock:
            session.segmenter.undo()
            return jsonify(session.state())

    @app.post(base + "/api/redo")
    def redo():
        with session.lock:
            session.segmenter.redo()
            return jsonify(session.state())

    @app.post(base + "/api/save")
    def save():
        with session.lock:
            out = session.save()
            out["state"] = session.state()
        return jsonify(out)

    @app.post(base + "/api/stop")
    def stop():
        if on_stop is not None:
            threading.Thread(target=on_stop, daemon=True).start()
        return jsonify(stopping=True)


STATIC_FILES = {
    "index.html": "text/html",
    "app.js": "text/javascript",
    "style.css": "text/css",
    "three.bundle.min.js": "text/javascript",
    "splats.js": "text/javascript",
    "sort-worker.js": "text/javascript",
}


class ViewerServer:
    """Serve a :class:`ViewerSession` on 127.0.0.1 (port 0 = a free port) in the calling thread.

    ``url`` is ready after construction; :meth:`serve_forever` blocks until :meth:`stop` (or
    Ctrl-C, which the caller catches). :meth:`start_background` runs it in a daemon thread (tests).
    """

    def __init__(self, session: ViewerSession, port: int = 0, token: str | None = None,
                 max_body: int = MAX_BODY):
        from werkzeug.serving import WSGIRequestHandler, make_server

        class _Quiet(WSGIRequestHandler):  # no per-request log lines (they would print the token)
            def log_request(self, *args, **kwargs):
                pass

        self.token = token or secrets.token_urlsafe(24)
        self.app = create_app(session, self.token, max_body=max_body, on_stop=self.stop)
        self._server = make_server("127.0.0.1", int(port), self.app, threaded=True,
                                   request_handler=_Quiet)
        self.port = self._server.server_port
        self.url = f"http://127.0.0.1:{self.port}/{self.token}/"
        self._thread = None

    def serve_forever(self) -> None:
        try:
            self._server.serve_forever(poll_interval=0.2)
        finally:
            self._server.server_close()

    def start_background(self) -> "ViewerServer":
        self._thread = threading.Thread(target=self.serve_forever, daemon=True)
        self._thread.start()
        return self

    def stop_soon(self) -> None:
        """Stop from any thread without waiting (``stop`` from a request would wait for itself)."""
        threading.Thread(target=self._server.shutdown, daemon=True).start()

    def stop(self) -> None:
        self._server.shutdown()
        if self._thread is not None:
            self._thread.join(timeout=5)


def build_session(cloud, labels, input_path, edits_out, labels_out, root_index=None,
                  height=None, n_samples=None, solver_factory=None, min_opacity: float = 0.0,
                  normals: str | None = "smallest-axis", up=None, confidence=None, frame=None):
    """Make a :class:`ViewerSession` for ``cloud`` (input frame) starting from ``labels`` (cloud order).

    input_path : the input file (hashed into the edits); height : plant height in input units
    (default: :func:`leaffit_usd.segment.edits.plant_frame`); min_opacity : Gaussians below it
    are not pickable (floaters); normals : "smallest-axis" for orientation-aware geodesics, or None;
    up : (3,) plant up axis, input frame (default: from :func:`plant_frame`, with the height);
    confidence : (L,) float in [0, 1] per starting leaf (label l+1 at index l), or None. An array
    of another length, or with values outside [0, 1], is a ParameterError. frame : the plant's
    ``Frame`` (input <-> working), for the leaf preview, or None (estimated when first needed).
    """
    from leaffit_usd.errors import ParameterError
    from leaffit_usd.io_util import file_sha256
    from leaffit_usd.segment.edits import Edits, flat_normals, labels_sha256, plant_frame
    from leaffit_usd.segment.manual import N_SAMPLES, ManualSegmenter
    from leaffit_usd.segment.picking import GaussianBVH

    labels = np.asarray(labels, np.int32)
    if confidence is not None:
        confidence = np.asarray(confidence, np.float64)
        n_leaves = int(labels.max(initial=0))
        if confidence.shape != (n_leaves,):
            raise ParameterError("confidence", f"({n_leaves},) values, one per leaf", confidence.shape)
        if not np.all((confidence >= 0) & (confidence <= 1)):
            raise ParameterError("confidence", "values in [0, 1]", confidence.tolist())
    t0 = time.perf_counter()
    if height is None or up is None:
        auto_height, auto_up = plant_frame(cloud)
        height = float(height or auto_height)
        up = auto_up if up is None else up
    up = np.asarray(up, np.float64)
    n_samples = int(n_samples or N_SAMPLES)
    template = Edits(input_sha256=file_sha256(input_path), n_gaussians=int(cloud.file_count),
                     height=height, n_samples=n_samples,
                     base_labels_sha256=labels_sha256(cloud.to_file_order(labels)),
                     base_leaves=int(labels.max(initial=0)), input_name=Path(input_path).name,
                     normals=normals)
    seg = ManualSegmenter(cloud.means, labels, height, n_samples=n_samples, solver_factory=solver_factory,
                          normals=flat_normals(cloud) if normals else None)
    t1 = time.perf_counter()
    pickable = cloud.opacities >= min_opacity if min_opacity > 0 else None
    bvh = GaussianBVH.from_cloud(cloud, pickable=pickable)
    t2 = time.perf_counter()
    log.info("edit: geodesics on %d samples in %.2f s, BVH over %d Gaussians in %.2f s",
             len(seg.geodesics.samples), t1 - t0, bvh.n_pickable, t2 - t1)
    return ViewerSession(cloud=cloud, height=height, segmenter=seg, bvh=bvh, edits_template=template,
                         edits_out=Path(edits_out), labels_out=Path(labels_out),
                         root_index=root_index, up=up, input_name=Path(input_path).name,
                         confidence=confidence, frame=frame)

