"""Image differences between two materials rendered the same way: FLIP, CIEDE2000 and ΔE_ITP.

Each lighting renders both spheres noise-free (:func:`~matfit.appearance.render_lit`); the
images are shown as a display would: times the lighting's exposure (a white Lambertian sphere's
brightest pixel is 1), clipped to [0, 1], sRGB. On those:

- **FLIP** (Andersson et al. 2020, NVIDIA's ``flip-evaluator``, LDR, 67 pixels per degree): the
  per-pixel perceived difference in [0, 1];
- **CIEDE2000** (Sharma et al. 2005, ``colour``): on CIE L*a*b* of the displayed linear sRGB,
  white Y = 1;
- **ΔE_ITP** (ITU-R BT.2124, ``colour``): on ICtCp with the display white at 100 cd/m².

Means are over the pixels of the sphere (the background is the same in both). A poor fit is
then located: near the mirror (pixels whose normal is within 12° of the half vector between
the camera and the lighting's brightest direction), at grazing angles (normals more than 65°
from the camera) or in colour (the part of CIEDE2000 left when the lightness is matched is more
than half of it)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..errors import ParameterError
from ..render import srgb_encode
from ._lighting import SIZE, lighting, render_lit

#: The lightings a fit is judged under.
JUDGE_LIGHTS = ("sky", "studio")
#: The lines a fit that "looks like its measurement" stays under, under every lighting.
FLIP_LINE, CIEDE2000_LINE = 0.05, 1.5
MIRROR_DEG, GRAZING_DEG = 12.0, 65.0
#: The display white of ΔE_ITP, in cd/m².
WHITE_NITS = 100.0


def display(img, exposure):
    """Linear ``img`` as displayed: times ``exposure``, clipped to [0, 1] (still linear).

    Parameters
    ----------
    img : array_like (..., 3)
    exposure : float

    Returns
    -------
    numpy.ndarray
    """
    return np.clip(np.asarray(img, np.float64) * exposure, 0.0, 1.0)


def _xyz(x):
    import colour

    return colour.RGB_to_XYZ(np.asarray(x, np.float64), colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)


def lab(x):
    """CIE L*a*b* (D65, white Y = 1: display white is exactly neutral) of displayed linear sRGB ``x``.

    Parameters
    ----------
    x : array_like (..., 3)

    Returns
    -------
    numpy.ndarray (..., 3)
    """
    import colour

    # the white of sRGB's (rounded) matrix, so that display white is exactly neutral
    return colour.XYZ_to_Lab(_xyz(x), colour.XYZ_to_xy(_xyz(np.ones(3))))


def ciede2000_map(a, b):
    """Per-pixel CIEDE2000 between two displayed linear sRGB images.

    Parameters
    ----------
    a, b : array_like (..., 3)

    Returns
    -------
    numpy.ndarray (...)
    """
    import colour

    return colour.delta_E(lab(a), lab(b), method="CIE 2000")


def itp_map(a, b, white_nits=WHITE_NITS):
    """Per-pixel ΔE_ITP between two displayed linear sRGB images (white at ``white_nits`` cd/m²).

    Parameters
    ----------
    a, b : array_like (..., 3)
    white_nits : float, default WHITE_NITS

    Returns
    -------
    numpy.ndarray (...)
    """
    import colour

    def ictcp(x):
        return colour.XYZ_to_ICtCp(_xyz(x) * white_nits)

    return colour.delta_E(ictcp(a), ictcp(b), method="ITP")


def flip_map(a, b):
    """Per-pixel FLIP (LDR) of test image ``b`` against reference ``a``, both displayed linear sRGB.

    Parameters
    ----------
    a, b : array_like (H, W, 3)

    Returns
    -------
    numpy.ndarray (H, W)
    """
    try:
        import flip_evaluator
    except ImportError:  # pragma: no cover - a dependency of matfit
        raise ParameterError("flip_map: needs the flip-evaluator package (pip install flip-evaluator)") from None
    ref = np.ascontiguousarray(srgb_encode(a), np.float32)
    test = np.ascontiguousarray(srgb_encode(b), np.float32)
    err, _, _ = flip_evaluator.evaluate(ref, test, "LDR", inputsRGB=True, applyMagma=False, computeMeanError=False)
    return np.asarray(err, np.float64).reshape(ref.shape[:2])


@dataclass
class LightDiff:
    """The two renders under one lighting and their differences.

    Attributes
    ----------
    light : str
    reference, fitted : numpy.ndarray (H, W, 3)
        Displayed linear sRGB (exposed and clipped).
    inside : numpy.ndarray (H, W) bool
    flip, ciede2000, itp : numpy.ndarray (H, W)
        Per-pixel maps (zero outside the sphere).
    means : dict
        ``flip``, ``ciede2000``, ``itp`` over the sphere.
    regions : dict
        Mean FLIP ``near_mirror``, ``grazing`` and ``elsewhere``, and ``colour_share`` (the part of
        CIEDE2000 left with the lightness matched).

    Examples
    --------
    >>> from matfit.models import Lambert
    >>> d = appearance_difference(Lambert(0.5), Lambert(0.5), lights=("sky",), size=16)
    >>> d.lights["sky"].means["flip"]
    0.0
    """

    light: str
    reference: np.ndarray
    fitted: np.ndarray
    inside: np.ndarray
    flip: np.ndarray
    ciede2000: np.ndarray
    itp: np.ndarray
    means: dict
    regions: dict


@dataclass
class AppearanceDiff:
    """Image differences of a fit against its reference under each judging lighting.

    Attributes
    ----------
    lights : dict of str to LightDiff

    Examples
    --------
    >>> from matfit.models import Lambert
    >>> d = appearance_difference(Lambert(0.5), Lambert(0.5), lights=("sky",), size=16)
    >>> d.looks_alike, d.worst("flip"), d.where(), d.warning()
    (True, 0.0, [], None)
    >>> d.summary()
    'sky: FLIP 0.000, CIEDE2000 0.00, ΔE_ITP 0.0'
    """

    lights: dict = field(default_factory=dict)

    def worst(self, metric="flip"):
        """The largest mean of ``metric`` ("flip", "ciede2000" or "itp") over the lightings."""
        return max(d.means[metric] for d in self.lights.values())

    @property
    def looks_alike(self):
        """Under every lighting, mean FLIP <= :data:`FLIP_LINE` and mean CIEDE2000 <= :data:`CIEDE2000_LINE`."""
        return self.worst("flip") <= FLIP_LINE and self.worst("ciede2000") <= CIEDE2000_LINE

    def where(self):
        """Where the fit fails to look alike (empty when it looks alike): ``near the mirror``,
        ``at grazing angles``, ``in colour``, or ``across the sphere`` when no region stands out."""
        if self.looks_alike:
            return []
        out = []
        for d in self.lights.values():
            r, m = d.regions, d.means["flip"]
            if r["near_mirror"] > 1.5 * max(m, 1e-6) and "near the mirror" not in out:
                out.append("near the mirror")
            if r["grazing"] > 1.5 * max(m, 1e-6) and "at grazing angles" not in out:
                out.append("at grazing angles")
            if r["colour_share"] > 0.5 and "in colour" not in out:
                out.append("in colour")
        return out or ["across the sphere"]

    def warning(self, reference="measured"):
        """The poor-fit warning (None when the fit looks alike): the worst means and where it fails;
        ``reference`` names what the fit is compared with."""
        if self.looks_alike:
            return None
        return (f"poor fit in appearance: the fitted sphere does not look like the {reference} one (worst mean FLIP "
                f"{self.worst('flip'):.3f}, line {FLIP_LINE}; worst mean CIEDE2000 {self.worst('ciede2000'):.2f}, "
                f"line {CIEDE2000_LINE}); it fails " + ", ".join(self.where()))

    def to_dict(self):
        """The means and regions per lighting, ``looks_alike`` and ``where``, for JSON."""
        return {k: {"means": {m: float(v) for m, v in d.means.items()},
                    "regions": {m: float(v) for m, v in d.regions.items()}} for k, d in self.lights.items()} | {
            "looks_alike": bool(self.looks_alike), "where": self.where()}

    def summary(self):
        """One line: the means under each lighting."""
        return "; ".join(f"{k}: FLIP {d.means['flip']:.3f}, CIEDE2000 {d.means['ciede2000']:.2f}, "
                         f"ΔE_ITP {d.means['itp']:.1f}" for k, d in self.lights.items())


def render_references(reference, lights=JUDGE_LIGHTS, size=SIZE):
    """The renders of ``reference`` under each lighting, to judge many fits against (computed once).

    Parameters
    ----------
    reference : matfit.models.AbstractBSDF
        The measured material (e.g. :class:`~matfit.models.MeasuredRGL`) or a true model.
    lights : sequence of lighting specs, default JUDGE_LIGHTS
    size : int, default SIZE

    Returns
    -------
    dict
        ``{name: (lighting, linear image, inside)}``, accepted by :func:`appearance_difference`.
    """
    out = {}
    for spec in lights:
        light = lighting(spec)
        out[light.name] = (light, *render_lit(reference, light, size))
    return out


def _regions(light, inside, flip, de, de_chroma):
    size = inside.shape[0]
    from ..render import sphere_frames

    n = sphere_frames(size)[1][inside][:, 2, :]
    brightest = light.directions[np.argmax(light.weights.sum(1))]
    h = brightest + np.array([0.0, 0.0, 1.0])
    h /= np.linalg.norm(h)
    mirror = n @ h > np.cos(np.radians(MIRROR_DEG))
    grazing = n[:, 2] < np.cos(np.radians(GRAZING_DEG))
    f = flip[inside]
    mean = lambda m: float(f[m].mean()) if m.any() else 0.0  # noqa: E731
    return {"near_mirror": mean(mirror), "grazing": mean(grazing), "elsewhere": mean(~mirror & ~grazing),
            "colour_share": float(de_chroma[inside].mean() / max(de[inside].mean(), 1e-12))}


def appearance_difference(model, reference, lights=JUDGE_LIGHTS, size=SIZE):
    """Render ``model`` and ``reference`` the same way under each lighting and compare the images.

    Parameters
    ----------
    model : matfit.models.AbstractBSDF
        The fitted material.
    reference : matfit.models.AbstractBSDF or dict
        The measured (or true) material, or its renders from :func:`render_references`.
    lights : sequence, default JUDGE_LIGHTS
        Lightings (names of :data:`~matfit.appearance.LIGHTINGS`, maps); ignored when
        ``reference`` is a dict of renders.
    size : int, default SIZE

    Returns
    -------
    AppearanceDiff

    Examples
    --------
    >>> from matfit.models import Lambert
    >>> d = appearance_difference(Lambert(0.3), Lambert(0.6), size=24)
    >>> d.looks_alike, d.where()
    (False, ['across the sphere'])
    """
    import colour

    refs = reference if isinstance(reference, dict) else render_references(reference, lights, size)
    out = AppearanceDiff()
    for name, (light, ref_img, inside) in refs.items():
        fit_img, _ = render_lit(model, light, inside.shape[0])
        e = light.exposure
        a, b = display(ref_img, e), display(fit_img, e)  # both zero outside the sphere
        fl = flip_map(a, b) * inside
        la, lb = lab(a), lab(b)
        de = colour.delta_E(la, lb, method="CIE 2000") * inside  # ciede2000_map, Lab computed once
        lb[..., 0] = la[..., 0]  # lightness matched: what is left is hue and chroma
        de_c = colour.delta_E(la, lb, method="CIE 2000") * inside
        it = itp_map(a, b) * inside
        means = {"flip": float(fl[inside].mean()), "ciede2000": float(de[inside].mean()),
                 "itp": float(it[inside].mean())}
        out.lights[name] = LightDiff(name, a, b, inside, fl, de, it, means, _regions(light, inside, fl, de, de_c))
    return out
