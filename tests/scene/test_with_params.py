"""Scene.with_params: the same geometry with some parameters replaced, checked as build_scene checks them."""

import pytest
import torch

import invrender as ir
from invrender.errors import ParameterError


@pytest.fixture()
def cbox():
    return ir.load_scene("cornell_box", resolution=(8, 8))


def test_values_replaced_geometry_and_the_other_parameters_shared(cbox):
    red = torch.tensor([0.5, 0.1, 0.1])
    new = cbox.with_params({"red.reflectance": red, "light.emission": [10.0, 9.0, 8.0], "green.reflectance": 0.25})
    assert new.triangles is cbox.triangles and new.camera is cbox.camera and new.materials == cbox.materials
    assert new.params["red.reflectance"] is red  # a tensor is used as it is
    assert torch.equal(new.params["light.emission"], torch.tensor([10.0, 9.0, 8.0]))
    assert new.params["light.emission"].dtype == torch.float32
    assert torch.equal(new.params["green.reflectance"], torch.full((3,), 0.25))  # one number stands for three
    assert new.params["white.reflectance"] is cbox.params["white.reflectance"]
    assert not torch.equal(cbox.params["red.reflectance"], red)  # the original scene keeps its values
    assert cbox.with_params().params == cbox.params


def test_a_replaced_tensor_keeps_its_graph(cbox):
    raw = torch.zeros(3, requires_grad=True)
    new = cbox.with_params({"red.reflectance": torch.sigmoid(raw)})
    new.params["red.reflectance"].sum().backward()
    assert torch.allclose(raw.grad, torch.full((3,), 0.25))


def test_detached_copies_share_no_parameter_tensor(cbox):
    leaf = torch.tensor([0.3, 0.3, 0.3], requires_grad=True)
    own = cbox.with_params({"red.reflectance": leaf}, detach=True)
    assert own.triangles is cbox.triangles
    for name, value in own.params.items():
        original = leaf if name == "red.reflectance" else cbox.params[name]
        assert value is not original and torch.equal(value, original.detach()) and not value.requires_grad
    with torch.no_grad():
        own.params["white.reflectance"].fill_(0.0)
    assert float(cbox.params["white.reflectance"].min()) > 0
    assert cbox.with_params(detach=True).params.keys() == cbox.params.keys()


@pytest.mark.parametrize(
    ("values", "message"),
    [
        ({"blue.reflectance": 0.5}, r"^unknown parameter 'blue.reflectance' \(did you mean 'red.reflectance'\?\) \(known: white.reflectance, red.reflectance, green.reflectance, light.emission\)$"),
        ({"ambient.emission": 0.1}, r"^the scene has no ambient.emission"),
        ({"red.reflectance": [1.5, 0.1, 0.1]}, r"^red.reflectance: reflectance rho must lie in \[0, 1\], got values in \[0.1, 1.5\]$"),
        ({"red.reflectance": torch.tensor([0.5, -0.1, 0.1], requires_grad=True)}, r"^red.reflectance: reflectance rho must lie in \[0, 1\]"),
        ({"light.emission": [1.0, float("nan"), 1.0]}, r"^light.emission: values must be finite$"),
        ({"light.emission": [1.0, 1e39, 1.0]}, r"^light.emission: value 1e\+39 is beyond float32's range \(\|x\| <= 3.403e\+38\): a render would compute with infinity$"),
        ({"light.emission": torch.ones(2)}, r"^light.emission: expected shape \(3,\) or \(h, w, 3\), got \(2,\)$"),
        ({"light.emission": "bright"}, r"^light.emission: expected an RGB triple or an \(h, w, 3\) texture, got 'bright'$"),
    ],
)
def test_a_bad_name_or_value_is_a_one_line_error(cbox, values, message):
    with pytest.raises(ParameterError, match=message) as error:
        cbox.with_params(values)
    assert "\n" not in str(error.value)


def test_looking_up_an_unknown_name_in_params_names_the_closest_and_all(cbox):
    """``scene.params[name]`` of a misspelt name: a one-line ParameterError with the closest known
    name and the list, which ``except KeyError`` still catches; ``get`` and ``in`` stay a dict's."""
    from invrender.errors import UnknownParameterError

    with pytest.raises(KeyError) as error:
        cbox.params["red.reflectence"]
    assert isinstance(error.value, UnknownParameterError) and isinstance(error.value, ParameterError)
    assert str(error.value) == "unknown parameter 'red.reflectence' (did you mean 'red.reflectance'?) (known: white.reflectance, red.reflectance, green.reflectance, light.emission)"
    assert cbox.params.get("red.reflectence") is None and "red.reflectence" not in cbox.params
    for scene in (cbox.with_params(detach=True), cbox.to("cpu"), cbox.with_ambient(0.1)):  # every copy keeps the behaviour
        with pytest.raises(UnknownParameterError, match=r"^unknown parameter 'nothing' \(known: "):
            scene.params["nothing"]
