"""Appearance as the judge of a fit: a material and its measurement rendered the same way,
noise-free (quadrature over each lighting), and compared as a viewer would (FLIP, CIEDE2000,
ΔE_ITP). :mod:`._lighting` holds the lightings and the render, :mod:`._judge` the metrics."""

from ._judge import (CIEDE2000_LINE, FLIP_LINE, JUDGE_LIGHTS, AppearanceDiff, LightDiff, appearance_difference,
                     ciede2000_map, display, flip_map, itp_map, lab, render_references)
from ._lighting import LIGHTINGS, SIZE, Lighting, disc_light, lighting, map_light, render_lit

__all__ = ["LIGHTINGS", "SIZE", "Lighting", "disc_light", "lighting", "map_light", "render_lit", "JUDGE_LIGHTS",
           "FLIP_LINE", "CIEDE2000_LINE", "AppearanceDiff", "LightDiff", "appearance_difference", "render_references",
           "ciede2000_map", "itp_map", "flip_map", "display", "lab"]
