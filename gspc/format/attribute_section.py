"""The attribute codec's header section (spec 10.0, ``meta["attributes"]``) as a typed, frozen record:
:class:`AttributeSection` with its :class:`PositionGrid` (a box, or a contracted grid with its
:class:`Contraction` and optionally a :class:`FarSet`).

Every field is checked here and nowhere else: ``from_dict`` checks the msgpack types of an untrusted
header, and each record's ``__post_init__`` checks the ranges, so a record the encoder builds obeys the same
rules as one read from a file (CodecError naming the field). ``to_dict`` is what the encoder writes: its key
order is part of the file's bytes. No numpy or torch here: ``gspc info`` reads headers.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from gspc.errors import CodecError
from gspc.format.chunks import ATTRIBUTE_TYPES, PREC, SHRS
from gspc.limits import max_coded_gaussians

FORMAT_VERSION = 1
# Version 2: the position grid may lie in contracted space (gspc/codec/positions.py, spec 10.1); written only
# then, so bounded scenes keep version 1 and their bytes. Version 3: a contracted grid with a far set coded
# on a coarser grid; written only where one pays.
CONTRACTED_VERSION = 2
FAR_VERSION = 3
# Version 4: per-Gaussian precision classes and SH degrees (chunk PREC, spec 10.13) on any of the three grids,
# which its position keys tell apart.
PRECISION_VERSION = 4
# Version 5: version 4 with the SH rest by codebook (spec 10.16): shared entries and one index per Gaussian
# with view-dependent colour; written only where the encoder's trial keeps it (gspc/encoder/removal.py).
CODEBOOK_VERSION = 5
VERSIONS = (FORMAT_VERSION, CONTRACTED_VERSION, FAR_VERSION, PRECISION_VERSION, CODEBOOK_VERSION)
# Precision classes per file at version 4 (class 0 and at most 15 more): each class's rows are their own
# matrices in every chunk, so the count bounds the number of matrices a file may ask for.
MAX_CLASSES = 16
# Codebook entries per section at version 5 (and at most its count n): bounds the entries' matrix whatever
# its bytes say.
MAX_CODEBOOK = 1 << 16
MAX_GAUSSIANS = 1 << 26
# The count is also bounded by the attribute payloads' bytes (gspc/limits.py max_coded_gaussians), checked
# where the payloads are (gspc/codec/attributes.py decode_attributes).
MAX_SH_DEGREE = 3

MAX_BITS = 17  # plain grid (version 1): 3 * 17 = 51 bits per code
# Contracted grid (versions 2, 3): 3 * 21 = 63 bits per code, the most an int64 holds; the far octaves need
# the extra bits to keep the foreground's voxel size.
CONTRACTED_MAX_BITS = 21

# Bounds of the position fields (spec 10.1), so that the decoder's binary64 steps stay finite and every
# decoded coordinate is a finite binary32 (finite values such as 1e20..1e300 overflow in the expansion).
# World coordinates (a box grid's corners, a contracted grid's centre and radius): 2^64 is far beyond any
# scene, and a box grid's decoded coordinates then stay below 2^82.
MAX_COORDINATE = 2.0**64
# A contracted grid's corners in grid space: |y_a| <= 32 keeps rho = |y| below 56, so the octave e =
# floor(rho - 1) is at most 54 and R 2^(e + 1) <= 2^120 (a grid point at 32 is 2^31 radii away).
MAX_CONTRACTED = 32.0
# On every axis a grid spans at least 2^-24 of the coordinates at its corners (and a contracted grid of its
# centre): binary32 holds 24 significant bits, so a grid spanning less decodes every Gaussian onto one
# binary32 coordinate on that axis whatever its payload says (a grid at lo = 2^64 did). Spec 10.1.
RESOLUTION = 2.0**-24
# Quantiser steps (scale_step, dc_step, sh_steps, of every class): a decoded integer is at most 2^48 in
# magnitude (spec 10.0), so a step of at most 2^64 keeps every decoded value a finite binary32 (a step of
# 3.4e38 decoded infinite values).
MAX_STEP = 2.0**64


def _show(value: object) -> str:
    """A value for an error message, cut short: a hostile header may hold megabytes in one field."""
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _is_int(v: object) -> bool:
    return type(v) is int  # bool is an int subclass but not a msgpack integer


def _fail(field: str, value: object, want: str) -> CodecError:
    return CodecError(f"attribute codec header's {field} is {_show(value)}, not {want}")


def _get(d: dict, key: str, where: str) -> object:
    if key not in d:
        raise CodecError(f"attribute codec header is malformed (it lacks {where})")
    return d[key]


def _integer(d: dict, key: str, where: str) -> int:
    v = _get(d, key, where)
    if not _is_int(v):
        raise _fail(where, v, "an integer")
    return v


def _floats(d: dict, key: str, where: str, length: int | None = None) -> tuple[float, ...]:
    """A msgpack float, or an array of them (``length``), as Python floats; range checks are the records'."""
    v = _get(d, key, where)
    if length is None:
        if type(v) is not float:
            raise _fail(where, v, "a float")
        return (v,)
    if not (isinstance(v, list | tuple) and all(type(x) is float for x in v)):
        raise _fail(where, v, "an array of floats")
    if len(v) != length:
        raise _fail(where, v, f"an array of {length} floats")
    return tuple(v)


