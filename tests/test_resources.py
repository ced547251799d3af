"""Package data lookup (hlip_jax.runtime.resources): the Cassie model and the shipped sweeps are found
in a source checkout, and a missing directory is a clear error naming where it looked.  (The
installed-wheel case is checked by .ci/run, which installs the built wheel elsewhere.)"""

import pytest

from hlip_jax.runtime import resources


def test_checkout_finds_assets_and_sweeps():
    assets = resources.data_dir("assets", "cassie")
    assert (assets / "scene.xml").is_file() and (assets / "cassie.xml").is_file()
    sweeps = resources.data_dir("sweeps")
    assert (sweeps / "paper.toml").is_file()


def test_missing_data_names_both_places():
    with pytest.raises(FileNotFoundError, match="no_such_dir.*not found in .* or "):
        resources.data_dir("no_such_dir")
