"""Fit reports, model comparison and the ``matfit fit`` / ``matfit compare`` commands.

Kept small for CPU: every table here has 34 rows (the demo scene's in-plane layout), so the 80 %
fit parts all have 27 rows and the compiled solvers (lambert, conductor) are shared by the
comparisons and by the CLI fit (``--subsample 27``).
"""

import json
import math

import numpy as np
import pytest

from data_synth import load_scene, parse_scene, synthesize
from matfit.cli import main
from matfit.fitting import compare_models, recommend
from matfit.io import save
from data_synth import truth_from_table
from matfit.report import in_plane_slices, write_report

PNG_MAGIC = b"\x89PNG\r\n\x1a\n"
ALBEDO = [0.6, 0.3, 0.2]


@pytest.fixture(scope="module")
def glossy():
    return synthesize(load_scene("demo"))  # rough gold, 34 rows, 2 % noise, sigma


@pytest.fixture(scope="module")
def lambertian():
    scene = parse_scene({
        "scene": {"name": "white_paint", "seed": 4},
        "geometry": {"kind": "inplane", "theta_i": [0.0, 45.0], "theta_o_step": 10.0, "theta_o_max": 80.0},
        "material": {"model": "Lambert", "albedo": ALBEDO},
        "effects": {"noise": {"relative": 0.02}},
    })
    t = synthesize(scene)
    assert len(t) == 34
    return t


@pytest.fixture(scope="module")
def cmp_lambertian(lambertian):
    return compare_models(lambertian, models=("lambert", "conductor"))


@pytest.fixture(scope="module")
def cmp_glossy(glossy):
    return compare_models(glossy, models=("lambert", "conductor"))


def run_cli(argv, capsys):
    try:
        rc = main([str(a) for a in argv])
    except SystemExit as e:  # argparse errors
        rc = e.code
    out, err = capsys.readouterr()
    return rc, out, err


class FakePosterior:
    def __init__(self, values, stderr, labels, seed=0):
        rng = np.random.default_rng(seed)
        self.chain = np.asarray(values) + rng.normal(size=(100, 8, len(values))) * np.asarray(stderr)
        self.labels = list(labels)


# ---------------------------------------------------------------------------------- model choice
@pytest.mark.check
def test_recommend_rule():
    rows = [{"model": "plastic", "p": 5, "holdout_rmse": 1.00}, {"model": "lambert", "p": 3, "holdout_rmse": 1.009},
            {"model": "conductor", "p": 7, "holdout_rmse": 0.99}, {"model": "x", "error": "failed"}]
    assert recommend(rows) == ("lambert", "conductor")  # 1.009 <= 0.99 * 1.02 = 1.0098
    assert recommend(rows, tol=0.0) == ("conductor", "conductor")
    assert recommend([{"model": "x", "error": "failed"}]) == (None, None)


def test_compare_recommends_lambert_for_lambertian(cmp_lambertian):
    c = cmp_lambertian
    assert c.recommended == "lambert", c.summary()
    assert (c.n_fit, c.n_holdout) == (27, 7)
    rows = {r["model"]: r for r in c.rows}
    lam = rows["lambert"]
    assert lam["p"] == 3 and lam["n"] == 81
    assert math.isclose(lam["aic"], lam["n"] * math.log(lam["rss"] / lam["n"]) + 2 * lam["p"], rel_tol=1e-9)
    assert math.isclose(lam["bic"], lam["n"] * math.log(lam["rss"] / lam["n"]) + 3 * math.log(81), rel_tol=1e-9)
    # sigma-weighted hold-out residuals of a correct model are O(1)
    assert lam["holdout_rmse"] < 2.0
    np.testing.assert_allclose(c.results["lambert"].params["albedo"], ALBEDO, rtol=0.03)
    assert "<- recommended" in c.summary()


def test_compare_does_not_recommend_lambert_for_glossy(cmp_glossy):
    c = cmp_glossy
    assert c.recommended == "conductor", c.summary()
    rows = {r["model"]: r for r in c.rows}
    assert rows["conductor"]["holdout_rmse"] < 0.2 * rows["lambert"]["holdout_rmse"]
    assert rows["conductor"]["aic"] < rows["lambert"]["aic"] and rows["conductor"]["bic"] < rows["lambert"]["bic"]
    assert abs(c.results["conductor"].params["alpha"] - 0.2) < 0.01


# ---------------------------------------------------------------------------------- report
def test_in_plane_slices(glossy):
    sl = in_plane_slices(glossy)
    assert [round(s[0]) for s in sl] == [0, 45]
    assert [len(s[2]) for s in sl] == [17, 17]
    for _, _, rows, to in sl:
        assert np.all(np.abs(to) <= 80.0 + 1e-6)


