"""Liu, Dong, Bao & Peng, Section 4: caustic spot lights under a moving directional light.

"Caustic spot light for rendering caustics" (2008) renders caustics for a changing light
direction by precomputing a CSL set for every vertex of a subdivided icosahedron of
light directions (they use two subdivisions: 162 directions), matching the CSLs of
neighbouring directions by tracking their axes, and, per frame, blending the CSL
triples of the face the light direction falls in with its barycentric weights (their
Sect. 4.1-4.3). They show frames, not errors; they note that fewer directions "lead to
noticeable jumping artifacts". This script measures the error.

Scene: the glass ball of ``fig6_intensity_correction.py`` (index 1.5, radius 0.3 m,
centre 1 m above the floor ``z = 0``, two interfaces, no Fresnel). Table:
`jaxcaustics.precompute_spot_lights` over the icosphere's directions (``--subdivisions``,
default 1: 42 directions, 120 edges, 80 faces; see below), ``rays_per_axis = 256`` per
fit, axes tracked along every edge in 20 steps with 64^2 rays (the paper tracks with the
full ray count; the axes only need the bundles' rough position), the fit's defaults
otherwise. Two light directions (each the direction of travel ``-s``, with ``s`` towards
the light), both with the light going down within 40 degrees of the vertical so the
caustic lands on a 2 x 2 m receiver (128^2 pixels) centred where the ball's axis along
the light meets the floor:

- *vertex*: the icosphere vertex nearest to 20 degrees from the vertical (a precomputed
  direction: the table gives that vertex's lights exactly);
- *face centre*: the normalised centroid of the face (all of whose vertices have the
  light going down) nearest to 25 degrees from the vertical: the farthest point of its
  face from the precomputed directions, where the interpolation is weakest.

Rendered with `jaxcaustics.spot_lights` (``lights=...``: the table's units are power for
unit irradiance across the light; `spot_lights` scales by ``1 / |d_z|``) and compared with
`jaxcaustics.reference.trace_ellipsoid` (2048^2 photons) by the relative L1 error
``sum |blur(img) - blur(ref)| / sum blur(ref)``, both blurred by a Gaussian of 1 pixel
(zero outside the receiver):

- table at the vertex (`interpolate_spot_lights` at ``-vertex``);
- the direct fit at the vertex (`spot_lights` fitting its own lights; same knobs);
- table interpolated at the face centre;
- the direct fit at the face centre;
- nearest precomputed set, no interpolation (the lights of the face's nearest vertex,
  rendered for the face-centre light): what a table without Sect. 4's interpolation
  would show.

Subdivisions: the full run uses one (42 directions): its table took 12 minutes on 2 CPU
cores (696 s; the whole run 12.2 minutes). Two subdivisions (the paper's 162 directions,
480 edges) scale the fits and the edge tracking by four, about 45 minutes, over this
script's budget; ``--subdivisions 2`` runs them. (`precompute_spot_lights` vmaps the fit
over directions, which on CPU costs 2-4 times a plain loop of single fits: about 3 s per
direction at 256^2 rays on its own, 8 s vmapped one at a time, 13 s each four at a time.)

Writes to ``--output`` (default ``paper_figures/output/``):

- ``csl_moving_light.png``: reference and CSL images for both directions;
- ``csl_moving_light.md``: the table (also printed);
- ``csl_moving_light_table.npz`` (+ ``.json``, its settings): the precomputed table;
  ``--reuse-table`` loads it instead of precomputing when the settings match.

Run ``python paper_figures/csl_moving_light.py`` or ``--quick`` (one subdivision, 48^2 rays,
4 tracking steps, 4 lights of 24^2 pixels, 32^2 receiver, 256^2 photons; a minute or two,
mostly jit compilation).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import jax  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import jaxcaustics as jc  # noqa: E402
from jaxcaustics import reference  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from fig6_intensity_correction import BLUR, HEIGHT, IOR, RADIUS  # noqa: E402

DEFAULT_OUTPUT = Path(__file__).resolve().parent / "output"
NAME = "csl_moving_light"

SIZE = 2.0  # receiver side, metres
MAX_ZENITH = 40.0  # degrees: both directions within this of the vertical
VERTEX_ZENITH = 20.0  # the vertex nearest this zenith angle is used
FACE_ZENITH = 25.0  # the face whose centre is nearest this zenith angle is used

FULL = dict(
    subdivisions=1,
    rays_per_axis=256,
    tracking_rays=64,
    tracking_steps=20,
    chunk=1,  # one direction per vmapped call: the fastest of 1 and 4 on 2 CPU cores
    pixels=128,
    reference=2048,
    fit_knobs={},
)
QUICK = dict(
    subdivisions=1,
    rays_per_axis=48,
    tracking_rays=24,
    tracking_steps=4,
    chunk=4,
    pixels=32,
    reference=256,
    fit_knobs=dict(max_lights=4, resolution=24),
)


def zenith_deg(s) -> np.ndarray:
    """Angle of unit vector(s) `s` (towards the light) from the vertical, degrees."""
    return np.degrees(np.arccos(np.clip(np.asarray(s)[..., 2], -1.0, 1.0)))


def azimuth_deg(s) -> float:
    """Azimuth of the light's direction of travel ``-s``, degrees from +x towards +y."""
    return round(float(np.degrees(np.arctan2(-s[1], -s[0]))), 9) + 0.0  # no "-0"


