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

Structures
    * :class:`Structure` -- one model structure of the hard-case matrix (tests/test_hard_cases.py):
      a class of :data:`matfit.models.MODELS` with its static options fixed, parameter cases that
      differ only in array values (the hard ones among them: weights 0 and 1, roughness at and near
      0 and wide, indices at and near 1, thin films of thickness 0, extreme conductors, black and
      white albedos), a builder per dtype, the hard direction set, tags, and what the property
      checks expect of each case (reciprocity, an energy bound, lobes the quadrature resolves);
    * :data:`STRUCTURES` -- every structure by name, at least one per entry of ``MODELS``
      (tests/test_catalogue.py checks that).

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


#: ``compiler_options`` of a test's own jitted programs that run once or a few times: XLA's CPU
#: compilation dominates such tests, and optimization level 0 compiles ~35 % faster (never for the
#: library's programs, whose speed or fusion a test may check).
FAST_COMPILE = {"xla_backend_optimization_level": 0}


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


# ------------------------------------------------------------------------------------------------
# Model structures: the hard-case matrix (tests/test_hard_cases.py)
# ------------------------------------------------------------------------------------------------
#: tags of a :class:`Structure`
REFLECTION = "reflection"  # reflection only: zero at and below the horizon
TRANSMISSION = "transmission"  # two-sided (transmits)
DELTA = "delta"  # Dirac lobes only: eval and pdf zero everywhere
DELTA_LOBE = "delta_lobe"  # a Dirac lobe at the mirror direction beside continuous lobes
STOCHASTIC = "stochastic"  # a Monte Carlo estimate of eval, no pdf or sampler
TABLE = "table"  # a measured table (one jitted call per case, not vmapped: see the structure)
MIRROR_SINGULAR = "mirror_singular"  # a density singular at the mirror direction (see the structure)


def _always(case):
    return True


@dataclass(frozen=True)
class Structure:
    """One model structure of the hard-case matrix: a class of :data:`matfit.models.MODELS` with
    its static options (distribution, masking, Fresnel kind, kind of coat and base, ...) fixed,
    and parameter ``cases`` that differ only in array values, so that tests/test_hard_cases.py
    stacks them into one batched module and compiles once per (structure, dtype).

    name : the id in test names.
    model : the name of the entry of ``matfit.models.MODELS`` it builds (the factory's name for
        CoatedConductor).
    cases : parameter cases, any values that name a failing case when printed.
    build : ``build(dtype, case)``, the model with every parameter an array of ``dtype``.
    zs : cos(theta) of the hard direction pairs (:data:`Z_REFL` or :data:`Z_DIEL`).
    tags : :data:`REFLECTION` or :data:`TRANSMISSION`, and :data:`DELTA`, :data:`DELTA_LOBE`,
        :data:`STOCHASTIC`, :data:`TABLE`, :data:`MIRROR_SINGULAR` where they apply.
    batched : vmapped over the stacked cases; False: one jitted call per case (equal shapes: one
        compilation), for models that cannot be stacked (the reason at the structure).
    reciprocal : ``reciprocal(case)``: whether ``f(wo, wi) == f(wi, wo)`` holds; None for a model
        that is not reciprocal (the reason at the structure).
    energy_bound : ``energy_bound(case)``: the bound of the directional albedo, a number or one per
        channel (1 for an energy-conserving model; a documented larger bound), or None where the
        model (or its data) bounds nothing (the reason at the structure).
    resolved : ``resolved(case)``: whether the fixed quadrature of the energy and pdf checks
        resolves the case's lobes (roughly alpha >= 0.3); the narrow ones are checked by Monte
        Carlo only. Every structure with a sampler has a resolved case, its representative
        parameter set for the pdf's integral, but MeasuredRGL's (the reason at the structure).
    weight_bound : ``weight_bound(case)``: the bound of a sample's weight at the hard sampler
        inputs (1e3; larger where the model's sampler is documented here to allow it).
    """

    name: str
    model: str
    cases: tuple = field(repr=False)
    build: Callable = field(compare=False, repr=False)
    zs: tuple = field(repr=False)
    tags: frozenset = frozenset()
    batched: bool = True
    reciprocal: Optional[Callable] = field(default=_always, compare=False, repr=False)
    energy_bound: Optional[Callable] = field(default=lambda case: 1.0, compare=False, repr=False)
    resolved: Callable = field(default=_always, compare=False, repr=False)
    weight_bound: Callable = field(default=lambda case: 1e3, compare=False, repr=False)