def _bound(most: float) -> str:
    """A bound as the spec writes it: 2^64, or 32."""
    return "2^64" if most == MAX_COORDINATE else f"{most:g}"


def _positive(values: tuple[float, ...], where: str, most: float = math.inf) -> None:
    if not all(math.isfinite(v) and 0 < v <= most for v in values):
        bound = "" if most == math.inf else f", at most {_bound(most)}"
        raise _fail(where, list(values) if len(values) > 1 else values[0], f"finite and > 0{bound}")


def _within(values: tuple[float, ...], where: str, most: float) -> None:
    if not all(math.isfinite(v) and abs(v) <= most for v in values):
        value = list(values) if len(values) > 1 else values[0]
        raise _fail(where, value, f"finite and within +-{_bound(most)}")


@dataclass(frozen=True)
class Contraction:
    """The region of interest of a contracted grid (spec 10.1): centre ``c`` and radius ``R``."""

    centre: tuple[float, float, float]
    radius: float

    def __post_init__(self) -> None:
        _within(self.centre, "position.centre", MAX_COORDINATE)
        _positive((self.radius,), "position.radius", MAX_COORDINATE)


@dataclass(frozen=True)
class FarSet:
    """The last ``count`` Gaussians in decoded order, on the grid coarsened by ``shift`` bits per axis."""

    count: int
    shift: int


