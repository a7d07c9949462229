"""Optics core: Snell's law, reflection, Fresnel, and finiteness at TIR and grazing."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import jaxcaustics as jc


def _incident(theta):
    """Unit direction travelling down at angle `theta` from the normal +z, in the xz plane."""
    return jnp.array([np.sin(theta), 0.0, -np.cos(theta)])


UP = jnp.array([0.0, 0.0, 1.0])


@settings(max_examples=50, deadline=None)
@given(theta=st.floats(0.0, 1.5), eta=st.floats(0.3, 3.0))
def test_refract_obeys_snell(theta, eta):
    t, tir = jc.internal.refract(_incident(theta), UP, eta)
    sin_t2 = eta**2 * np.sin(theta) ** 2
    assert bool(tir) == (sin_t2 > 1.0)
    np.testing.assert_allclose(float(jnp.linalg.norm(t)), 1.0, atol=1e-12)
    if not tir:
        # tangential component scaled by eta, still travelling down, in the plane of incidence
        np.testing.assert_allclose(float(t[0]), eta * np.sin(theta), atol=1e-12)
        assert float(t[1]) == 0.0 and float(t[2]) <= 0.0
    else:
        np.testing.assert_allclose(
            np.asarray(t), np.asarray(jc.internal.reflect(_incident(theta), UP))
        )


def test_refract_flips_a_normal_on_the_wrong_side():
    d = _incident(0.4)
    t1, _ = jc.internal.refract(d, UP, 0.75)
    t2, _ = jc.internal.refract(d, -UP, 0.75)
    np.testing.assert_allclose(np.asarray(t1), np.asarray(t2))


def test_reflect_mirror():
    r = jc.internal.reflect(_incident(0.3), UP)
    np.testing.assert_allclose(np.asarray(r), [np.sin(0.3), 0.0, np.cos(0.3)], atol=1e-15)


def test_fresnel_known_values():
    n = 1.5
    normal = float(jc.internal.fresnel_transmittance(jnp.array(1.0), 1 / n))
    np.testing.assert_allclose(normal, 1 - ((n - 1) / (n + 1)) ** 2, rtol=1e-12)
    # Brewster angle: p-polarised reflectance vanishes, so R = R_s / 2
    tb = np.arctan(n)
    cos_t = np.sqrt(1 - (np.sin(tb) / n) ** 2)
    rs = ((np.cos(tb) - n * cos_t) / (np.cos(tb) + n * cos_t)) ** 2
    got = float(jc.internal.fresnel_transmittance(jnp.array(np.cos(tb)), 1 / n))
    np.testing.assert_allclose(got, 1 - rs / 2, rtol=1e-12)
    assert float(jc.internal.fresnel_transmittance(jnp.array(0.0), 1 / n)) == 0.0  # grazing
    assert float(jc.internal.fresnel_transmittance(jnp.array(0.2), 1.5)) == 0.0  # TIR


def test_fresnel_is_symmetric_in_direction():
    """Stokes reciprocity: the transmittance is the same both ways through an interface."""
    n, theta = 1.333, 0.6
    cos_t = np.sqrt(1 - (np.sin(theta) / n) ** 2)
    a = float(jc.internal.fresnel_transmittance(jnp.array(np.cos(theta)), 1 / n))
    b = float(jc.internal.fresnel_transmittance(jnp.array(cos_t), n))
    np.testing.assert_allclose(a, b, rtol=1e-12)


@pytest.mark.parametrize("dtype", [jnp.float32, jnp.float64])
@pytest.mark.parametrize("eta", [1 / 1.333, 1.333])
def test_values_and_gradients_finite_everywhere(dtype, eta):
    """Across normal, critical, beyond-critical and exactly grazing incidence."""
    crit = np.arcsin(1 / eta) if eta > 1 else np.pi / 2
    thetas = jnp.asarray([0.0, 0.5, crit, crit + 1e-7, 1.2, np.pi / 2], dtype=dtype)

    def total(theta):
        d = jnp.stack([jnp.sin(theta), 0.0 * theta, -jnp.cos(theta)])
        t, _ = jc.internal.refract(d, UP.astype(dtype), eta)
        return jnp.sum(t) + jc.internal.fresnel_transmittance(jnp.cos(theta), eta)

    values = jax.vmap(total)(thetas)
    grads = jax.vmap(jax.grad(total))(thetas)
    assert values.dtype == dtype
    assert bool(jnp.all(jnp.isfinite(values))) and bool(jnp.all(jnp.isfinite(grads)))
