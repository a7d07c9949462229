"""Liu, Dong, Bao & Peng, Figure 2: rays of a directional light refracted by glass spheres.

"Caustic spot light for rendering caustics" (2008) motivates its spot lights' focus law
``f(r) = alpha / (1 + beta r)`` (Eq. 1) by the refraction pattern of a transparent sphere
(their Fig. 2: indices 1.1, 1.2 and 1.3, left to right): the rays of a parallel beam
leave the ball and cross its axis at a distance that shrinks with their height, from the
paraxial focus ``n R / (2 (n - 1))`` past the centre for the rays near the axis down to
about a radius for the grazing ones (spherical aberration), so no single focal point
exists.

This script traces a vertical directional light through a glass sphere of radius ``R``
(`jaxcaustics.trace_exit_rays`, exact ray/sphere intersections, two interfaces, no
Fresnel) for each index and draws, one panel per index, the rays of the meridional
plane (the grid row through the centre; an odd number of rays per axis puts one row
and one ray exactly on the axis): each from above the ball to its entry point, through
the glass to where it leaves and on to well past the paraxial focus, with the sphere's
outline, the paraxial focus and the marginal rays' crossing marked. Lengths are in
units of ``R``, measured from the centre along the light.

It prints, for each index: the paraxial focus ``n R / (2 (n - 1))``, the axis crossing
of the traced ray nearest the axis (which tends to it), the crossing of the traced
marginal ray (the outermost of the row, at height ``h``) next to the exact value for
that height, ``h / sin(2 (asin(h / R) - asin(h / (n R))))``, and the grazing limit
(``h = R``). Writes to ``--output`` (default ``paper_figures/output/``):

- ``fig2_sphere_rays.png``: the three panels;
- ``fig2_sphere_rays.md``: the table (also printed).

Run ``python paper_figures/fig2_sphere_rays.py`` (a few seconds) or ``--quick``.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxcaustics as jc  # noqa: E402
from jaxcaustics.internal import orthonormal_basis

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "output"
NAME = "fig2_sphere_rays"

INDICES = (1.1, 1.2, 1.3)
RADIUS = 1.0  # metres: lengths come out in units of R
CENTRE = (0.0, 0.0, 1.0)  # the scene wants the ball above the screen z = 0
# rays per grid side (odd: one row and one ray on the axis) and rays drawn per panel
FULL = dict(rays_per_axis=2001, drawn=31)
QUICK = dict(rays_per_axis=201, drawn=21)
ABOVE = 1.6  # rays are drawn from this far above the centre (units of R)
PAST = 1.25  # ... to this factor times the largest paraxial focus below it


def paraxial_focus(n: float, radius: float = RADIUS) -> float:
    """Distance of the paraxial focus from the centre of a ball of index `n`."""
    return n * radius / (2.0 * (n - 1.0))


def exact_crossing(n: float, height: float, radius: float = RADIUS) -> float:
    """Distance from the centre at which the ray entering at `height` off the axis
    crosses the axis after two refractions: the exit line keeps the entry's distance
    ``h`` from the centre and is turned by ``D = 2 (i - r)`` (``sin i = h / R``,
    ``sin r = sin i / n``), so it meets the axis ``h / sin D`` from the centre."""
    i = math.asin(height / radius)
    r = math.asin(math.sin(i) / n)
    return height / math.sin(2.0 * (i - r))


def meridional_rays(n: float, rays_per_axis: int) -> dict:
    """Trace a vertical light through a ball of index `n`; the middle row of the grid in
    plane coordinates ``(s, w)`` (units of R): ``s`` across, ``w`` along the light's
    direction of travel from the centre (negative: above the centre)."""
    if rays_per_axis % 2 != 1:
        raise ValueError("rays_per_axis must be odd (a row and a ray on the axis)")
    scene = jc.EllipsoidScene(
        jc.Ellipsoid.sphere(CENTRE, RADIUS),
        jc.DirectionalLight([0.0, 0.0, -1.0]),
        jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (8, 8)),
        ior=n,
    )
    rays = jc.internal.trace_exit_rays(scene, rays_per_axis)
    light = np.array([0.0, 0.0, -1.0])
    e1, e2 = (np.asarray(e, np.float64) for e in orthonormal_basis(np.asarray(light, np.float32)))
    mid = rays_per_axis // 2
    row = slice(mid * rays_per_axis, (mid + 1) * rays_per_axis)  # rows run along e2: v = 0
    origin = np.asarray(rays.origin, np.float64)[row] - np.asarray(CENTRE)
    direction = np.asarray(rays.direction, np.float64)[row]
    valid = np.asarray(rays.energy)[row] > 0
    spacing = float(rays.spacing)
    # the grid's cell centres across the row (the entry heights), as trace_exit_rays lays it
    height = (np.arange(rays_per_axis) + 0.5) * spacing - RADIUS
    off_plane = np.abs(origin @ e2).max()
    return dict(
        height=height / RADIUS,
        entry_w=-np.sqrt(np.clip(RADIUS**2 - height**2, 0.0, None)) / RADIUS,
        exit_s=origin @ e1 / RADIUS,
        exit_w=origin @ light / RADIUS,
        dir_s=direction @ e1,
        dir_w=direction @ light,
        valid=valid,
        off_plane=float(off_plane) / RADIUS,
    )


def axis_crossings(rays: dict) -> np.ndarray:
    """Where each exit line meets the axis ``s = 0`` (``w``, units of R; NaN for the
    axial ray and invalid rays)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t = -rays["exit_s"] / rays["dir_s"]
        w = rays["exit_w"] + t * rays["dir_w"]
    ok = rays["valid"] & (np.abs(rays["height"]) > 1e-12) & np.isfinite(w)
    return np.where(ok, w, np.nan)