def choose_directions(subdivisions: int) -> dict:
    """The vertex and the face centre used (unit vectors towards the light)."""
    vertices, faces = jc.internal.icosphere_directions(subdivisions)
    zen = zenith_deg(vertices)
    down = (vertices[:, 2] > 0) & (zen <= MAX_ZENITH)
    if not down.any():
        raise RuntimeError("no icosphere vertex within MAX_ZENITH of the vertical")
    vertex = int(np.where(down, np.abs(zen - VERTEX_ZENITH), np.inf).argmin())
    centre = vertices[faces].mean(axis=1)
    centre /= np.linalg.norm(centre, axis=1, keepdims=True)
    czen = zenith_deg(centre)
    ok = (vertices[faces][..., 2] > 0).all(axis=1) & (czen <= MAX_ZENITH)
    if not ok.any():
        raise RuntimeError("no icosphere face within MAX_ZENITH of the vertical")
    face = int(np.where(ok, np.abs(czen - FACE_ZENITH), np.inf).argmin())
    s_mid = centre[face]
    cos = vertices[faces[face]] @ s_mid
    nearest = int(faces[face][cos.argmax()])
    return dict(
        vertices=vertices,
        faces=faces,
        vertex=vertex,
        s_vertex=vertices[vertex],
        face=face,
        s_mid=s_mid,
        nearest=nearest,
        s_nearest=vertices[nearest],
        mid_to_vertices_deg=float(np.degrees(np.arccos(np.clip(cos.max(), -1, 1)))),
    )


def scene_for(s, pixels: int, size: float = SIZE) -> jc.EllipsoidScene:
    """The ball lit along ``-s``, the receiver centred where its axis meets the floor."""
    d = -np.asarray(s, np.float64)
    cx, cy = HEIGHT * d[0] / -d[2], HEIGHT * d[1] / -d[2]
    return jc.EllipsoidScene(
        jc.Ellipsoid.sphere([0.0, 0.0, HEIGHT], RADIUS),
        jc.DirectionalLight(d.tolist()),
        jc.PlaneReceiver(
            (cx - size / 2, cx + size / 2, cy - size / 2, cy + size / 2), (pixels, pixels)
        ),
        ior=IOR,
    )


def _table_settings(settings: dict) -> dict:
    keys = ("subdivisions", "rays_per_axis", "tracking_rays", "tracking_steps", "fit_knobs")
    return {k: settings[k] for k in keys} | dict(ior=IOR, radius=RADIUS, height=HEIGHT)


