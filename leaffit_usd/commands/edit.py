"""``leaffit-usd edit INPUT``: interactive manual segmentation in a local web page."""
from __future__ import annotations

import logging
import os
import signal
import sys
import threading
from pathlib import Path

import numpy as np

from leaffit_usd.commands import _args

NAME = "edit"
HELP = "fix a segmentation by hand in a local web page (geodesic drag and brush tools)"
DESCRIPTION = """Open the plant in a local web page (127.0.0.1 only, a free port, a random token in
the URL) with the paper's geodesic selection tools:

  drag   press on a leaf tip and drag toward its base: selects D_p[g] <= D_p[cursor]
  brush  paint with a geodesic radius (fraction of the plant height): add or erase

then assign the selection to a new leaf, an existing leaf or the stem; merge, split and delete
leaves; undo/redo. Save writes two files (never a path chosen by the page):

  EDITS.json   the operations, replayable:  leaffit-usd segment INPUT --edits EDITS.json
  LABELS.npz   the labels (int32 per Gaussian, file order, 0 = stem), usable with --labels

Defaults: next to INPUT as <stem>.edits.json and <stem>.labels.npz. Stop with Ctrl-C.

The session starts from --labels, or else from the automatic segmentation exactly as
'convert' computes it (same --up/--root, paper defaults), so 'convert INPUT --edits EDITS.json'
(with the same --labels, if any) reproduces the saved labels.

Confidence: the automatic segmentation gives each leaf a confidence in [0, 1] (so does a labels
file written by 'segment', in its 'confidence' array). The page lists it beside each leaf, marks
the doubtful leaves (confidence < 0.5) with '?', and opens on the least confident one (checked,
camera on it); 'Next doubtful' (key N) goes through the others. The terminal lists them too."""
ORDER = 25

log = logging.getLogger("leaffit_usd")


def add_arguments(p) -> None:
    from leaffit_usd.commands._args import add_frame_arguments, add_isolate_arguments
    from leaffit_usd.segment.manual import N_SAMPLES

    p.add_argument("input", metavar="INPUT", help="3DGS capture (.ply, .compressed.ply, .spz, .sog, .splat or USD)")
    p.add_argument("--labels", metavar="LABELS.npz",
                   help="start from this segmentation (.npz with 'labels', file order); "
                        "default: the automatic segmentation")
    p.add_argument("--empty", action="store_true", help="start with every Gaussian unassigned")
    p.add_argument("--edits", metavar="EDITS.json",
                   help="continue a session: replay these edits first (they can be undone)")
    p.add_argument("--edits-out", metavar="PATH", help="where Save writes the edits (default: INPUT stem + .edits.json)")
    p.add_argument("--labels-out", metavar="PATH", help="where Save writes the labels (default: INPUT stem + .labels.npz)")
    p.add_argument("--port", type=int, default=0, help="TCP port on 127.0.0.1 (default %(default)s: a free port)")
    p.add_argument("--no-browser", action="store_true", help="print the URL only, do not open a browser")
    p.add_argument("--samples", type=int, default=N_SAMPLES,
                   help=f"geodesic subsample size N_s (default {N_SAMPLES}, the paper's)")
    p.add_argument("--min-opacity", type=float, default=0.0,
                   help="Gaussians less opaque than this cannot be picked (default %(default)g: all)")
    add_frame_arguments(p)  # for the automatic segmentation the session starts from (as in convert)
    add_isolate_arguments(p)  # the page shows the plant as convert isolates it


def read_labels_file(path, cloud) -> tuple[np.ndarray, int | None, np.ndarray | None]:
    """(labels (N,) int32 cloud order, root index (cloud order) or None, confidence (L,) or
    None) from a segmentation .npz, read exactly as ``convert --labels`` reads it
    (``segment.labels_file.cloud_labels``), so edits replay on the same starting labels."""
    from leaffit_usd.segment.labels_file import cloud_labels

    return cloud_labels(path, cloud)


def prepare_capture(inp, up="auto", root="auto", root_index=None, keep_scene=False, crop=None):
    """The capture at ``inp`` as ``convert`` prepares it (``leaffit_usd.prepare.PreparedPlant``:
    isolation, canonical order, frame): the page shows the isolated plant, and its automatic
    labels are convert's. up, root : the --up / --root strings; root_index : --root-index.
    Raises ParameterError for a bad --up / --root."""
    from leaffit_usd.prepare import FrameOptions, PreparedPlant

    fo = FrameOptions(_args.parse_up(up), _args.parse_root(root), root_index)
    return PreparedPlant.open(inp, fo, keep_scene=keep_scene, crop=crop)


