"""What a scene simulates is visible: `scene.effects`, checked against what is traced.

For every effect and every method that supports it, two things are shown:

1. **A scene without the effect traces none of its work.** Checked on the jaxpr of a
   whole method (`jax.make_jaxpr`: nothing is compiled): spies on the effect's kernels,
   monkeypatched in the modules that call them, see no call, and the jaxpr has strictly
   fewer equations (counted through nested jaxprs: `jit`, `scan`, `cond`...) than that of
   the same scene with the effect. Jit caches are cleared before each trace (`_trace`),
   so that a spy sees every call of a trace, never a cached one.
2. **A scene where the effect is present but has no influence gives the same image** as
   the scene without it, to float64 rounding. Where a whole image is costly to compile,
   the rays the image is a deterministic function of are compared instead (said so in
   the test), and the whole-image versions are marked slow.

The effects and their kernels:

- refraction: `refract_components` (`jaxcaustics.trace.optics`); reflection (mirror
  generators): `reflect`. They are the generator's material, not switches of their own:
  a refractor traces no `reflect`, a mirror no `refract_components`. Refraction present
  without influence is an index of 1: the light goes straight through.
- Fresnel (`fresnel=True`): `fresnel_transmittance`; without influence at an index of 1
  (transmittance 1).
- total internal reflection (TIR): the TIR test inside the refraction kernel
  (`_cos_transmitted` returns a mask). It has no switch either: it is traced wherever
  the indices make it possible (`jaxcaustics.trace.optics.tir_possible`), and not for water of
  index > 1 (light going into a denser medium). Without influence: a scene where TIR is
  possible but no ray reaches the critical angle gives the same image as the same scene
  traced with the TIR test switched off (`tir_possible` patched to ``False``).
- dispersion (`ior` a sequence): one channel per index; the per-channel tracer runs once
  per index; with equal indices every channel is the single-index image.
- occlusion (`occluders`): exact visibility tests occluder triangles (`nearest_hits` on
  them), the distance-map pipeline samples them (`ray_triangle_distances` while building
  the map), caustic spot lights test occluder ellipsoids (`_segment_blocked`); without
  influence: occluders far beside the scene, where no light goes.
- interfaces (`interfaces`): the per-event body of the mesh tracer (`hit_on_triangle`),
  a loop (a `scan` named ``interfaces``) of ``interfaces`` steps; for ellipsoids one
  `scan` step of length ``interfaces``; without influence: more interfaces than any
  path needs.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
import trimesh
from conftest import make_scene

import jaxcaustics as jc
from jaxcaustics.methods import twopass
from jaxcaustics.methods.caustic_map import gbuffer as _gbuffer
from jaxcaustics.methods.spot_lights import exit_rays as _ellipsoid
from jaxcaustics.methods.spot_lights import lights as _spot_lights
from jaxcaustics.methods.triangles import distance_map as _distance_map
from jaxcaustics.methods.triangles import layered_map as _layered_map
from jaxcaustics.methods.triangles import visibility as triangles_visibility
from jaxcaustics.methods.triangles.method import CubeMapOptions
from jaxcaustics.trace import optics as _optics
from jaxcaustics.trace import photons as _photons

# ----------------------------------------------------------------------------- helpers


def _subjaxprs(params):
    for value in params.values():
        for v in value if isinstance(value, (tuple, list)) else (value,):
            if hasattr(v, "eqns"):
                yield v
            elif hasattr(getattr(v, "jaxpr", None), "eqns"):
                yield v.jaxpr


def _all_eqns(jaxpr):
    for eqn in jaxpr.eqns:
        yield eqn
        for sub in _subjaxprs(eqn.params):
            yield from _all_eqns(sub)


def _trace(fn, scene):
    """All equations (nested ones included) of the jaxpr of ``fn(scene)``, traced afresh
    (jit caches cleared), and the shape of its first output."""
    jax.clear_caches()
    closed = jax.make_jaxpr(fn)(scene)
    return list(_all_eqns(closed.jaxpr)), closed.out_avals[0].shape


class Kernels:
    """Spies on the kernels that do each effect's work; `calls[name]` lists the calls
    of one trace (positional arguments)."""

    # (module, name) of each spied kernel, as the tracing code looks it up
    TARGETS = {
        "refract": [twopass, _photons, _gbuffer, _ellipsoid, _optics],
        "reflect": [_photons, _gbuffer],
        "fresnel": [twopass, _photons, _gbuffer, _ellipsoid],
        "nearest_hits": [_photons],
        "hit_on_triangle": [_photons],
        "ray_triangle_distances": [_layered_map],
        "segment_blocked": [_spot_lights],
    }
    NAMES = {
        "refract": "refract_components",
        "reflect": "reflect",
        "fresnel": "fresnel_transmittance",
        "nearest_hits": "nearest_hits",
        "hit_on_triangle": "hit_on_triangle",
        "ray_triangle_distances": "ray_triangle_distances",
        "segment_blocked": "_segment_blocked",
    }

    def __init__(self, monkeypatch):
        self.calls = {key: [] for key in self.TARGETS}
        self.tir_masks = []
        for key, modules in self.TARGETS.items():
            for module in modules:
                name = self.NAMES[key]
                monkeypatch.setattr(module, name, self._spy(key, getattr(module, name)))
        original = _optics._cos_transmitted

        def cos_transmitted(cos_i, eta):
            cos_t, tir = original(cos_i, eta)
            self.tir_masks.append(tir is not None)
            return cos_t, tir

        monkeypatch.setattr(_optics, "_cos_transmitted", cos_transmitted)

    def _spy(self, key, original):
        def spy(*args, **kwargs):
            self.calls[key].append(args)
            return original(*args, **kwargs)

        return spy

    def reset(self):
        for calls in self.calls.values():
            calls.clear()
        self.tir_masks.clear()

    def count(self, key) -> int:
        return len(self.calls[key])


@pytest.fixture
def kernels(monkeypatch):
    return Kernels(monkeypatch)


def _close(a, b, rtol=1e-12, atol=1e-12):
    """Equal to float64 rounding (the "no influence" comparisons), and not vacuously:
    `b` holds some light."""
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=rtol, atol=atol)
    assert np.any(np.asarray(b) != 0)


# ------------------------------------------------------------------------------ scenes

UNIT = (0.0, 1.0, 0.0, 1.0)
APERTURE = (0.0, 0.1, 0.0, 0.1)
SCREEN = (-1.5, 1.5, -1.5, 1.5)


def _water(ior=1.333, fresnel=False, zenith=0.0):
    """Gentle waves (slopes below 3 degrees) over a 9 x 11 map."""
    terms = ((2, 1, 0.004, 0.0), (1, 3, 0.003, 1.0))
    heights = np.asarray(jc.sine_sum((9, 11), UNIT, terms=terms))
    return make_scene(heights, UNIT, zenith=zenith, ior=ior, fresnel=fresnel)


def _lens(ior=1.5, fresnel=False):
    """A gently curved slab (slopes below 2 degrees), vertical light, screen = aperture."""
    x = (np.arange(8) + 0.5) / 8
    heights = 0.0003 * np.outer(np.sin(np.pi * x), np.sin(np.pi * x))
    return jc.LensScene(
        jc.HeightField(heights, APERTURE, "clamp"),
        jc.DirectionalLight.from_angles(0.0),
        jc.PlaneReceiver(APERTURE, (10, 10)),
        thickness=0.01,
        screen_distance=0.3,
        ior=ior,
        fresnel=fresnel,
    )


def _mesh(mesh: trimesh.Trimesh) -> jc.Mesh:
    return jc.Mesh(np.asarray(mesh.vertices, float), mesh.faces)


def _ball_mesh() -> jc.Mesh:
    ball = trimesh.creation.icosphere(1, radius=0.5)  # 80 faces
    ball.apply_translation([0.0, 0.0, 1.0])
    return _mesh(ball)


def _far_box() -> jc.Mesh:
    """An opaque box (12 faces) 20 m beside the scene: no light goes there."""
    box = trimesh.creation.box((0.2, 0.2, 0.2))
    box.apply_translation([20.0, 20.0, 0.5])
    return _mesh(box)


def _ball(**kwargs):
    return jc.MeshScene(
        _ball_mesh(),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver(SCREEN, (12, 12)),
        **kwargs,
    )


def _slab(**kwargs):
    """A glass slab under vertical light, flat normals: every path enters through the top
    and leaves through the bottom at normal incidence (two interfaces, never TIR)."""
    box = trimesh.creation.box((0.6, 0.6, 0.1))
    box.apply_translation([0.0, 0.0, 1.0])
    return jc.MeshScene(
        _mesh(box),
        jc.DirectionalLight.from_angles(0.0),
        jc.PlaneReceiver(SCREEN, (12, 12)),
        normals="flat",
        **kwargs,
    )


def _sphere(**kwargs):
    """An exact glass sphere: a path that enters leaves at the angle it entered (no TIR,
    two interfaces)."""
    return jc.EllipsoidScene(
        jc.Ellipsoid.sphere([0.0, 0.0, 1.0], 0.4),
        jc.DirectionalLight.from_angles(10.0),
        jc.PlaneReceiver(SCREEN, (12, 12)),
        **kwargs,
    )


def _far_sphere() -> jc.Ellipsoid:
    return jc.Ellipsoid.sphere([20.0, 20.0, 1.0], 0.3)


def _lights(resolution=6):
    """Two hand-made caustic spot lights above the screen (no fit: cheap)."""
    return jc.internal.SpotLights(
        [[0.0, 0.0, 1.0], [0.3, -0.2, 1.0]],
        [[0.0, 0.0, -1.0], [0.0, 0.0, -1.0]],
        [[1.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
        [0.6, 0.8],
        [0.0, 0.0],
        [0.3, 0.2],
        np.ones((2, resolution, resolution)),
    )


# ------------------------------------------------------------------------------ methods


def two_pass(s):
    return jc.internal.two_pass(s, samples_x=1, channels_y=0, hit_iterations=0).image


def triangles(s):
    return jc.internal.caustic_triangles(s, photons=7, window=4).image


def distance_map(s):
    options = CubeMapOptions(resolution=8, linear_steps=8, secant_iterations=1, window=4)
    return jc.internal.caustic_triangles(
        s, photons=5, visibility="distance_map", cube_map=options
    ).image


def caustics_mapping(s):
    return jc.internal.caustics_mapping(s, photons=8, map_resolution=16).image


def caustics_mapping_exact(s):
    return jc.internal.caustics_mapping(s, photons=8, map_resolution=16, intersection="exact").image


def adaptive(s):
    return jc.internal.adaptive_caustic_map(
        s, photons=16, base=8, map_resolution=16, capacity=16
    ).image


def exit_rays(s):
    return jc.internal.trace_exit_rays(s, 6).energy


def spot_light_render(s):
    """`spot_lights` with given lights (its render stage: one per channel)."""
    return jc.internal.spot_lights(s, lights=_lights(), samples=1).image


# ------------------------------------------------------------ effects match the traces

# which effects each method's traces show (given spot lights: only the render stage;
# exit rays: one channel at a time, and occluders only matter when rendering)
ALL_EFFECTS = (
    "refraction",
    "reflection",
    "fresnel",
    "total_internal_reflection",
    "dispersion_channels",
    "occlusion",
    "interfaces",
)
OBSERVABLE = {
    "spot_light_render": ("occlusion", "dispersion_channels"),
    "exit_rays": ("refraction", "reflection", "fresnel", "total_internal_reflection", "interfaces"),
}


def _named(eqn, name: str) -> bool:
    """Whether `eqn` was traced inside ``jax.named_scope(name)``."""
    return name in str(eqn.source_info.name_stack).split("/")


def _observed(kernels: Kernels, scene, method, eqns, out_shape) -> dict:
    """The effects a trace shows, from the spies and the jaxpr."""
    channels = len(scene.iors)
    if isinstance(scene, jc.EllipsoidScene):
        occlusion = kernels.count("segment_blocked") > 0
    elif method is distance_map:
        occlusion = kernels.count("ray_triangle_distances") > 0
    else:  # occluder triangles searched (the generator has another number of faces)
        faces = sum(int(o.faces.shape[0]) for o in getattr(scene, "occluders", ()))
        occlusion = any(int(a[2].shape[0]) == faces for a in kernels.calls["nearest_hits"])
    if isinstance(scene, jc.EllipsoidScene):
        scans = [e for e in eqns if e.primitive.name == "scan"]
        interfaces = scans[0].params["length"] if scans else None
    elif kernels.count("hit_on_triangle"):  # the mesh tracer: a loop over events
        loops = [e for e in eqns if e.primitive.name == "scan" and _named(e, "interfaces")]
        lengths = {e.params["length"] for e in loops}
        # one loop per channel, each traced once
        assert len(loops) == channels == kernels.count("hit_on_triangle"), (loops, channels)
        interfaces = lengths.pop() if len(lengths) == 1 else lengths
    else:  # unrolled refraction (or reflection) per channel
        per_channel = (kernels.count("refract") + kernels.count("reflect")) // channels
        if isinstance(scene, jc.WaterScene):
            per_channel -= 1  # the flat rest surface's, for the illumination centres
        interfaces = per_channel
    return {
        "refraction": kernels.count("refract") > 0,
        "reflection": kernels.count("reflect") > 0,
        "fresnel": kernels.count("fresnel") > 0,
        "total_internal_reflection": any(kernels.tir_masks),
        "dispersion_channels": out_shape[2] if len(out_shape) == 3 else 1,
        "occlusion": occlusion,
        "interfaces": interfaces,
    }


def _check_effects(kernels: Kernels, scene, method, differs=None) -> tuple[list, dict]:
    """Trace `method` on `scene` afresh and check that what is traced is what
    `scene.effects` says (`differs`: what the method documents doing otherwise).
    **Returns:** the equations and the spies' call counts."""
    kernels.reset()
    eqns, out_shape = _trace(method, scene)
    observed = _observed(kernels, scene, method, eqns, out_shape)
    expected = dict(vars(scene.effects), **(differs or {}))
    keys = OBSERVABLE.get(method.__name__, ALL_EFFECTS)
    assert {k: observed[k] for k in keys} == {k: expected[k] for k in keys}
    return eqns, {key: kernels.count(key) for key in kernels.calls}


