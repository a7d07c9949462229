"""Differentiate a caustic image with respect to the water surface.

`jaxcaustics.render` is a differentiable JAX function: `jax.grad` of any loss on the
image gives the derivative with respect to every height sample. Here the target is a
blurred copy of the caustics of a rippled surface (softer caustics), and a few steps of
plain gradient descent on the heights bring the image closer to it.
Run: ``python examples/gradient_of_caustic.py`` (a few seconds).
"""

import jax
import jax.numpy as jnp
import numpy as np

import jaxcaustics as jc

extent = (0.0, 1.0, 0.0, 0.75)  # metres
shape = (48, 64)  # (rows, cols) of both the height field and the caustic map
light = jc.DirectionalLight.from_angles(20.0, 30.0)
floor = jc.PlaneReceiver(extent, shape)


def caustics(heights):
    """The caustic image of water `heights` (metres) 0.3 m above the floor."""
    scene = jc.WaterScene(jc.HeightField(heights, extent), light, floor, rest_depth=0.3)
    # Under jax.grad / jax.jit the window must be given as integers, not "auto".
    return jc.render(scene, "twopass", samples_x=5, channels_y=4)


def blur(image, sigma):
    """Periodic Gaussian blur (sigma in pixels) with NumPy's FFT."""
    fy, fx = np.fft.fftfreq(image.shape[0]), np.fft.fftfreq(image.shape[1])
    kernel = np.exp(-2 * (np.pi * sigma) ** 2 * (fy[:, None] ** 2 + fx[None, :] ** 2))
    return np.real(np.fft.ifft2(np.fft.fft2(image) * kernel))


heights = jc.wave_heights(
    shape, extent, amplitude=0.001, depth=0.3, wavelength_range=(0.1, 0.5), seed=3
)
target = jnp.asarray(blur(np.asarray(caustics(heights)), sigma=2.0))


def loss(heights):
    return jnp.mean((caustics(heights) - target) ** 2)


# One compiled function gives the loss and its gradient with respect to all 48 x 64
# heights (reverse mode: about the cost of a few renders).
loss_and_grad = jax.jit(jax.value_and_grad(loss))
learning_rate = 3e-4  # m^2: the loss is unitless, its gradient is per metre of height
for step in range(6):
    value, grad = loss_and_grad(heights)
    steepest = float(jnp.abs(grad).max())
    print(f"step {step}: loss {float(value):.4e}, largest |d loss / d height| {steepest:.3g} /m")
    heights = heights - learning_rate * grad

scene = jc.WaterScene(jc.HeightField(heights, extent), light, floor, rest_depth=0.3)
_, stats = jc.render(scene, return_stats=True, samples_x=5, channels_y=4)
print(f"missed flux after the steps: {100 * float(stats['missed_flux_fraction'][0]):.3g}%")