def automatic_labels(prep):
    """(labels, root index, Frame, confidence) from the automatic segmentation of a
    ``PreparedPlant``, as convert does: labels : (P,) int32, plant order; confidence : (L,)
    float64 in [0, 1] per leaf, or None when the segmentation failed (then every Gaussian is
    unassigned)."""
    from leaffit_usd.errors import UserError

    conf = None
    try:
        seg = prep.segment()
        labels = np.asarray(seg.labels, np.int32)
        log.info("edit: %d leaves found", int(labels.max(initial=0)))
        if seg.confidence is not None:
            conf = np.asarray(seg.confidence, np.float64)
            if conf.shape != (int(labels.max(initial=0)),):
                log.warning("edit: the segmentation gave %d confidences for %d leaves; not shown",
                            conf.size, int(labels.max(initial=0)))
                conf = None
    except UserError as e:  # a plant the automatic method cannot handle is what edit is for
        log.warning("edit: automatic segmentation failed (%s); starting with every Gaussian "
                    "unassigned", e)
        labels = np.zeros(len(prep.plant), np.int32)
    return labels, int(prep.root_index), prep.frame, conf


def _open_browser(url: str) -> None:
    """Open ``url`` in a browser if one can show it (never a text browser blocking the terminal)."""
    import webbrowser

    graphical = sys.platform in ("darwin", "win32") or os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")
    if not graphical:
        return
    threading.Thread(target=webbrowser.open, args=(url,), daemon=True).start()


def doubtful_lines(session) -> list[str]:
    """What the terminal says at start about the leaves' confidence (empty when there is none)."""
    from leaffit_usd.segment.result import DOUBTFUL_CONFIDENCE
    from leaffit_usd.viewer.server import least_confident

    rows, _ = session.leaves()
    known = [r for r in rows if r["confidence"] is not None]
    if not known:
        return []
    least = least_confident(rows)
    doubtful = sorted((r for r in known if r["doubtful"]), key=lambda r: (r["confidence"], r["label"]))
    if doubtful:
        listed = ", ".join(f"{r['label']} ({r['confidence']:.2f})" for r in doubtful)
        return [f"leaffit-usd edit: leaves to check (confidence < {DOUBTFUL_CONFIDENCE:g}): {listed}; "
                f"the page opens on leaf {least}"]
    low = min(known, key=lambda r: (r["confidence"], r["label"]))
    return [f"leaffit-usd edit: no doubtful leaf (all {len(known)} with confidence >= {DOUBTFUL_CONFIDENCE:g}; "
            f"lowest: leaf {low['label']}, {low['confidence']:.2f})"]


_PRINT_LOCK = threading.Lock()


def _say(line: str) -> None:
    """Print one line to the terminal; the session builder prints too, and a TextIOWrapper
    written by two threads at once can break (its buffer then fails at exit)."""
    with _PRINT_LOCK:
        print(line, flush=True)


def _interrupt(*_):
    raise KeyboardInterrupt