# effect-method: (scene without the effect, the same scene with it, method, what the
# method documents doing otherwise than `scene.effects` says)
PAIRS = {
    "fresnel-two-pass": (lambda: _water(), lambda: _water(fresnel=True), two_pass, None),
    "fresnel-lens-triangles": (lambda: _lens(), lambda: _lens(fresnel=True), triangles, None),
    "fresnel-mesh-triangles": (lambda: _ball(), lambda: _ball(fresnel=True), triangles, None),
    "fresnel-caustics-mapping": (
        lambda: _ball(),
        lambda: _ball(fresnel=True),
        caustics_mapping,
        None,
    ),
    "fresnel-adaptive": (lambda: _ball(), lambda: _ball(fresnel=True), adaptive, None),
    "fresnel-ellipsoid-exit-rays": (
        lambda: _sphere(),
        lambda: _sphere(fresnel=True),
        exit_rays,
        None,
    ),
    "fresnel-mesh-exit-rays": (lambda: _ball(), lambda: _ball(fresnel=True), exit_rays, None),
    "tir-two-pass": (lambda: _water(ior=1.333), lambda: _water(ior=0.95), two_pass, None),
    "dispersion-two-pass": (lambda: _water(), lambda: _water(ior=(1.33, 1.34)), two_pass, None),
    "dispersion-lens-triangles": (
        lambda: _lens(),
        lambda: _lens(ior=(1.5, 1.6)),
        triangles,
        None,
    ),
    "dispersion-mesh-triangles": (
        lambda: _ball(),
        lambda: _ball(ior=(1.4, 1.5)),
        triangles,
        None,
    ),
    "dispersion-caustics-mapping": (
        lambda: _ball(),
        lambda: _ball(ior=(1.4, 1.5)),
        caustics_mapping,
        None,
    ),
    "dispersion-adaptive": (lambda: _ball(), lambda: _ball(ior=(1.4, 1.5)), adaptive, None),
    "dispersion-spot-lights": (
        lambda: _sphere(),
        lambda: _sphere(ior=(1.5, 1.6)),
        spot_light_render,
        None,
    ),
    "occlusion-mesh-triangles": (
        lambda: _ball(),
        lambda: _ball(occluders=[_far_box()]),
        triangles,
        None,
    ),
    "occlusion-distance-map": (
        lambda: _ball(),
        lambda: _ball(occluders=[_far_box()]),
        distance_map,
        None,
    ),
    "occlusion-spot-lights": (
        lambda: _sphere(),
        lambda: _sphere(occluders=[_far_sphere()]),
        spot_light_render,
        None,
    ),
    "interfaces-mesh-triangles": (lambda: _ball(), lambda: _ball(interfaces=3), triangles, None),
    "interfaces-mesh-exit-rays": (lambda: _ball(), lambda: _ball(interfaces=3), exit_rays, None),
    "interfaces-caustics-mapping-exact": (
        lambda: _ball(),
        lambda: _ball(interfaces=3),
        caustics_mapping_exact,
        None,
    ),
}


