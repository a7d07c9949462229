"""Mesh tracing: the bounding volume hierarchy against brute force and the reference.

A glass ball from ``trimesh.creation.icosphere(subdivisions=5)`` (20,480 faces, radius
0.3 m, centre 1 m up, index 1.5, light 20 degrees off vertical), over a 2 x 2 m
receiver of 128 x 128 pixels, rendered by ``jc.render(scene, "triangles")`` at its
defaults (257^2 photons, exact reconstruction, float32):

1. the library's time per render, median after compilation (``block_until_ready``),
   compile time apart; with the tree (the default above `BRUTE_FORCE_FACES` faces) and,
   once, with brute force (every ray against every triangle), and the two images'
   difference;
2. the error of both against the NumPy reference (`reference.trace_mesh`, 2048^2
   photons: `jc.image_error`, relative L1 after a 1-pixel blur), and the reference's
   time at 256^2 .. 1024^2 photons with its own error;
3. larger meshes (icosphere 6: 81,920 faces; a UV sphere of 100,000+ faces): time.

Writes ``benchmarks/results/mesh.md`` and ``mesh.json`` (the environment and the raw rows).

    python benchmarks/bench_mesh.py        # about 5 minutes on 2 cores
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

import jaxcaustics as jc
from jaxcaustics import reference

sys.path.insert(0, str(Path(__file__).parent))  # the harness beside this script
from harness import environment, once, timed, write_results  # noqa: E402


def ball(mesh: trimesh.Trimesh, pixels: int = 128) -> jc.MeshScene:
    mesh = mesh.copy()
    mesh.apply_translation([0.0, 0.0, 1.0])
    return jc.MeshScene(
        jc.Mesh(np.asarray(mesh.vertices, np.float32), mesh.faces),
        jc.DirectionalLight.from_angles(20.0),
        jc.PlaneReceiver((-1.0, 1.0, -1.0, 1.0), (pixels, pixels)),
        ior=1.5,
    )


def timed_render(fn, repeats: int = 5, budget_s: float = 30.0):
    """(compile seconds: the first call less the median, median seconds, the image), by
    the benchmarks' `harness.timed`."""
    t = timed(fn, repeats=repeats, budget_s=budget_s)
    return t.compile_s, t.median, np.asarray(t.out)


def main() -> None:
    env = environment()
    lines = [
        "# Mesh tracing: bounding volume hierarchy, brute force, reference",
        "",
        "`python benchmarks/bench_mesh.py`; see its docstring for the setting. "
        f"Device: `{env['device']}`; scene float32; {env['cpus']} CPU cores; "
        f"run {env['date'].replace('T', ' ')[:16]}.",
        "",
    ]
    scene = ball(trimesh.creation.icosphere(subdivisions=5, radius=0.3))
    truth = reference.trace_mesh(scene, photons_per_axis=2048)
    rows = []
    compile_s, tree_s, tree_image = timed_render(lambda: jc.render(scene, "triangles"))
    rows.append(("tree", compile_s, tree_s, jc.image_error(tree_image, truth)))
    with jc.internal.brute_force_limit(10**9):
        compile_s, brute_s, brute_image = timed_render(
            lambda: jc.render(scene, "triangles"), repeats=1
        )
    rows.append(("brute force", compile_s, brute_s, jc.image_error(brute_image, truth)))
    difference = float(np.abs(tree_image - brute_image).max() / np.abs(brute_image).max())
    lines += [
        "## The 20,480-face ball, 257^2 photons, 128^2 pixels",
        "",
        "| search | compile s | render s (median) | error against the reference |",
        "|---|--:|--:|--:|",
        *(f"| {n} | {c:.1f} | {t:.3f} | {e:.4f} |" for n, c, t, e in rows),
        "",
        f"Largest difference between the two images: {difference:.2e} of the peak. "
        f"Render with the tree {brute_s / tree_s:.0f}x faster than with brute force.",
        "",
        "The reference (`reference.trace_mesh`, NumPy, float64, one call each; error "
        "against its 2048^2 run):",
        "",
        "| photons per axis | error | time s |",
        "|--:|--:|--:|",
    ]
    reference_runs = []
    for n in (256, 512, 1024):
        seconds, image = once(lambda n=n: reference.trace_mesh(scene, photons_per_axis=n))
        error = jc.image_error(image, truth)
        reference_runs.append(dict(photons_per_axis=n, error=error, s=seconds))
        lines.append(f"| {n} | {error:.4f} | {seconds:.2f} |")
    tree_error = rows[0][3]
    as_good = [r["s"] for r in reference_runs if r["error"] <= tree_error]
    if as_good:
        lines += ["", f"The reference is as accurate as the tree's render in {min(as_good):.2f} s."]
    else:
        error, seconds = reference_runs[-1]["error"], reference_runs[-1]["s"]
        lines += [
            "",
            f"No reference run is as accurate as the tree's render (error {tree_error:.4f}): "
            f"its densest, {error / tree_error:.1f}x the error, took {seconds:.2f} s, "
            f"{seconds / tree_s:.1f}x the render.",
        ]
    lines += [
        "",
        "## Larger meshes (257^2 photons, 128^2 pixels, the tree)",
        "",
        "| mesh | faces | compile s | render s (median) | flux on the screen |",
        "|---|--:|--:|--:|--:|",
    ]
    meshes = {
        "icosphere 6": trimesh.creation.icosphere(subdivisions=6, radius=0.3),
        "UV sphere 225 x 225": trimesh.creation.uv_sphere(radius=0.3, count=(225, 225)),
    }
    larger = []
    for name, mesh in meshes.items():
        big = ball(mesh)
        compile_s, seconds, image = timed_render(
            lambda big=big: jc.render(big, "triangles"), repeats=3
        )
        flux = float(image.sum() * (2.0 / 128) ** 2)
        row = dict(mesh=name, faces=len(mesh.faces), compile_s=compile_s, s=seconds, flux=flux)
        larger.append(row)
        lines.append(
            f"| {name} | {len(mesh.faces)} | {compile_s:.1f} | {seconds:.3f} | {flux:.4f} |"
        )
    raw = dict(
        ball=[dict(search=n, compile_s=c, s=t, error=e) for n, c, t, e in rows],
        difference=difference,
        reference=reference_runs,
        larger=larger,
    )
    write_results("mesh", raw, "\n".join(lines) + "\n", env=env)
    print("\n".join(lines))


if __name__ == "__main__":
    main()
