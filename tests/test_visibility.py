"""visible_mask with a real capture's camera ring: a Gaussian any one photo sees is kept, wherever it lies."""

import numpy as np

from gspc.cameras import Camera
from gspc.views import look_at
from gspc.visibility import footprints, sampling_coverage, visible_mask


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


def test_sampling_coverage_counts_views_by_the_pixels_they_give():
    cams = ring()
    # The centre of the ring is in every view at the same distance; a point above everything in none.
    means = np.array([[0.0, 0, 0], [0, 0, 50.0]])
    cover = sampling_coverage(means, np.full((2, 3), -3.0), cams)
    assert np.allclose(cover, [len(cams), 0])
    # Near camera 0 (depth 1, where the opposite camera sees it at depth 7): each view that sees it counts
    # (its closest depth / this view's depth)^2, so camera 0 counts 1 and the opposite one 1/49.
    near = np.array([[3.0, 0, 0]])
    depths = [
        (c.world_to_cam[:3, :3] @ near[0] + c.world_to_cam[:3, 3])[2]
        for c in cams
        if visible_mask(near, np.full((1, 3), -3.0), [c])[0]
    ]
    assert min(depths) == 1.0 and 7.0 in [round(d, 9) for d in depths]
    expected = sum((min(depths) / d) ** 2 for d in depths)
    assert np.allclose(sampling_coverage(near, np.full((1, 3), -3.0), cams), expected)


def test_decoder_rates_shrink_with_few_views_per_gaussian():
    from gspc.reconstruct import COVERAGE_FULL, decoder_schedule, view_coverage
    from gspc.scene import make_scene

    cams = ring()
    n = 4
    scene = make_scene(
        means=np.zeros((n, 3)),
        quats=np.tile([1.0, 0, 0, 0], (n, 1)),
        log_scales=np.full((n, 3), -3.0),
        opacities=np.zeros(n),
        sh_dc=np.zeros((n, 3)),
        sh_degree=0,
    )
    assert view_coverage(scene, cams) == len(cams) and view_coverage(scene, cams[:2]) == 2
    assert decoder_schedule(300, 1.0, 2 * COVERAGE_FULL).rate == 1.0  # enough views: the full rates
    assert decoder_schedule(300, 1.0, COVERAGE_FULL).rate == 1.0
    assert decoder_schedule(300, 0.5, COVERAGE_FULL / 4).rate == 0.5 / 16  # the share's square


def test_footprints_count_the_part_of_a_gaussian_inside_the_image():
    """Centred in camera 0's image: its whole area, 2 pi sigma_px^2 of the image's pixels; on its edge,
    half; behind it, nothing. Averaged over the cameras given."""
    cam = ring()[0]
    R = cam.world_to_cam[:3, :3]
    ahead = cam.center + 4.0 * R[2]  # 4 units along the optical axis
    edge = ahead + 4.0 * 0.5 * R[0]  # 50 px right of the centre: the image's right edge
    behind = cam.center - 4.0 * R[2]
    sigma = 0.04  # 1 px at 4 units (fx 100)
    f = footprints(np.array([ahead, edge, behind]), np.full((3, 3), np.log(sigma)), [cam])
    whole = 2 * np.pi * 1.0**2 / (100 * 100)
    assert np.allclose(f, [whole, whole / 2, 0.0], rtol=1e-3, atol=1e-12)
    assert np.allclose(footprints(np.array([ahead]), np.full((1, 3), np.log(sigma)), [cam, cam])[0], whole)


def test_footprints_stay_finite_for_extreme_gaussians():
    """A camera inside a huge Gaussian, a vanishing speck, one at 1e30: finite and never negative."""
    cams = ring()
    means = np.array([cams[0].center, [0.0, 0, 0], [1e30, 0, 0], [0.0, 0, 0]])
    log_scales = np.array([[700.0] * 3, [-700.0] * 3, [0.0] * 3, [60.0] * 3])
    f = footprints(means, log_scales, cams)
    assert np.isfinite(f).all() and (f >= 0).all()
