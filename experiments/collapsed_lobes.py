"""Collapsed lobes in the measured protocol: which MERL/RGL fits of lobes2, lobes3 and metal2 left
a lobe unused, and what the chosen families count as once such fits are read as the smaller
family (:func:`matfit.fitting.reduced_family`; issue #39).

Reads experiments/results/fit_measured.json (the protocol's stored fits, their parameters); no
fit is rerun. Writes experiments/results/collapsed_lobes.md and prints it.

Usage: python experiments/collapsed_lobes.py
"""

from __future__ import annotations

import json
from collections import Counter
from pathlib import Path

from matfit.fitting import Parametrization, reduced_family

RES = Path(__file__).parent / "results"
MULTI = ("lobes2", "lobes3", "metal2")


def main():
    d = json.loads((RES / "fit_measured.json").read_text())
    lines = ["# Collapsed lobes in the measured protocol", "",
             "`experiments/collapsed_lobes.py` over the stored fits of `fit_measured.json` (no refit): a fit of "
             "lobes2, lobes3 or metal2 whose extra lobe ended at zero weight (every channel <= 1e-3) or at its "
             "neighbour's width (ratio within 1e-3 of 1) is the smaller family (`reduced_family`).", ""]
    for kind in ("merl", "rgl"):
        recs = d.get(kind) or []
        if not recs:
            continue
        per_family = Counter()
        collapsed = Counter()
        chosen_reduced = []
        examples = []
        for rec in recs:
            for fam, f in (rec.get("fits") or {}).items():
                if fam not in MULTI or "params" not in f:
                    continue
                per_family[fam] += 1
                red = reduced_family(fam, f["params"])
                if red:
                    collapsed[fam] += 1
                    if len(examples) < 12:
                        examples.append(f"{rec['material']}: {fam} -> {red[0]} ({red[1]})")
                    if rec.get("chosen") == fam:
                        chosen_reduced.append((rec["material"], fam, red[0]))
        lines += [f"## {kind.upper()} ({len(recs)} files)", "",
                  "| family | fits | a lobe unused (reduces) |", "| --- | --- | --- |"]
        lines += [f"| {fam} | {per_family[fam]} | {collapsed[fam]} |" for fam in MULTI if per_family[fam]]
        lines += ["", "Examples: " + "; ".join(examples) if examples else "No fit collapsed.", ""]
        if chosen_reduced:
            lines += [f"Chosen fits that reduce ({len(chosen_reduced)}): counted as the smaller family, with its "
                      "parameter count:", ""]
            lines += [f"- {m}: chosen {fam} (p = {Parametrization(fam, 3).size}) is {red} (p = "
                      f"{Parametrization(red, 3).size})" for m, fam, red in chosen_reduced]
        else:
            lines.append("No chosen fit reduces to a smaller family.")
        chosen = Counter(rec.get("chosen") for rec in recs)
        counted = Counter(next((r for m, f, r in chosen_reduced if m == rec["material"]), rec.get("chosen"))
                          for rec in recs)
        lines += ["", "Chosen families as fitted: " + ", ".join(f"{k} {v}" for k, v in chosen.most_common()),
                  "", "Counted with collapsed lobes as the smaller family: "
                  + ", ".join(f"{k} {v}" for k, v in counted.most_common()), ""]
    text = "\n".join(lines) + "\n"
    (RES / "collapsed_lobes.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
