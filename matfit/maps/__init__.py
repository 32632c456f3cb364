"""Parameter maps: fit every texel of a capture, read captures, write maps.

- :func:`fit_map`: one fit per texel, chunked, over one or several processes
  (:func:`initialize_processes`); returns a :class:`MapResult`.
- :func:`load_capture`: a folder of images (PNG 8/16-bit, EXR) and their light and camera
  directions (``capture.json`` / ``capture.toml``) as a :class:`Capture`.
- :func:`write_maps`: parameter maps as 16-bit PNG and float EXR, and a glTF material with
  textures.
"""

from ._fit_map import DEFAULT_CHUNK, LOBE_STARTS, MapResult, fit_map, initialize_processes
from ._capture import Capture, CaptureError, load_capture, write_capture_document
from ._images import read_image, write_exr, write_png
from ._write import FORMATS, GLTF_FAMILIES, gltf_maps, read_maps, write_maps

__all__ = ["DEFAULT_CHUNK", "LOBE_STARTS", "MapResult", "fit_map", "initialize_processes", "FORMATS", "GLTF_FAMILIES", "gltf_maps",
           "read_maps", "write_maps", "Capture", "CaptureError", "load_capture", "write_capture_document",
           "read_image", "write_exr", "write_png"]
