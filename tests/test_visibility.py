"""visible_mask with a real capture's camera ring: a Gaussian any one photo sees is kept, wherever it lies."""

import numpy as np

from gspc.cameras import Camera
from gspc.views import look_at
from gspc.visibility import visible_mask


def ring(n: int = 8, radius: float = 4.0) -> list[Camera]:
    K = np.array([[100.0, 0, 50], [0, 100.0, 50], [0, 0, 1]])
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n
        eye = np.array([radius * np.cos(a), radius * np.sin(a), 0.0])
        cams.append(Camera(look_at(eye, np.zeros(3), np.array([0.0, 0, 1])), K, 100, 100, f"c{i}"))
    return cams


def test_gaussians_seen_by_one_photo_of_a_ring_are_kept():
    cams = ring()
    # Behind camera 0 (outside the ring, only the opposite camera looks that way), on the room's walls at
    # 20 units in each camera's view, and one above everything that no camera sees.
    means = np.array(
        [[6.0, 0, 0], *[-20.0 * c.center / np.linalg.norm(c.center) for c in cams], [0, 0, 50.0]]
    )
    mask = visible_mask(means, np.full((len(means), 3), -3.0), cams)
    assert mask[:-1].all() and not mask[-1]
    # With the one camera that sees the first point left out, it is pruned.
    seen_by = [visible_mask(means[:1], np.full((1, 3), -3.0), [c])[0] for c in cams]
    assert (
        sum(seen_by) >= 1
        and not visible_mask(means[:1], np.full((1, 3), -3.0), [c for c, s in zip(cams, seen_by) if not s])[0]
    )