@pytest.mark.parametrize("case", sorted(PAIRS))
def test_a_scene_without_an_effect_traces_none_of_its_work(kernels, case):
    """Both scenes trace what their `effects` say (the spies), and the scene without the
    effect has strictly fewer equations. Dispersion: the per-channel tracer runs once
    per index (the refraction kernel's calls double with two indices)."""
    make_without, make_with, method, differs = PAIRS[case]
    fewer, calls_without = _check_effects(kernels, make_without(), method, differs)
    more, calls_with = _check_effects(kernels, make_with(), method, differs)
    if case.startswith("interfaces-mesh") or case == "interfaces-caustics-mapping-exact":
        # the mesh tracer's events are a loop: its length (checked above) is the work,
        # the traced body is the same
        assert len(fewer) == len(more)
    else:
        assert len(fewer) < len(more)
    if case.startswith("dispersion") and method is not spot_light_render:
        assert calls_with["refract"] == 2 * calls_without["refract"] > 0


MATERIALS = {
    # a mirror reflects (one event per interface) and refracts nothing
    "mirror-triangles": (lambda: _ball(material="mirror", fresnel=True), triangles, None),
    # image space: one reflection, whatever the scene allows
    "mirror-caustics-mapping": (
        lambda: _ball(material="mirror", fresnel=True),
        caustics_mapping,
        {"interfaces": 1},
    ),
    # the image-space intersection (the papers') always traces two interfaces
    "refractor-caustics-mapping": (
        lambda: _ball(ior=(1.4, 1.5), fresnel=True, interfaces=3),
        caustics_mapping,
        {"interfaces": 2},
    ),
    # occluders only matter when rendering, not for the rays leaving the object
    "ellipsoid-exit-rays-occluded": (
        lambda: _sphere(fresnel=True, interfaces=4, occluders=[_far_sphere()]),
        exit_rays,
        None,
    ),
}


