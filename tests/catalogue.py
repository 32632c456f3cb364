"""The test catalogue: named model cases and direction sets that the test files cross.

Models
    * materials (gold, copper, an RGB albedo) and the hard parameter values: roughness at and near
      0 and above 1, indices at and near 1 and far from it, conductors that pass everything or
      absorb almost everything;
    * :class:`Lobe` -- a microfacet lobe (distribution, masking form, roughness, sampling), with
      :func:`lobe_params` crossing distributions x maskings x roughnesses for ``parametrize``, and
      the builders :func:`rough_conductor` / :func:`rough_dielectric` of a lobe;
    * :data:`MODEL_CASES` -- named :class:`ModelCase` instances (a builder per dtype and tags:
      ``reflection`` / ``transmission``, ``hard``), selected with :func:`model_params`: Lambert,
      the rough conductor and dielectric for every distribution x masking form (anisotropic), and
      the hard ones (alpha 0, 1e-8 and 2; index-matched, absorbing and mixed conductors; a
      dielectric at eta = 1, 1 + 1e-6 and 0.67, i.e. total internal reflection from outside).

Directions
    * :func:`unit`, :func:`from_degrees`: directions from cos(theta) or theta and phi;
    * hard sets: :data:`Z_REFL` / :data:`Z_DIEL` (grazing, just below the horizon, normal),
      :func:`pairs` (every pair of them, the mirror plane and off it, wo == wi, wo == -wi),
      :func:`sample_inputs` (sampler corners), :data:`SPECIAL_PAIRS` (removable singularities);
    * random sets: :func:`directions` (uniform plus near the normal), :func:`normals` (where a
      lobe has its mass), :func:`conductor_pairs` / :func:`dielectric_pairs` (around the specular
      directions), :func:`random_pairs` (uniform, away from the horizon) and
      :func:`smooth_dielectric_pairs` (away from every kink, for finite differences).

Everything here is test data: the references live in ``numpy_ref`` (never matfit).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable, Optional

import jax.numpy as jnp
import numpy as np
import pytest

import numpy_ref as R

# ------------------------------------------------------------------------------------------------
# Materials and hard parameter values
# ------------------------------------------------------------------------------------------------
GOLD_ETA = (0.143, 0.374, 1.442)
GOLD_K = (3.983, 2.385, 1.603)
CU_ETA = (0.27, 0.68, 1.32)
CU_K = (3.61, 2.63, 2.29)
RGB = (0.8, 0.5, 0.2)  # an albedo with three different channels

DISTRIBUTIONS = ("ggx", "beckmann", "blinn_phong")
MASKINGS = ("separable", "height_correlated")
#: roughnesses (alpha, alpha_y) of the reference agreement: narrow, medium, wide, anisotropic
ROUGHNESSES = ((0.05, None), (0.3, None), (1.0, None), (0.05, 0.3), (1.0, 0.3))

#: roughness at and just above 0 (the rough models must approach the smooth ones)
ALPHA_NEAR_ZERO = (0.0, 1e-8, 1e-4, 1e-3)
#: hard roughnesses: near 0, 1, and 2 (above Blinn-Phong's limit of 1)
ALPHAS_HARD = ALPHA_NEAR_ZERO + (1.0, 2.0)
ALPHAS_HARD_BP = ALPHA_NEAR_ZERO + (1.0,)
#: indices at and near 1 (an index-matched interface passes everything)
ETA_NEAR_ONE = (1.0, 1 + 1e-6, 1 - 1e-6, 1.0001)
#: hard dielectric indices: near 1, far below (total internal reflection from outside) and above
ETAS_HARD = ETA_NEAR_ONE + (0.5, 4.0, 1.5)
#: the dielectric indices of the statistical and reference tests: almost index-matched, glass,
#: high, below 1 (total internal reflection from outside)
DIELECTRIC_ETAS = (1.01, 1.5, 3.0, 0.67)
#: conductors (eta, k): gold, index-matched (F = 0 at normal incidence), almost perfectly absorbing
#: index (F ~ 1), and channels of all three kinds at once
CONDUCTORS_HARD = (
    (GOLD_ETA, GOLD_K),
    ((1.0,) * 3, (0.0,) * 3),
    ((0.2,) * 3, (50.0,) * 3),
    ((1.5, 0.5, 3.0), (0.0, 50.0, 1.0)),
)


def arr(x, dtype=np.float64):
    """``x`` as a jax array of ``dtype``."""
    return jnp.asarray(np.asarray(x, dtype=dtype))


# ------------------------------------------------------------------------------------------------
# Microfacet lobes
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Lobe:
    """A microfacet lobe: distribution, masking form, roughness ``(alpha, alpha_y)`` (None:
    isotropic) and sampling."""

    dist: str = "ggx"
    masking: str = "separable"
    alpha: float = 0.3
    alpha_y: Optional[float] = None
    sampling: str = "visible"

    @property
    def dist_id(self):
        a = f"a{self.alpha:g}" if self.alpha_y is None else f"aniso{self.alpha:g}x{self.alpha_y:g}"
        return f"{self.dist}-{a}"

    @property
    def id(self):
        return f"{self.dist_id}-{self.masking}" + ("" if self.sampling == "visible" else f"-{self.sampling}")

    @property
    def alphas(self):
        """``(alpha_x, alpha_y)`` with alpha_y filled in."""
        return self.alpha, self.alpha if self.alpha_y is None else self.alpha_y

    def ref(self):
        """The numpy reference distribution of the lobe."""
        return R.Dist(self.dist, self.alpha, self.alpha_y)

    def options(self, dtype=np.float64):
        """The keyword arguments of a model with this lobe (alpha_y None stays None)."""
        return dict(distribution=self.dist, masking=self.masking, sampling=self.sampling,
                    alpha_y=None if self.alpha_y is None else arr(self.alpha_y, dtype))


def lobes(dists=DISTRIBUTIONS, maskings=MASKINGS, alphas=((0.3, None),), samplings=("visible",)):
    """Every combination of the arguments, as :class:`Lobe` instances (distribution slowest)."""
    return [Lobe(d, m, a, ay, s) for d in dists for (a, ay) in alphas for m in maskings for s in samplings]


def lobe_params(distribution_only=False, **kw):
    """:func:`lobes` as ``pytest.param`` s with their ids; ``distribution_only``: one masking form
    and ids without it (for tests of the distribution alone)."""
    if distribution_only:
        return [pytest.param(lobe, id=lobe.dist_id) for lobe in lobes(maskings=MASKINGS[:1], **kw)]
    return [pytest.param(lobe, id=lobe.id) for lobe in lobes(**kw)]


def rough_conductor(lobe, eta=GOLD_ETA, k=GOLD_K, dtype=np.float64):
    from matfit.models import RoughConductor

    return RoughConductor(arr(lobe.alpha, dtype), arr(eta, dtype), arr(k, dtype), **lobe.options(dtype))


def rough_dielectric(lobe, eta=1.5, dtype=np.float64):
    from matfit.models import RoughDielectric

    return RoughDielectric(arr(lobe.alpha, dtype), arr(eta, dtype), **lobe.options(dtype))


# ------------------------------------------------------------------------------------------------
# Named model cases
# ------------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class ModelCase:
    """A named model: ``build(dtype)`` returns it with every parameter an array of ``dtype``."""

    id: str
    build: Callable = field(compare=False)
    tags: frozenset = frozenset()

    def param(self):
        return pytest.param(self, id=self.id)


def _lambert(dt):
    from matfit.models import Lambert

    return Lambert(arr(RGB, dt))


def _conductor_case(lobe, eta=GOLD_ETA, k=GOLD_K, tag=None, name=None):
    tags = {"reflection"} | ({tag} if tag else set())
    return ModelCase(name or f"conductor-{lobe.id}", lambda dt: rough_conductor(lobe, eta, k, dt), frozenset(tags))


def _dielectric_case(lobe, eta, tag=None, name=None):
    tags = {"transmission"} | ({tag} if tag else set())
    return ModelCase(name or f"dielectric-{lobe.id}-eta{eta:.7g}", lambda dt: rough_dielectric(lobe, eta, dt),
                     frozenset(tags))


def _model_cases():
    aniso = ((0.3, 0.2),)
    cases = [ModelCase("lambert", _lambert, frozenset({"reflection"}))]
    cases += [_conductor_case(lobe) for lobe in lobes(alphas=aniso)]
    cases += [_dielectric_case(lobe, 1.5) for lobe in lobes(alphas=aniso)]
    # hard cases: roughness at and near 0 and wide, index at and near 1, TIR, extreme conductors
    cases += [_conductor_case(Lobe(alpha=a), tag="hard") for a in (0.0, 1e-8, 2.0)]
    cases += [_conductor_case(Lobe(alpha=0.3), eta, k, "hard", f"conductor-{name}")
              for (eta, k), name in zip(CONDUCTORS_HARD[1:], ("index-matched", "k50", "mixed"))]
    cases += [_dielectric_case(Lobe(alpha=0.3), eta, "hard") for eta in (1.0, 1 + 1e-6, 0.67)]
    cases += [_dielectric_case(Lobe(alpha=a), 1.5, "hard") for a in (0.0, 1e-8)]
    return cases


MODEL_CASES = _model_cases()
assert len({c.id for c in MODEL_CASES}) == len(MODEL_CASES)


def model_params(*tags, exclude=()):
    """``pytest.param`` s of the cases that have every tag in ``tags`` and none in ``exclude``."""
    return [c.param() for c in MODEL_CASES if set(tags) <= c.tags and not (set(exclude) & c.tags)]


# ------------------------------------------------------------------------------------------------
# Directions: structured (hard) sets
# ------------------------------------------------------------------------------------------------
#: cos(theta) of hard directions for reflection models: on, just above and just below the
#: horizon, near grazing, midway, normal, and below
Z_REFL = (0.0, 1e-7, -1e-7, 1e-4, 0.5, 1.0, -0.5)
#: the same for two-sided models: both hemispheres
Z_DIEL = (0.0, 1e-7, -1e-7, 1e-4, -1e-4, 0.5, -0.5, 0.9, -0.9, 1.0, -1.0)
#: sampler inputs: every corner of [0, 1)^3 (the largest float32 below 1) and a few inside
ONE_M = 1.0 - 2.0**-24
U_CORNERS = tuple((a, b, c) for a in (0.0, ONE_M) for b in (0.0, ONE_M) for c in (0.0, ONE_M))
U_EXTRA = ((0.5, 0.5, 0.5), (0.3, 0.7, 0.1), (0.9, 0.2, 0.6), (0.02, 0.98, 0.4))

#: direction pairs where the value is 0 or a formula has a removable singularity
SPECIAL_PAIRS = (
    ((0, 0, 1), (0, 0, 1)),  # normal incidence, h = n (Blinn-Phong's phi is undefined there)
    ((0.6, 0, 0.8), (-0.6, 0, 0.8)),  # mirror configuration, h = n
    ((0.6, 0, 0.8), (0.0, 0.6, -0.8)),  # one direction below the surface
    ((0, 0, 1), (0, 0, -1)),  # straight through
    ((0, 0, -1), (0, 0, -1)),  # inside, normal
    ((0.8, 0, -0.6), (-0.8, 0, -0.6)),  # inside mirror configuration (TIR at eta = 1.5)
    ((1.0, 0, 0.0), (0.0, 0, 1.0)),  # grazing wo
)


def unit(z, phi):
    """Unit vectors of cos(theta) ``z`` and azimuth ``phi`` (broadcast)."""
    z = np.asarray(z, np.float64)
    s = np.sqrt(np.maximum(0.0, 1 - z * z))
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], -1)


def from_degrees(deg, phi=0.0, inside=False):
    """Unit vectors at ``deg`` degrees from the normal (broadcast), azimuth ``phi``; mirrored
    through the origin (pointing into the lower hemisphere) when ``inside``."""
    th = np.radians(np.asarray(deg, np.float64))
    w = np.stack(np.broadcast_arrays(np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.cos(th)), -1)
    return -w if inside else w


def pairs(zs):
    """Direction pairs: every (z_o, z_i) with wi at azimuth pi (plane of incidence, mirror) and
    pi/3, plus wo = wi and wo = -wi for every z_o."""
    wo, wi = [], []
    for zo in zs:
        for zi in zs:
            for phi in (np.pi, np.pi / 3):
                wo.append(unit(zo, 0.0))
                wi.append(unit(zi, phi))
        a = unit(zo, 0.3)
        wo += [a, a]
        wi += [a, -a]
    return np.array(wo), np.array(wi)


def sample_inputs(zs, us=U_CORNERS + U_EXTRA):
    """(wo, u): every outgoing direction of cos(theta) in ``zs`` (azimuth 0.2) with every u."""
    wo, u = [], []
    for zo in zs:
        for uu in us:
            wo.append(unit(zo, 0.2))
            u.append(uu)
    return np.array(wo), np.array(u)


def special_pairs():
    """:data:`SPECIAL_PAIRS` as two (n, 3) float64 arrays."""
    return tuple(np.array([p[i] for p in SPECIAL_PAIRS], np.float64) for i in (0, 1))


# ------------------------------------------------------------------------------------------------
# Directions: random sets
# ------------------------------------------------------------------------------------------------
def directions(rng, n, hemisphere="both", min_abs_cos=0.02):
    """n directions: uniform ones (|cos| >= min_abs_cos) and 20 close to the normal (small
    Lambda), the normal itself among them; in ``hemisphere`` ("upper", "lower", "both")."""
    v = R.random_directions(rng, n - 20, hemisphere, min_abs_cos)
    w = R.random_normals_near_z(rng, 20, 0.02, 0.02)
    w[0] = [0, 0, 1]
    if hemisphere == "lower":
        w[:, 2] *= -1
    elif hemisphere == "both":
        w[10:, 2] *= -1
    return np.concatenate([v, w])


def normals(rng, ax, ay, n):
    """Microfacet normals: half concentrated where D has its mass, the rest uniform + 10 below,
    the normal first."""
    k = n // 2
    m = np.concatenate([
        R.random_normals_near_z(rng, k, ax, ay if ay is not None else ax),
        R.random_directions(rng, n - k - 10, "upper"),
        R.random_directions(rng, 10, "lower"),
    ])
    m[0] = [0.0, 0.0, 1.0]
    return m


def conductor_pairs(rng, n, ax, ay=None):
    """Reflection pairs: a third with wi close to the mirror direction of wo (spread by a lobe of
    roughness (ax, ay)), the rest uniform, and 12 with one direction below the horizon."""
    wo = directions(rng, n, "upper")
    wi = directions(rng, n, "upper")
    wi[-12:-6, 2] *= -1
    wo[-6:, 2] *= -1
    k = n // 3
    jitter = R.random_normals_near_z(rng, k, ax, ax if ay is None else ay, spread=1.5)
    mirror = wo[:k] * np.array([-1, -1, 1])
    wi[:k] = mirror + 2 * (jitter - [0, 0, 1])
    wi[:k, 2] = np.abs(wi[:k, 2]) + 0.02
    wi[:k] /= np.linalg.norm(wi[:k], axis=-1, keepdims=True)
    return wo, wi


def dielectric_pairs(rng, n, eta, ax=0.3, ay=None):
    """wo from both sides; wi: reflections and refractions of wo about microfacet normals near the
    lobe's peak (a third each) and uniform directions, all with |cos| >= 0.02."""
    wo = directions(rng, n, "both")
    n1 = n // 3
    wi_rand = R.random_directions(rng, n - 2 * n1, "both", 0.02)
    m = R.random_normals_near_z(rng, 2 * n1, ax, ax if ay is None else ay, spread=2.0)
    w = wo[: 2 * n1]
    c = np.sum(w * m, axis=-1)
    refl = 2 * c[:, None] * m - w
    inside = c < 0
    e = np.where(inside, 1 / eta, eta)  # index ratio (other side / wo side), pbrt-v4 convention
    mm = np.where(inside[:, None], -m, m)
    ca = np.abs(c)
    s2 = np.maximum(0, 1 - ca**2) / e**2
    ok = s2 < 1
    ct = np.sqrt(np.maximum(0, 1 - s2))
    refr = -w / e[:, None] + (ca / e - ct)[:, None] * mm
    refr = np.where(ok[:, None], refr, refl)
    wi = np.concatenate([refl[:n1], refr[n1:], wi_rand])
    wi /= np.linalg.norm(wi, axis=-1, keepdims=True)
    bad = np.abs(wi[:, 2]) < 0.02
    wi[bad] = R.random_directions(rng, int(bad.sum()), "both", 0.02)
    return wo, wi