def _cast(model, dt):
    """``model`` with every floating array leaf in ``dt`` (a parameter given as a Python number is
    stored in the default float type)."""
    import equinox as eqx
    import jax

    return jax.tree_util.tree_map(lambda x: x.astype(dt) if eqx.is_inexact_array(x) else x, model)


def _a(x, dt):
    return np.asarray(x, dt)


def _rgb(x, dt):
    """``x`` (a number or three) as three channels of ``dt`` (the cases of one structure stack)."""
    return np.broadcast_to(np.asarray(x, dt), (3,)).copy()


WHITE, BLACK, RAMP = (1.0,) * 3, (0.0,) * 3, (0.0, 0.5, 1.0)
#: a conductor per row: gold, index-matched (passes everything), absorbing (F ~ 1)
COND3 = (CONDUCTORS_HARD[0], CONDUCTORS_HARD[1], CONDUCTORS_HARD[2])


# --- the structures of the analytic single-lobe models -------------------------------------------
def _lambert_structure():
    def build(dt, p):
        from matfit.models import Lambert

        return Lambert(_a(p, dt))

    return Structure("lambert", "Lambert", (BLACK, WHITE, RAMP), build, Z_REFL, frozenset({REFLECTION}))


def _alpha_min(a, ay):
    return min(a, a if ay is None else ay)


def _rough_conductor_structure(dist):
    # alpha_y is always an array (isotropic cases pass alpha_y = alpha), so the isotropic and
    # anisotropic cases share one compiled function; the alpha_y=None path is exercised by the
    # property tests of tests/test_hard_cases.py.
    def build(dt, p):
        from matfit.models import RoughConductor

        (a, ay), (eta, k) = p
        return RoughConductor(dt(a), _a(eta, dt), _a(k, dt), distribution=dist, alpha_y=dt(a if ay is None else ay))

    al = [(a, None) for a in (ALPHAS_HARD_BP if dist == "blinn_phong" else ALPHAS_HARD)]
    al += [(0.0, 0.5), (0.5, 0.0)] + ([(1e-8, 2.0)] if dist != "blinn_phong" else [(1e-8, 1.0)])
    cases = tuple((a, c) for a in al for c in CONDUCTORS_HARD)

    def energy_bound(p):
        (a, ay) = p[0]
        # Documented limitation (docs/models.md, "Blinn-Phong energy", tests/test_sampling.py):
        # Beckmann's Lambda standing in for Blinn-Phong's own under-masks at grazing incidence for
        # alpha > 0.3; with F = 1 the albedo reaches 1.31 at alpha = 1.
        return 1.35 if dist == "blinn_phong" and max(a, a if ay is None else ay) > 0.3 else 1.0

    return Structure(f"rough_conductor_{dist}", "RoughConductor", cases, build, Z_REFL, frozenset({REFLECTION}),
                     energy_bound=energy_bound, resolved=lambda p: _alpha_min(*p[0]) >= 0.3)


def _rough_dielectric_structure(dist):
    def build(dt, p):
        from matfit.models import RoughDielectric

        (a, ay), eta = p
        return RoughDielectric(dt(a), dt(eta), distribution=dist, alpha_y=dt(a if ay is None else ay))

    al = [(a, None) for a in ALPHAS_HARD] + [(0.0, 0.5), (0.5, 0.0)]
    # Not reciprocal: the radiance BTDF obeys the generalized reciprocity f_t(wo, wi) / eta_o^2 ==
    # f_t(wi, wo) / eta_i^2 (tests/test_reciprocity_gradients.py), not symmetry.
    # Near eta = 1 the transmitted lobe collapses onto -wo whatever the roughness: unresolved.
    return Structure(f"rough_dielectric_{dist}", "RoughDielectric", tuple((a, e) for a in al for e in ETAS_HARD), build,
                     Z_DIEL, frozenset({TRANSMISSION}), reciprocal=None,
                     resolved=lambda p: _alpha_min(*p[0]) >= 0.3 and abs(p[1] - 1) >= 0.05)


