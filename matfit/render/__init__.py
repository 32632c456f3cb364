"""Preview renders: a sphere of a material under a furnace, a procedural sky or an environment
map, by BSDF sampling, environment sampling and multiple importance sampling (in JAX)."""

from ._env import SUN_DIRECTION, SUN_RADIANCE, SUN_RADIUS, Environment, load_environment, sky_map
from ._sphere import (STRATEGIES, RenderStats, image_ciede2000, render_sphere, save_png, sphere_frames, srgb_decode,
                      srgb_encode, tonemap)

__all__ = ["render_sphere", "RenderStats", "STRATEGIES", "Environment", "sky_map", "load_environment", "tonemap",
           "save_png", "image_ciede2000", "sphere_frames", "srgb_encode", "srgb_decode", "SUN_DIRECTION", "SUN_RADIUS", "SUN_RADIANCE"]
