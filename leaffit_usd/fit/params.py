"""Registration parameters (no torch: the CLI reads their defaults for its help text)."""
from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from leaffit_usd.errors import ParameterError
from leaffit_usd.fit.denoise import DenoiseParams
from leaffit_usd.fit.mls import DEFAULT_REG, DEFAULT_SIGMA

#: FitParams overrides that give the paper's registration exactly (``FitParams.paper()``,
#: ``convert --paper-fit``): its 32 control points, its absolute kernel width, its initial
#: correspondence, 200 Adam steps at lr 7e-3 and nothing after them, and the smallest regulariser
#: that keeps a flat template's MLS solvable (the paper has none).
PAPER_FIT = {"K": 32, "sigma": DEFAULT_SIGMA, "steps": 200, "lr": 7e-3, "refine": 0, "reg": 0.01,
             "start": "assignment"}
#: how the targets start (``FitParams.start``)
STARTS = ("best", "rigid", "assignment")

#: a leaf is seen face-on along its frame's +Z when its mean normal is within this angle of +Z
#: (degrees): then its xy silhouette is its outline (the fit's outline term) and the template is
#: built, charted and cut out along +Z (``mesh.view_frame``, ``mesh.texture_bake``)
FACE_ON_MAX_DEG = 30.0
#: the most control points a leaf can have: the GLSL deformer's per-vertex weight array
#: (``LEAFFIT_MAX_K`` in runtime/glsl, which ``runtime.shader`` builds from this) holds this many
MAX_K = 64