def precompute(settings: dict, output: Path, reuse: bool):
    """The table (loaded from `output` if `reuse` and its settings match) and the
    seconds it took (None if loaded)."""
    path = output / f"{NAME}_table.npz"
    meta = output / f"{NAME}_table.json"
    wanted = _table_settings(settings)
    if reuse and path.exists() and meta.exists() and json.loads(meta.read_text()) == wanted:
        return jc.SpotLightTable.load(path), None
    scene = scene_for([0.0, 0.0, 1.0], 8)  # the table ignores the light and the receiver
    start = time.perf_counter()
    table = jc.precompute_spot_lights(
        scene,
        subdivisions=settings["subdivisions"],
        rays_per_axis=settings["rays_per_axis"],
        tracking_rays_per_axis=settings["tracking_rays"],
        tracking_steps=settings["tracking_steps"],
        chunk=settings["chunk"],
        progress=False,
        **settings["fit_knobs"],
    )
    jax.block_until_ready(table.lights.image)
    seconds = time.perf_counter() - start
    output.mkdir(parents=True, exist_ok=True)
    table.save(path)
    meta.write_text(json.dumps(wanted))
    return table, seconds


def _render(scene, lights):
    start = time.perf_counter()
    result = jc.internal.spot_lights(scene, lights=lights)
    image = np.asarray(result.image, np.float64)
    return image, int(result.stats["lights"][0]), time.perf_counter() - start


def _fit(scene, settings):
    start = time.perf_counter()
    result = jc.internal.spot_lights(
        scene, rays_per_axis=settings["rays_per_axis"], **settings["fit_knobs"]
    )
    image = np.asarray(result.image, np.float64)
    return (
        image,
        int(result.stats["lights"][0]),
        time.perf_counter() - start,
        float(result.missed_flux_fraction[0]),
    )


def run(settings: dict, output: Path, reuse: bool = False) -> tuple[dict, dict]:
    dirs = choose_directions(settings["subdivisions"])
    table, precompute_s = precompute(settings, output, reuse)
    interp = jax.jit(jc.internal.interpolate_spot_lights)
    rows, images = [], {}
    for key, s in (("vertex", dirs["s_vertex"]), ("face centre", dirs["s_mid"])):
        scene = scene_for(s, settings["pixels"])
        d = -np.asarray(s)
        start = time.perf_counter()
        truth = np.asarray(reference.trace_ellipsoid(scene, settings["reference"]), np.float64)
        ref_s = time.perf_counter() - start
        images[(key, "reference")] = truth
        cases = [("table", interp(table, d))]
        if key == "face centre":
            cases.append(("nearest precomputed set", interp(table, -dirs["s_nearest"])))
        for name, lights in cases:
            image, count, seconds = _render(scene, lights)
            images[(key, name)] = image
            rows.append(
                dict(
                    direction=key,
                    method=name,
                    lights=count,
                    seconds=seconds,
                    missed=None,
                    image=image,
                    truth=truth,
                )
            )
        image, count, seconds, missed = _fit(scene, settings)
        images[(key, "direct fit")] = image
        rows.append(
            dict(
                direction=key,
                method="direct fit",
                lights=count,
                seconds=seconds,
                missed=missed,
                image=image,
                truth=truth,
            )
        )
        rows[-1]["reference_seconds"] = ref_s
    for row in rows:
        image, truth = row.pop("image"), row.pop("truth")
        row["rel_l1"] = jc.image_error(image, truth, BLUR)
        row["rel_l1_unblurred"] = jc.image_error(image, truth, 0.0)
        row["flux"] = float(image.sum() / truth.sum())
    # interpolation time after compilation
    d_mid = -np.asarray(dirs["s_mid"])
    jax.block_until_ready(interp(table, d_mid).image)
    start = time.perf_counter()
    jax.block_until_ready(interp(table, d_mid).image)
    interp_s = time.perf_counter() - start
    s_v, s_m = dirs["s_vertex"], dirs["s_mid"]
    face_vertices = dirs["vertices"][dirs["faces"][dirs["face"]]]
    results = dict(
        settings=settings,
        directions=len(dirs["vertices"]),
        faces=len(dirs["faces"]),
        vertex=dict(index=dirs["vertex"], zenith=float(zenith_deg(s_v)), azimuth=azimuth_deg(s_v)),
        face_centre=dict(
            face=dirs["face"],
            zenith=float(zenith_deg(s_m)),
            azimuth=azimuth_deg(s_m),
            vertex_zeniths=[float(z) for z in zenith_deg(face_vertices)],
            to_nearest_vertex_deg=dirs["mid_to_vertices_deg"],
        ),
        slots_per_direction=table.max_lights,
        triple_slots=table.max_triples,
        active_lights=[int(k) for k in np.asarray(table.lights.active).sum(axis=1)],
        precompute_seconds=precompute_s,
        interpolate_seconds=interp_s,
        rows=rows,
    )
    return results, images