def _smooth_conductor_structure():
    def build(dt, p):
        from matfit.models import SmoothConductor

        return SmoothConductor(_a(p[0], dt), _a(p[1], dt))

    return Structure("smooth_conductor", "SmoothConductor", CONDUCTORS_HARD, build, Z_REFL,
                     frozenset({REFLECTION, DELTA}))


def _smooth_dielectric_structure():
    def build(dt, p):
        from matfit.models import SmoothDielectric

        return SmoothDielectric(dt(p))

    # eval is zero everywhere (Dirac lobes only): reciprocity holds trivially, but the model's
    # transmission obeys the generalized form (as RoughDielectric's)
    return Structure("smooth_dielectric", "SmoothDielectric", ETAS_HARD, build, Z_DIEL,
                     frozenset({TRANSMISSION, DELTA}), reciprocal=None)


def _plastic_structure(rough):
    def build(dt, p):
        from matfit.models import Plastic

        alb, a, eta = p
        return Plastic(_a(alb, dt), dt(a), dt(eta))

    alphas = [1e-8, 1e-4, 1e-3, 1.0, 2.0] if rough else [0.0]
    albs = [BLACK, WHITE, RAMP]
    etas = [1.0, 1.0001, 1.5, 4.0] if rough else [1.0, 1 + 1e-6, 1.0001, 1.5, 0.5, 4.0]
    cases = tuple((alb, a, e) for alb in albs for a in alphas for e in etas)
    return Structure(f"plastic_{'rough' if rough else 'smooth'}", "Plastic", cases, build, Z_REFL,
                     frozenset({REFLECTION} | (set() if rough else {DELTA_LOBE})),
                     resolved=lambda p: (p[1] >= 0.3 or not rough) and p[2] >= 1)


def _coated_structure():
    def build(dt, p):
        from matfit.models import CoatedConductor

        ab, (eta, k), ac, d = p
        return CoatedConductor(dt(ab), _a(eta, dt), _a(k, dt), alpha_coat=dt(ac), eta_coat=dt(1.5), thickness=dt(d),
                               sigma_a=_a(RAMP, dt))

    cases = tuple((ab, c, ac, d) for ab in (0.0, 1e-4, 0.3, 2.0) for c in COND3 for ac in (1e-8, 0.2, 1.0)
                  for d in (0.0, 100.0))
    return Structure("coated_conductor_rough_coat", "CoatedConductor", cases, build, Z_REFL, frozenset({REFLECTION}),
                     resolved=lambda p: p[0] >= 0.3 and p[2] >= 0.3)


def _coat_resolved(p):
    # a coat of index below 1 cuts the diffuse part off at its critical angle: 16 nodes put the
    # albedo of a white Plastic at eta = 0.5 at 1.10 (1.0000 with 1024)
    return p[0] >= 1


# --- composites, layers and the other analytic models ---------------------------------------------
def _layered_structure():
    # a smooth coat (a Dirac lobe) over a Lambertian base, with and without absorption; the rough
    # coat over a rough conductor is the CoatedConductor structure
    def build(dt, p):
        from matfit.models import Lambert, Layered, SmoothDielectric

        eta, alb, (d, sigma) = p
        return Layered(SmoothDielectric(dt(eta)), Lambert(_a(alb, dt)), thickness=dt(d), sigma_a=_a(sigma, dt))

    cases = tuple((eta, alb, ds) for eta in (1.0, 1 + 1e-6, 1.5, 4.0, 0.67) for alb in (BLACK, WHITE, RAMP)
                  for ds in ((0.0, BLACK), (100.0, RAMP)))
    return Structure("layered_smooth_coat_lambert", "Layered", cases, build, Z_REFL,
                     frozenset({REFLECTION, DELTA_LOBE}), resolved=_coat_resolved)


def _blend_structure():
    def build(dt, p):
        from matfit.models import Blend, Lambert, RoughConductor

        w, a, (eta, k) = p
        return Blend(Lambert(_a(RGB, dt)), RoughConductor(dt(a), _a(eta, dt), _a(k, dt)), dt(w))

    cases = tuple((w, a, c) for w in (0.0, 0.5, 1.0) for a in (0.0, 1e-4, 0.5, 2.0) for c in COND3)
    return Structure("blend_lambert_conductor", "Blend", cases, build, Z_REFL, frozenset({REFLECTION}),
                     resolved=lambda p: p[1] >= 0.3)