def test_report_contents(cmp_lambertian, lambertian, tmp_path):
    res = cmp_lambertian.results["lambert"]
    post = FakePosterior(res.values, res.stderr, res.labels)
    out = tmp_path / "rep"
    s = write_report(res, lambertian, out, posterior=post, truth=truth_from_table(lambertian, "lambert"))
    for f in ("report.md", "report.json", "lobes.png", "residuals.png", "loss.png", "corner.png"):
        p = out / f
        assert p.exists() and p.stat().st_size > 500, f
        if f.endswith(".png"):
            assert p.read_bytes()[:8] == PNG_MAGIC
    j = json.loads((out / "report.json").read_text())
    assert j == json.loads(json.dumps(s))
    assert [r["label"] for r in j["params"]] == ["albedo[0]", "albedo[1]", "albedo[2]"]
    for r, a in zip(j["params"], ALBEDO):
        assert r["truth"] == pytest.approx(a)
        assert r["value"] == pytest.approx(a, rel=0.03)
        assert abs(r["error_in_stderr"]) < 5
        assert r["posterior"]["q2.5"] < r["value"] < r["posterior"]["q97.5"]
    m = j["metrics"]
    assert m["n_rows_evaluated"] == 34 and m["relative_rmse"] < 0.05
    cd = j["colour_difference"]
    assert 0 <= cd["delta_e_mean_appearance"] < 1.0 and cd["delta_e_rows_median"] < 2.0
    md = (out / "report.md").read_text()
    for needle in ("| albedo[0] |", "![lobes](lobes.png)", "![residuals](residuals.png)", "![corner](corner.png)",
                   "CIEDE2000", "truth", "![preview](preview.png)"):
        assert needle in md, needle
    # preview: truth | fitted | FLIP under each lighting; the fit looks like the truth
    assert (out / "preview.png").read_bytes()[:8] == PNG_MAGIC
    assert j["preview"]["panels"][:2] == ["truth", "fitted"] and j["preview"]["looks_alike"]
    from matfit.export import load_model

    assert type(load_model(out / "model.json")).__name__ == "Lambert"
    assert type(load_model(out / "report.json")).__name__ == "Lambert"


def test_report_history_and_no_truth(cmp_glossy, glossy, tmp_path):
    res = cmp_glossy.results["conductor"]
    s = write_report(res, glossy, tmp_path, history=[100.0, 10.0, 1.0, 0.5])
    assert s["truth_available"] is False and "corner" not in s["files"]
    assert not (tmp_path / "corner.png").exists()
    assert all("truth" not in r for r in s["params"])
    assert s["colour_difference"]["delta_e_mean_appearance"] < 1.0
    assert (tmp_path / "loss.png").read_bytes()[:8] == PNG_MAGIC


# ---------------------------------------------------------------------------------- CLI
def test_cli_fit_npz_with_report(glossy, cmp_glossy, tmp_path, capsys):
    path = tmp_path / "gold.npz"
    save(path, glossy)
    rep = tmp_path / "report"
    rc, out, err = run_cli(["fit", path, "--model", "conductor", "--subsample", 27, "--report", rep], capsys)
    assert rc == 0, err
    assert "alpha" in out and "truth" in out and "k[2]" in out
    j = json.loads((rep / "report.json").read_text())
    alpha = next(r for r in j["params"] if r["label"] == "alpha")
    assert abs(alpha["value"] - 0.2) < 0.01 and alpha["truth"] == 0.2
    assert j["metrics"]["n_rows_evaluated"] == 34  # the report covers the whole table
    assert (rep / "lobes.png").exists() and (rep / "report.md").exists()


def test_cli_fit_export_and_render(glossy, tmp_path, capsys):
    path = tmp_path / "gold.npz"
    save(path, glossy)
    xml, fitj = tmp_path / "gold.xml", tmp_path / "fit.json"
    rc, out, err = run_cli(["fit", path, "--model", "conductor", "--export", "mitsuba-xml", xml, "--save-model", fitj],
                           capsys)
    assert rc == 0, err
    assert "export to mitsuba-xml: exact" in out and xml.read_text().lstrip().startswith("<bsdf")
    gl = tmp_path / "gold.gltf"
    rc, out, err = run_cli(["export", fitj, "--to", "gltf", "-o", gl], capsys)
    assert rc == 0, err
    doc = json.loads(gl.read_text())
    assert doc["asset"]["version"] == "2.0" and doc["materials"][0]["pbrMetallicRoughness"]["metallicFactor"] == 1.0
    assert "fidelity (fitted): relative RMSE" in out
    png = tmp_path / "gold.png"
    rc, out, err = run_cli(["render", fitj, "--env", "furnace", "--size", 16, "--spp", 4, "-o", png], capsys)
    assert rc == 0, err
    assert png.read_bytes()[:8] == PNG_MAGIC
    npy = tmp_path / "gold.npy"
    rc, out, err = run_cli(["render", fitj, "--size", 8, "--spp", 2, "-o", npy], capsys)
    assert rc == 0 and np.load(npy).shape == (8, 8, 3)


