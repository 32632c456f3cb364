r"""Microfacet normal distributions with Smith masking: GGX, Beckmann, normalized Blinn-Phong, and
distributions tabulated or extracted from measurements. The shared math (normalization, Smith
:math:`G_1`, :math:`G_2`, visible normals, what ``alpha`` means) is in :class:`AbstractDistribution`;
each distribution's :math:`D` and :math:`\Lambda` in its module."""

from ._base import ALPHA_MIN, MASKING_FORMS, AbstractDistribution
from .beckmann import Beckmann
from .blinn_phong import BlinnPhong
from .ggx import GGX
from .tabulated import TabulatedNDF, back_facing_area, interpolate_ndf, ndf_grid, projected_mass
from .extract import EXTRACTION_MASKING, extract_ndf, ndf_start, nearest_analytic

DISTRIBUTIONS = {"ggx": GGX, "beckmann": Beckmann, "blinn_phong": BlinnPhong}


def make_distribution(name, alpha_x, alpha_y=None):
    """Build a distribution by name.

    Parameters
    ----------
    name : {"ggx", "beckmann", "blinn_phong"}
        A key of :data:`DISTRIBUTIONS`; another name raises ValueError.
    alpha_x, alpha_y : array_like
        Widths along x and y (``alpha_y`` default: ``alpha_x``, isotropic).

    Returns
    -------
    AbstractDistribution
    """
    try:
        cls = DISTRIBUTIONS[name]
    except (KeyError, TypeError):
        raise ValueError(f"distribution must be one of {sorted(DISTRIBUTIONS)}, got {name!r}") from None
    return cls(alpha_x, alpha_y)


__all__ = [
    "ALPHA_MIN",
    "MASKING_FORMS",
    "DISTRIBUTIONS",
    "AbstractDistribution",
    "GGX",
    "Beckmann",
    "BlinnPhong",
    "make_distribution",
    "TabulatedNDF",
    "ndf_grid",
    "projected_mass",
    "back_facing_area",
    "interpolate_ndf",
    "extract_ndf",
    "ndf_start",
    "nearest_analytic",
    "EXTRACTION_MASKING",
]