def _rotated_structure():
    # an anisotropic GGX conductor turned about the normal: the hard widths (0 along one axis, a
    # spike against a wide lobe) at angles 0, a quarter turn, a half turn (the same lobe) and
    # one far outside [-pi, pi]
    def build(dt, p):
        from matfit.models import Rotated, RoughConductor

        (a, ay), (eta, k), phi = p
        return Rotated(RoughConductor(dt(a), _a(eta, dt), _a(k, dt), alpha_y=dt(ay)), dt(phi))

    al = [(0.05, 0.4), (0.0, 0.5), (1e-8, 2.0), (0.5, 0.5)]
    cases = tuple((a, c, phi) for a in al for c in COND3 for phi in (0.0, 0.7, np.pi / 2, np.pi, -40.0))
    return Structure("rotated_anisotropic_conductor", "Rotated", cases, build, Z_REFL, frozenset({REFLECTION}),
                     resolved=lambda p: _alpha_min(*p[0]) >= 0.3)


def _stochastic_layered_structure():
    # StochasticLayered is an evaluation reference: a Monte Carlo estimate of eval by random walks
    # (a fixed key: deterministic, so the cases still stack and vmap), without pdf or sampler
    # (both raise, tests/test_stochastic_layered.py): it has its own runner in test_hard_cases.py
    # (eval, its standard error and the walks' albedo), and no sampling checks. A smooth coat: the
    # gradient through a rough coat's walk (its MIS connection, in a scan) takes ~45 s to compile
    # per dtype, against ~5 s. Few walks and bounces keep it cheap.
    def build(dt, p):
        from matfit.models import Lambert, SmoothDielectric, StochasticLayered

        eta, alb, (d, sigma) = p
        return StochasticLayered(SmoothDielectric(dt(eta)), Lambert(_a(alb, dt)), thickness=dt(d),
                                 sigma_a=_a(sigma, dt), n_samples=64, max_depth=4)

    cases = tuple((eta, alb, ds) for eta in (1.0, 1 + 1e-6, 1.5, 4.0, 0.67) for alb in (BLACK, WHITE, RAMP)
                  for ds in ((0.0, BLACK), (100.0, RAMP)))
    # Reciprocal only in expectation: f(wo, wi) and f(wi, wo) are estimated by different walks
    # (the test compares them within their standard errors).
    return Structure("stochastic_layered_smooth_coat", "StochasticLayered", cases, build, Z_REFL,
                     frozenset({REFLECTION, STOCHASTIC, DELTA_LOBE}))


def _gltf_structure():
    # With the film (has_film: a static choice made when iridescence is given as anything but the
    # number 0) in every case, iridescence 0 among them: the film's path computes everything the
    # path without it does, and the film's hard values (thickness 0, film index 1) with it; likewise
    # the anisotropic lobe (has_anisotropy), strength 0 among the cases.
    def build(dt, p):
        from matfit.models import GltfPBR

        base, metal, alpha, ior, spec, cc, cca, (w, ieta, d), (an, rot) = p
        return _cast(GltfPBR(_a(base, dt), metallic=_a(metal, dt), alpha=_a(alpha, dt), ior=_a(ior, dt),
                             specular=_a(spec[0], dt), specular_color=_a(spec[1], dt), clearcoat=_a(cc, dt),
                             clearcoat_alpha=_a(cca, dt), iridescence=_a(w, dt), iridescence_ior=_a(ieta, dt),
                             iridescence_thickness=_a(d, dt), anisotropy=_a(an, dt), anisotropy_rotation=_a(rot, dt)),
                     dt)

    base = (RGB, 0.5, 0.25, 1.5, (1.0, WHITE), 0.0, 0.01, (0.0, 1.3, 400.0), (0.0, 0.0))

    def vary(**kw):
        keys = ("base", "metal", "alpha", "ior", "spec", "cc", "cca", "irid", "aniso")
        return tuple(kw.get(k, v) for k, v in zip(keys, base))

    cases = [vary(base=b, metal=m) for b in (BLACK, WHITE, RAMP) for m in (0.0, 1.0)]
    cases += [vary(alpha=a, metal=m) for a in (1e-8, 1e-4, 1.0, 2.0) for m in (0.0, 1.0)]
    cases += [vary(ior=e) for e in (1.0, 1 + 1e-6, 0.5, 4.0)]
    cases += [vary(spec=s) for s in ((0.0, WHITE), (1.0, BLACK), (1.0, (0.0, 1.0, 4.0)))]
    cases += [vary(cc=1.0, cca=a, metal=m) for a in (1e-8, 0.01, 1.0) for m in (0.0, 1.0)]
    cases += [vary(base=WHITE, metal=0.0, alpha=1.0, cc=1.0, cca=1.0)]
    cases += [vary(irid=(w, e, d)) for w in (0.5, 1.0) for e, d in ((1.3, 0.0), (1.0, 400.0), (2.0, 1000.0),
                                                                   (2.0, 250.0))]
    cases += [vary(irid=(1.0, 1.8, 300.0), ior=e, alpha=a) for e in (1.0, 4.0) for a in (1e-8, 1.0)]
    cases += [vary(aniso=(an, r), alpha=a, metal=m) for an in (0.5, 1.0) for r in (0.0, 2.0, -40.0)
              for a, m in ((1e-8, 1.0), (0.3, 0.0))]
    # Not reciprocal with a clear coat: the coat's Fresnel reads the viewing angle (cos theta_o), as
    # KHR_materials_clearcoat specifies; without one, every Fresnel term reads |wo.h| = |wi.h|.
    return Structure("gltf_pbr", "GltfPBR", tuple(cases), build, Z_REFL, frozenset({REFLECTION}),
                     reciprocal=lambda p: p[5] == 0, resolved=lambda p: min(p[2], p[6] if p[5] > 0 else 1.0) >= 0.3)


