"""Where the package's data lives: the Cassie model (``assets/cassie``) and the shipped sweeps
(``sweeps``).  An installed wheel carries them inside the package (``hlip_jax/assets/cassie``,
``hlip_jax/sweeps``, mapped there by ``pyproject.toml``); a source checkout or an editable
install keeps them at the repository's top level."""

from __future__ import annotations

import importlib.resources
from pathlib import Path

_REPO = Path(__file__).resolve().parents[2]      # hlip_jax/runtime/resources.py -> the checkout


def data_dir(*parts: str) -> Path:
    """The directory ``parts`` (e.g. ``("assets", "cassie")`` or ``("sweeps",)``): inside the
    installed package if it is there, else at the repository's top level.  Raises
    FileNotFoundError naming both places when neither exists."""
    packaged = importlib.resources.files("hlip_jax").joinpath(*parts)
    if packaged.is_dir():
        return Path(str(packaged))
    top = _REPO.joinpath(*parts)
    if top.is_dir():
        return top
    raise FileNotFoundError(f"package data {'/'.join(parts)!r} not found in {packaged} or {top}")