@dataclass(frozen=True)
class PositionGrid:
    """The voxel grid of the positions (spec 10.1): ``bits`` per axis, origin ``lo`` and ``step`` per axis,
    in world space (a box grid) or in contracted grid space (``contraction`` set); ``far`` only with one."""

    bits: int
    lo: tuple[float, float, float]
    step: tuple[float, float, float]
    contraction: Contraction | None = None
    far: FarSet | None = None

    def __post_init__(self) -> None:
        most = MAX_BITS if self.contraction is None else CONTRACTED_MAX_BITS
        if not 1 <= self.bits <= most:
            raise _fail("position.bits", self.bits, f"an integer in 1..{most} at version {self.version}")
        bound = MAX_COORDINATE if self.contraction is None else MAX_CONTRACTED
        _positive(self.step, "position.step")
        _within(self.lo, "position.lo", bound)
        # The grid's far corner, computed as the decoder computes grid points (binary64, one product and
        # one sum): every grid point then lies between lo and it.
        top = tuple(lo + float((1 << self.bits) - 1) * s for lo, s in zip(self.lo, self.step))
        if not all(abs(t) <= bound for t in top):
            raise CodecError(
                f"attribute codec header's position grid reaches {_show(list(top))} "
                f"(lo + (2^bits - 1) step), beyond +-{_bound(bound)} (spec 10.1)"
            )
        for a, (lo, s, t) in enumerate(zip(self.lo, self.step, top)):
            span = float((1 << self.bits) - 1) * s  # the product T_a adds to lo_a
            if span < RESOLUTION * max(abs(lo), abs(t)):
                raise CodecError(
                    f"attribute codec header's position grid spans {span!r} on axis {a} (position.step[{a}] "
                    f"x (2^bits - 1)), under 2^-24 of its corner {max(abs(lo), abs(t))!r}: binary32 decodes "
                    "it onto one point (spec 10.1)"
                )
            c = self.contraction
            if c is not None and c.radius * span < RESOLUTION * abs(c.centre[a]):
                raise CodecError(
                    f"attribute codec header's position grid spans {c.radius * span!r} on axis {a} in world "
                    f"space (radius x step x (2^bits - 1)), under 2^-24 of position.centre[{a}] = "
                    f"{c.centre[a]!r}: binary32 decodes it onto one point (spec 10.1)"
                )
        if self.far is not None and self.contraction is None:
            raise CodecError("attribute codec header has a far set on a grid that is not contracted")
        if self.far is not None and not 1 <= self.far.shift <= self.bits - 1:
            raise CodecError(
                f"attribute codec header has an impossible far set (far_shift {self.far.shift} with "
                f"{self.bits} bits)"
            )

    @property
    def is_contracted(self) -> bool:
        return self.contraction is not None

    @property
    def version(self) -> int:
        """The lowest attribute codec version that holds this grid (older readers read the most)."""
        if self.far is not None:
            return FAR_VERSION
        return CONTRACTED_VERSION if self.contraction is not None else FORMAT_VERSION

    def split(self, n: int) -> tuple[int, int]:
        """(Gaussians on the fine grid, far shift) of ``n``: the first of them come first in decoded order,
        the far set after; (n, 0) without a far set."""
        if self.far is None:
            return n, 0
        return n - self.far.count, self.far.shift

    def to_dict(self) -> dict:
        out: dict = {"bits": self.bits, "lo": list(self.lo), "step": list(self.step)}
        if self.contraction is not None:
            out["centre"] = list(self.contraction.centre)
            out["radius"] = self.contraction.radius
        if self.far is not None:
            out["far_count"] = self.far.count
            out["far_shift"] = self.far.shift
        return out

    @classmethod
    def from_dict(cls, grid: object, version: int) -> PositionGrid:
        """The ``position`` map of a section at ``version``: each key that version has, and no other."""
        if not isinstance(grid, dict):
            raise _fail("position", grid, "a map")
        contracted, has_far = "radius" in grid or "centre" in grid, "far_count" in grid or "far_shift" in grid
        if version in (PRECISION_VERSION, CODEBOOK_VERSION):  # any grid: its keys say which (spec 10.0)
            version = FAR_VERSION if has_far else CONTRACTED_VERSION if contracted else FORMAT_VERSION
        if (version != FORMAT_VERSION) != contracted:
            raise CodecError("attribute codec version and position grid disagree on contraction")
        if (version == FAR_VERSION) != has_far:
            raise CodecError("attribute codec version and position grid disagree on a far set")
        bits = _integer(grid, "bits", "position.bits")
        lo = _floats(grid, "lo", "position.lo", 3)
        step = _floats(grid, "step", "position.step", 3)
        contraction = far = None
        if version != FORMAT_VERSION:
            centre = _floats(grid, "centre", "position.centre", 3)
            (radius,) = _floats(grid, "radius", "position.radius")
            contraction = Contraction(centre, radius)  # type: ignore[arg-type]
        if version == FAR_VERSION:
            count = _integer(grid, "far_count", "far set's far_count")
            far = FarSet(count, _integer(grid, "far_shift", "far set's far_shift"))
        return cls(bits, lo, step, contraction, far)  # type: ignore[arg-type]


@dataclass(frozen=True)
class ClassSteps:
    """One precision class's quantisers (spec 10.0): opacity levels, log-scale step, rotation levels, DC step
    and one step per SH rest coefficient."""

    opacity_levels: int
    scale_step: float
    rotation_levels: int
    dc_step: float
    sh_steps: tuple[float, ...]
    where: str = field(default="", compare=False, repr=False)  # "classes[k]." of a map read from a file

    def __post_init__(self) -> None:
        # Levels up to 2^48, as every other integer of the codec (spec 10.0): each enters binary64 exactly.
        if not (1 <= self.opacity_levels <= 1 << 48 and 1 <= self.rotation_levels <= 1 << 48):
            raise CodecError(
                f"attribute codec header has impossible quantiser levels ({self.opacity_levels}, "
                f"{self.rotation_levels})"
            )
        _positive((self.scale_step,), f"{self.where}scale_step", MAX_STEP)
        _positive((self.dc_step,), f"{self.where}dc_step", MAX_STEP)
        _positive(self.sh_steps, f"{self.where}sh_steps", MAX_STEP)

    def to_dict(self) -> dict:
        return {
            "opacity_levels": self.opacity_levels,
            "scale_step": self.scale_step,
            "rotation_levels": self.rotation_levels,
            "dc_step": self.dc_step,
            "sh_steps": list(self.sh_steps),
        }

    @classmethod
    def from_dict(cls, meta: dict, degree: int, where: str = "") -> ClassSteps:
        """The five quantiser keys of ``meta`` (the section itself, or one of its ``classes`` maps)."""
        opacity_levels = _integer(meta, "opacity_levels", where + "opacity_levels")
        rotation_levels = _integer(meta, "rotation_levels", where + "rotation_levels")
        (scale_step,) = _floats(meta, "scale_step", where + "scale_step")
        (dc_step,) = _floats(meta, "dc_step", where + "dc_step")
        sh = _get(meta, "sh_steps", where + "sh_steps")
        if not isinstance(sh, list | tuple):
            raise _fail(where + "sh_steps", sh, "an array of floats")
        num_sh = (degree + 1) ** 2 - 1
        if len(sh) != num_sh:
            raise CodecError(
                f"attribute codec header has {len(sh)} {where}sh_steps for SH degree {degree} "
                f"(needs {num_sh})"
            )
        sh_steps = _floats(meta, "sh_steps", where + "sh_steps", num_sh)
        return cls(opacity_levels, scale_step, rotation_levels, dc_step, sh_steps, where)


