"""Attribute codec version 5: the SH rest by codebook (spec 10.16), the encoder's fit and the decoder's
cells."""

from dataclasses import replace

import msgpack
import numpy as np
import pytest
import torch
from scenes import random_scene
from test_precision import PARAMS, _significance

from gspc.codec.attributes import decode_attributes, decoded_precision
from gspc.codec.cells import quantisation_cells
from gspc.encoder.codebook import fit_codebook
from gspc.encoder.coding import encode_attributes
from gspc.encoder.params import SHRules
from gspc.errors import CodecError
from gspc.format.attribute_section import AttributeSection
from gspc.format.chunks import SHRS
from gspc.scene import scene_equal

BOOK = replace(PARAMS, sh_codebook=32)  # at most 32 entries: the rule asks for more here


@pytest.mark.parametrize("degree", [1, 3])
def test_round_trip_and_every_coded_gaussian_takes_an_entry(degree):
    scene = random_scene(500, sh_degree=degree, seed=degree)
    enc = encode_attributes(scene, BOOK, significance=_significance(500, degree, seed=degree))
    section = enc.section
    assert section.version == 5 and 1 <= section.codebook <= 32
    again = AttributeSection.from_dict(section.to_dict())
    assert again == section
    dec = decode_attributes(enc.chunks, again)
    assert scene_equal(dec, enc.decoded)
    pmap = decoded_precision(enc.chunks, section)
    assert set(np.unique(pmap.degrees).tolist()) <= {0, degree}  # an entry carries every band
    coded = torch.from_numpy(pmap.degrees > 0)
    rest = dec.sh_rest[coded].flatten(1)
    assert len(torch.unique(rest, dim=0)) <= section.codebook  # the coded SH rest is one of E entries
    assert not dec.sh_rest[~coded].any()


def test_entries_are_ordered_by_use_and_fit_the_weighted_rows():
    rng = np.random.default_rng(1)
    centres = rng.normal(size=(4, 3, 3))
    rest = np.repeat(centres, [50, 30, 15, 5], axis=0) + rng.normal(scale=1e-3, size=(100, 3, 3))
    rows = np.arange(100)
    book = fit_codebook(rest, rows, np.ones(100), 4, np.full(3, 1e-3))
    counts = np.bincount(book.index)
    assert counts.tolist() == [50, 30, 15, 5]  # the most taken entry first: the smallest indices
    assert np.abs(book.entries.reshape(4, 3, 3) * 1e-3 - centres).max() < 2e-3
    again = fit_codebook(rest, rows, np.ones(100), 4, np.full(3, 1e-3))
    assert (again.entries == book.entries).all() and (again.index == book.index).all()


def test_a_row_outside_the_coded_ones_has_no_entry():
    rest = np.random.default_rng(2).normal(size=(20, 3, 3))
    book = fit_codebook(rest, np.arange(0, 20, 2), np.ones(20), 4, np.full(3, 0.1))
    assert (book.index[1::2] == -1).all() and (book.index[::2] >= 0).all()


def test_cells_are_class_zero_steps_around_each_entry():
    scene = random_scene(400, sh_degree=2, seed=5)
    enc = encode_attributes(scene, BOOK, significance=_significance(400, 2, seed=5))
    pmap = decoded_precision(enc.chunks, enc.section)
    assert len(enc.section.classes) >= 1  # several classes, one step for the SH rest
    lo, hi = quantisation_cells(enc.decoded, enc.section, pmap)["sh_rest"]
    coded = torch.from_numpy(pmap.degrees > 0)
    steps = torch.tensor(enc.section.sh_steps, dtype=lo.dtype)[None, :, None]
    width = (hi - lo)[coded]
    assert torch.allclose(width, (2 * steps).expand_as(width))
    assert torch.isinf(lo[~coded]).all()  # no SH rest coded: nothing bounds it


def test_a_codebook_index_past_its_entries_is_refused():
    scene = random_scene(200, sh_degree=1, seed=6)
    enc = encode_attributes(scene, BOOK, significance=_significance(200, 1, seed=6))
    entries, index = msgpack.unpackb(enc.chunks[SHRS])
    with pytest.raises(CodecError, match="not an array of 2 msgpack bins"):
        decode_attributes({**enc.chunks, SHRS: msgpack.packb([entries])}, enc.section)
    with pytest.raises(CodecError, match="codebook"):
        AttributeSection.from_dict(dict(enc.section.to_dict(), codebook=201))
    with pytest.raises(CodecError, match="lacks codebook"):
        AttributeSection.from_dict({k: v for k, v in enc.section.to_dict().items() if k != "codebook"})


def test_sh_rules_name_the_codebook():
    rules = SHRules(4.0, 0.0, 0.02, 1024)
    assert rules.words() == "SH rest by a codebook of up to 1,024 entries"
    assert BOOK.with_sh_rules(rules).sh_codebook == 1024
    assert BOOK.with_sh_rules(rules).sh_rules == rules