def _diffuse_specular_structure():
    def build(dt, p):
        from matfit.models import DiffuseSpecular

        alb, f0, (a, ay) = p
        return DiffuseSpecular(_rgb(alb, dt), _rgb(f0, dt), dt(a), alpha_y=dt(a if ay is None else ay))

    pairs = ((BLACK, 0.0), (WHITE, 1.0), (RGB, 0.04), (BLACK, 1.0), (WHITE, 0.0), (0.5, 0.04))
    al = [(a, None) for a in ALPHAS_HARD] + [(0.0, 0.5), (1e-8, 2.0)]
    cases = tuple((alb, f0, a) for alb, f0 in pairs for a in al)

    def energy_bound(p):
        # Documented (DiffuseSpecular's docstring, tests/test_diffuse_specular.py): the diffuse
        # term and the lobe are added, not coupled, so the albedo is at most albedo + the lobe's
        # (<= 1: F <= 1), and reaches past 1 towards grazing even at albedo + f0 = 1. 1 bounds it
        # when there is no diffuse term, or a small lobe (f0 = 0.04) over at most 0.8.
        alb = np.asarray(p[0], np.float64)
        return 1.0 if alb.max() == 0 or (p[1] <= 0.04 and alb.max() <= 0.8) else alb + 1.0

    return Structure("diffuse_specular", "DiffuseSpecular", cases, build, Z_REFL, frozenset({REFLECTION}),
                     energy_bound=energy_bound, resolved=lambda p: _alpha_min(*p[2]) >= 0.3)


def _tabulated_ndfs():
    """name -> D(theta) of the tabulated distributions (numpy): GGX and Beckmann of several widths,
    a ring (D = 0 at the normal) and a spike on a wide base."""
    def ggx(a):
        return lambda t: 1 / (np.pi * a * a * np.cos(t) ** 4 * (1 + np.tan(t) ** 2 / (a * a)) ** 2)

    def beckmann(a):
        return lambda t: np.exp(-np.tan(t) ** 2 / (a * a)) / (np.pi * a * a * np.cos(t) ** 4)

    return {"ggx0.01": ggx(0.01), "ggx0.3": ggx(0.3), "ggx1": ggx(1.0), "beckmann0.3": beckmann(0.3),
            "ring": lambda t: np.sin(t) ** 4, "spike": lambda t: 1.0 + 1e4 * np.exp(-(t / 0.02) ** 2)}