@dataclass(frozen=True)
class AttributeSection:
    """What the attribute decoder needs (spec 10.0): the count, SH degree, position grid and every
    quantiser's levels or steps; at version 4 (``precision``) also the further precision classes
    (``classes``: class 1 first; class 0 is the section's own quantisers); at version 5 also the number of
    SH rest ``codebook`` entries (0: none, below version 5)."""

    n: int
    sh_degree: int
    position: PositionGrid
    opacity_levels: int
    scale_step: float
    rotation_levels: int
    dc_step: float
    sh_steps: tuple[float, ...]
    precision: bool = False  # version 4: a PREC chunk gives each Gaussian a class and an SH degree
    classes: tuple[ClassSteps, ...] = ()
    codebook: int = 0  # version 5: the SH rest's codebook entries (spec 10.16)

    def __post_init__(self) -> None:
        if not 1 <= self.n <= MAX_GAUSSIANS:
            raise _fail("n", self.n, f"a count in 1..{MAX_GAUSSIANS}")
        if not 0 <= self.sh_degree <= MAX_SH_DEGREE:
            raise _fail("sh_degree", self.sh_degree, f"an SH degree in 0..{MAX_SH_DEGREE}")
        k = (self.sh_degree + 1) ** 2 - 1
        if len(self.sh_steps) != k:
            raise CodecError(
                f"attribute codec header has {len(self.sh_steps)} sh_steps for SH degree {self.sh_degree} "
                f"(needs {k})"
            )
        self.base_class()  # checks the levels and steps
        if self.classes and not self.precision:
            raise CodecError("attribute codec header has precision classes below version 4")
        if len(self.classes) > MAX_CLASSES - 1:
            raise _fail("classes", f"{len(self.classes)} maps", f"at most {MAX_CLASSES - 1} maps")
        if any(len(c.sh_steps) != k for c in self.classes):
            raise CodecError(f"attribute codec header has a precision class without {k} sh_steps")
        if self.codebook and not (self.precision and self.sh_degree > 0):
            raise CodecError("attribute codec header has an SH codebook below version 5 or at SH degree 0")
        if not 0 <= self.codebook <= min(MAX_CODEBOOK, self.n):
            most = min(MAX_CODEBOOK, self.n)
            raise _fail("codebook", self.codebook, f"a count of entries in 1..{most} (at most 2^16 and n)")
        far = self.position.far
        if far is not None and not 1 <= far.count <= self.n - 1:
            raise CodecError(
                f"attribute codec header has an impossible far set (far_count {far.count} of {self.n})"
            )

    @classmethod
    def of_classes(
        cls,
        n: int,
        sh_degree: int,
        position: PositionGrid,
        classes: tuple[ClassSteps, ...],
        precision: bool,
        codebook: int = 0,
    ) -> AttributeSection:
        """The section of ``classes`` (class 0 first; one class below version 4) and ``codebook`` entries."""
        b = classes[0]
        return cls(
            n, sh_degree, position, b.opacity_levels, b.scale_step, b.rotation_levels, b.dc_step, b.sh_steps,
            precision, tuple(classes[1:]), codebook,
        )  # fmt: skip

    @property
    def version(self) -> int:
        if self.codebook:
            return CODEBOOK_VERSION
        return PRECISION_VERSION if self.precision else self.position.version

    def base_class(self) -> ClassSteps:
        """Class 0: the section's own quantisers."""
        return ClassSteps(
            self.opacity_levels, self.scale_step, self.rotation_levels, self.dc_step, self.sh_steps
        )

    @property
    def all_classes(self) -> tuple[ClassSteps, ...]:
        """Every precision class, class 0 first (one class below version 4)."""
        return (self.base_class(), *self.classes)

    def to_dict(self) -> dict:
        """The map the encoder writes (key order is part of the bytes: keep it)."""
        out = {
            "version": self.version,
            "n": self.n,
            "sh_degree": self.sh_degree,
            "position": self.position.to_dict(),
            **self.base_class().to_dict(),
        }
        if self.precision:
            out["classes"] = [c.to_dict() for c in self.classes]
        if self.codebook:
            out["codebook"] = self.codebook
        return out

    @classmethod
    def from_dict(cls, meta: object) -> AttributeSection:
        """The section of an untrusted header, typed and in range; CodecError naming the first bad field.
        Integers are msgpack integers and steps msgpack floats (spec 10.0): 300.0 Gaussians is refused."""
        if not isinstance(meta, dict):
            raise _fail("section", meta, "a map")
        version = _get(meta, "version", "version")
        if not _is_int(version) or version not in VERSIONS:
            raise CodecError(f"attribute codec version {_show(version)} is not supported")
        n = _integer(meta, "n", "n")
        degree = _integer(meta, "sh_degree", "sh_degree")
        grid = PositionGrid.from_dict(_get(meta, "position", "position"), version)
        if not 0 <= degree <= MAX_SH_DEGREE:  # before any sh_steps array is read against it
            raise _fail("sh_degree", degree, f"an SH degree in 0..{MAX_SH_DEGREE}")
        base = ClassSteps.from_dict(meta, degree)
        classes: tuple[ClassSteps, ...] = ()
        precision = version in (PRECISION_VERSION, CODEBOOK_VERSION)
        if precision:
            maps = _get(meta, "classes", "classes")
            if not isinstance(maps, list | tuple):
                raise _fail("classes", maps, "an array of maps")
            if len(maps) > MAX_CLASSES - 1:
                raise _fail("classes", f"{len(maps)} maps", f"at most {MAX_CLASSES - 1} maps")
            for i, m in enumerate(maps):
                if not isinstance(m, dict):
                    raise _fail(f"classes[{i}]", m, "a map")
            classes = tuple(ClassSteps.from_dict(m, degree, f"classes[{i}].") for i, m in enumerate(maps))
        codebook = 0
        if version == CODEBOOK_VERSION:
            codebook = _integer(meta, "codebook", "codebook")
            if codebook < 1:
                raise _fail("codebook", codebook, "a count of entries >= 1")
        return cls(
            n,
            degree,
            grid,
            base.opacity_levels,
            base.scale_step,
            base.rotation_levels,
            base.dc_step,
            base.sh_steps,
            precision,
            classes,
            codebook,
        )


