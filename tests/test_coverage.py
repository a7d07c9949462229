"""The reference's exact binning of triangles into pixels (`_coverage.bin_triangles`):
each pixel gets the flux times the share of the triangle's area inside it."""

import numpy as np
import pytest

from jaxcaustics.reference._coverage import bin_triangles


def by_points(u, v, flux, shape, m=300):
    """The same binning by ``m^2 / 2`` points spread over each triangle (the check)."""
    rows, cols = shape
    a = (np.arange(m) + 0.5) / m
    s, t = (g.ravel() for g in np.meshgrid(a, a))
    keep = s + t < 1
    s, t = s[keep], t[keep]
    out = np.zeros(rows * cols)
    for k in range(len(flux)):
        x = u[k, 0] + s * (u[k, 1] - u[k, 0]) + t * (u[k, 2] - u[k, 0])
        y = v[k, 0] + s * (v[k, 1] - v[k, 0]) + t * (v[k, 2] - v[k, 0])
        ok = (x >= 0) & (x < cols) & (y >= 0) & (y < rows)
        pix = np.floor(y[ok]).astype(int) * cols + np.floor(x[ok]).astype(int)
        out += np.bincount(pix, np.full(ok.sum(), flux[k] / len(s)), minlength=rows * cols)
    return out


def test_shares_are_the_areas_inside_each_pixel():
    # half of pixel (0, 0); a triangle over four pixels, a quarter in each by symmetry
    half = bin_triangles(np.array([[0.0, 1, 0]]), np.array([[0.0, 0, 1]]), np.ones(1), (2, 2))
    np.testing.assert_allclose(half, [1, 0, 0, 0], atol=1e-15)
    # corners (0.5, 0.5), (1.5, 0.5), (1.5, 1.5), clockwise: area 1/2; in pixel (0, 0) the
    # triangle (0.5, 0.5), (1, 0.5), (1, 1): 1/8, a quarter; in (1, 1) an eighth too;
    # in (0, 1) the square (1, 1.5) x (0.5, 1): 1/4, a half
    img = bin_triangles(np.array([[0.5, 1.5, 1.5]]), np.array([[0.5, 1.5, 0.5]]), [2.0], (2, 2))
    np.testing.assert_allclose(img, [0.5, 1.0, 0.0, 0.5], atol=1e-14)
    # half of the triangle lies off the grid (x < 0): that half is lost
    off = bin_triangles(np.array([[-1.0, 1, -1]]), np.array([[0.0, 0, 2]]), np.ones(1), (2, 2))
    np.testing.assert_allclose(off, [0.25, 0, 0, 0], atol=1e-15)


def test_random_triangles_match_dense_points_and_keep_their_flux():
    rng = np.random.default_rng(0)
    n = 120
    u = rng.uniform(3, 13, (n, 1)) + rng.normal(0, 1.2, (n, 3))
    v = rng.uniform(3, 13, (n, 1)) + rng.normal(0, 1.2, (n, 3))
    u[:3] = [[4.2, 4.3, 4.25], [7.0, 7.0, 7.0], [9.1, 9.6, 10.1]]  # tiny, a point, a line
    v[:3] = [[5.1, 5.15, 5.3], [2.5, 2.5, 2.5], [1.1, 1.6, 2.1]]
    flux = rng.uniform(0.5, 2.0, n)
    exact = bin_triangles(u, v, flux, (16, 16))
    inside = (u.min(1) >= 0) & (u.max(1) < 16) & (v.min(1) >= 0) & (v.max(1) < 16)
    assert inside.sum() > 100
    # every triangle within the grid gives all its flux; those across the edge lose some
    assert exact.sum() == pytest.approx(
        bin_triangles(u[inside], v[inside], flux[inside], (16, 16)).sum()
        + bin_triangles(u[~inside], v[~inside], flux[~inside], (16, 16)).sum()
    )
    assert bin_triangles(u[inside], v[inside], flux[inside], (16, 16)).sum() == pytest.approx(
        flux[inside].sum(), rel=1e-12
    )
    # the points' estimate converges to it as 1 / points per side (relative L1 measured:
    # 0.0018 at 300, half that at 600), for the triangles with an area (a line's points
    # spread along it)
    body = bin_triangles(u[3:], v[3:], flux[3:], (16, 16))
    coarse, fine = (
        np.abs(by_points(u[3:], v[3:], flux[3:], (16, 16), m) - body).sum() / body.sum()
        for m in (300, 600)
    )
    assert fine < 0.6 * coarse and fine < 1.2e-3
    # a triangle with no area: its flux in its centroid's pixel
    point = bin_triangles(u[1:2], v[1:2], flux[1:2], (16, 16))
    assert point[2 * 16 + 7] == pytest.approx(flux[1])
