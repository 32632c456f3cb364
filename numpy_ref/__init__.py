"""Independent numpy references of matfit's physics, shared by the tests and the benchmarks.

Written from the formulas of the API contract and docs/models.md, deliberately not a port of the
JAX code; only numpy and scipy are imported, never matfit (tests/test_import_graph.py checks it).
Not shipped with the library: the tests import it from the repository root (tests/conftest.py puts
the root on ``sys.path``), the benchmarks likewise (benchmarks/_common.py).

Modules by topic, everything re-exported here (``import numpy_ref as R``):

* :mod:`numpy_ref.fresnel` -- Fresnel reflectance: complex-index (exact, TIR through the complex
  square root), real-arithmetic forms, Schlick, the hemispherical average;
* :mod:`numpy_ref.microfacet` -- distributions: the reference :class:`Dist` (GGX, Beckmann,
  Blinn-Phong in spherical form) and :class:`GGXCartesian` (the baselines' fast GGX);
* :mod:`numpy_ref.models` -- Lambert, rough conductor and dielectric, diffuse + specular, smooth
  plastic, smooth-coated conductor (eval and pdf);
* :mod:`numpy_ref.baselines` -- the fitting families' vectorized baselines for the benchmarks and
  :class:`FamilyModel` (the unconstrained parametrization, residuals, log-probability);
* :mod:`numpy_ref.directions`, :mod:`numpy_ref.quadrature` -- direction sets, hemisphere rules and
  reference albedos;
* :mod:`numpy_ref.compare` -- relative errors and the assertion with a report of the worst points;
* :mod:`numpy_ref.published` -- the published analytic fits of the MERL materials (Ngan 2005, Löw
  2012, Bagher 2012, as the bbm benchmark collection defines them) as numpy BRDFs, and their loader
  (only :func:`~numpy_ref.published.published_fits` and its error class are re-exported here; the
  models are ``numpy_ref.published.<Name>``).

All functions work in float64 (inputs are converted) and broadcast numpy-style.
"""

from .baselines import (ALPHA_MIN, COS_EPS, FAMILY_MODELS, FamilyModel, coat_transmittance_table, conductor_ggx,
                        diffuse_specular_ggx, plastic_ggx)
from .compare import assert_rel, input_sensitivity, rel_err
from .directions import generalized_half_vector, random_directions, random_normals_near_z
from .fresnel import (fresnel_complex, fresnel_conductor, fresnel_conductor_real, fresnel_dielectric,
                      fresnel_dielectric_average, fresnel_dielectric_real, fresnel_schlick, thin_film_rgb,
                      thin_film_spectrum)
from .microfacet import Dist, GGXCartesian
from .models import (coated_conductor_smooth_eval, conductor_eval, conductor_pdf, dielectric_eval, dielectric_pdf,
                     diffuse_probability, diffuse_specular_eval, diffuse_specular_pdf, lambert_eval, lambert_pdf,
                     plastic_smooth_eval, reflection_lobe)
from .published import PublishedFitError, published_fits
from .quadrature import ggx_conductor_albedo, upper_hemisphere_rule

__all__ = [
    "ALPHA_MIN", "COS_EPS", "FAMILY_MODELS", "FamilyModel", "coat_transmittance_table", "conductor_ggx",
    "diffuse_specular_ggx", "plastic_ggx",
    "assert_rel", "input_sensitivity", "rel_err",
    "generalized_half_vector", "random_directions", "random_normals_near_z",
    "fresnel_complex", "fresnel_conductor", "fresnel_conductor_real", "fresnel_dielectric",
    "fresnel_dielectric_average", "fresnel_dielectric_real", "fresnel_schlick",
    "Dist", "GGXCartesian",
    "coated_conductor_smooth_eval", "conductor_eval", "conductor_pdf", "dielectric_eval", "dielectric_pdf",
    "diffuse_probability", "diffuse_specular_eval", "diffuse_specular_pdf", "lambert_eval", "lambert_pdf",
    "plastic_smooth_eval", "reflection_lobe",
    "PublishedFitError", "published_fits",
    "ggx_conductor_albedo", "upper_hemisphere_rule",
]
