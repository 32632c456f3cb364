"""Checks moved from the docstring examples of matfit.io, matfit.export and matfit.maps.

Small and fast: tiny arrays, no long fits.
"""
import json
import os

import numpy as np
import pytest

from matfit.errors import DataFormatError, ParameterError
from matfit.io import MerlBRDF, load, read_merl, read_rgl, read_tensor_file, save, write_merl
from matfit.io._source import read_source
from matfit.io.merl import FILE_SIZE
from matfit.io.rgl import MAGIC, tensor_file_bytes, uniform_fields
from matfit.table import Table


# ----------------------------------------------------------------------------------------- matfit.io
def test_save_load_npz_round_trip(tmp_path):
    t = Table(wo=[[0.0, 0.0, 1.0]], wi=[[0.0, 0.6, 0.8]], values=[[0.1, 0.2, 0.3]])
    save(tmp_path / "t.npz", t)
    assert load(tmp_path / "t.npz").values.tolist() == [[0.1, 0.2, 0.3]]


@pytest.mark.check
def test_read_source_bytes_and_limit(tmp_path):
    assert read_source(b"#DIM 1 1") == (b"#DIM 1 1", None, "<bytes>")
    p = str(tmp_path / "x.bin")
    with open(p, "wb") as fh:
        fh.write(b"abcdef")
    assert read_source(p, limit=4) == (b"abcd", p, p)


def test_merl_from_values_lookup_table_and_files(tmp_path):
    valid = np.ones((90, 90, 180), bool)
    valid[0, 0, 0] = False
    m = MerlBRDF.from_values(np.full((3, 90, 90, 180), 0.3), valid)
    assert float(m.raw[0, 0, 0, 0]) == -1.0 and int((~m.valid).sum()) == 1
    full = MerlBRDF.from_values(np.full((3, 90, 90, 180), 0.3))
    values, ok = full.lookup([[0.0, 0.6, 0.8], [0.0, 0.0, -1.0]], [[0.0, -0.6, 0.8], [0.0, 0.0, 1.0]])
    assert np.round(values, 6).tolist() == [[0.3, 0.3, 0.3], [0.0, 0.0, 0.0]] and ok.tolist() == [True, False]
    t = full.to_table()
    assert (len(t), t.channels, t.provenance["format"]) == (1458000, "rgb", "merl")
    write_merl(tmp_path / "grey.binary", full)
    assert os.path.getsize(tmp_path / "grey.binary") == FILE_SIZE
    back = read_merl(tmp_path / "grey.binary")
    assert np.array_equal(back.raw, full.raw) and not back.raw.flags.writeable


def test_alta_to_table_sigma_and_geometry():
    from matfit.io import read_alta

    d = read_alta(b"#DIM 1 1\n#PARAM_IN COS_TH\n#PARAM_OUT INV_STERADIAN\n#VS 1\n1.0 0.5 0.05\n")
    t = d.to_table()
    assert t.channels == "mono" and t.sigma.tolist() == [[0.05]]
    assert t.provenance["geometry"] == "theta_h = acos(COS_TH), theta_d = 0.0, phi_d = 0.0, phi_h = 0"
    r = read_alta(b"#DIM 1 1\n#PARAM_IN RUSIN_TH\n#PARAM_OUT INV_STERADIAN\n0.3 1.0\n")
    wo, wi = r.directions()  # theta_d = 0: wi = wo = h
    assert np.allclose(wo, wi) and round(float(np.arccos(wo[0, 2])), 6) == 0.3


def test_tensor_file_layout_and_errors():
    data = tensor_file_bytes({"jacobian": np.ones(1, np.uint8), "ndf": np.ones((2, 8), np.float32)})
    assert data[:12] == MAGIC and len(data) % 8 == 0
    tf = read_tensor_file(data)
    assert sorted(tf.fields) == ["jacobian", "ndf"] and tf["ndf"].dtype.name == "float32"
    assert not tf["ndf"].flags.writeable
    with pytest.raises(DataFormatError, match=r"<bytes>: field 'version': expected 1.0, found 2.0"):
        read_tensor_file(MAGIC + bytes([2, 0, 0, 0, 0, 0]))
    with pytest.raises(DataFormatError, match="field 'file': expected a tensor file, found an empty file"):
        read_rgl(b"")


