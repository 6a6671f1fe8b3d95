"""Exploration noise: OU moments against theory, Gaussian std, masked resets, seeding, factory."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from triplesumo.algos.noise import (
    NOISE_KINDS,
    GaussianNoise,
    OrnsteinUhlenbeckNoise,
    ZeroNoise,
    make_noise,
)

torch.set_num_threads(1)


def test_ou_transient_mean_and_variance_match_ar1_theory() -> None:
    # x_t = a x_{t-1} + σ√dt ε, a = 1 - θ dt, x_0 = μ + x0_offset:
    #   E[x_t] = μ + (x_0 - μ) a^t,   Var[x_t] = σ² dt (1 - a^{2t}) / (1 - a²).
    sigma, theta, dt, mu, scale, t = 0.2, 0.15, 1e-2, 0.3, 2.0, 300
    n = 20_000
    noise = OrnsteinUhlenbeckNoise((n, 1), sigma=sigma, theta=theta, dt=dt, mu=mu, scale=scale)
    noise.load_state_dict({"x": np.full((n, 1), mu + 1.0)})
    rng = np.random.default_rng(0)
    for _ in range(t):
        x = noise.sample(rng)
    a = 1.0 - theta * dt
    mean = scale * (mu + a**t)
    var = scale**2 * sigma**2 * dt * (1 - a ** (2 * t)) / (1 - a**2)
    assert abs(x.mean() - mean) < 4 * math.sqrt(var / n)
    assert x.var() == pytest.approx(var, rel=0.04)
    # The variance with dt ignored (σ² t) would be ~1.6x larger: the test can tell them apart.
    assert abs(var / (scale**2 * sigma**2 * t * dt) - 1) > 0.2


def test_ou_stationary_variance() -> None:
    # Fast-mixing parameters so stationarity is reached quickly: θ dt = 0.5.
    sigma, theta, dt = 0.3, 0.5, 1.0
    noise = OrnsteinUhlenbeckNoise((5_000, 2), sigma=sigma, theta=theta, dt=dt)
    rng = np.random.default_rng(1)
    for _ in range(60):  # a^(2·60) ≈ 1e-36: stationary
        noise.sample(rng)
    xs = np.stack([noise.sample(rng) for _ in range(20)])
    expected = sigma**2 / (theta * (2 - theta * dt))
    assert noise.stationary_std == pytest.approx(math.sqrt(expected))
    assert xs.mean() == pytest.approx(0.0, abs=0.01)
    assert xs.var() == pytest.approx(expected, rel=0.03)
    # ... and differs from the continuous-time σ²/(2θ) by the factor 2/(2 - θ dt) = 4/3.
    assert xs.var() > 1.2 * sigma**2 / (2 * theta)


def test_ou_defaults_and_temporal_correlation() -> None:
    noise = OrnsteinUhlenbeckNoise(3)
    assert (noise.sigma, noise.theta, noise.dt, noise.scale) == (0.2, 0.15, 1e-2, 1.0)
    rng = np.random.default_rng(2)
    x1, x2 = noise.sample(rng), noise.sample(rng)
    assert x1.dtype == np.float32 and x1.shape == (3,)
    # Consecutive samples differ by one increment of std σ√dt = 0.02, far less than |x|.
    assert np.abs(x2 - x1).max() < 0.1


def test_gaussian_std_and_scale() -> None:
    noise = GaussianNoise((200, 50), scale=0.5)
    assert noise.sigma == 0.1
    x = noise.sample(np.random.default_rng(0))
    assert x.shape == (200, 50) and x.dtype == np.float32
    assert x.std() == pytest.approx(0.05, rel=0.03)
    assert abs(x.mean()) < 0.003


def test_ou_reset_mask_resets_only_masked_rows() -> None:
    noise = OrnsteinUhlenbeckNoise((4, 2), mu=0.0, theta=0.5, dt=1.0)
    rng = np.random.default_rng(0)
    for _ in range(5):
        noise.sample(rng)
    before = noise.state_dict()["x"]
    assert np.all(before != 0)
    mask = np.array([True, False, True, False])
    noise.reset(mask)
    after = noise.state_dict()["x"]
    np.testing.assert_array_equal(after[mask], 0.0)
    np.testing.assert_array_equal(after[~mask], before[~mask])
    noise.reset()
    np.testing.assert_array_equal(noise.state_dict()["x"], 0.0)
    with pytest.raises(ValueError, match="mask"):
        noise.reset(np.array([True, False]))
    with pytest.raises(ValueError, match="mask"):
        noise.reset(np.array([1, 0, 1, 0]))


def test_seeded_determinism_and_state_round_trip() -> None:
    def run(seed: int) -> np.ndarray:
        noise, rng = OrnsteinUhlenbeckNoise((2, 3)), np.random.default_rng(seed)
        return np.stack([noise.sample(rng) for _ in range(10)])

    np.testing.assert_array_equal(run(7), run(7))
    assert not np.array_equal(run(7), run(8))
    # Resume mid-way: state + generator state give the uninterrupted sequence.
    noise, rng = OrnsteinUhlenbeckNoise((2, 3)), np.random.default_rng(7)
    for _ in range(4):
        noise.sample(rng)
    resumed = OrnsteinUhlenbeckNoise((2, 3))
    resumed.load_state_dict(noise.state_dict())
    rng2 = np.random.default_rng(7)
    rng2.bit_generator.state = rng.bit_generator.state
    np.testing.assert_array_equal(resumed.sample(rng2), noise.sample(rng))
    with pytest.raises(ValueError, match="shape"):
        resumed.load_state_dict({"x": np.zeros(3)})


def test_does_not_touch_global_numpy_rng() -> None:
    # The legacy global RNG is used on purpose here, to check that noise never draws from it.
    np.random.seed(0)  # noqa: NPY002
    expected = np.random.random()  # noqa: NPY002
    np.random.seed(0)  # noqa: NPY002
    make_noise("ou", 4).sample(np.random.default_rng(0))
    make_noise("gaussian", 4).sample(np.random.default_rng(0))
    assert np.random.random() == expected  # noqa: NPY002


def test_factory() -> None:
    ou = make_noise("ou", (2, 3), sigma=0.3, theta=0.2, dt=0.05, scale=0.5)
    assert isinstance(ou, OrnsteinUhlenbeckNoise)
    assert (ou.sigma, ou.theta, ou.dt, ou.scale, ou.shape) == (0.3, 0.2, 0.05, 0.5, (2, 3))
    gauss = make_noise("gaussian", 3, sigma=0.4)
    assert isinstance(gauss, GaussianNoise) and gauss.sigma == 0.4
    none = make_noise("none", (2, 3))
    assert isinstance(none, ZeroNoise)
    np.testing.assert_array_equal(none.sample(np.random.default_rng(0)), np.zeros((2, 3)))
    with pytest.raises(ValueError, match="'ou', 'gaussian', 'none'") as info:
        make_noise("brownian", 3)
    assert "brownian" in str(info.value)
    assert NOISE_KINDS == ("ou", "gaussian", "none")


@pytest.mark.parametrize(
    ("kwargs", "field"),
    [
        ({"sigma": -0.1}, "sigma"),
        ({"theta": 0.0}, "theta"),
        ({"dt": 0.0}, "dt"),
        ({"scale": 0.0}, "scale"),
        ({"theta": 2.0, "dt": 1.0}, "theta \\* dt"),
    ],
)
def test_ou_parameter_validation(kwargs: dict[str, float], field: str) -> None:
    with pytest.raises(ValueError, match=field):
        OrnsteinUhlenbeckNoise(3, **kwargs)


@pytest.mark.parametrize("shape", [0, (2, 0), (1, 2, 3), ()])
def test_shape_validation(shape: int | tuple[int, ...]) -> None:
    with pytest.raises(ValueError, match="shape"):
        GaussianNoise(shape)
