"""Where rendered files go in a results directory: ``videos/INDEX_NAME.mp4`` (a scenario's
video) and ``videos/INDEX_NAME_strip.png`` (its snapshot strip, one frame per simulated
second), NAME the scenario's name as a file-name slug (:func:`hlip_jax.sweepio.sweep.file_slug`).
``hlip-sweep render`` writes its default output there, ``hlip-sweep run --render`` both, and
the report shows what it finds (:func:`index_of` reads the index back)."""

from __future__ import annotations

from pathlib import Path

VIDEOS = "videos"
STRIP = "_strip"


def stem(index: int, name: str) -> str:
    """``INDEX_NAME`` of scenario ``index`` named ``name``."""
    from hlip_jax.sweepio import sweep
    return f"{index}_{sweep.file_slug(name)}"


def video(out_dir, index: int, name: str) -> Path:
    """The scenario's video in results directory ``out_dir``."""
    return Path(out_dir) / VIDEOS / f"{stem(index, name)}.mp4"


def strip(out_dir, index: int, name: str) -> Path:
    """The scenario's snapshot strip in results directory ``out_dir``."""
    return Path(out_dir) / VIDEOS / f"{stem(index, name)}{STRIP}.png"


def index_of(path) -> int | None:
    """The scenario index a file of :data:`VIDEOS` is named with (None: not one of ours)."""
    head = Path(path).stem.split("_", 1)[0]
    return int(head) if head.isdigit() else None
