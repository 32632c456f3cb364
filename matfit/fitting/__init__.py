"""Fitting model families to measurement tables: parameters, losses, solvers, uncertainty.

A walk-through of the entry points on one table (fit, the choice of family, fit_batch, the
posterior): ``docs/examples.md``, whose examples run as tests."""

from .fit import (CHANNEL_RHO_REFIT, METHODS, NOISE_FLOOR, channel_correlation, REFIT_MIN_BATCH, REFIT_SIGMAS, REFIT_STARTS, SUSPECT_FACTOR, BatchFit, FitError, FitResult,
                  fit_arrays, fit_batch, guesses_from_arrays, initial_guess, initial_guesses, noise_level, refit_line, covariance, SANDWICH_MAX, LEVERAGE_MAX)
from .losses import DEFAULT_LOSS, LOSSES, residuals
from .methods import DEFAULT_METHOD, Method, get_method
from .families import (FAMILIES, METAL_ETA_RANGE, METAL_K_RANGE, REDUCE_TOL, Family, Lobe, Param, TruthMap, compose_family,
                       family_describing, get_family, reduced_family, DEFAULT_FAMILY, COMPARE_FAMILIES)
from .params import Parametrization
from ._problem import Problem

__all__ = [
    "FAMILIES", "Family", "Param", "Parametrization", "TruthMap", "family_describing", "get_family", "Lobe",
    "compose_family", "METAL_ETA_RANGE", "METAL_K_RANGE", "reduced_family", "REDUCE_TOL", "Problem", "DEFAULT_FAMILY", "COMPARE_FAMILIES",
    "DEFAULT_LOSS", "LOSSES", "residuals", "DEFAULT_METHOD", "Method", "get_method",
    "METHODS", "FitError", "FitResult", "fit", "fit_batch", "initial_guess", "initial_guesses",
    "BatchFit", "CHANNEL_RHO_REFIT", "channel_correlation", "fit_arrays", "guesses_from_arrays", "NOISE_FLOOR", "REFIT_MIN_BATCH", "REFIT_SIGMAS", "REFIT_STARTS", "SUSPECT_FACTOR",
    "refit_line", "noise_level", "covariance", "SANDWICH_MAX", "LEVERAGE_MAX",
]
from .mcmc import NOISE_MODES, LogProb, PosteriorResult, SamplingError, make_log_prob, sample_posterior

__all__ += ["NOISE_MODES", "LogProb", "PosteriorResult", "SamplingError", "make_log_prob", "sample_posterior"]
from .select import ModelComparison, compare_models, recommend, robust_fit  # noqa: E402
from ._history import loss_history  # noqa: E402

__all__ += ["ModelComparison", "compare_models", "recommend", "robust_fit", "loss_history"]
from ._choose import CHOICE_LOSS, Choice, appearance_cues, candidates_for, choose_family, fit, highlight_hues  # noqa: E402

__all__ += ["CHOICE_LOSS", "Choice", "appearance_cues", "candidates_for", "choose_family", "highlight_hues"]