def run(args) -> int:
    from leaffit_usd.errors import ParameterError, UserError
    from leaffit_usd.segment.edits import load_edits
    from leaffit_usd.viewer.server import ViewerServer, ViewerSession

    if not 0 <= args.port <= 65535:
        raise ParameterError("--port", "a port number in [0, 65535]", args.port)
    if args.samples < 16:
        raise ParameterError("--samples", "at least 16", args.samples)
    if args.labels and args.empty:
        raise ParameterError("--empty", "not together with --labels", True)
    inp = Path(args.input)
    edits = load_edits(args.edits, inp) if args.edits else None   # refused before anything slow
    prep = prepare_capture(inp, args.up, args.root, args.root_index, args.keep_scene, args.crop)
    cloud = prep.plant   # the plant as convert isolates it (file_index: each Gaussian's identity)
    given = read_labels_file(args.labels, cloud) if args.labels else None
    stem = inp.name.rsplit(".", 1)[0]
    edits_out = Path(args.edits_out) if args.edits_out else inp.with_name(stem + ".edits.json")
    labels_out = Path(args.labels_out) if args.labels_out else inp.with_name(stem + ".labels.npz")
    # the page draws the capture at once; the segmentation and the geodesics follow
    session = ViewerSession.starting(cloud, edits.height if edits else prep.frame.height, edits_out,
                                     labels_out, up=prep.frame.up, input_name=inp.name,
                                     frame=prep.frame, phase="segmenting")
    server = ViewerServer(session, port=args.port)
    failure = []
    builder = threading.Thread(target=_build_session, daemon=True,
                               args=(session, prep, args, given, edits, server, failure))
    previous = _install_stop_handlers()  # before the URL: whoever reads it may send Ctrl-C at once
    try:
        _say(f"leaffit-usd edit: open {server.url}")
        _say("  (local only; the token in the URL is required; Ctrl-C to stop)")
        builder.start()
        if not args.no_browser:
            _open_browser(server.url)
        server.serve_forever()
    except KeyboardInterrupt:
        pass
    finally:
        for s, h in previous.items():
            signal.signal(s, h)
    if failure:
        if isinstance(failure[0], UserError):
            raise failure[0]
        raise RuntimeError("edit: starting the session failed") from failure[0]
    if session.ready and session.segmenter.operations != session.saved_ops:
        log.warning("edit: stopped with %d unsaved operations", len(session.segmenter.operations))
    _say("leaffit-usd edit: stopped")
    if builder.is_alive():
        # stopped while still starting (segmenting, or choosing the preview's template): a thread
        # deep in numpy / torch cannot be interrupted, and finalising the interpreter under it
        # breaks the standard streams; nothing is left to write (Save is atomic), so leave now
        sys.stderr.flush()
        os._exit(0)
    return 0


def _install_stop_handlers() -> dict:
    """SIGTERM stops as Ctrl-C does, and Ctrl-C works even when the process started with SIGINT
    ignored (launched in the background by a script, or under a test runner that was): Python
    then installs no handler of its own and the server could only be killed. Returns the
    previous handlers (none off the main thread)."""
    previous = {}
    if threading.current_thread() is threading.main_thread():
        previous[signal.SIGTERM] = signal.signal(signal.SIGTERM, _interrupt)
        previous[signal.SIGINT] = signal.signal(signal.SIGINT, signal.default_int_handler)
    return previous


def _build_session(session, prep, args, given, edits, server, failure: list) -> None:
    """The slow half of starting, behind the served page: the starting labels (``given`` =
    (labels, root, confidence) from --labels, --empty, or convert's automatic segmentation), the
    geodesics and BVH, the replayed --edits; then ``session`` is ready. A failure is put in
    ``failure`` and stops the server (``run`` raises it: a user error exits 2 with one line)."""
    from leaffit_usd.segment.edits import to_cloud_operations
    from leaffit_usd.viewer.server import build_session

    try:
        cloud, frame, conf = prep.plant, prep.frame, None
        if given is not None:
            labels, root, conf = given
        elif args.empty:
            labels, root = np.zeros(len(cloud), np.int32), prep.root_index
            log.info("edit: starting with every Gaussian unassigned")
        else:
            log.info("edit: automatic segmentation (as convert does; --empty to skip, --labels to reuse one)")
            labels, root, frame, conf = automatic_labels(prep)
        session.phase = "geodesics"
        built = build_session(cloud, labels, Path(args.input), session.edits_out, session.labels_out,
                              root_index=root, height=session.height, up=frame.up,
                              n_samples=edits.n_samples if edits else args.samples,
                              min_opacity=args.min_opacity, confidence=conf, frame=frame)
        if edits is not None:
            session.phase = "replaying edits"
            built.segmenter.replay(to_cloud_operations(edits.operations, cloud))
            built.saved_ops = list(built.segmenter.operations)
            log.info("edit: replayed %d operations from %s", len(edits.operations), args.edits)
        session.attach(built)
        log.info("edit: ready")
        for line in doubtful_lines(session):
            _say(line)
        session.warm_preview()  # the template of the fitted-leaf preview, behind the ready page
    except Exception as e:  # noqa: BLE001 - handed to run(), which raises it in the main thread
        session.failed = str(e)
        failure.append(e)
        server.stop_soon()