def markdown(r: dict) -> str:
    s = r["settings"]
    v, m = r["vertex"], r["face_centre"]
    pre = (
        f"{r['precompute_seconds']:.0f} s"
        if r["precompute_seconds"] is not None
        else "loaded from a previous run"
    )
    active = np.asarray(r["active_lights"])
    knobs = ", ".join(f"{k}={val}" for k, val in s["fit_knobs"].items()) or "defaults"
    lines = [
        "# Liu et al., Sect. 4: CSLs for a moving light, interpolated from a table",
        "",
        f"Glass ball n = {IOR}, radius {RADIUS} m, centre {HEIGHT} m up; receiver "
        f"{SIZE:g} x {SIZE:g} m centred under the ball along the light, {s['pixels']}^2 "
        f"pixels. Table: `precompute_spot_lights`, {s['subdivisions']} subdivision(s) "
        f"({r['directions']} directions, {r['faces']} faces), {s['rays_per_axis']}^2 rays "
        f"per fit (fit knobs: {knobs}), tracking {s['tracking_steps']} steps of "
        f"{s['tracking_rays']}^2 rays; {r['slots_per_direction']} light slots per direction "
        f"({active.min()}-{active.max()} active, mean {active.mean():.2f}), "
        f"{r['triple_slots']} triple slots per face. Precompute: {pre}. Interpolation: "
        f"{1000 * r['interpolate_seconds']:.1f} ms per direction (jit-compiled). "
        f"Reference: `trace_ellipsoid`, {s['reference']}^2 photons. Error: relative L1 "
        f"sum|blur(img) - blur(ref)| / sum blur(ref), Gaussian blur sigma = {BLUR:g} px on "
        "both images (zero outside the receiver), and without the blur. Times: wall clock "
        "of one call; the run's first direct fit includes the fit's jit compilation.",
        "",
        f"Directions (zenith / azimuth of travel, degrees): vertex {v['index']}: "
        f"{v['zenith']:.1f} / {v['azimuth']:.1f}; face {m['face']} centre: "
        f"{m['zenith']:.1f} / {m['azimuth']:.1f} (its vertices at zenith "
        + ", ".join(f"{z:.1f}" for z in m["vertex_zeniths"])
        + f"; {m['to_nearest_vertex_deg']:.1f} deg from the nearest).",
        "",
        "| light direction | CSLs | lights | rel. L1 (1 px blur) | rel. L1 (no blur) "
        "| flux ratio | time (s) |",
        "|---|---|---:|---:|---:|---:|---:|",
    ]
    names = {
        ("vertex", "table"): "table at the vertex",
        ("vertex", "direct fit"): "direct fit",
        ("face centre", "table"): "table, interpolated",
        ("face centre", "nearest precomputed set"): "nearest vertex's set, not interpolated",
        ("face centre", "direct fit"): "direct fit",
    }
    for row in r["rows"]:
        what = names[(row["direction"], row["method"])]
        note = " (trace + fit + render)" if row["method"] == "direct fit" else " (render)"
        lines.append(
            f"| {row['direction']} | {what} | {row['lights']} | {row['rel_l1']:.4f} | "
            f"{row['rel_l1_unblurred']:.4f} | {row['flux']:.3f} | {row['seconds']:.1f}{note} |"
        )
    return "\n".join(lines) + "\n"


