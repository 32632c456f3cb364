r"""Spectral to RGB: the weights that turn a reflectance spectrum into linear sRGB.

A reflectance spectrum :math:`R(\lambda)` seen under the sRGB white (CIE illuminant D65) by the
CIE 1931 2° observer has the linear sRGB value

.. math::
    R_c = \sum_\lambda W_{\lambda c}\,R(\lambda),\qquad
    W_{\lambda c} = \frac{[M\,\bar{\mathbf x}(\lambda)]_c\,S(\lambda)}
                         {\sum_{\lambda'} [M\,\bar{\mathbf x}(\lambda')]_c\,S(\lambda')}

with :math:`\bar{\mathbf x}` the colour matching functions, :math:`S` the D65 spectrum and
:math:`M` the XYZ to linear sRGB matrix. Each channel's weights sum to 1, so a flat spectrum
:math:`R` gives :math:`(R, R, R)`: white stays white and a lossless layer's reflectance and
transmittance still add to 1 per channel. The weights are signed (sRGB's matrix is), so a very
saturated spectrum can leave [0, 1]; callers clamp.

:data:`WAVELENGTHS`: 380-780 nm every 5 nm (81 samples; the tables of ``colour`` read there).
A thin film of optical path :math:`2\eta_f d \le 5200` nm (the range of
:func:`~matfit.fresnel.fresnel_thin_film`) has fringes at least :math:`\lambda^2 / 5200 \approx 28`
nm apart at 380 nm: five samples or more per fringe.

Example
-------
>>> from matfit._spectral import rgb_weights
>>> w = rgb_weights()
>>> w.shape, [round(float(s), 6) for s in w.sum(axis=0)]
((81, 3), [1.0, 1.0, 1.0])
"""

from __future__ import annotations

import functools

import numpy as np

__all__ = ["WAVELENGTHS", "rgb_weights"]

#: The wavelengths (nm) of every spectral sum: 380-780 nm every 5 nm.
WAVELENGTHS = np.arange(380.0, 781.0, 5.0)


@functools.lru_cache(maxsize=None)
def rgb_weights() -> np.ndarray:
    """The weights ``W`` (L, 3) of :data:`WAVELENGTHS` to linear sRGB (each column sums to 1).

    Returns
    -------
    numpy.ndarray
        Read-only, float64.

    Examples
    --------
    >>> from matfit._spectral import rgb_weights
    >>> bool(rgb_weights()[:, 2].argmax() < rgb_weights()[:, 0].argmax())  # blue peaks before red
    True
    """
    import colour

    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    d65 = colour.SDS_ILLUMINANTS["D65"]
    xyz = np.stack([np.interp(WAVELENGTHS, cmfs.wavelengths, cmfs.values[:, i]) for i in range(3)], axis=-1)
    s = np.interp(WAVELENGTHS, d65.wavelengths, d65.values)
    m = np.asarray(colour.RGB_COLOURSPACES["sRGB"].matrix_XYZ_to_RGB, float)
    w = (xyz * s[:, None]) @ m.T
    w = w / w.sum(axis=0, keepdims=True)
    w.setflags(write=False)
    return w