def _tabulated_structure():
    def build(dt, p):
        from matfit.microfacet import TabulatedNDF
        from matfit.models import TabulatedMicrofacet

        ndf, (eta, k) = p
        fn = _tabulated_ndfs()[ndf]
        with np.errstate(all="ignore"):
            table = TabulatedNDF.from_function(lambda t: np.nan_to_num(fn(np.minimum(t, np.pi / 2 - 1e-6))), n=64,
                                               n_lambda=64, dtype=dt)
        return TabulatedMicrofacet(table, _a(eta, dt), _a(k, dt))

    cases = tuple((n, c) for n in _tabulated_ndfs() for c in CONDUCTORS_HARD)
    # Sampled from D cos (a table has no visible-normal sampler): a sample's weight is
    # G2 F (wo.h) / (cos theta_o cos theta_h), ~8e3 at cos theta_o = 1e-4 for a half vector in the
    # tail of a narrow lobe (alpha = 0.01, u = (0, 1, 0)).
    return Structure("tabulated_microfacet", "TabulatedMicrofacet", cases, build, Z_REFL, frozenset({REFLECTION}),
                     resolved=lambda p: p[0] in ("ggx0.3", "ggx1", "beckmann0.3", "ring"),
                     weight_bound=lambda p: 1e4)


def _multi_lobe_structure():
    # two lobes: a GGX lobe with Schlick's Fresnel and a Beckmann lobe (height-correlated masking)
    # with a conductor's, their widths, weights and Fresnel parameters at the hard values; the
    # dielectric and thin-film Fresnel kinds are the specular_lobe structure's and
    # tests/test_multi_lobe.py's (each lobe is a copy of its graph to compile)
    def build(dt, p):
        from matfit.models import MultiLobe, SpecularLobe

        alb, (a1, w1, f0), (a2, w2, (ce, ck)) = p
        lobes = [SpecularLobe(dt(a1), "schlick", _rgb(w1, dt), f0=_rgb(f0, dt), alpha_y=dt(a1)),
                 SpecularLobe(dt(a2), "conductor", _rgb(w2, dt), eta=_rgb(ce, dt), k=_rgb(ck, dt),
                              distribution="beckmann", masking="height_correlated", alpha_y=dt(a2))]
        return MultiLobe(_rgb(alb, dt), lobes)

    gold = CONDUCTORS_HARD[0]
    cases = [(RGB, (0.08, 0.9, 0.04), (0.3, (0.02, 0.03, 0.05), gold))]
    cases += [(alb, *cases[0][1:]) for alb in (BLACK, WHITE)]
    cases += [(BLACK, (a, 1.0, f0), (0.3, 0.0, gold)) for a in ALPHAS_HARD for f0 in (0.0, 1.0)]
    cases += [(BLACK, (0.3, 0.0, 0.04), (a, 1.0, c)) for a in ALPHAS_HARD for c in CONDUCTORS_HARD]
    cases += [(RGB, (0.3, 0.5, 0.04), (a, 0.5, gold)) for a in (0.0, 0.5)]
    cases += [(WHITE, (0.3, 0.0, 0.04), (0.3, 0.0, gold))]  # every lobe weight 0

    def energy_bound(p):
        # Documented (MultiLobe's docstring): the terms are added, so the albedo is at most
        # albedo + the sum of the weights per channel (1 when that sum is)
        alb, (_, w1, _), (_, w2, _) = p
        return np.asarray(alb, np.float64) + w1 + np.asarray(w2, np.float64)

    def resolved(p):
        return all(a >= 0.3 or np.max(w) == 0 for a, w, _ in p[1:])

    return Structure("multi_lobe", "MultiLobe", tuple(cases), build, Z_REFL, frozenset({REFLECTION}),
                     energy_bound=energy_bound, resolved=resolved)


def _specular_lobe_structure():
    # the lobe alone with its thin-film Fresnel (the other Fresnel kinds: the multi_lobe structure)
    def build(dt, p):
        from matfit.models import SpecularLobe

        (a, ay), w, (d, feta, eta) = p
        return SpecularLobe(dt(a), "thin_film", _rgb(w, dt), alpha_y=dt(a if ay is None else ay), thickness=_a(d, dt),
                            film_eta=_a(feta, dt), eta=_a(eta, dt))

    films = ((0.0, 1.3, 1.5), (400.0, 1.0, 1.5), (400.0, 1.8, 1.0), (1000.0, 2.5, 4.0), (250.0, 1.3, 1.5))
    al = [(a, None) for a in (0.0, 1e-8, 0.3, 2.0)] + [(0.05, 0.5)]
    cases = tuple((a, w, f) for a in al for w in (1.0,) for f in films) + tuple(
        ((0.3, None), w, films[4]) for w in (0.0, (0.0, 0.5, 1.0)))
    return Structure("specular_lobe_thin_film", "SpecularLobe", cases, build, Z_REFL, frozenset({REFLECTION}),
                     energy_bound=lambda p: np.asarray(p[1], np.float64), resolved=lambda p: _alpha_min(*p[0]) >= 0.3)