def test_rgl_uniform_eval_samples_table_albedo():
    grey = read_rgl(tensor_file_bytes(uniform_fields(0.5, description="grey")))
    f = grey.eval_cos([[0.0, 0.6, 0.8], [0.0, 0.6, -0.8]], [[0.0, -0.6, 0.8], [0.0, -0.6, 0.8]])
    assert f.tolist() == [[0.125, 0.125, 0.125], [0.0, 0.0, 0.0]]
    assert grey.eval([0.0, 0.6, 0.8], [0.0, -0.6, 0.8]).round(6).tolist() == [[0.15625] * 3]  # 0.125 / cos
    wo, wi, f, valid = grey.stored_samples()
    assert f.shape == (64, 3) and int(valid.sum()) == 32 and np.allclose(f[valid] * wo[valid, 2:], 0.125)
    t = grey.to_table()
    assert (len(t), t.n_valid, t.provenance["material"]) == (64, 32, "grey")
    a = grey.albedo(np.radians(30.0), n=16)
    assert a.shape == (3,) and np.all(a == a[0]) and 0 < a[0] < 1


# ----------------------------------------------------------------------------------------- matfit.export
def test_export_result_document_text_write_dict(tmp_path):
    from matfit.export import export, to_gltf, to_mitsuba, to_pbrt
    from matfit.models import Lambert

    r = to_mitsuba(Lambert([0.5, 0.4, 0.3]))
    assert (r.target, r.exact, r.fidelity) == ("mitsuba", True, None)
    assert r.content["reflectance"] == {"type": "rgb", "value": [0.5, 0.4, 0.3]}
    assert export(Lambert(0.5), "mitsuba").content["type"] == "diffuse"
    assert json.loads(to_gltf(Lambert(0.5)).text())["asset"]["version"] == "2.0"
    p = to_pbrt(Lambert(0.5)).write(tmp_path / "scene" / "material.pbrt")
    assert p.name == "material.pbrt" and p.read_text().splitlines()[0] == "# matfit export: Lambert (exact)"
    assert p.read_text().endswith("\n")
    d = to_pbrt(Lambert(0.5)).to_dict()
    assert (d["exact"], d["mapping"][0]["target"], d["fidelity"]) == (True, "reflectance", None)


def test_export_helpers_numbers_colours_ndf():
    from matfit.export import describe_model
    from matfit.export._model_file import describe_ndf, ndf_from_description, plain_numbers
    from matfit.export._result import rgb
    from matfit.microfacet import GGX, TabulatedNDF
    from matfit.models import Lambert

    assert plain_numbers(np.float32(0.4)) == 0.4 and plain_numbers(np.array([0.1, 0.2], np.float32)) == [0.1, 0.2]
    assert rgb("to_gltf", np.float32(0.4)) == [0.4, 0.4, 0.4] and rgb("to_gltf", [0.1, 0.2, 0.3]) == [0.1, 0.2, 0.3]
    with pytest.raises(ParameterError, match="to_gltf: colours have 3 channels, the model has 2"):
        rgb("to_gltf", [0.1, 0.2])
    assert describe_model(Lambert([0.5, 0.4, 0.3]))["type"] == "Lambert"
    d = describe_ndf(TabulatedNDF.from_distribution(GGX(0.3), n=16, n_lambda=32))
    assert (d["type"], len(d["theta"]), len(d["d"]), d["n_lambda"]) == ("TabulatedNDF", 16, 16, 32)
    tab = TabulatedNDF.from_distribution(GGX(0.3), n=64)
    assert round(float(ndf_from_description(describe_ndf(tab)).alpha_x), 3) == 0.3


def test_hemisphere_pairs_and_measure_of_identical_models():
    from matfit.export import hemisphere_pairs, measure
    from matfit.models import Lambert

    wo, wi = hemisphere_pairs(Lambert(0.5), n=64)
    assert wo.shape == wi.shape == (64, 3) and (wo[:, 2] >= 0.02).all() and (wi[:, 2] > 0).all()
    f = measure(Lambert(0.5), Lambert(0.5))
    assert (f.relative_rmse, f.ciede2000, f.method) == (0.0, 0.0, "fitted")