def test_cli_compare(lambertian, cmp_lambertian, tmp_path, capsys):
    path = tmp_path / "paint.csv"
    save(path, lambertian)
    js = tmp_path / "cmp.json"
    rc, out, err = run_cli(["compare", path, "--models", "lambert,conductor", "--json", js], capsys)
    assert rc == 0, err
    assert "recommended: lambert" in out
    assert json.loads(js.read_text())["recommended"] == "lambert"


def _fit_lambert(*options, table="ok.npz"):
    """``matfit fit {dir}/<table> --model lambert <options>``."""
    return ["fit", "{dir}/" + table, "--model", "lambert", *options]


@pytest.mark.parametrize("argv, needle", [
    (_fit_lambert(table="missing.npz"), "no such file"),
    (_fit_lambert(table="table.txt"), "extension"),
    (_fit_lambert(table="bad.npz"), "npz"),
    (["fit", "{dir}/ok.npz", "--model", "nosuch"], "invalid choice"),
    (_fit_lambert("--method", "newton"), "invalid choice"),
    (_fit_lambert("--fixed", "eta"), "name=value"),
    (_fit_lambert("--fixed", "eta=1.5"), "no parameter 'eta'"),
    (_fit_lambert("--fixed", "albedo=abc"), "expected numbers"),
    (_fit_lambert("--subsample", "0"), "positive integer"),
    (_fit_lambert("--subsample", "1"), "usable residuals"),
    (["compare", "{dir}/ok.npz", "--models", "lambert,nosuch"], "model must be one of"),
    (["compare", "{dir}/ok.npz", "--holdout", "1.5"], "fraction"),
    (["fit", "{dir}/ok.npz", "--fixed", "albedo=0.5"], "--model"),
    (_fit_lambert("--candidates", "lambert"), "leave out --model"),
    (["fit", "{dir}/ok.npz", "--candidates", "lambert,nosuch"], "unknown families"),
    (["export", "{dir}/missing.json", "--to", "gltf", "-o", "{dir}/x.gltf"], "no such file"),
    (["export", "{dir}/ok.npz", "--to", "gltf", "-o", "{dir}/x.gltf"], "not a JSON document"),
    (["export", "{dir}/m.json", "--to", "blender", "-o", "{dir}/x"], "invalid choice"),
    (["render", "{dir}/m.json", "--env", "{dir}/nosky.hdr", "-o", "{dir}/x.png"], "no such file"),
    (["render", "{dir}/m.json", "--size", "0", "-o", "{dir}/x.png"], "positive integer"),
])
def test_cli_errors_exit_2_with_one_line(argv, needle, lambertian, tmp_path, capsys):
    save(tmp_path / "ok.npz", lambertian.select(np.arange(3)))  # 3 rows x 3 channels: a tiny table
    (tmp_path / "table.txt").write_text("1 2 3\n")
    (tmp_path / "bad.npz").write_bytes(b"not a zip archive")
    from matfit.export import save_model
    from matfit.models import Lambert

    save_model(tmp_path / "m.json", Lambert(0.5))
    rc, out, err = run_cli([a.format(dir=tmp_path) for a in argv], capsys)
    assert rc == 2
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert needle in lines[0], lines[0]
    assert lines[0].startswith("matfit")


def test_cli_fit_without_a_family_chooses_one_by_appearance(lambertian, tmp_path, capsys):
    """``matfit fit TABLE`` with no --model: the candidates' lines, the choice and why, and a
    report with the table of candidates (a synthetic table: its truth is the reference)."""
    path = tmp_path / "white.npz"
    save(path, lambertian)
    rc, out, err = run_cli(["fit", path, "--report", tmp_path / "r", "--starts", "1", "--candidates",
                            "lambert,conductor"], capsys)
    assert rc == 0, err
    assert "chose lambert by appearance" in out and "runner-up conductor" in out
    for fam in ("lambert", "conductor"):
        assert f"  {fam} " in out
    j = json.loads((tmp_path / "r" / "report.json").read_text())
    assert j["family"] == "lambert" and j["choice"]["chosen"] == "lambert" and j["loss"] == "e2"
    assert j["preview"]["panels"] == ["truth", "fitted", "FLIP"] and j["preview"]["looks_alike"]
    md = (tmp_path / "r" / "report.md").read_text()
    assert "## Why this family" in md and "| lambert (chosen) |" in md and "## Appearance" in md