@pytest.mark.parametrize("case", sorted(MATERIALS))
def test_reflection_and_refraction_are_what_is_traced(kernels, case):
    """Reflection and refraction are the generator's material, not switches: a refractor
    traces no `reflect` (the pairs above), a mirror no `refract_components` and no
    Fresnel factor (its reflectance is taken as 1)."""
    make, method, differs = MATERIALS[case]
    _check_effects(kernels, make(), method, differs)


def test_a_mirror_reports_no_fresnel():
    """`fresnel=True` does nothing for a mirror, and its effects say so (they said
    ``fresnel=True`` before)."""
    fx = _ball(material="mirror", fresnel=True).effects
    assert (fx.reflection, fx.refraction, fx.fresnel, fx.total_internal_reflection) == (
        True,
        False,
        False,
        False,
    )
    assert fx.dispersion_channels == 1


def test_ellipsoid_interfaces_are_one_scan_step():
    """Ellipsoid paths are a `scan` over events: ``interfaces`` sets its length, the
    traced work (one step) does not grow with it."""
    two, _ = _trace(exit_rays, _sphere(interfaces=2))
    five, _ = _trace(exit_rays, _sphere(interfaces=5))
    lengths = [
        [e.params["length"] for e in eqns if e.primitive.name == "scan"] for eqns in (two, five)
    ]
    assert lengths == [[2], [5]]
    assert len(two) == len(five)


