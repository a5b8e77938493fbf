"""The .gspc header (spec 10.8) as a typed value: :class:`FileHeader` with ``to_dict`` (what the encoder
writes) and a validating ``from_dict`` (what the decoder, ``gspc info`` and the tools read).

The container (gspc/format/container.py) guarantees only a msgpack map; every field below comes from an
untrusted file, so each is checked here before use and a bad one is refused with a CodecError that names the
field and its value (issue 15). The sections are typed records, each checked where it is defined: the
attribute codec's in gspc/format/attribute_section.py, the 1.0 layout's view records in
gspc/format/view_records.py; payload checks (counts against payload sizes, model tables) belong to the
codecs themselves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from gspc.errors import CodecError
from gspc.format.attribute_section import MAX_SH_DEGREE, AttributeSection
from gspc.format.coordinates import CONVENTIONS as COORDINATE_CONVENTIONS
from gspc.format.side_chunk import legacy_views
from gspc.format.view_records import ViewRecord
from gspc.limits import MAX_REFINE_ITERATIONS

DEFAULT_ITERATIONS = 300  # decoder refinement when the file names none (spec: side_info.refine_iterations)
UNNAMED_RESTORER = "none"  # the restorer when the file names none (the encoder names one)


def _show(value: object) -> str:
    """A value for an error message, cut short: a hostile header may hold megabytes in one field."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_int(v: object) -> bool:
    return type(v) is int  # bool is an int subclass but not a msgpack integer


def _is_number(v: object) -> bool:
    return _is_int(v) or type(v) is float


def _map(parent: dict, key: str, where: str) -> dict:
    if key not in parent:
        raise CodecError(f"the .gspc header lacks {where}")
    v = parent[key]
    if not isinstance(v, dict):
        raise CodecError(f"the .gspc header's {where} is {_show(v)}, not a map")
    return v


def _int(
    parent: dict, key: str, where: str, lo: int, hi: int | None = None, default: int | None = None
) -> int:
    if key not in parent and default is not None:
        return default
    if key not in parent:
        raise CodecError(f"the .gspc header lacks {where}")
    v = parent[key]
    if not (_is_int(v) and v >= lo and (hi is None or v <= hi)):
        span = f"in {lo}..{hi}" if hi is not None else f">= {lo}"
        raise CodecError(f"the .gspc header's {where} is {_show(v)}, not an integer {span}")
    return v


def _finite(v: object, where: str, positive: bool = False) -> float:
    if not (_is_number(v) and math.isfinite(v) and (v > 0 or not positive)):
        want = "a positive finite number" if positive else "a finite number"
        raise CodecError(f"the .gspc header's {where} is {_show(v)}, not {want}")
    return float(v)


def _numbers(parent: dict, key: str, where: str, length: int, positive: bool = False) -> list[float]:
    if key not in parent:
        raise CodecError(f"the .gspc header lacks {where}")
    v = parent[key]
    if not (isinstance(v, list) and len(v) == length):
        raise CodecError(f"the .gspc header's {where} is {_show(v)}, not a list of {length} numbers")
    return [_finite(x, f"{where}[{i}]", positive) for i, x in enumerate(v)]


def _background(side: dict) -> tuple[float, float, float]:
    where = "side_info.background"
    if "background" not in side:
        raise CodecError(f"the .gspc header lacks {where}")
    rgb = _numbers(side, "background", where, 3)
    if not all(0.0 <= v <= 1.0 for v in rgb):
        raise CodecError(f"the .gspc header's {where} is {_show(side['background'])}, not RGB in [0, 1]")
    return rgb[0], rgb[1], rgb[2]


def _restorer(side: dict) -> str:
    v = side.get("restorer", UNNAMED_RESTORER)
    if not (isinstance(v, str) and 0 < len(v) <= 200):
        raise CodecError(f"the .gspc header's side_info.restorer is {_show(v)}, not a restorer name")
    return v