def _sheen_structure():
    def build(dt, p):
        from matfit.models import Lambert, Sheen

        alb, color, a = p
        return Sheen(Lambert(_a(alb, dt)), _a(color, dt), dt(a))

    # Below alpha ~ 0.06 the white lobe's own albedo passes 1 towards grazing (2.1 at alpha = 0.01):
    # Sheen divides the lobe by it there and keeps the base's scaling >= 0 (once eval < 0 for a
    # bright sheen): the narrow cases take white sheens too.
    dim = (0.0, 0.2, 0.45)
    cases = tuple((alb, c, a) for alb in (BLACK, WHITE) for c in (BLACK, WHITE, RAMP) for a in (0.3, 1.0))
    cases += tuple((alb, c, a) for alb in (BLACK, WHITE) for c in (BLACK, dim, WHITE) for a in (1e-8, 1e-4, 0.01, 0.05))
    # The sheen lobe is sampled from the cosine-weighted hemisphere: a sample's weight f pi / P
    # grows towards a grazing wo (~1e3 at mu_o = 1e-4 for alpha >= 0.05, 1e4 at alpha = 0.01) and
    # without bound as alpha -> 0, where D becomes a spike at the horizon (1e6 at alpha = 1e-4).
    return Structure("sheen_lambert", "Sheen", cases, build, Z_REFL, frozenset({REFLECTION}),
                     resolved=lambda p: p[2] >= 0.3,
                     weight_bound=lambda p: 1e4 if p[2] >= 0.05 else 1e5 if p[2] >= 0.01 else np.inf)


# --- measured tables -------------------------------------------------------------------------------
def _rgl_fields(kind):
    """Small synthetic RGL measurements (no file of ../shared): the constant ones of
    ``uniform_fields`` and one whose tables vary (a peaked VNDF and NDF, a colour ramp, zero nodes)."""
    from matfit.io.rgl import uniform_fields

    if kind in (0.0, 0.5, 1.0):
        return uniform_fields(kind)
    f = uniform_fields(0.5)  # the shapes of the constant ones: one compiled program
    x = np.linspace(0, 1, 8)
    bump = (1e-3 + np.exp(-(x[:, None] ** 2 + x[None] ** 2) / 0.02)).astype(np.float32)
    f["vndf"] = np.broadcast_to(bump, f["vndf"].shape).copy()
    f["ndf"] = np.broadcast_to(1e-3 + np.exp(-x ** 2 / 0.02), f["ndf"].shape).astype(np.float32).copy()
    rgb = np.broadcast_to(np.linspace(0, 1, 16, dtype=np.float32).reshape(4, 4), f["rgb"].shape).copy()
    rgb[:, :, 1] = 0.0
    f["rgb"] = rgb
    return f


