"""USD export (``to_usd``): usd-core opens the layer; its UsdPreviewSurface's inputs are the
shader's own (names and types from usd-core's shader registry) with the values of the mapping,
and its OpenPBR shader's are those of MaterialX's ``open_pbr_surface`` node definition with the
values of ``to_openpbr``; a Lambertian material is exact, the new lobes (anisotropy, thin film,
sheen) travel in the OpenPBR shader."""

import numpy as np
import pytest

from matfit.errors import ParameterError
from matfit.export import export, to_openpbr, to_usd
from matfit.models import Lambert, MultiLobe, Rotated, RoughConductor, Sheen, SmoothDielectric, SpecularLobe

pxr = pytest.importorskip("pxr", reason="usd-core is not installed")
mx = pytest.importorskip("MaterialX", reason="materialx is not installed")

GOLD_ETA, GOLD_K = np.array([0.143, 0.374, 1.442]), np.array([3.983, 2.385, 1.603])


def _open(result, tmp_path):
    from pxr import Usd, UsdShade

    path = result.write(tmp_path / "material.usda")
    stage = Usd.Stage.Open(str(path))
    assert stage is not None and stage.GetDefaultPrim().GetPath().pathString == "/matfit"
    material = UsdShade.Material(stage.GetPrimAtPath("/matfit/Material"))
    # the stage travels with the shaders (they expire with it)
    return material.ComputeSurfaceSource()[0], material.ComputeSurfaceSource("mtlx")[0], stage


def _value(inp):
    v = inp.Get()
    return [float(x) for x in v] if hasattr(v, "__len__") else v


def _check_inputs(result, prefix, shader, declared):
    """The shader's inputs are the mapping's entries under ``prefix`` (names and values), each of
    the type ``declared(name)`` gives (None: the shader has no such input)."""
    want = {m.target[len(prefix):]: m.value for m in result.mapping if m.target.startswith(prefix)}
    got = {i.GetBaseName(): i for i in shader.GetInputs()}
    assert set(got) == set(want)
    for name, inp in got.items():
        kind = declared(name)
        assert kind is not None, name
        assert str(inp.GetTypeName()) == kind, name
        np.testing.assert_allclose(_value(inp), want[name], rtol=1e-6, err_msg=name)


def _check_shaders(result, preview, openpbr):
    from pxr import Sdr

    from matfit.export._materialx import standard_library

    # UsdPreviewSurface: usd-core's shader registry names every input, with its type
    node = Sdr.Registry().GetShaderNodeByIdentifier("UsdPreviewSurface")
    assert preview.GetIdAttr().Get() == "UsdPreviewSurface"

    def preview_type(name):
        sdr = node.GetShaderInput(name)
        return None if sdr is None else str(sdr.GetTypeAsSdfType().GetSdfType())

    _check_inputs(result, "preview:", preview, preview_type)
    # OpenPBR: MaterialX's node definition names every input, with its type
    nodedef = standard_library().getNodeDef("ND_open_pbr_surface_surfaceshader")
    assert openpbr.GetIdAttr().Get() == nodedef.getName()

    def openpbr_type(name):
        spec = nodedef.getActiveInput(name)
        return None if spec is None else {"color3": "color3f", "float": "float"}[spec.getType()]

    _check_inputs(result, "openpbr:", openpbr, openpbr_type)


@pytest.mark.check
def test_lambert_is_exact_in_both_shaders(tmp_path):
    r = to_usd(Lambert([0.5, 0.4, 0.3]))
    preview, openpbr, _stage = _open(r, tmp_path)
    _check_shaders(r, preview, openpbr)
    assert r.exact and r.fidelity is None
    assert [float(x) for x in preview.GetInput("diffuseColor").Get()] == pytest.approx([0.5, 0.4, 0.3])
    assert list(preview.GetInput("specularColor").Get()) == [0, 0, 0]
    assert export(Lambert(0.2), "usd").target == "usd"


@pytest.mark.parametrize("which", ["brushed", "film", "sheen"])
def test_new_lobes_travel_in_the_openpbr_shader(which, tmp_path):
    model = {"brushed": Rotated(RoughConductor(0.08, GOLD_ETA, GOLD_K, alpha_y=0.35), 0.6),
             "film": MultiLobe(np.array([0.05, 0.05, 0.05]), [SpecularLobe(0.08, "thin_film", 1.0, thickness=420.0,
                                                                           film_eta=1.8, eta=1.5)]),
             "sheen": Sheen(Lambert([0.5, 0.4, 0.3]), [0.3, 0.3, 0.3], 0.4)}[which]
    r = to_usd(model)
    preview, openpbr, _stage = _open(r, tmp_path)
    _check_shaders(r, preview, openpbr)
    assert not r.exact
    carried = {"brushed": "specular_roughness_anisotropy", "film": "thin_film_thickness", "sheen": "fuzz_color"}[which]
    assert openpbr.GetInput(carried) is not None and openpbr.GetInput(carried).Get() is not None
    # the OpenPBR shader is to_openpbr's, value for value, and the preview surface names what it drops
    ref = {m.target: m.value for m in to_openpbr(model).mapping}
    assert {m.target[8:]: m.value for m in r.mapping if m.target.startswith("openpbr:")} == ref
    assert any("UsdPreviewSurface has no" in n for n in r.notes), r.notes


def test_a_model_openpbr_cannot_take_is_refused():
    with pytest.raises(ParameterError, match="to_usd, through OpenPBR's glTF stand-in: to_gltf: SmoothDielectric has a Dirac lobe"):
        to_usd(SmoothDielectric(1.5))
    with pytest.raises(ParameterError, match="to_usd: model must be a matfit model"):
        to_usd("gold")