@dataclass(frozen=True)
class SceneSummary:
    """The informative ``scene`` section: counts for people (``gspc info``); decoders use attributes.n."""

    num_gaussians: int = 0
    sh_degree: int | None = None
    source_gaussians: int | None = None  # the count the encoder received
    coordinates: str | None = None  # the axis convention the source stated (spec 10.8)
    psnr_db: float | None = None  # the fidelity the encoder measured, where it coded to one (spec 10.8)

    def to_dict(self) -> dict:
        out: dict = {"num_gaussians": self.num_gaussians}
        if self.sh_degree is not None:
            out["sh_degree"] = self.sh_degree
        if self.source_gaussians is not None:
            out["source_gaussians"] = self.source_gaussians
        if self.coordinates is not None:
            out["coordinates"] = self.coordinates
        if self.psnr_db is not None:
            out["psnr_db"] = float(self.psnr_db)
        return out

    @classmethod
    def from_dict(cls, meta: dict) -> SceneSummary:
        """The ``scene`` section of a header ``meta``; missing fields (files written by other tools may lack
        the section) give zero and None, present ones must be well typed."""
        if "scene" not in meta:
            return cls()
        scene = _map(meta, "scene", "scene section")
        n = _int(scene, "num_gaussians", "scene.num_gaussians", 0, None, 0)
        degree = _int(scene, "sh_degree", "scene.sh_degree", 0, MAX_SH_DEGREE, -1)
        source = scene.get("source_gaussians")  # informative only: never refused
        coordinates = scene.get("coordinates")  # informative: a value naming no convention is ignored
        psnr = scene.get("psnr_db")  # informative: a value that is not a finite float is ignored
        return cls(
            n,
            None if degree < 0 else degree,
            source if _is_int(source) and source >= 0 else None,
            coordinates if coordinates in COORDINATE_CONVENTIONS else None,
            psnr if isinstance(psnr, float) and math.isfinite(psnr) else None,
        )


@dataclass(frozen=True)
class SideInfoHeader:
    """The ``side_info`` section: how the decoder renders, restores and refines."""

    background: tuple[float, float, float]
    restorer: str
    refine_iterations: int
    # The 1.0 layout's view records (its ``views`` key); 1.1 files carry their views in a SIDE chunk, and
    # gspc/format/side_chunk.py reads both layouts.
    legacy_views: tuple[ViewRecord, ...] = ()

    def to_dict(self) -> dict:
        out: dict = {
            "background": list(self.background),
            "restorer": self.restorer,
            "refine_iterations": self.refine_iterations,
        }
        if self.legacy_views:
            out["views"] = [v.to_dict() for v in self.legacy_views]
        return out

    @classmethod
    def from_dict(cls, side: dict) -> SideInfoHeader:
        views = legacy_views(side["views"]) if "views" in side else ()
        iterations = _int(
            side,
            "refine_iterations",
            "side_info.refine_iterations",
            0,
            MAX_REFINE_ITERATIONS,
            DEFAULT_ITERATIONS,
        )
        return cls(_background(side), _restorer(side), iterations, views)


@dataclass(frozen=True)
class FileHeader:
    """A .gspc file's header: the attribute codec's section (None in a tiled file, whose sections are in its
    tile index: spec 10.14), the side information's, the informative scene summary and the writer's name."""

    attributes: AttributeSection | None
    side_info: SideInfoHeader
    scene: SceneSummary | None = None
    encoder: str | None = None

    def to_dict(self) -> dict:
        """The header map the container stores (key order is part of the bytes: keep it)."""
        out: dict = {}
        if self.encoder is not None:
            out["encoder"] = self.encoder
        if self.scene is not None:
            out["scene"] = self.scene.to_dict()
        if self.attributes is not None:
            out["attributes"] = self.attributes.to_dict()
        out["side_info"] = self.side_info.to_dict()
        return out

    @classmethod
    def from_dict(cls, meta: dict, tiled: bool = False) -> FileHeader:
        """The header sections gspc 1 writes (spec 10.8), checked field by field; CodecError otherwise.
        ``tiled``: the file has a tile index, and no attribute section of its own (spec 10.14)."""
        if tiled:
            if "attributes" in meta:
                raise CodecError("a tiled file's header has an attributes section; its tiles hold theirs")
            attributes = None
        else:
            attributes = AttributeSection.from_dict(_map(meta, "attributes", "attributes section"))
        side = SideInfoHeader.from_dict(_map(meta, "side_info", "side_info section"))
        scene = SceneSummary.from_dict(meta) if "scene" in meta else None
        encoder = meta.get("encoder")
        return cls(attributes, side, scene, encoder if isinstance(encoder, str) else None)