def _rgl_structure():
    # Not batched: a measurement's static description (its _Info) is part of the model's
    # structure, and its tables are data rather than parameters; the cases share their shapes, so
    # one jitted call per case compiles once.
    def build(dt, kind):
        from matfit.io.rgl import read_rgl, tensor_file_bytes
        from matfit.models import MeasuredRGL

        return MeasuredRGL(read_rgl(tensor_file_bytes(_rgl_fields(kind))), dtype=dt)

    # Not reciprocal: the RGL scheme reads wi in the measurement's incidence role (a measurement is
    # one-way; a constant table has f cos(theta_o) constant, f = v / (4 cos theta_o)). No energy
    # bound: these synthetic tables are not of a passive material (f cos(theta_o) constant grows
    # without bound towards a grazing wo: albedo 1.5 at 75 deg for v = 0.5, and the samples'
    # weights with it, past 1e3 at cos theta_o = 1e-4); tests/test_measured_models.py bounds the
    # albedo of the real measurements of ../shared.
    # No case the quadrature resolves: the RGL density is singular towards the mirror direction
    # (its Jacobian 1 / sin(theta_m)), and a fixed rule does not converge on it (16 to 256 nodes:
    # 0.06 to 2.0 for the peaked table); tests/test_measured_models.py tests the sampler with a
    # chi-square on a grid of half vectors aligned with the table's nodes.
    # At the mirror direction itself (the half vector on the normal: a sampler input u = (., 0, 0)
    # lands there) the density's Jacobian 1 / max(2 pi^2 u_m sin(theta_m), 1e-6) is clamped, and
    # sample's pdf (from the warp's u_m) and pdf() (from the inverted half vector) clamp at
    # different points: 1.5e11 against 1.6e8 for the peaked table at cos theta_o = 1e-4. The
    # sampling check leaves those samples out (MIRROR_SINGULAR), as it does a Dirac lobe's.
    return Structure("measured_rgl", "MeasuredRGL", (0.0, 0.5, 1.0, "peaked"), build, Z_REFL,
                     frozenset({REFLECTION, TABLE, MIRROR_SINGULAR}), batched=False, reciprocal=None,
                     energy_bound=lambda kind: None, resolved=lambda kind: False,
                     weight_bound=lambda kind: 1e5)


def _merl_values(kind):
    """A synthetic MERL table (values (3, 90, 90, 180), valid): black, grey, white (1/pi: albedo
    1), grey with the cells of theta_d > 60 deg invalid, and a narrow specular spike."""
    from matfit.io.merl import cell_centres

    th, td, pd = cell_centres()
    shape = (3, 90, 90, 180)
    valid = None
    if kind == "black":
        v = np.zeros(shape)
    elif kind == "grey":
        v = np.full(shape, 0.1)
    elif kind == "white":
        v = np.full(shape, 1 / np.pi)
    elif kind == "holes":
        v = np.full(shape, 0.2)
        valid = np.broadcast_to((td < np.radians(60))[None, :, None], (90, 90, 180)).copy()
    else:
        spike = np.exp(-(th / 0.03) ** 2)[:, None, None] * np.ones((1, 90, 180))
        v = 0.02 + 30.0 * np.stack([spike, 0.5 * spike, 0.1 * spike])
    return v, valid


def _merl_structure():
    # Not batched: each table holds 90 x 90 x 180 x 3 values (35 MB in float64), which stacking
    # would copy; one jitted call per case (equal shapes: one compilation). Small sampling tables
    # (n_theta_o etc.) keep the construction cheap.
    def build(dt, kind):
        from matfit.io import MerlBRDF
        from matfit.models import MeasuredMERL

        v, valid = _merl_values(kind)
        return MeasuredMERL(MerlBRDF.from_values(v, valid), n_theta_o=4, n_theta_h=16, n_phi_h=16, dtype=dt)

    # The spike's albedo is not bounded by 1 (a synthetic table, not a passive material).
    return Structure("measured_merl", "MeasuredMERL", ("black", "grey", "white", "holes", "spike"), build, Z_REFL,
                     frozenset({REFLECTION, TABLE}), batched=False,
                     energy_bound=lambda kind: None if kind == "spike" else 1.0,
                     resolved=lambda kind: kind != "spike")


def _structures():
    out = [_lambert_structure()]
    out += [_rough_conductor_structure(d) for d in DISTRIBUTIONS]
    out += [_rough_dielectric_structure(d) for d in ("ggx", "beckmann")]
    out += [_smooth_conductor_structure(), _smooth_dielectric_structure(), _plastic_structure(False),
            _plastic_structure(True), _coated_structure(), _layered_structure(), _blend_structure(), _rotated_structure(),
            _stochastic_layered_structure(), _gltf_structure(),
            _diffuse_specular_structure(), _tabulated_structure(), _multi_lobe_structure(),
            _specular_lobe_structure(), _sheen_structure(), _rgl_structure(), _merl_structure()]
    return {s.name: s for s in out}


#: every model structure of the hard-case matrix by name (at least one per entry of
#: ``matfit.models.MODELS``: tests/test_catalogue.py)
STRUCTURES = _structures()
assert len(STRUCTURES) == len(set(STRUCTURES))