def test_image_space_caustic_maps_trace_two_interfaces_whatever_the_scene():
    """The papers' image-space refraction (front and back surface of the geometry
    buffers) is a two-interface method: a scene's larger `interfaces` changes nothing
    there (``intersection="exact"`` follows it: see `ABSENT`)."""
    two, _ = _trace(caustics_mapping, _ball(interfaces=2))
    four, _ = _trace(caustics_mapping, _ball(interfaces=4))
    assert len(two) == len(four)


def test_tir_test_is_traced_only_where_possible():
    """The refraction kernel traces the TIR test unless the index ratio is a concrete
    number below 1 (into a denser medium), where it cannot happen."""
    d = (jnp.zeros(4), jnp.zeros(4), -jnp.ones(4))
    n = (jnp.linspace(0.0, 0.5, 4), jnp.zeros(4), jnp.ones(4))
    for eta, expected in ((0.75, False), (1.0, True), (1.33, True)):
        assert _optics.tir_possible(eta) is expected
        jaxpr = jax.make_jaxpr(lambda d, n, eta=eta: _optics.refract_components(d, n, eta))(d, n)
        assert any(e.primitive.name == "le" for e in jaxpr.jaxpr.eqns) is expected
    assert _optics.tir_possible(jnp.asarray(0.75))  # traced or array indices: always
    assert _water(ior=1.333).effects.total_internal_reflection is False
    assert _water(ior=(1.333, 1.0)).effects.total_internal_reflection is True