def attribute_chunks(chunks: list) -> dict[str, bytes]:
    """The attribute payloads of a container's chunks by type; each type occurs once, with index 0."""
    out = {}
    for ch in chunks:
        if ch.type in ATTRIBUTE_TYPES:
            if ch.index != 0:
                raise CodecError(f"chunk {ch.type} has index {ch.index}; attribute chunks have index 0")
            out[ch.type] = ch.payload
    return out


def check_attribute_chunks(
    chunks: dict[str, bytes], section: AttributeSection, payload_bytes: int | None = None
) -> None:
    """What can be checked of the attribute payloads before decoding them (``gspc info`` runs it too): each
    chunk the section needs is present, no other, and the count is within what their bytes may declare
    (``payload_bytes``: their total where the payloads are not read yet, from the chunk table)."""
    n, degree = section.n, section.sh_degree
    if degree == 0 and SHRS in chunks:
        raise CodecError("chunk SHRS in a file of SH degree 0")
    if not section.precision and PREC in chunks:
        raise CodecError(f"chunk PREC in a file of attribute codec version {section.version}")
    for t in ATTRIBUTE_TYPES:
        if t not in chunks and (t != SHRS or degree > 0) and (t != PREC or section.precision):
            raise CodecError(f"chunk {t} is missing")
    if payload_bytes is None:
        payload_bytes = sum(len(chunks[t]) for t in chunks)
    if n > max_coded_gaussians(payload_bytes):  # gspc/limits.py: a minimum of coded bits per Gaussian
        raise CodecError(
            f"{n} Gaussians from {payload_bytes} payload bytes (at most {max_coded_gaussians(payload_bytes)})"
        )