def figure(r: dict, images: dict, path: Path, dpi: int = 100) -> None:
    errors = {(row["direction"], row["method"]): row["rel_l1"] for row in r["rows"]}
    layout = [
        ("vertex", ["reference", "table", "direct fit", None]),
        ("face centre", ["reference", "table", "direct fit", "nearest precomputed set"]),
    ]
    titles = {
        ("vertex", "table"): "table at the vertex",
        ("face centre", "table"): "table, interpolated",
        ("face centre", "nearest precomputed set"): "nearest vertex's set",
    }
    fig, axes = plt.subplots(2, 4, figsize=(15, 7.6), constrained_layout=True)
    for i, (key, methods) in enumerate(layout):
        truth = images[(key, "reference")]
        white = float(np.percentile(truth, 99.8)) or 1.0
        info = r["vertex"] if key == "vertex" else r["face_centre"]
        for j, method in enumerate(methods):
            ax = axes[i, j]
            if method is None:
                ax.axis("off")
                continue
            ax.imshow(images[(key, method)], origin="lower", cmap="gray", vmin=0, vmax=white)
            title = titles.get((key, method), method)
            if method == "reference":
                title = (
                    f"{key}: zenith {info['zenith']:.1f}, azimuth {info['azimuth']:.0f} deg\n"
                    f"reference ({r['settings']['reference']}^2 photons)"
                )
            else:
                title += f"\nrel. L1 = {errors[(key, method)]:.3f}"
            ax.set_title(title, fontsize=9)
            ax.set_xticks([])
            ax.set_yticks([])
    pre = r["precompute_seconds"]
    axes[0, 3].text(
        0.0,
        0.5,
        f"{r['directions']} precomputed directions\n"
        f"({r['settings']['subdivisions']} subdivision(s))\n"
        + (f"precompute {pre:.0f} s\n" if pre is not None else "")
        + f"{r['settings']['rays_per_axis']}^2 rays per fit\n"
        f"relative L1 after a {BLUR:g} px Gaussian blur\n(both images, zero outside)",
        fontsize=10,
        va="center",
    )
    fig.suptitle(
        "Liu et al. Sect. 4: caustic spot lights for a moving light (glass ball)", fontsize=11
    )
    fig.savefig(path, dpi=dpi)
    plt.close(fig)


def main(argv=None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="small sizes (a test)")
    parser.add_argument(
        "--subdivisions", type=int, default=None, help="icosahedron subdivisions (default: 1)"
    )
    parser.add_argument(
        "--reuse-table",
        action="store_true",
        help="load the table of a previous run with the same settings",
    )
    parser.add_argument("--output", type=Path, default=DEFAULT_OUTPUT, metavar="DIR")
    parser.add_argument("--dpi", type=int, default=100)
    args = parser.parse_args(argv)
    settings = dict(QUICK if args.quick else FULL)
    if args.subdivisions is not None:
        settings["subdivisions"] = args.subdivisions
    start = time.perf_counter()
    results, images = run(settings, args.output, args.reuse_table)
    args.output.mkdir(parents=True, exist_ok=True)
    text = markdown(results)
    (args.output / f"{NAME}.md").write_text(text)
    figure(results, images, args.output / f"{NAME}.png", args.dpi)
    print(text)
    print(f"total {time.perf_counter() - start:.1f} s")
    results["markdown"] = text
    results["files"] = [args.output / f"{NAME}.{e}" for e in ("md", "png")]
    return results


if __name__ == "__main__":
    main()