def test_occluders_where_a_method_cannot_test_them_are_refused():
    """Caustic maps and mesh spot lights do not test occlusion: a scene with occluders is
    refused with a clear error rather than rendered as if they were absent."""
    scene = _ball(occluders=[_far_box()])
    for method in (
        jc.internal.caustics_mapping,
        jc.internal.adaptive_caustic_map,
        jc.internal.spot_lights,
    ):
        with pytest.raises(ValueError, match="occluders"):
            method(scene)


def _distance_map_occlusion_work(monkeypatch, scene) -> dict:
    """What the distance-map pipeline does for occlusion when tracing `scene`: the layers
    of its distance map and whether the camera pass runs the shadow test."""
    seen = {}
    build, project = _distance_map.build_distance_map, _distance_map.project_light_cube_map

    def build_spy(center, occluders=(), resolution=128, layers=2, *args, **kwargs):
        seen["layers"] = layers
        return build(center, occluders, resolution, layers, *args, **kwargs)

    def project_spy(*args, **kwargs):
        seen["shadow_test"] = kwargs.get("shadow_test", True)
        return project(*args, **kwargs)

    # (patched where the pipeline looks them up: `methods/triangles/visibility.py` imports them)
    monkeypatch.setattr(triangles_visibility, "build_distance_map", build_spy)
    monkeypatch.setattr(triangles_visibility, "project_light_cube_map", project_spy)
    _trace(distance_map, scene)
    return seen


