"""What a fit solves, built once per configuration: :class:`Problem`.

A problem is a family on ``C`` colour channels with some parameters fixed or tied, under a loss
(and optionally a robust loss of a scale). It is a frozen, hashable value: the compiled solvers,
the posterior's log-probability and the sandwich's Jacobian are cached on it, and equal problems
are one object (:meth:`Problem.of` interns them), so its parametrization, residual functions,
column groups and objective are built once per process, whichever entry point asks first
(``fit``, ``fit_arrays``/``fit_batch``/``fit_map``, ``sample_posterior``, ``loss_history``).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .lm import column_groups
from .losses import DEFAULT_LOSS, check_loss
from .params import Parametrization
from ._residuals import objective_fn, prepared_residual_fn, split_residual_fn

__all__ = ["Problem", "fixed_items"]


def fixed_items(fixed):
    """``fixed`` (name -> value or per-channel values) as a sorted tuple of ``(name, values)``."""
    return tuple(sorted((k, tuple(np.atleast_1d(np.asarray(v, float)).tolist())) for k, v in (fixed or {}).items()))


@dataclass(frozen=True)
class Problem:
    """A family on ``channels`` colour channels, some parameters fixed or tied, under a loss.

    Attributes
    ----------
    family : str or Family
        A key of :data:`~matfit.fitting.FAMILIES`, or a :class:`~matfit.fitting.Family`.
    channels : int
        Colour channels of the tables.
    fixed : tuple of (str, tuple of float)
        Parameters held at given values (:func:`fixed_items`' form).
    tied : tuple of str
        Per-channel parameters shared by all channels.
    loss : str
        A key of :data:`~matfit.fitting.LOSSES`.
    robust : str or None
        A robust loss applied to the residuals, with scale ``robust_scale``.
    robust_scale : float

    Examples
    --------
    >>> from matfit.fitting import Problem
    >>> p = Problem.of("plastic", 3, fixed={"eta": 1.5})
    >>> p.par.labels, p is Problem.of("plastic", 3, fixed={"eta": 1.5})
    (['albedo[0]', 'albedo[1]', 'albedo[2]', 'alpha'], True)
    """

    family: str
    channels: int
    fixed: tuple = ()
    tied: tuple = ()
    loss: str = DEFAULT_LOSS
    robust: Optional[str] = None
    robust_scale: float = 1.0

    @classmethod
    def of(cls, family, channels, fixed=None, tied=(), loss=None, robust=None, robust_scale=1.0) -> "Problem":
        """The problem of these settings, checked (family, fixed, tied, loss), one object per value.

        Parameters
        ----------
        family, channels, fixed, tied, loss, robust, robust_scale
            As the attributes; ``fixed`` a mapping of name -> value(s), ``loss=None`` is ``l2``.

        Returns
        -------
        Problem
        """
        loss = DEFAULT_LOSS if loss is None else loss
        check_loss(loss, robust)
        try:
            problem = _interned(cls(family, int(channels), fixed_items(fixed), tuple(tied), loss, robust,
                                    float(robust_scale)))
            problem.par  # noqa: B018  (builds and checks the parametrization: unknown names raise here)
        except (TypeError, ValueError):
            # the error names the caller's own values (not their canonical form)
            Parametrization(family, channels, fixed, tied)
            raise
        return problem

    @functools.cached_property
    def par(self) -> Parametrization:
        """The parametrization (free parameters, their ranges and the unconstrained map); one per
        family, channels, fixed and tied, whatever the loss."""
        return _parametrization(self.family, self.channels, self.fixed, self.tied)

    @functools.cached_property
    def residuals(self):
        """``(prepare, fn)``: the table-only work and the ``(N, C)`` residuals (:func:`prepared_residual_fn`)."""
        return prepared_residual_fn(self.par, self.loss, self.robust, self.robust_scale)

    @functools.cached_property
    def split_residuals(self):
        """``(prepare, fn)`` of the channel-split residuals (:func:`split_residual_fn`)."""
        return split_residual_fn(self.par, self.loss, self.robust, self.robust_scale)

    @functools.cached_property
    def groups(self):
        """``(seeds, owner)``: the column groups of the grouped differences (:func:`~matfit.fitting.lm.column_groups`)."""
        return column_groups(self.par)

    @functools.cached_property
    def objective(self):
        """``objective(zs, arrays)``: ``0.5 |r|^2`` of a stack of unconstrained vectors."""
        return objective_fn(*self.residuals)


@functools.lru_cache(maxsize=256)
def _parametrization(family, channels, fixed, tied):
    return Parametrization(family, channels, dict(fixed), tied)


@functools.lru_cache(maxsize=256)
def _interned(problem):
    """The first problem equal to ``problem`` (its cached properties are then built once)."""
    return problem
