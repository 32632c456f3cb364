"""The ground truth of a synthetic table, read back from its provenance.

:func:`synthesize` records the scene's material in ``table.provenance["ground_truth"]``;
:func:`truth_from_table` turns it into what a report compares a fit with: the family that
describes the true material exactly (:func:`matfit.fitting.family_describing`), its parameter
values, and the true model itself.
"""

from __future__ import annotations

import numpy as np

from matfit.fitting import family_describing

from .scene import Scene

__all__ = ["truth_from_table"]


def truth_from_table(table, family=None):
    """Ground truth of a synthetic table (``provenance["ground_truth"]`` written by :func:`synthesize`).

    Parameters
    ----------
    table : matfit.Table
        Any table; one without ground truth gives None.
    family : str, optional
        The family fitted. ``params`` is filled only when this family (or, when None, any
        registered family) describes the true material exactly.

    Returns
    -------
    dict or None
        ``{"family": name or None, "params": dict or None, "model": model or None}``.
        ``params`` holds the family's parameter values (a metal's ``eta``, ``k`` from the recorded
        n, k table) when the scene is not spectral; ``model`` is the true matfit model, rebuilt
        from the scene, when its channels are the table's.

    Examples
    --------
    >>> from data_synth import load_scene, synthesize, truth_from_table
    >>> t = truth_from_table(synthesize(load_scene("demo")), "conductor")
    >>> t["family"], sorted(t["params"])
    ('conductor', ['alpha', 'eta', 'k'])
    """
    gt = (table.provenance or {}).get("ground_truth")
    if not gt or "params" not in gt:
        return None
    spec = dict(gt["params"])
    spec.setdefault("model", gt.get("model"))
    described = family_describing(spec)
    fam = described.name if described is not None else None
    spectral = (gt.get("effects", {}).get("colour", {}) or {}).get("mode") == "spectral"
    if "metal" in spec and "metal_nk" in gt and not spectral:
        n, k = gt["metal_nk"][spec["metal"]]
        spec["eta"], spec["k"] = n, k
    params = None
    if described is not None and (family is None or family == fam) and not spectral:
        params = {p.name: np.asarray(spec[p.name], float) for p in described.params if p.name in spec}
        # A default the scene did not set is the model's own default: leave it out of the comparison.
    model = None
    if not spectral:
        try:
            sc = Scene(name=str(gt.get("scene", "truth")), seed=int(gt.get("seed", 0)), geometry=gt.get("geometry", {}),
                       material=gt["params"], effects=gt["effects"])
            model = sc.build_model()
            if model.channels not in (1, table.n_channels):
                model = None
        except Exception:  # noqa: BLE001 - the truth model is a nicety of the plots
            model = None
    return {"family": fam, "params": params, "model": model}