def test_distance_map_with_occluders_peels_layers_and_tests_shadows(monkeypatch):
    seen = _distance_map_occlusion_work(monkeypatch, _ball(occluders=[_far_box()]))
    assert seen == {"layers": 2, "shadow_test": True}


def test_distance_map_without_occluders_traces_no_occlusion_work(monkeypatch):
    """Without occluders the layered distance map holds the screen alone (one surface:
    its second layer is empty everywhere) and every caustic lands on the screen (the
    shadow test passes everywhere): both are occlusion work. Measured: the images with
    ``layers=1, shadow_test=False`` equal the defaults' exactly (icosphere ball, 17^2
    photons, 32^2 cube faces)."""
    seen = _distance_map_occlusion_work(monkeypatch, _ball())
    assert seen == {"layers": 1, "shadow_test": False}


# -------------------------------------------------- present without influence: same image


def _index_one_changes_nothing(make, method):
    off = method(make(ior=1.0))
    _close(method(make(ior=1.0, fresnel=True)), off)
    _close(off, np.ones(off.shape))


def test_fresnel_and_refraction_at_index_one_change_nothing():
    """At an index of 1 the light goes straight through (refraction without influence)
    and the Fresnel transmittance is 1: two-pass water gives the unrefracted light (1
    everywhere), Fresnel on or off."""
    _index_one_changes_nothing(_water, two_pass)


@pytest.mark.slow
def test_fresnel_and_refraction_at_index_one_change_no_lens_image():
    """The same for a lens (its screen is its aperture: 1 everywhere)."""
    _index_one_changes_nothing(_lens, triangles)


def test_fresnel_at_index_one_changes_no_exit_ray():
    """Exit rays of a glass sphere of index 1 (the rays a caustic spot-light fit and
    rendering use): the same energies with Fresnel on as off."""
    _close(exit_rays(_sphere(ior=1.0, fresnel=True)), exit_rays(_sphere(ior=1.0)))


def _tir_off(monkeypatch):
    """Trace the refraction kernel without its TIR test (`tir_possible` false)."""
    monkeypatch.setattr(_optics, "tir_possible", lambda eta: False)
    monkeypatch.setattr(twopass, "tir_possible", lambda eta: False)
    jax.clear_caches()


def test_tir_that_no_ray_reaches_changes_nothing(monkeypatch):
    """Water of index 0.95 (TIR possible beyond 72 degrees) under vertical light with
    slopes below 3 degrees, and an exact glass sphere (a path leaves at the angle it
    entered): the images (the sphere's exit rays) equal those traced without the TIR
    test, which has strictly fewer equations."""
    water, sphere = _water(ior=0.95), _sphere()
    assert water.effects.total_internal_reflection and sphere.effects.total_internal_reflection
    jax.clear_caches()
    with_tir = (two_pass(water), exit_rays(sphere))
    traced = [len(_trace(f, s)[0]) for f, s in ((two_pass, water), (exit_rays, sphere))]
    _tir_off(monkeypatch)
    without = (two_pass(water), exit_rays(sphere))
    fewer = [len(_trace(f, s)[0]) for f, s in ((two_pass, water), (exit_rays, sphere))]
    for a, b in zip(with_tir, without, strict=True):
        _close(a, b)
    assert all(f < t for f, t in zip(fewer, traced, strict=True))


