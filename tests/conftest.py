"""Shared test fixtures."""

import jax
import pytest


@pytest.fixture
def float64():
    """Run the test with JAX's float64 enabled (restored afterwards)."""
    old = jax.config.jax_enable_x64
    jax.config.update("jax_enable_x64", True)
    try:
        yield
    finally:
        jax.config.update("jax_enable_x64", old)
