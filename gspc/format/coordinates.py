"""The names of axis conventions a .gspc header may record (spec 10.8, ``scene.coordinates``).

Three letters, one per axis in x, y, z order: R or L (right, left), U or D (up, down), B or F (back, front).
They are the sixteen names of Niantic's SPZ library, in its numbering (a name's number there is its position
here plus one): eight with y along up/down, eight with y along front/back. gspc/io/coordinates.py moves
scenes between them.
"""

CONVENTIONS = (
    "LDB",
    "RDB",
    "LUB",
    "RUB",
    "LDF",
    "RDF",
    "LUF",
    "RUF",
    "LFD",
    "RFD",
    "LFU",
    "RFU",
    "LBD",
    "RBD",
    "LBU",
    "RBU",
)
