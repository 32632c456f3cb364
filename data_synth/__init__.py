"""data_synth: a synthetic gonioreflectometer producing :class:`matfit.Table` objects from TOML scenes.

>>> from data_synth import load_scene, synthesize
>>> table = synthesize(load_scene("demo"))          # a shipped scene, by name
>>> table.provenance["ground_truth"]["model"]
'RoughConductor'

Modules: :mod:`~data_synth.scene` (scene files), :mod:`~data_synth.geometry` (measurement geometries),
:mod:`~data_synth.effects` (aperture and noise), :mod:`~data_synth.spectral` (metal n, k and colour),
:mod:`~data_synth.synth` (the pipeline), :mod:`~data_synth.truth` (the ground truth read back). Scene keys are documented in docs/data.md.
"""
from .errors import (MissingKeyError, SceneError, SceneSyntaxError, SceneTypeError, SceneValueError,
                     UnknownKeyError, UnknownModelError, UnknownParameterError)
from .scene import Scene, load_scene, parse_scene, shipped_scenes
from .synth import EvalCounter, synthesize
from .truth import truth_from_table

__all__ = ["Scene", "load_scene", "parse_scene", "shipped_scenes", "synthesize", "truth_from_table", "EvalCounter", "SceneError",
           "SceneSyntaxError", "UnknownKeyError", "MissingKeyError", "SceneTypeError", "UnknownModelError",
           "UnknownParameterError", "SceneValueError"]