@dataclass
class FitParams:
    """Registration parameters (working units: plant height 1). Defaults = ours; the paper's
    optimisation exactly is ``FitParams.paper()`` (K 32, sigma 0.1, 200 Adam steps, no
    Gauss-Newton).

    K : control points per leaf (48; the paper's 32: ``FitParams.paper()``). Why 48: with the
        refinement's outline term the field follows each leaf's own outline, and 32 handles
        could not follow a hooked tip (overlap's worst view, IoU 0.899). 13 render plants, K = 48
        and reg 0.03 against 32 and 0.01: leaf HD, Corr, PSNR and SSIM better on 12, outline
        error on 11 (``benchmarks/render.py``; docs/fitting.md, "Control points"). 64 threw a
        region of two apple leaves off the leaf (``benchmarks/results/render_k64.json``).
    steps, lr : Adam iterations and learning rate (ours: 0, no Adam: Gauss-Newton from the
        start; the paper's: 200 and 7e-3, ``FitParams.paper()``). Why 0: the MLS field is linear
        in the targets, so each leaf's fit is a small least-squares problem that Gauss-Newton
        solves in 10 iterations (``fit.gauss_newton``); Adam's 200 rendered steps cost 2 s per
        leaf on 100k Gaussians, 10x the solve, for the shape error 10 solves from the better of
        two starts reach (``start``). Range >= 0.
    lam : Chamfer weight lambda (0.7); reg : MLS regulariser (fraction of sigma; 0.03, why:
        ``fit.mls``)
    sigma : MLS kernel width: "auto" = ``sigma_relative`` x the template leaf's size (RMS radius
        in its plane; ours, see the module doc), or a number in working units (paper: 0.1)
    refine : Gauss-Newton iterations (after Adam when ``steps`` > 0; ours: 10; 0 = none, the
        paper's optimisation only). Range >= 0.
    refine_points : Gauss-Newton pairs at most this many of the template's and of each leaf's
        denoised Gaussians, farthest point samples (uniform over the blade, as the area-sampled
        shape errors are; 0 = all). 2048: the same errors as 16,384 random ones (4 suite plants,
        Corr x10 0.0063 both) at a quarter of the cost. Range >= 0.
    plane_weight, landmark_weight : weights of the point-to-plane (depth) term and of the
        base/apex landmark term in the Gauss-Newton objective
    damping, damping_start : Marquardt damping (a fraction of each unknown's own curvature) of
        the last and of the first Gauss-Newton iteration, geometric in between (1.0 -> 1e-3;
        why: ``fit.gauss_newton``). Range >= 0.
    start : where the targets start: "best" (ours: Gauss-Newton from both of the others, in one
        batch, keeping per leaf the lower objective), "rigid" (the template placed by the leaf's
        frame and scale) or "assignment" (the paper's: FPS of the leaf matched by
        Jonker-Volgenant). Why "best": from the rigid start the field unfolds smoothly on most
        leaves, but an arched strap leaf needs the assignment's start (lucky bamboo Corr x10
        0.0117 rigid, 0.0079 best). 14 suite plants (``benchmarks/deformation.py``'s plants,
        GT labels), Corr / CD / HD x10: 200 Adam steps + 10 Gauss-Newton 0.0058 / 0.00004 /
        0.121, rigid 0.0067 / 0.00006 / 0.122, best 0.0059 / 0.00004 / 0.116, at a third of
        the fit's CPU (210 -> 70 s for the 14). The "w/o
        optim." ablation (``optimize=False``) is the assignment either way
    outline_weight : weight of the refinement's silhouette-outline Chamfer, relative to the
        surface Chamfer's lam (ours; 0 = off; see ``fit.gauss_newton``)
    template : "auto" or a leaf label (int or digit string)
    optimize : False = initial correspondence only (the paper's "w/o optim." ablation)
    seed : torch/numpy seed (the method itself is deterministic)
    image_size : side of each leaf's square depth image, pixels
    max_points : Gaussians per leaf used in the optimisation (farthest point sampling)
    leaf_gaussians : at most this many of a leaf's Gaussians enter denoising, the leaf frame,
        the fit and its error (a deterministic random subset; 0 = all). A dense capture's
        leaves hold tens of thousands (1M Gaussians: 35-165k per leaf), and the optimisation
        itself already uses ``max_points``; the cap keeps denoising and the error from growing
        without bound. 65536 leaves every 100k-Gaussian benchmark plant whole; the denoiser
        fits its planes at ``denoise.plane_points`` anchors, so the cap's cost grows with it,
        not with its square. (16384 cost the 1M capsicum's accuracy: HD x10 0.0452 against
        100k's 0.0407, ``benchmarks/scale.py``.) The template's texture bake and every leaf's
        outline silhouette still get every Gaussian of the leaf near its denoised surface.
    max_scale_ratio : a leaf more than this many times larger (or smaller) than the template is
        treated as degenerate (likely a merged segment) and fitted rigidly
    fg_alpha : a depth-map pixel is foreground where its accumulated alpha exceeds this
    denoise : ``DenoiseParams`` (paper: sigma 0.1, the same value as the MLS kernel)
    """

    K: int = 48
    steps: int = 0
    lr: float = 7e-3
    lam: float = 0.7
    sigma: float | str = "auto"
    sigma_relative: float = 0.7
    reg: float = DEFAULT_REG
    refine: int = 10
    refine_points: int = 2048
    plane_weight: float = 1.0
    landmark_weight: float = 0.05
    damping: float = 1e-3
    damping_start: float = 1.0
    start: str = "best"
    outline_weight: float = 1.0
    template: str | int = "auto"
    optimize: bool = True
    seed: int = 0
    image_size: int = 64
    max_points: int = 1024
    leaf_gaussians: int = 65536
    max_scale_ratio: float = 4.0
    fg_alpha: float = 0.5
    denoise: DenoiseParams = field(default_factory=DenoiseParams)

    @classmethod
    def paper(cls, **overrides) -> "FitParams":
        """The paper's registration exactly: K = 32, sigma = 0.1 for the kernel, its initial
        correspondence, 200 Adam steps (lr 7e-3), no Gauss-Newton."""
        return cls(**{**PAPER_FIT, **overrides})

    def solver(self) -> str:
        """What the optimisation runs, for progress lines: "10 Gauss-Newton iterations",
        "200 Adam steps", "200 Adam steps + 10 Gauss-Newton iterations" or "no optimisation"."""
        parts = ([f"{self.steps} Adam steps"] if self.steps else []) + (
            [f"{self.refine} Gauss-Newton iterations"] if self.refine else [])
        return " + ".join(parts) if self.optimize and parts else "no optimisation"

    def validate(self) -> None:
        for name, lo in (("K", 1), ("steps", 0), ("image_size", 8), ("max_points", 16),
                         ("leaf_gaussians", 0), ("refine", 0), ("refine_points", 0)):
            v = getattr(self, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < lo:
                raise ParameterError(name, f"an integer >= {lo}", v)
        if self.K > MAX_K:   # refused here: the GLSL deformer could not be built after the fit
            raise ParameterError("K", f"at most {MAX_K} control points (the GLSL deformer's limit)", self.K)
        pos = ["lr", "max_scale_ratio", "sigma_relative"] + ([] if self.sigma == "auto" else ["sigma"])
        for name in pos:
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v)
                    and v > 0):
                raise ParameterError(name, "a positive number" + (" or 'auto'" if name == "sigma" else ""), v)
        if self.start not in STARTS:
            raise ParameterError("start", " or ".join(STARTS), self.start)
        for name in ("lam", "plane_weight", "landmark_weight", "damping", "damping_start",
                     "outline_weight"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and np.isfinite(v) and v >= 0):
                raise ParameterError(name, "a number >= 0", v)
        if self.max_scale_ratio < 1:
            raise ParameterError("max_scale_ratio", "a number >= 1", self.max_scale_ratio)
        for name, lo in (("neighbors", 3), ("reference_points", 0), ("plane_points", 0)):
            v = getattr(self.denoise, name)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < lo:
                raise ParameterError(f"denoise.{name}", f"an integer >= {lo}", v)
        t = self.template
        if not (t == "auto" or isinstance(t, (int, np.integer)) and not isinstance(t, bool)
                or isinstance(t, str) and t.strip().isdigit()):
            raise ParameterError("template", "'auto' or a leaf label (1..L)", t)

    def to_dict(self) -> dict:
        d = asdict(self)
        d["template"] = self.template if isinstance(self.template, str) else int(self.template)
        return d
