"""Writing an INRIA PLY too large to hold: the header with the final count first, then the rows part by part.

Each part is a GaussianScene turned into rows by gspc/io/ply.py's own ``scene_to_vertex_array``, so the
property layout is write_ply's (tests/test_district.py checks the bytes are the same as write_ply's for the
whole scene). The file appears only when every row is written (gspc.atomic): a failure leaves nothing.
"""

from __future__ import annotations

import os
from collections.abc import Iterable

import numpy as np
import torch

from gspc.atomic import atomic_write
from gspc.io.ply import scene_to_vertex_array
from gspc.scene import GaussianScene, make_scene, num_sh_rest

_PLY_TYPES = {"f4": "float", "f8": "double", "i4": "int", "u4": "uint", "u1": "uchar", "i1": "char"}


def vertex_dtype(sh_degree: int) -> np.dtype:
    """The row layout write_ply uses for a scene of ``sh_degree`` without extra properties."""
    one = make_scene(
        np.zeros((1, 3)),
        np.array([[1.0, 0.0, 0.0, 0.0]]),
        np.zeros((1, 3)),
        np.zeros(1),
        np.zeros((1, 3)),
        torch.zeros(1, num_sh_rest(sh_degree), 3),
        sh_degree,
    )
    return scene_to_vertex_array(one).dtype


def ply_header(dtype: np.dtype, count: int) -> bytes:
    """A binary little-endian PLY header for one ``vertex`` element of ``count`` rows of ``dtype``."""
    lines = ["ply", "format binary_little_endian 1.0", f"element vertex {count}"]
    lines += [f"property {_PLY_TYPES[dtype[name].str[1:]]} {name}" for name in dtype.names]
    return ("\n".join(lines + ["end_header"]) + "\n").encode("ascii")


def write_ply_parts(
    path: str | os.PathLike, count: int, sh_degree: int, parts: Iterable[GaussianScene]
) -> None:
    """Write the scenes ``parts`` (each of ``sh_degree``, without extra properties) one after another as one
    PLY of ``count`` Gaussians; ValueError (and no file) when the parts hold another count."""
    dtype = vertex_dtype(sh_degree)

    def write(f) -> None:
        f.write(ply_header(dtype, count))
        written = 0
        for part in parts:
            rows = scene_to_vertex_array(part)
            if rows.dtype != dtype:
                raise ValueError(f"a part has rows {rows.dtype}, not the header's {dtype}")
            written += len(rows)
            if written > count:
                raise ValueError(f"the parts hold more than the header's {count:,} Gaussians")
            f.write(rows.tobytes())
        if written != count:
            raise ValueError(f"the parts hold {written:,} Gaussians; the header says {count:,}")

    atomic_write(path, write)