def sin2_transmitted(wo, wi, eta):
    """``(sin^2 theta_t at wo.m, the generalized half vector m)`` of each pair: 1 at the critical
    angle (seen from the side of wo)."""
    m, _ = R.generalized_half_vector(wo, wi, eta)
    c = np.sum(wo * m, axis=-1)
    e = np.where(c < 0, 1 / eta, eta)
    return (1 - c**2) / e**2, m


def random_pairs(rng, n, min_cos=0.15, hemisphere="upper"):
    """Uniform pairs in ``hemisphere`` with |cos| >= min_cos (the default keeps away from the
    horizon, where reflection models are discontinuous)."""
    return R.random_directions(rng, n, hemisphere, min_cos), R.random_directions(rng, n, hemisphere, min_cos)


def smooth_dielectric_pairs(rng, eta, dist, n=40):
    """Pairs whose generalized half vector is well inside the valid region and away from the
    critical angle (where F has a square-root kink and 1 - F a corner), half reflections and half
    refractions; ``dist`` the reference distribution (the value must not vanish)."""
    wo, wi = random_pairs(rng, 25 * n, 0.15, "both")
    co, ci = wo[:, 2], wi[:, 2]
    m, hn = R.generalized_half_vector(wo, wi, eta)
    wom, wim = np.sum(wo * m, -1), np.sum(wi * m, -1)
    e = np.where(wom < 0, 1 / eta, eta)
    s2t = (1 - wom**2) / e**2
    f = R.dielectric_eval(wo, wi, dist, eta)[:, 0]
    ok = (hn > 0.2) & (wom * co > 0.1) & (wim * ci > 0.1) & (np.abs(s2t - 1) > 0.05) & (f > 1e-8)
    ok &= m[:, 2] > 0.15
    wo, wi = wo[ok], wi[ok]
    refl = wo[:, 2] * wi[:, 2] > 0
    k = min(n // 2, int(refl.sum()), int((~refl).sum()))
    assert k >= 8
    return np.concatenate([wo[refl][:k], wo[~refl][:k]]), np.concatenate([wi[refl][:k], wi[~refl][:k]])


# ------------------------------------------------------------------------------------------------
# Finite differences
# ------------------------------------------------------------------------------------------------
def check_leaf_gradients(loss, grads, params, rtol, h=1e-6):
    """Compare ``grads`` (the gradient pytree of ``loss`` at ``params``) with central finite
    differences of ``loss``, every element of every leaf (step ``h`` relative, at least absolute);
    returns the number of elements checked. Fails naming the leaf, the element and both values."""
    import jax

    leaves, tree = jax.tree_util.tree_flatten(params)
    checked = 0
    for i, (leaf, g) in enumerate(zip(leaves, jax.tree_util.tree_leaves(grads))):
        for idx in np.ndindex(leaf.shape):
            step = h * max(1.0, abs(float(leaf[idx])))

            def at(d, i=i, idx=idx, leaf=leaf):
                new = list(leaves)
                new[i] = leaf.at[idx].add(d)
                return float(loss(jax.tree_util.tree_unflatten(tree, new)))

            fd = (at(step) - at(-step)) / (2 * step)
            assert abs(float(g[idx]) - fd) <= rtol * max(1.0, abs(fd)), (i, idx, float(g[idx]), fd)
            checked += 1
    return checked


def check_float32_eval_pdf_finite(model, wo, wi):
    """``model.eval`` (float32) and ``pdf`` at the float32 pairs ``wo``, ``wi`` and their gradients
    in every parameter of the model are finite."""
    import equinox as eqx
    import jax

    assert model.eval(wo, wi).dtype == jnp.float32
    params, static = eqx.partition(model, eqx.is_inexact_array)
    for fn in (lambda p: eqx.combine(p, static).eval(wo, wi).sum(), lambda p: eqx.combine(p, static).pdf(wo, wi).sum()):
        value, grads = jax.jit(jax.value_and_grad(fn))(params)
        assert np.isfinite(float(value))
        for leaf in jax.tree_util.tree_leaves(grads):
            assert np.all(np.isfinite(np.asarray(leaf)))