def test_equal_indices_give_the_single_index_image_per_channel():
    """Dispersion without influence: ``ior=(n, n)`` gives the ``ior=n`` image in each
    channel (two-pass water), and the same exit rays for each channel (sphere)."""
    single = two_pass(_water(ior=1.333))
    pair = two_pass(_water(ior=(1.333, 1.333)))
    assert pair.shape == single.shape + (2,)
    for c in range(2):
        _close(pair[..., c], single)
    scene = _sphere(ior=(1.5, 1.5))
    one = exit_rays(_sphere(ior=1.5))
    for c in range(2):
        _close(jc.internal.trace_exit_rays(scene, 6, channel=c).energy, one)


def test_far_occluders_change_nothing():
    """Ellipsoid occluders where no light goes: the same spot-light render as without
    them; one under the lights does block (the test is not vacuous)."""
    occluded = spot_light_render(_sphere(occluders=[_far_sphere()]))
    _close(occluded, spot_light_render(_sphere()))
    assert float(jnp.sum(occluded)) > 0
    near = spot_light_render(_sphere(occluders=[jc.Ellipsoid.sphere([0.0, 0.0, 0.5], 0.1)]))
    assert float(jnp.sum(near)) < float(jnp.sum(occluded))


@pytest.mark.slow
def test_far_occluders_change_no_mesh_image():
    """A mesh occluder where no light goes: the same caustic-triangle image (exact
    visibility and the distance-map pipeline; measured equal to the last bit)."""
    for method in (triangles, distance_map):
        _close(method(_ball(occluders=[_far_box()])), method(_ball()))


def test_interfaces_no_path_needs_change_nothing():
    """A sphere's paths need two interfaces: four give the same exit rays."""
    two = jc.internal.trace_exit_rays(_sphere(interfaces=2), 6)
    four = jc.internal.trace_exit_rays(_sphere(interfaces=4), 6)
    for a, b in ((two.energy, four.energy), (two.origin, four.origin)):
        _close(a, b)
    assert float(jnp.sum(two.energy > 0)) > 0


# --------------------------------------------------------------- slow: whole images


@pytest.mark.slow
@pytest.mark.parametrize("method", [triangles, caustics_mapping, caustics_mapping_exact])
def test_fresnel_at_index_one_changes_no_mesh_image(method):
    """A glass ball of index 1, Fresnel on or off: the same caustic-triangle and caustic
    map images (image-space and exact intersections)."""
    _close(method(_ball(ior=1.0, fresnel=True)), method(_ball(ior=1.0)))


@pytest.mark.slow
def test_lens_tir_that_no_ray_reaches_changes_nothing(monkeypatch):
    """The lens's bottom face (TIR beyond 42 degrees inside glass of index 1.5) under
    vertical light and slopes below 2 degrees: the same image without the TIR test."""
    jax.clear_caches()
    image = triangles(_lens())
    _tir_off(monkeypatch)
    _close(triangles(_lens()), image)


@pytest.mark.slow
def test_equal_indices_give_the_single_index_mesh_images():
    """``ior=(n, n)`` gives the ``ior=n`` image per channel: caustic triangles and
    caustics mapping on a ball, fitted caustic spot lights on a sphere."""
    for method in (triangles, caustics_mapping):
        single = method(_ball(ior=1.5))
        pair = method(_ball(ior=(1.5, 1.5)))
        for c in range(2):
            _close(pair[..., c], single)
    scene = _sphere(ior=(1.5, 1.5))
    single = jc.internal.spot_lights(_sphere(ior=1.5), rays_per_axis=16, samples=1).image
    pair = jc.internal.spot_lights(scene, rays_per_axis=16, samples=1).image
    for c in range(2):
        _close(pair[..., c], single)


@pytest.mark.slow
def test_interfaces_no_path_needs_change_no_mesh_image():
    """A slab's paths need two interfaces: four give the same caustic-triangle image."""
    _close(triangles(_slab(interfaces=4)), triangles(_slab(interfaces=2)))
