"""Sheen: the "Charlie" sheen lobe of Estevez & Kulla (2017) over any base, and its albedo table."""

from __future__ import annotations

import functools

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._math import cosine_hemisphere, safe_div
from ..errors import ParameterError
from ._base import AbstractBSDF
from ._pairs import SoAPairs
from ._params import as_channels, as_param, channel_count, check_channels, check_directions, check_range, check_u
from .lambert import cosine_pdf

__all__ = ["Sheen", "sheen_albedo", "SHEEN_L_FITS", "SHEEN_ALPHA_MIN"]

#: Estevez & Kulla's fits of L(x) = a / (1 + b x^c) + d x + e at alpha = 1 and alpha = 0
#: (rows a, b, c, d, e), interpolated by (1 - alpha)^2.
SHEEN_L_FITS = ((21.5473, 25.3245), (3.82987, 3.32435), (0.19823, 0.16801), (-1.97760, -1.27393),
                (-4.32054, -4.85967))
#: The smallest width the albedo table reads (a narrower sheen reflects almost nothing).
SHEEN_ALPHA_MIN = 0.01
#: The albedo table's grid: cosines (uniform in sqrt(mu): dense at grazing, where E changes
#: fastest) and widths.
_MU_GRID, _ALPHA_GRID = np.linspace(0.0, 1.0, 33) ** 2, np.linspace(SHEEN_ALPHA_MIN, 1.0, 34)


def _L(x, alpha, xp):
    t = (1 - alpha) ** 2
    a, b, c, d, e = (lo + (hi - lo) * t for lo, hi in SHEEN_L_FITS)
    # x^c at x = 0 has a NaN derivative in c (0 * log 0): x >= 1e-6 changes L by < 1e-4
    return a / (1 + b * xp.power(xp.maximum(x, 1e-6), c)) + d * x + e


def _lambda(mu, alpha, xp):
    """Estevez & Kulla's Lambda(mu) (mu in [0, 1]); ``xp`` numpy or jax.numpy."""
    lo = xp.exp(_L(xp.minimum(mu, 0.5), alpha, xp))
    hi = xp.exp(2 * _L(0.5, alpha, xp) - _L(xp.maximum(1 - mu, 0.0), alpha, xp))
    return xp.where(mu < 0.5, lo, hi)


def _lobe(cos_h, mu_o, mu_i, alpha, xp):
    """``D V`` of valid pairs (cosines > 0): the white sheen lobe, 1/sr."""
    sin2 = xp.maximum(1 - cos_h * cos_h, 0.0)
    inv = 1 / alpha
    # double where: sin^(1/alpha) at sin = 0 (h along the normal) is 0, its derivatives finite
    pos = sin2 > 1e-30
    D = xp.where(pos, (2 + inv) * xp.power(xp.where(pos, sin2, 1.0), 0.5 * inv) / (2 * np.pi), 0.0)
    return D / ((1 + _lambda(mu_o, alpha, xp) + _lambda(mu_i, alpha, xp)) * 4 * mu_o * mu_i)


@functools.lru_cache(maxsize=1)
def _albedo_table():
    """E(mu, alpha) on the grid (33 cosines x 34 widths), by Gauss-Legendre quadrature in numpy."""
    x, w = np.polynomial.legendre.leggauss(96)
    mu_i, w_mu = 0.5 * (x + 1), 0.5 * w
    phi = (np.arange(192) + 0.5) * (np.pi / 96)
    s = np.sqrt(1 - mu_i**2)
    wi = np.stack(np.broadcast_arrays(s[:, None] * np.cos(phi), s[:, None] * np.sin(phi), mu_i[:, None]), -1)
    wts = (w_mu * mu_i)[:, None] * (np.pi / 96)
    out = np.zeros((len(_MU_GRID), len(_ALPHA_GRID)))
    for i, mu in enumerate(np.maximum(_MU_GRID, 1e-4)):
        wo = np.array([np.sqrt(1 - mu * mu), 0.0, mu])
        h = wo + wi
        h = h / np.linalg.norm(h, axis=-1, keepdims=True)
        for j, a in enumerate(_ALPHA_GRID):
            out[i, j] = np.sum(_lobe(h[..., 2], mu, wi[..., 2], a, np) * wts)
    out.setflags(write=False)
    return out