def measure(quick: bool = False) -> list[dict]:
    settings = QUICK if quick else FULL
    n_rays = settings["rays_per_axis"]
    rows = []
    for n in INDICES:
        rays = meridional_rays(n, n_rays)
        cross = axis_crossings(rays)
        h = np.abs(rays["height"])
        usable = np.isfinite(cross)
        inner = np.where(usable, h, np.inf).argmin()
        outer = np.where(usable, h, -np.inf).argmax()
        rows.append(
            dict(
                n=n,
                rays=rays,
                crossings=cross,
                paraxial=paraxial_focus(n) / RADIUS,
                near_axis_height=float(h[inner]),
                near_axis=float(cross[inner]),
                marginal_height=float(h[outer]),
                marginal=float(cross[outer]),
                marginal_exact=exact_crossing(n, h[outer] * RADIUS) / RADIUS,
                grazing=exact_crossing(n, RADIUS) / RADIUS,
                valid=int(rays["valid"].sum()),
            )
        )
    return rows


def markdown(rows: list[dict], rays_per_axis: int) -> str:
    lines = [
        "# Liu et al., Fig. 2: a parallel beam through glass spheres",
        "",
        f"Vertical directional light, sphere of radius R, {rays_per_axis}^2 rays "
        f"(`trace_exit_rays`), meridional row of {rays_per_axis} rays. Distances from the "
        "centre along the light, in units of R. Paraxial focus: n R / (2 (n - 1)); "
        "near-axis / marginal: where the traced ray nearest to / farthest from the axis "
        "(entry height h) crosses it; exact: h / sin(2 (asin(h/R) - asin(h/(n R)))) for "
        "the marginal ray's h; grazing: the same at h = R.",
        "",
        "| n | paraxial focus | traced near-axis crossing | marginal ray h / R "
        "| traced marginal crossing | exact, same h | grazing limit | marginal / paraxial |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(
            f"| {r['n']:g} | {r['paraxial']:.4f} | {r['near_axis']:.4f} | "
            f"{r['marginal_height']:.4f} | {r['marginal']:.4f} | {r['marginal_exact']:.4f} | "
            f"{r['grazing']:.4f} | {r['marginal'] / r['paraxial']:.3f} |"
        )
    return "\n".join(lines) + "\n"


def figure(rows: list[dict], drawn: int, path: Path, dpi: int = 120) -> None:
    bottom = PAST * max(r["paraxial"] for r in rows)
    fig, axes = plt.subplots(
        1, len(rows), figsize=(3.4 * len(rows), 6.4), sharey=True, constrained_layout=True
    )
    circle = np.linspace(0.0, 2.0 * np.pi, 361)
    for ax, r in zip(np.atleast_1d(axes), rows, strict=True):
        rays = r["rays"]
        count = len(rays["height"])
        picks = np.unique(np.round(np.linspace(0, count - 1, drawn)).astype(int))
        for k in picks:
            if not rays["valid"][k]:
                continue
            s0, w_in = rays["height"][k], rays["entry_w"][k]
            se, we = rays["exit_s"][k], rays["exit_w"][k]
            ds, dw = rays["dir_s"][k], rays["dir_w"][k]
            # continue to w = bottom (rays that turn sideways: 3 * bottom long)
            t = (bottom - we) / dw if dw > 1e-6 else 3.0 * bottom
            ax.plot([s0, s0], [-ABOVE, w_in], color="0.6", lw=0.6)
            ax.plot([s0, se], [w_in, we], color="tab:orange", lw=0.7)
            ax.plot([se, se + t * ds], [we, we + t * dw], color="tab:red", lw=0.6)
        ax.plot(np.cos(circle), np.sin(circle), color="k", lw=1.0)
        ax.axvline(0.0, color="0.8", lw=0.5, zorder=0)
        ax.plot([0.0], [r["paraxial"]], "o", ms=6, mfc="none", mec="tab:blue", mew=1.5)
        ax.plot([0.0], [r["marginal"]], "s", ms=6, mfc="none", mec="tab:green", mew=1.5)
        ax.set_title(
            f"n = {r['n']:g}\nparaxial focus (o) {r['paraxial']:.2f} R\n"
            f"marginal rays cross ([]) {r['marginal']:.2f} R",
            fontsize=9,
        )
        ax.set_xlim(-2.2, 2.2)
        ax.set_ylim(bottom, -ABOVE)  # the light travels down the page
        ax.set_aspect("equal")
        ax.set_xlabel("across / R")
    np.atleast_1d(axes)[0].set_ylabel("along the light from the centre / R")
    fig.suptitle(
        "Refracted rays of a directional light through glass spheres (Liu et al. Fig. 2)",
        fontsize=10,
    )
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer rays (a test)")
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT, metavar="DIR")
    parser.add_argument("--dpi", type=int, default=120)
    args = parser.parse_args(argv)
    settings = QUICK if args.quick else FULL
    rows = measure(args.quick)
    text = markdown(rows, settings["rays_per_axis"])
    args.output.mkdir(parents=True, exist_ok=True)
    (args.output / f"{NAME}.md").write_text(text)
    figure(rows, settings["drawn"], args.output / f"{NAME}.png", args.dpi)
    print(text)
    worst = max(r["rays"]["off_plane"] for r in rows)
    if worst > 1e-5:
        print(f"WARNING: the meridional row leaves its plane by {worst:.3g} R")
    table = [{k: v for k, v in r.items() if k not in ("rays", "crossings")} for r in rows]
    return dict(
        rows=table, markdown=text, files=[args.output / f"{NAME}.{e}" for e in ("md", "png")]
    )


if __name__ == "__main__":
    main()