def test_materialx_standard_library_has_standard_surface():
    pytest.importorskip("MaterialX")
    from matfit.export._materialx import standard_library

    assert standard_library().getNodeDef("ND_standard_surface_surfaceshader") is not None


# ----------------------------------------------------------------------------------------- matfit.maps
def _lambert_map(albedo=0.3):
    """A 1 x 2 lambert MapResult built by hand (no fit)."""
    from matfit.maps import MapResult

    shape = (1, 2)
    return MapResult(family="lambert", labels=["albedo[0]", "albedo[1]", "albedo[2]"],
                     params={"albedo": np.full(shape + (3,), albedo, np.float32)},
                     stderr={"albedo": np.full(shape + (3,), 0.01, np.float32)},
                     objective=np.zeros(shape, np.float32), rel_rmse=np.zeros(shape, np.float32),
                     converged=np.ones(shape, bool), at_bound=np.zeros(shape, bool), fitted=np.ones(shape, bool),
                     steps=np.ones(shape, np.int32), n_measurements=np.full(shape, 3, np.int32),
                     suspect=np.zeros(shape, bool), refitted=0, noise_level=float("nan"), wall_time=1.0)


def test_map_result_model_at_summary_and_gltf_maps():
    from matfit.maps import gltf_maps

    r = _lambert_map()
    m = r.model_at(0, 1)
    assert type(m).__name__ == "Lambert" and [round(float(x), 4) for x in m.reflectance] == [0.3, 0.3, 0.3]
    lines = r.summary().splitlines()
    assert lines[0].split(" in ")[0] == "lambert map 1x2: 2 texels fitted"
    assert lines[3].split(",")[0] == "  albedo     median 0.3 0.3 0.3"
    images, material, notes = gltf_maps(r)
    assert sorted(images) == ["base_color.png"] and material["pbrMetallicRoughness"]["metallicFactor"] == 0.0


def test_initialize_processes_checks_its_arguments():
    from matfit.maps import initialize_processes

    with pytest.raises(ParameterError, match="num_processes must be an integer >= 1, got 0"):
        initialize_processes("127.0.0.1:1", 0, 0)
    with pytest.raises(ParameterError, match="process_id must be < num_processes = 2, got 2"):
        initialize_processes("127.0.0.1:1", 2, 2)
    with pytest.raises(ParameterError, match="coordinator must be 'host:port'"):
        initialize_processes("localhost", 1, 0)


def test_image_rows_finish_close_and_png_clipping(tmp_path):
    from matfit.maps import read_image, write_exr, write_png
    from matfit.maps._images import open_image_rows

    write_exr(tmp_path / "flat.exr", np.ones((3, 4)))
    im = open_image_rows(tmp_path / "flat.exr")
    with pytest.raises(ValueError, match="3 rows not read"):
        im.finish()
    im.read(3)
    im.finish()
    im.close()  # idempotent
    write_png(tmp_path / "rgb.png", np.full((4, 5, 3), 2.0))  # clipped to 1, 16-bit by default
    pixels, info = read_image(tmp_path / "rgb.png")
    assert float(pixels.min()) == 1.0 and pixels.shape == (4, 5, 3) and info["bit_depth"] == 16


def test_write_capture_document_fills_format_and_lists(tmp_path):
    from matfit.maps import CaptureError, write_capture_document

    p = write_capture_document(tmp_path, {"images": ["a.png"], "lights": np.array([[0.0, 0.0, 1.0]]),
                                          "camera": [0, 0, 1]})
    doc = json.loads(p.read_text())
    assert (p.name, doc["format"], doc["version"], doc["lights"]) == ("capture.json", "matfit-capture", 1,
                                                                     [[0.0, 0.0, 1.0]])
    with pytest.raises(CaptureError, match="unknown key 'light'"):
        write_capture_document(tmp_path, {"light": [0, 0, 1]})