def sheen_albedo(mu, alpha):
    """The white sheen lobe's directional albedo :math:`E(\\mu)`, bilinear in a table (:class:`Sheen`).

    Parameters
    ----------
    mu : array_like
        Cosine of the direction, in [0, 1].
    alpha : array_like
        The sheen's width (clamped to [:data:`SHEEN_ALPHA_MIN`, 1]).

    Returns
    -------
    jax.Array
        ``E``, broadcast over the arguments.

    Examples
    --------
    >>> from matfit.models import sheen_albedo
    >>> 0.0 < float(sheen_albedo(1.0, 0.5)) < float(sheen_albedo(0.2, 0.5)) < 1.0  # more sheen at grazing
    True
    """
    table = jnp.asarray(_albedo_table(), jnp.result_type(mu, alpha, float))
    m = jnp.sqrt(jnp.clip(jnp.asarray(mu), 1e-12, 1.0)) * (len(_MU_GRID) - 1)
    a = (jnp.clip(jnp.asarray(alpha), SHEEN_ALPHA_MIN, 1.0) - SHEEN_ALPHA_MIN) / (1 - SHEEN_ALPHA_MIN) * (len(_ALPHA_GRID) - 1)
    i0 = jnp.clip(jnp.floor(m).astype(int), 0, len(_MU_GRID) - 2)
    j0 = jnp.clip(jnp.floor(a).astype(int), 0, len(_ALPHA_GRID) - 2)
    ti, tj = m - i0, a - j0
    return ((1 - ti) * (1 - tj) * table[i0, j0] + ti * (1 - tj) * table[i0 + 1, j0]
            + (1 - ti) * tj * table[i0, j0 + 1] + ti * tj * table[i0 + 1, j0 + 1])


