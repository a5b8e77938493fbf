"""The typed file header: to_dict writes what the encoder always wrote, from_dict checks every field."""

import pytest

from gspc.errors import CodecError
from gspc.format import container
from gspc.format.attribute_section import AttributeSection
from gspc.format.chunks import ATTRIBUTE_TYPES, KNOWN_TYPES, REGISTRY
from gspc.format.header import FileHeader, SceneSummary, SideInfoHeader

ATTRIBUTES = {
    "version": 1,
    "n": 2,
    "sh_degree": 0,
    "position": {"bits": 11, "lo": [0.0, 0.0, 0.0], "step": [0.1, 0.1, 0.1]},
    "opacity_levels": 21,
    "scale_step": 0.1,
    "rotation_levels": 18,
    "dc_step": 0.05,
    "sh_steps": [],
}


def header() -> FileHeader:
    return FileHeader(
        attributes=AttributeSection.from_dict(ATTRIBUTES),
        side_info=SideInfoHeader((1.0, 1.0, 1.0), "none", 300),
        scene=SceneSummary(2, 0, 5),
        encoder="gspc test",
    )


def test_round_trip_and_key_order():
    d = header().to_dict()
    assert list(d) == ["encoder", "scene", "attributes", "side_info"]
    assert d["attributes"] == ATTRIBUTES and list(d["attributes"]) == list(ATTRIBUTES)
    assert list(d["side_info"]) == ["background", "restorer", "refine_iterations"]
    assert FileHeader.from_dict(d) == header()
    packed = container.unpack(container.pack(d, [])).header
    assert FileHeader.from_dict(packed).to_dict() == d


@pytest.mark.parametrize(
    "path, value, words",
    [
        (("side_info", "refine_iterations"), -1, "refine_iterations"),
        (("side_info", "background"), [2.0, 0.0, 0.0], "background"),
        (("side_info", "restorer"), 7, "restorer"),
        (("attributes", "n"), 1.5, "not an integer"),
        (("attributes", "version"), 9, "version"),
    ],
)
def test_from_dict_refuses_bad_fields(path, value, words):
    d = header().to_dict()
    d[path[0]] = {**d[path[0]], path[1]: value}
    with pytest.raises(CodecError, match=words):
        FileHeader.from_dict(d)


def test_defaults_of_optional_fields():
    d = header().to_dict()
    del d["side_info"]["refine_iterations"], d["side_info"]["restorer"], d["scene"], d["encoder"]
    h = FileHeader.from_dict(d)
    assert (h.side_info.refine_iterations, h.side_info.restorer) == (300, "none")
    assert h.scene is None and h.encoder is None


def test_one_registry_of_chunk_types():
    assert set(ATTRIBUTE_TYPES) <= KNOWN_TYPES == set(REGISTRY)
    registered = {"POSN", "PREC", "OPAC", "SCAL", "ROTN", "SHDC", "SHRS", "RESI", "SIDE", "TIDX", "TSID"}
    assert KNOWN_TYPES == registered