class Sheen(AbstractBSDF):
    r"""The Charlie sheen lobe over a base, the base scaled so that no energy is created.

    Cloth, velvet and satin scatter light back at grazing angles: the fibres standing out of the
    surface form a distribution of normals that lies near the horizon,

    .. math::
        D(h) = \frac{(2 + 1/\alpha)\,\sin^{1/\alpha}\theta_h}{2\pi},\qquad
        V = \frac{1}{(1 + \Lambda(\mu_o) + \Lambda(\mu_i))\,4\mu_o\mu_i},

    with Estevez & Kulla's fitted masking :math:`\Lambda(\mu) = e^{L(\mu)}` for :math:`\mu < 1/2`,
    :math:`e^{2L(1/2) - L(1 - \mu)}` otherwise, :math:`L(x) = a/(1 + b x^c) + d x + e`, the five
    coefficients interpolated by :math:`(1 - \alpha)^2` between their fits at :math:`\alpha = 1`
    and :math:`\alpha = 0` (:data:`SHEEN_L_FITS`; the values of the KHR_materials_sheen
    extension). The material is

    .. math::
        f = c\,\frac{D\,V}{\max(1, \bar E)} + s\,f_{base},\qquad
        s = 1 - \max_k c_k\,\min(1, \bar E),\qquad \bar E = \max(E(\mu_o), E(\mu_i))

    with :math:`c` the sheen colour, :math:`E(\mu) = \int D\,V\cos\theta_i\,d\omega_i` the
    white lobe's directional albedo (tabulated over :math:`\sqrt\mu` and :math:`\alpha` by
    quadrature, bilinear between: :func:`sheen_albedo`) and :math:`s` the energy-preserving
    albedo scaling of the base (the extension's, symmetric in the two directions: the model is
    reciprocal when the base is). The fitted :math:`\Lambda` is not exact: below
    :math:`\alpha \approx 0.06` the lobe's albedo passes 1 towards grazing (2.1 at
    :math:`\alpha = 0.01`, :math:`\mu = 0.004`), and there the lobe is divided by
    :math:`\bar E` (elsewhere nothing changes). The directional albedo is at most
    :math:`\max_k c_k \min(1, E(\mu_o)) + (1 - \max_k c_k \min(1, E(\mu_o)))\,E_{base} \le 1`,
    and :math:`f \ge 0`.

    Sampling: the sheen lobe by the cosine-weighted hemisphere with probability
    :math:`P = \bar c\,E(\mu_o)` (clamped to [0.05, 0.95]; 0 for a black sheen), the base's own
    sampler otherwise; the pdf is the exact mixture.

    Parameters
    ----------
    base : AbstractBSDF; no Dirac lobe, reflection only; differentiable (its array leaves)
        The material under the sheen.
    color : array_like, scalar or (..., C); [0, 1]; differentiable
        The sheen colour :math:`c` per channel.
    alpha : array_like, scalar or (...), default 0.3; > 0 and <= 1; differentiable
        The sheen's width :math:`\alpha`. It is glTF's ``sheenRoughness`` squared; the albedo
        table reads it clamped to :data:`SHEEN_ALPHA_MIN`.
    normalize : bool, default True; static, not differentiable
        Divide the lobe by :math:`\max(1, \bar E)` and clamp the scaling's :math:`\bar E` at 1;
        False gives KHR_materials_sheen's own formula (the glTF exporter's stand-in), which below
        :math:`\alpha \approx 0.06` reflects more than it receives and may go negative.

    References
    ----------
    - A. C. Estevez, C. Kulla, "Production Friendly Microfacet Sheen BRDF", Sony Pictures
      Imageworks technical report, 2017.
    - The Khronos Group, KHR_materials_sheen extension specification (the albedo scaling).

    Examples
    --------
    >>> import jax.numpy as jnp
    >>> from matfit.models import Lambert, Sheen
    >>> velvet = Sheen(Lambert([0.3, 0.05, 0.1]), [0.9, 0.4, 0.5], 0.3)
    >>> wo = jnp.array([0.0, 0.98, 0.2]) / jnp.hypot(0.98, 0.2); wi = jnp.array([0.0, 0.6, 0.8])
    >>> bool(velvet.eval(wo, wi)[0] > Lambert(0.3).eval(wo, wi)[0])  # brighter than its base near grazing
    True
    """

    base: AbstractBSDF
    color: jnp.ndarray
    alpha: jnp.ndarray
    normalize: bool = eqx.field(static=True)

    def __init__(self, base, color, alpha=0.3, normalize=True):
        owner = "Sheen"
        if not isinstance(base, AbstractBSDF):
            raise ParameterError(f"{owner}: base must be a matfit model, got {type(base).__name__}")
        if base.has_delta_lobe or base.transmits:
            raise ParameterError(f"{owner}: base ({type(base).__name__}) must reflect only, without a Dirac lobe")
        check_range(owner, "color", color, 0.0, 1.0)
        check_range(owner, "alpha", alpha, 0.0, 1.0, lo_open=True)
        check_channels(owner, base=base.channels, color=color)
        self.base = base
        self.color = as_channels(color)
        self.alpha = as_param(alpha)
        if not isinstance(normalize, bool):
            raise ParameterError(f"{owner}: normalize must be True or False, got {normalize!r}")
        self.normalize = normalize

    @property
    def channels(self):
        return max(self.base.channels, channel_count(self.color))

    def normalized(self) -> bool:
        """True when the lobe's albedo passes 1 at some cosine (alpha below ~0.06), where it is divided by it."""
        # the bilinear table's maximum over the cosines lies on its nodes
        return bool(np.max(sheen_albedo(_MU_GRID[:, None], np.ravel(np.asarray(self.alpha))[None, :])) > 1)

    def _energy(self, mu_o, mu_i):
        """``max(E(mu_o), E(mu_i))`` per pair (the lobe's normalization and the base's scaling)."""
        return jnp.maximum(sheen_albedo(mu_o, self.alpha), sheen_albedo(mu_i, self.alpha))

    def eval(self, wo, wi):
        check_directions("Sheen.eval", wo=wo, wi=wi)
        pairs = SoAPairs.of(wo, wi)
        ok, mu_o, mu_i = pairs.valid, pairs.cos_o, pairs.cos_i
        # the pairs' cosines are mapped to the normal where a pair is invalid: finite everywhere
        e = self._energy(mu_o, mu_i)
        lobe = _lobe(jnp.where(ok, pairs.h.z, 0.0), mu_o, mu_i, self.alpha, jnp)
        if self.normalize:
            lobe, e = lobe / jnp.maximum(e, 1), jnp.minimum(e, 1)
        scale = 1 - jnp.max(self.color, axis=-1) * e
        # the base reads the pairs derived here (its own kernels, or its eval on rebuilt arrays)
        f = self.color * lobe[..., None] + scale[..., None] * self.base.eval_pairs(pairs)
        return jnp.where(ok[..., None], f, 0)

    def _p_sheen(self, wo):
        q = jnp.mean(self.color, axis=-1) * sheen_albedo(jnp.clip(wo[..., 2], 0, 1), self.alpha)
        return jnp.where(jnp.max(self.color, axis=-1) > 0, jnp.clip(q, 0.05, 0.95), 0.0)

    def pdf(self, wo, wi):
        check_directions("Sheen.pdf", wo=wo, wi=wi)
        p = self._p_sheen(wo)
        return p * cosine_pdf(wo, wi) + (1 - p) * self.base.pdf(wo, wi)

    def sample(self, wo, u):
        check_directions("Sheen.sample", wo=wo)
        check_u("Sheen.sample", u, 3)
        p = self._p_sheen(wo)
        pick = u[..., 0] < p
        u0 = jnp.clip(jnp.where(pick, 0.0, safe_div(u[..., 0] - p, 1 - p)), 0, 1 - 1e-7)
        wi_b, _, _ = self.base.sample(wo, jnp.concatenate([u0[..., None], u[..., 1:3]], axis=-1))
        wi = jnp.where(pick[..., None], cosine_hemisphere(u[..., 1], u[..., 2]), wi_b)
        return self._weighted(wo, wi, above=True)
